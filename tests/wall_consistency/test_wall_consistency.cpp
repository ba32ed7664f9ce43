// Consistency of the wall feature (T-RO §IV-F) through the real kernel and
// EKF.
//
// Walls are placed relative to the robot, so once they are in the map nothing
// can tell the filter more about the robot's absolute pose (x, y, heading)
// than it knew at that moment: the global motion of robot and map together is
// unobservable. The tests below establish, in order:
//  1. with exact data (every linearisation point is the truth) the heading
//     variance never falls below its value when the first wall entered, and
//     with noisy data from an exact line sensor the robot NEES is in its band:
//     the wall's B, B̃ (anchor), innovation Jacobians, extension Jacobians and
//     the kernel's chaining of them are right;
//  2. in the laser room every linearised observation annihilates the global
//     motion at its own linearisation point (|J U|² ≈ 1e-24): no update takes
//     information along it;
//  3. yet the plain EKF loses the unobservable rotation between updates,
//     because the estimate moves (walls rotate) and the global-motion
//     directions at the new estimate differ from those the covariance keeps
//     uninformed — the classic EKF-SLAM linearisation inconsistency, made
//     severe here by line measurements that are millimetre precise; the ekf's
//     observability-constrained mode (`observability_constrained: true`, Huang,
//     Mourikis & Roumeliotis, IJRR 2010), which carries those directions with
//     the covariance from the kernel's set_unobservable at the start, is
//     consistent.
#include <gtest/gtest.h>

#include <dlfcn.h>

#include <Eigen/Dense>
#include <cmath>
#include <iostream>
#include <map>
#include <numbers>
#include <string>
#include <vector>

#include "build_path.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "mspace/estimator.hpp"
#include "plugin_registry.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

constexpr double kDeg = std::numbers::pi / 180.0;

// ---------------------------------------------------------------- scripted world

struct Script {
  int walls = 2;
  double odometry_noise = 0.0;   ///< scale of the drawn odometry noise
  double rho_sigma = 0.0;        ///< noise added to ρ (m); declared σ is 0.01 m
  double alpha_sigma_deg = 0.0;  ///< noise added to α (deg); declared σ is 0.5°
  int seed = 1;
};

std::string noise_model_yaml() {
  return R"(
  xy_noise_per_m: 0.05
  xy_noise_floor: 0.005
  theta_noise_per_rad: 0.05
  theta_noise_per_m: 2.0
  theta_noise_floor: 0.2)";
}

std::string script_config(const Script& s) {
  return R"(
run: {name: wall_consistency}
source:
  plugin: wall_script
  seed: )" + std::to_string(s.seed) + R"(
  walls: )" + std::to_string(s.walls) + R"(
  still: 5
  turn: 20
  turn_deg: 5
  move: 20
  move_m: 0.05
  odometry_noise: )" + std::to_string(s.odometry_noise) + R"(
  rho_sigma: )" + std::to_string(s.rho_sigma) + R"(
  alpha_sigma_deg: )" + std::to_string(s.alpha_sigma_deg) + noise_model_yaml() + R"(
motion:
  plugin: odometry2d)" + noise_model_yaml() + R"(
estimator: {plugin: ekf}
features:
  wall: {plugin: wall, min_observations: 3, min_points: 30, min_length: 1.0}
sensors:
  lines:
    channel: lines
    mount: [0, 0, 0, 0, 0, 0]
    extractor: {plugin: line_pass, rho_sigma: 0.01, alpha_sigma_deg: 0.5, s_sigma: 0.05, points: 30}
    feeds: [wall]
association: {gate_probability: 0.9999, new_feature_probability: 0.99999}
)";
}

// ---------------------------------------------------------------- laser room

