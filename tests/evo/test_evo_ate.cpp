// The run summary's ATE, reproduced from the written files by code of this
// test's own, the way a third-party tool (evo's `evo_ape tum ground_truth.tum
// EST --align`, or the TUM benchmark's evaluate_ate.py) computes it:
//
//   1. read both TUM files, skipping '#' comment lines (the frame headers);
//   2. pair poses by time stamp: each reference pose with the estimate whose
//      stamp is nearest, if within 0.01 s (evo's default max_diff);
//   3. align the estimate's positions to the reference's by the least-squares
//      rigid motion in the plane (Umeyama 1991 without scale: SVD of the
//      2 × 2 cross-covariance, a reflection excluded by the sign of det);
//   4. ATE RMSE = sqrt(mean |R p_est + t − p_ref|²).
//
// The estimate file is the one summary.yaml names (estimate_file):
// trajectory.tum, or trajectory_<sensor>.tum when the ground truth is of a
// sensor (Victoria Park: the GPS antenna with the laser, not the rear axle).
// The figure must equal summary.yaml's ate_rmse_m to 1e-6 relative: the files
// carry positions to 1e-9 m and the summary 12 significant digits.
//
// Each configuration runs through the `mspace` binary as a user runs it,
// shortened with --max-steps where that keeps the run to a few seconds (the
// comparison is as strict on a shorter run).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>
#include <yaml-cpp/yaml.h>

#include "build_path.hpp"

namespace {

namespace fs = std::filesystem;

struct TumPose {
  double t = 0.0;
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();
};

struct TumFile {
  std::vector<std::string> comments;  ///< the '#' lines
  std::vector<TumPose> poses;
};

TumFile read_tum(const fs::path& file) {
  TumFile out;
  std::ifstream in(file);
  EXPECT_TRUE(in.good()) << "cannot read " << file;
  for (std::string line; std::getline(in, line);) {
    if (line.empty()) continue;
    if (line[0] == '#') {
      out.comments.push_back(line);
      continue;
    }
    std::istringstream s(line);
    double v[8];
    for (double& x : v) s >> x;
    EXPECT_FALSE(s.fail()) << file << ": not 8 numbers: " << line;
    out.poses.push_back({v[0], {v[1], v[2]}});
  }
  return out;
}

struct Ape {
  std::size_t pairs = 0;
  double rmse = 0.0;
};

/// Steps 2–4 of the file comment.
Ape ape(const std::vector<TumPose>& reference, const std::vector<TumPose>& estimate) {
  constexpr double kMaxDiff = 0.01;  // s, evo's default
  std::vector<Eigen::Vector2d> ref, est;
  for (const TumPose& r : reference) {
    auto it = std::lower_bound(estimate.begin(), estimate.end(), r.t,
                               [](const TumPose& p, double t) { return p.t < t; });
    const TumPose* best = nullptr;
    if (it != estimate.end()) best = &*it;
    if (it != estimate.begin() && (best == nullptr || r.t - (it - 1)->t < best->t - r.t)) best = &*(it - 1);
    if (best == nullptr || std::abs(best->t - r.t) > kMaxDiff) continue;
    ref.push_back(r.xy);
    est.push_back(best->xy);
  }
  Ape out;
  out.pairs = ref.size();
  if (ref.empty()) return out;
  const double n = static_cast<double>(ref.size());
  Eigen::Vector2d mr = Eigen::Vector2d::Zero(), me = Eigen::Vector2d::Zero();
  for (std::size_t i = 0; i < ref.size(); ++i) mr += ref[i], me += est[i];
  mr /= n, me /= n;
  Eigen::Matrix2d sigma = Eigen::Matrix2d::Zero();  // Umeyama's Σ_xy = 1/n Σ (ref − μ_r)(est − μ_e)ᵀ
  for (std::size_t i = 0; i < ref.size(); ++i) sigma += (ref[i] - mr) * (est[i] - me).transpose();
  sigma /= n;
  const Eigen::JacobiSVD<Eigen::Matrix2d> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix2d S = Eigen::Matrix2d::Identity();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0) S(1, 1) = -1.0;
  const Eigen::Matrix2d R = svd.matrixU() * S * svd.matrixV().transpose();
  const Eigen::Vector2d t = mr - R * me;
  double sq = 0.0;
  for (std::size_t i = 0; i < ref.size(); ++i) sq += (R * est[i] + t - ref[i]).squaredNorm();
  out.rmse = std::sqrt(sq / n);
  return out;
}

bool contains(const std::vector<std::string>& lines, const std::string& text) {
  return std::any_of(lines.begin(), lines.end(), [&](const std::string& l) { return l.find(text) != std::string::npos; });
}

