// Tests of the relations metric (kernel/src/relations.hpp): a synthetic
// trajectory with known errors, malformed files, and the Intel data set's
// GMapping and raw-odometry figures from its README.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>

#include "relations.hpp"

namespace mspace::kernel {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

std::vector<StampedPose> straight_line() {
  std::vector<StampedPose> poses;
  for (int i = 0; i < 5; ++i) poses.push_back({static_cast<double>(i), make_pose2d(i * 1.0, 0.5 * i, 0.3 * i)});
  return poses;
}

std::vector<Relation> consecutive_relations(const std::vector<StampedPose>& truth) {
  std::vector<Relation> out;
  for (std::size_t i = 0; i + 1 < truth.size(); ++i)
    out.push_back({truth[i].t, truth[i + 1].t, relative(truth[i].pose, truth[i + 1].pose)});
  return out;
}

TEST(Relations, PerfectTrajectoryHasNoError) {
  const auto truth = straight_line();
  const RelationErrors e = evaluate_relations(truth, consecutive_relations(truth), 0.01);
  EXPECT_EQ(e.total, 4u);
  EXPECT_EQ(e.matched, 4u);
  EXPECT_NEAR(e.translation.mean, 0.0, 1e-12);
  EXPECT_NEAR(e.rotation_deg.mean, 0.0, 1e-6);
}

// Pose 2 shifted by (0.3, 0.4): relations 1→2 and 2→3 are 0.5 m off, the
// others exact. The last pose turned by 2°: relation 3→4 is 2° off (and
// its translation exact: it is expressed in the frame of pose 3).
TEST(Relations, KnownErrors) {
  const auto truth = straight_line();
  std::vector<Relation> relations = consecutive_relations(truth);
  relations.push_back({10.0, 11.0, Pose6::Zero()});  // not on the trajectory
  auto estimate = truth;
  estimate[2].pose[kX] += 0.3;
  estimate[2].pose[kY] += 0.4;
  estimate[4].pose[kTheta] += 2.0 * kDeg;
  estimate[3].t += 0.004;  // within the tolerance
  const RelationErrors e = evaluate_relations(estimate, relations, 0.01);
  EXPECT_EQ(e.total, 5u);
  EXPECT_EQ(e.matched, 4u);
  EXPECT_NEAR(e.translation.mean, 0.25, 1e-9);
  EXPECT_NEAR(e.translation.std, 0.25, 1e-9);
  EXPECT_NEAR(e.translation_sq.mean, 0.125, 1e-9);
  EXPECT_NEAR(e.translation_sq.std, 0.125, 1e-9);
  EXPECT_NEAR(e.rotation_deg.mean, 0.5, 1e-6);
  EXPECT_NEAR(e.rotation_deg.std, std::sqrt(0.75), 1e-6);
  EXPECT_NEAR(e.rotation_sq_deg.mean, 1.0, 1e-5);
  // A tighter tolerance loses the time stamp of pose 3.
  EXPECT_EQ(evaluate_relations(estimate, relations, 0.001).matched, 2u);
}

TEST(Relations, ReadsFileAndNamesMalformedLine) {
  const auto dir = std::filesystem::temp_directory_path();
  const auto good = dir / "mspace_relations_good.txt";
  std::ofstream(good) << "# comment\n1 2 0.5 0 0 0 0 1.5\n\n3 4 0 1 0 0 0 -0.1\n";
  const auto r = read_relations(good);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_DOUBLE_EQ(r[0].delta[kX], 0.5);
  EXPECT_DOUBLE_EQ(r[0].delta[kTheta], 1.5);  // yaw is the 8th field
  const auto bad = dir / "mspace_relations_bad.txt";
  std::ofstream(bad) << "1 2 0 0 0 0 0 0\n1 2 0 0 x 0 0 0\n";
  try {
    read_relations(bad);
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("mspace_relations_bad.txt:2:"), std::string::npos) << e.what();
  }
}

/// The Intel table's time stamps with its odometry (columns 1–3) or GMapping poses (4–6).
std::vector<StampedPose> intel_trajectory(const std::filesystem::path& table, int first_column) {
  std::ifstream in(table);
  std::vector<StampedPose> out;
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream f(line);
    double v[7];
    for (double& x : v) f >> x;
    out.push_back({v[0], make_pose2d(v[first_column], v[first_column + 1], v[first_column + 2])});
  }
  return out;
}

TEST(Relations, IntelGMappingAndOdometryMatchTheReadme) {
  const std::filesystem::path dir = std::filesystem::path(MSPACE_SOURCE_DIR) / "../shared/datasets/intel_lab";
  if (!std::filesystem::exists(dir / "intel.relations") || !std::filesystem::exists(dir / "intel_910_scans.txt"))
    GTEST_SKIP() << "Intel data not found in " << dir << "; skipping";
  const auto relations = read_relations(dir / "intel.relations");
  EXPECT_EQ(relations.size(), 2984u);
  const RelationErrors gfs = evaluate_relations(intel_trajectory(dir / "intel_910_scans.txt", 4), relations, 1e-4);
  const RelationErrors odo = evaluate_relations(intel_trajectory(dir / "intel_910_scans.txt", 1), relations, 1e-4);
  std::cout << "GMapping: " << gfs.matched << " relations, " << gfs.translation.mean << " ± " << gfs.translation.std
            << " m, " << gfs.rotation_deg.mean << " ± " << gfs.rotation_deg.std << " deg\n"
            << "odometry: " << odo.translation.mean << " m, " << odo.rotation_deg.mean << " deg\n";
  EXPECT_EQ(gfs.matched, 90u);
  EXPECT_NEAR(gfs.translation.mean, 0.036, 0.0005);
  EXPECT_NEAR(gfs.rotation_deg.mean * kDeg, 0.0073, 0.00005);
  EXPECT_NEAR(odo.translation.mean, 3.31, 0.005);
  EXPECT_NEAR(odo.rotation_deg.mean * kDeg, 0.30, 0.005);
}

}  // namespace
}  // namespace mspace::kernel