/// The laser_room floor and settings of tests/intel (walls up to dim 4) with
/// the given estimator instance and corner join distance (0: no corners).
std::string room_config(int seed, const std::string& estimator, double join_distance = 0.0) {
  return R"(
run: {name: laser_room}
source:
  plugin: laser_room
  seed: )" + std::to_string(seed) + R"(
  laps: 2
  step: 0.3
  range_sigma: 0.01)" + noise_model_yaml() + R"(
motion:
  plugin: odometry2d)" + noise_model_yaml() + R"(
estimator: )" + estimator + R"(
features:
  wall: {plugin: wall, min_observations: 3, min_points: 30, min_length: 1.0, max_normal_std: 0.05,
         min_end_observations: 3, max_end_spread: 0.1, max_path_distance: 15, max_observations: 40,
         match_margin: 0.5}
sensors:
  laser:
    channel: laser
    mount: [0, 0, 0, 0, 0, 0]
    extractor: {plugin: laser_lines, range_sigma: 0.01, max_range: 20, split_distance: 0.06, min_points: 10,
                min_length: 0.6, max_rms: 0.03, depth_jump: 0.2}
    feeds: [wall]
association: {gate_probability: 0.99, new_feature_probability: 0.9999, tentative_max_age: 10,
              join_distance: )" + std::to_string(join_distance) + R"(}
)";
}

// ---------------------------------------------------------------- traces

/// Per step: heading σ, robot NEES (3 dof) and walls in the map.
struct Trace {
  std::vector<double> sigma_theta, nees;
  int entered = -1;  ///< first step with a wall in the map
};

void record(const Slam& slam, Trace& tr) {
  const Eigen::MatrixXd P = slam.robot_covariance();
  const Pose6 err = pose_difference(slam.pose(), slam.ground_truth().back().pose);
  const Eigen::Vector3d e(err[kX], err[kY], err[kTheta]);
  tr.sigma_theta.push_back(std::sqrt(P(2, 2)));
  tr.nees.push_back(e.dot(P.ldlt().solve(e)));
  bool any = false;
  for (const MapFeature& f : slam.features()) any = any || f.feature->mspace_dim() > 0;
  if (tr.entered < 0 && any) tr.entered = static_cast<int>(tr.nees.size()) - 1;
}

/// Mean over runs of the per-step NEES, and the fraction of steps (from
/// `from` on) where it lies in the two-sided 95 % band of χ²(3·runs)/runs.
struct NeesSummary {
  double mean = 0.0, in_band = 0.0;
};
NeesSummary summarise(const std::vector<Trace>& runs, int from, double lo, double hi) {
  NeesSummary s;
  int steps = 0, inside = 0;
  for (std::size_t i = static_cast<std::size_t>(from); i < runs.front().nees.size(); ++i) {
    double m = 0.0;
    for (const Trace& t : runs) m += t.nees[i] / static_cast<double>(runs.size());
    s.mean += m;
    ++steps;
    inside += (m >= lo && m <= hi) ? 1 : 0;
  }
  s.mean /= steps;
  s.in_band = static_cast<double>(inside) / steps;
  return s;
}

// ---------------------------------------------------------------- global motion

/// Rows of the unobservable global motion (x, y translation; rotation about
/// the map origin) for every state index at the current estimates: the robot
/// (x, y, θ) and each feature's M-space, B · (the motion of its end points).
std::map<int, Eigen::RowVector3d> global_motion_rows(const Slam& slam) {
  std::map<int, Eigen::RowVector3d> rows;
  rows[0] = {1, 0, -slam.pose()[kY]};
  rows[1] = {0, 1, slam.pose()[kX]};
  rows[2] = {0, 0, 1};
  for (const MapFeature& f : slam.features()) {
    if (f.state_idx.empty()) continue;
    const Eigen::VectorXd x = f.feature->coords();
    Eigen::Matrix<double, 4, 3> dx;
    dx << 1, 0, -x[1], 0, 1, x[0], 1, 0, -x[3], 0, 1, x[2];
    const Eigen::MatrixXd rows_f = f.feature->B() * dx;
    for (std::size_t j = 0; j < f.state_idx.size(); ++j) rows[f.state_idx[j]] = rows_f.row(static_cast<Eigen::Index>(j));
  }
  return rows;
}