/// Runs `config` with `mspace run` into EVO_OUT/<config> and checks the ATE.
void check(const std::string& config, long max_steps) {
  const fs::path out = fs::path(EVO_OUT) / config;
  fs::remove_all(out);
  std::ostringstream cmd;
  cmd << "cd '" << MSPACE_SOURCE_DIR << "' && '" << MSPACE_EXE << "' run config/" << config << ".yaml --out '"
      << out.string() << "' --log-level warn";
  if (max_steps > 0) cmd << " --max-steps " << max_steps;
  cmd << " > '" << (fs::path(EVO_OUT) / (config + ".log")).string() << "' 2>&1";
  fs::create_directories(EVO_OUT);
  ASSERT_EQ(std::system(cmd.str().c_str()), 0) << cmd.str() << " failed; see " << config << ".log";

  const YAML::Node summary = YAML::LoadFile((out / "summary.yaml").string());
  ASSERT_TRUE(summary["ground_truth"]) << config << ": the summary has no ground-truth section";
  const YAML::Node gt = summary["ground_truth"];
  const std::string estimate_file = gt["estimate_file"].as<std::string>();
  const double printed = gt["ate_rmse_m"].as<double>();
  const auto compared = gt["poses_compared"].as<std::size_t>();

  const TumFile reference = read_tum(out / "ground_truth.tum");
  const TumFile estimate = read_tum(out / estimate_file);
  const TumFile robot = read_tum(out / "trajectory.tum");
  // Every pose file says which body frame and which frame it is in.
  for (const TumFile* f : {&reference, &estimate, &robot}) {
    EXPECT_TRUE(contains(f->comments, "# t x y z qx qy qz qw"));
    EXPECT_TRUE(contains(f->comments, "frame"));
  }
  EXPECT_TRUE(contains(robot.comments, "poses of the robot frame"));
  EXPECT_TRUE(contains(robot.comments, "map frame"));
  EXPECT_TRUE(contains(reference.comments, "reference poses"));

  const Ape mine = ape(reference.poses, estimate.poses);
  std::cout << config << ": " << estimate_file << " vs ground_truth.tum: " << mine.pairs << " pairs, ATE "
            << mine.rmse << " m; summary " << compared << " pairs, " << printed << " m\n";
  if (estimate_file != "trajectory.tum")
    std::cout << "  (trajectory.tum, the robot frame, against the same reference: " << ape(reference.poses, robot.poses).rmse
              << " m)\n";
  EXPECT_EQ(mine.pairs, compared);
  ASSERT_GT(mine.pairs, 10u);
  EXPECT_NEAR(mine.rmse, printed, 1e-6 * printed) << config;
}

/// ../shared/datasets/<name> beside the source tree, or $MSPACE_DATA/<name>.
bool have_data(const std::string& name) {
  const char* env = std::getenv("MSPACE_DATA");
  const fs::path base =
      env != nullptr && *env != '\0' ? fs::path(env) : fs::path(MSPACE_SOURCE_DIR).parent_path() / "shared" / "datasets";
  return fs::exists(base / name);
}

TEST(EvoAte, sim_points) { check("sim_points", 1500); }

TEST(EvoAte, intel_walls) {
  if (!have_data("intel_lab")) GTEST_SKIP() << "Intel Research Lab data not found (../shared/datasets/intel_lab)";
  check("intel_walls", 0);
}

TEST(EvoAte, victoria_park) {
  if (!have_data("victoria_park")) GTEST_SKIP() << "Victoria Park data not found (../shared/datasets/victoria_park)";
  check("victoria_park", 20000);
}

void check_ceiling(const std::string& config) {
  if (!fs::exists(fs::path(EVO_CEILING_ROUTE) / "groundtruth.tum"))
    GTEST_SKIP() << "no rendered ceiling route in " << EVO_CEILING_ROUTE << " (CTest fixture render_ceiling_route)";
  setenv("MSPACE_CEILING", EVO_CEILING_ROUTE, 1);
  check(config, 400);
}

TEST(EvoAte, ceiling_lamps) { check_ceiling("ceiling_lamps"); }
TEST(EvoAte, ceiling_lines) { check_ceiling("ceiling_lines"); }
TEST(EvoAte, ceiling_both) { check_ceiling("ceiling_both"); }
TEST(EvoAte, ceiling_fused) { check_ceiling("ceiling_fused"); }

TEST(EvoAte, sim_building) {
  if (!fs::exists(fs::path(EVO_BUILDING) / "building.clf"))
    GTEST_SKIP() << "no generated building in " << EVO_BUILDING << " (CTest fixture evo_sim_building_data)";
  setenv("MSPACE_SIM_BUILDING", EVO_BUILDING, 1);
  check("sim_building", 600);
}

}  // namespace