const Slam* g_slam = nullptr;
double g_max_info = 0.0;  ///< largest whitened |J U|² of any observation so far
int g_observations = 0;

void check_observations(const std::vector<LinearizedObservation>& obs) {
  const auto rows = global_motion_rows(*g_slam);
  for (const LinearizedObservation& o : obs) {
    Eigen::MatrixXd U(static_cast<Eigen::Index>(o.idx.size()), 3);
    for (std::size_t j = 0; j < o.idx.size(); ++j) U.row(static_cast<Eigen::Index>(j)) = rows.at(o.idx[j]);
    const Eigen::MatrixXd JU = o.C_eta.llt().matrixL().solve(o.J * U);
    g_max_info = std::max(g_max_info, JU.colwise().squaredNorm().maxCoeff());
    ++g_observations;
  }
}

/// The fixture library's exported C function `name`.
template <class F>
F fixture_function(const char* name) {
  const std::string path = std::string(MSPACE_WALL_FIXTURE_DIR) + "/libmspace-plugin-ekf_trace.so";
  void* lib = dlopen(path.c_str(), RTLD_NOW);
  if (!lib) throw std::runtime_error("cannot open " + path);
  return reinterpret_cast<F>(dlsym(lib, name));
}

using ObservationCallback = void (*)(const std::vector<LinearizedObservation>&);

class WallConsistency : public ::testing::Test {
 protected:
  void SetUp() override {
    registry_.add_search_dir(MSPACE_WALL_FIXTURE_DIR);
    registry_.add_search_dir(MSPACE_INTEL_FIXTURE_DIR);
    registry_.add_search_dir(MSPACE_PLUGIN_DIR);
    set_log_level(LogLevel::Warn);
  }
  void TearDown() override {
    fixture_function<void (*)(ObservationCallback)>("mspace_ekf_trace_set_callback")(nullptr);
  }

  Trace run(const std::string& yaml) {
    Slam slam(parse_config(yaml, "wall_consistency.yaml", registry_), registry_);
    g_slam = &slam;
    Trace tr;
    while (slam.step()) record(slam, tr);
    g_slam = nullptr;
    return tr;
  }

  PluginRegistry registry_;
};

/// Exact data: after the first wall entered, the heading variance never falls
/// below its value at that step (relative tolerance 1e-6 for round-off).
void expect_heading_not_learned(const Trace& tr) {
  ASSERT_GE(tr.entered, 0) << "no wall entered the map";
  const double at_entry = tr.sigma_theta[static_cast<std::size_t>(tr.entered)];
  for (std::size_t i = static_cast<std::size_t>(tr.entered); i < tr.sigma_theta.size(); ++i)
    EXPECT_GE(tr.sigma_theta[i], at_entry * (1.0 - 1e-6))
        << "step " << i << ": heading σ " << tr.sigma_theta[i] / kDeg << "° below " << at_entry / kDeg
        << "° when the first wall entered (step " << tr.entered << ")";
}

// 1. ------------------------------------------------------------------------

// Measured: the walls enter at step 2 with heading σ 0.283°; σ then grows
// to 0.559° while turning and settles at 0.527° while creeping.
TEST_F(WallConsistency, OneWallExactDataTeachesNoHeading) {
  Script s;
  s.walls = 1;
  expect_heading_not_learned(run(script_config(s)));
}

TEST_F(WallConsistency, TwoWallsExactDataTeachNoHeading) { expect_heading_not_learned(run(script_config(Script{}))); }

// 50 seeds with odometry noise as modelled and (ρ, α) noise as declared.
// Band of the 50-run mean of a 3-dof NEES: χ²(150)/50 ∈ [2.34, 3.73].
// Measured: mean 2.80, 95 % of the steps after entry inside the band.
TEST_F(WallConsistency, NoisyTurnAndCreepIsConsistent) {
  std::vector<Trace> runs;
  for (int seed = 1; seed <= 50; ++seed) {
    Script s;
    s.odometry_noise = 1.0;
    s.rho_sigma = 0.01;
    s.alpha_sigma_deg = 0.5;
    s.seed = seed;
    runs.push_back(run(script_config(s)));
  }
  const NeesSummary n = summarise(runs, runs.front().entered + 1, 2.34, 3.73);
  std::cout << "turn and creep, 50 seeds: mean NEES " << n.mean << ", " << 100.0 * n.in_band << " % in band\n";
  EXPECT_GT(n.mean, 2.34);
  EXPECT_LT(n.mean, 3.73);
  EXPECT_GE(n.in_band, 0.9);
}

// 2. ------------------------------------------------------------------------

// Every update of a laser-room run (walls at dims 2, 3 and 4), at its own
// linearisation point: measured max whitened |J U|² 5e-23 over 954
// observations (an observation carrying the information of a 1° heading
// measurement would give 3283).
TEST_F(WallConsistency, RoomObservationsCarryNoGlobalMotionInformation) {
  fixture_function<void (*)(ObservationCallback)>("mspace_ekf_trace_set_callback")(&check_observations);
  g_max_info = 0.0;
  g_observations = 0;
  run(room_config(1, "{plugin: ekf_trace}"));
  std::cout << g_observations << " observations, max whitened |J U|² " << g_max_info << "\n";
  EXPECT_GT(g_observations, 900);
  EXPECT_LT(g_max_info, 1e-12);
}

// 3. ------------------------------------------------------------------------

// 20 seeds of the laser room. Band of the 20-run mean of a 3-dof NEES:
// χ²(60)/20 ∈ [2.02, 4.17]. Measured: plain ekf mean 9.78 with 9.5 % of the
// steps in the band; observability-constrained mean 3.43 with 100 % of the
// steps in the band. The bound asserted is on the constrained ekf; the plain
// ekf's numbers are printed.
constexpr const char* kConstrainedEkf = "{plugin: ekf, observability_constrained: true}";

TEST_F(WallConsistency, RoomIsConsistentWithObservabilityConstrainedEkf) {
  std::vector<Trace> plain, constrained;
  for (int seed = 1; seed <= 20; ++seed) {
    plain.push_back(run(room_config(seed, "{plugin: ekf}")));
    constrained.push_back(run(room_config(seed, kConstrainedEkf)));
  }
  const NeesSummary p = summarise(plain, 1, 2.02, 4.17), c = summarise(constrained, 1, 2.02, 4.17);
  std::cout << "laser room, 20 seeds: ekf mean NEES " << p.mean << " (" << 100.0 * p.in_band
            << " % in band), observability-constrained " << c.mean << " (" << 100.0 * c.in_band << " % in band)\n";
  EXPECT_GT(c.mean, 2.02);
  EXPECT_LT(c.mean, 4.17);
  EXPECT_GE(c.in_band, 0.95);
}

// The same with shared corners (join_distance 0.3 m, 12 corners per run).
// Measured: plain ekf mean 22.3 with 1 % of the steps in the band; the
// constrained ekf 3.43 with 100 % in the band — the corners themselves
// (eq. 33, turning about the corner) carry no spurious information.
TEST_F(WallConsistency, RoomWithSharedCornersIsConsistentWithObservabilityConstrainedEkf) {
  std::vector<Trace> plain, constrained;
  for (int seed = 1; seed <= 20; ++seed) {
    for (int oc = 0; oc < 2; ++oc) {
      const char* estimator = oc ? kConstrainedEkf : "{plugin: ekf}";
      (oc ? constrained : plain).push_back(run(room_config(seed, estimator, 0.3)));
    }
  }
  const NeesSummary p = summarise(plain, 1, 2.02, 4.17), c = summarise(constrained, 1, 2.02, 4.17);
  std::cout << "laser room with corners, 20 seeds: ekf mean NEES " << p.mean << " (" << 100.0 * p.in_band
            << " % in band), observability-constrained " << c.mean << " (" << 100.0 * c.in_band << " % in band)\n";
  EXPECT_GT(c.mean, 2.02);
  EXPECT_LT(c.mean, 4.17);
  EXPECT_GE(c.in_band, 0.95);
}

}  // namespace
