// Laser odometry: point-to-line ICP between two 2-D scans (with the
// correlative fallback), on simulated lasers of every kind in several worlds
// (tests/fixtures/laser_sim.hpp) and on the Intel scans against GMapping.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "carmen_reader.hpp"
#include "laser_sim.hpp"
#include "scan_matcher.hpp"

namespace sm = mspace::scan_matching;
namespace tl = mspace::test_laser;
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;
using tl::relative;

/// Two infinite-looking walls along x: nothing tells where along it the robot is.
tl::World plain_corridor() { return {"plain corridor", {tl::wall(-50, -1, 50, -1), tl::wall(-50, 1, 50, 1)}, {}}; }

/// The Intel-like laser: 180 beams over 180°, 1 cm noise, no mount offset.
tl::Laser intel_like(double sigma) {
  tl::Laser l;
  l.name = "intel";
  l.sigma = sigma;
  return l;
}

/// Points of a simulated scan (no-return beams dropped as the reader does).
sm::ScanPoints points(const tl::World& w, const tl::Laser& l, const Eigen::Vector3d& robot, int index,
                      std::mt19937_64& rng) {
  const tl::SimScan s = tl::simulate(w, l, robot, index, rng);
  return sm::scan_to_points(s.ranges, s.bearings, l.no_return - 1e-6);
}

TEST(ScanMatcher, RecoversAKnownMotionFromAPoorSeed) {
  std::mt19937_64 rng(7);
  const Eigen::Vector3d a(0, 0, 0.2), b(0.6, 0.25, 0.2 + 23 * kDeg);  // a typical Intel step
  const Eigen::Vector3d truth = relative(a, b);
  const tl::Laser laser = intel_like(0.01);
  const sm::ReferenceScan reference(points(tl::l_room(), laser, a, 0, rng), sm::MatchOptions{});
  // Wheel odometry errs by a few degrees and centimetres.
  const Eigen::Vector3d seed = truth + Eigen::Vector3d(0.08, -0.06, 4 * kDeg);
  const sm::MatchResult m = reference.match(points(tl::l_room(), laser, b, 1, rng), seed);
  ASSERT_TRUE(m.ok);
  EXPECT_GT(m.pairs, 80);
  EXPECT_NEAR(m.rms, 0.01, 0.005);    // the range noise
  EXPECT_NEAR(m.noise, 0.01, 0.004);  // …and the matcher's own estimate of it
  EXPECT_LT((m.increment.head<2>() - truth.head<2>()).norm(), 0.01);
  EXPECT_LT(std::abs(m.increment[2] - truth[2]), 0.2 * kDeg);
}

TEST(ScanMatcher, LeavesTheUnconstrainedDirectionOfACorridorAtTheSeedAndReportsIt) {
  std::mt19937_64 rng(3);
  const Eigen::Vector3d a(0, 0.1, 0), b(0.7, -0.1, 3 * kDeg);
  const Eigen::Vector3d truth = relative(a, b);
  const tl::Laser laser = intel_like(0.005);
  const sm::ReferenceScan reference(points(plain_corridor(), laser, a, 0, rng), sm::MatchOptions{});
  const Eigen::Vector3d seed = truth + Eigen::Vector3d(0.2, 0.05, 1 * kDeg);
  const sm::MatchResult m = reference.match(points(plain_corridor(), laser, b, 1, rng), seed);
  ASSERT_TRUE(m.ok);
  // Across the corridor and in heading the walls correct the seed...
  EXPECT_LT(std::abs(m.increment[1] - truth[1]), 0.01);
  EXPECT_LT(std::abs(m.increment[2] - truth[2]), 0.1 * kDeg);
  // ...along it nothing does: the seed's error stays (no drift invented by the solver).
  EXPECT_NEAR(m.increment[0] - truth[0], 0.2, 0.02);
  // The quality figure says so: the weakest direction of the information is
  // the corridor's axis (x of the reference frame), with next to no information,
  // and the covariance along it is the seed prior's (0.1 m)², across it far less.
  EXPECT_GT(std::abs(m.weakest_direction[0]), 0.99);
  EXPECT_LT(m.weakest_information, 1e-3 * m.information.trace());
  EXPECT_NEAR(std::sqrt(m.covariance(0, 0)), 0.1, 0.005);
  EXPECT_LT(std::sqrt(m.covariance(1, 1)), 0.01);
}

TEST(ScanMatcher, FailsWithoutOverlap) {
  std::mt19937_64 rng(5);
  const tl::Laser laser = intel_like(0.01);
  const sm::ReferenceScan reference(points(tl::l_room(), laser, {0, 0, 0}, 0, rng), sm::MatchOptions{});
  // The second scan is of another place altogether.
  const sm::MatchResult m =
      reference.match(points(plain_corridor(), laser, {0, 0, 0}, 1, rng), Eigen::Vector3d(5, 5, 0));
  EXPECT_FALSE(m.ok);
}

// The correlative search finds a motion the wheel seed is far from (0.67 m,
// 25°: beyond the heading search and the correspondence distance), where ICP
// from the seed alone fails.
TEST(ScanMatcher, CorrelativeSearchRecoversFromAFarSeed) {
  std::mt19937_64 rng(11);
  const Eigen::Vector3d a(-2, -1, 0.1), b(-1.2, -0.7, 0.1 + 35 * kDeg);
  const Eigen::Vector3d truth = relative(a, b);
  const tl::Laser laser = intel_like(0.01);
  const sm::ScanPoints previous = points(tl::l_room(), laser, a, 0, rng);
  const sm::ScanPoints current = points(tl::l_room(), laser, b, 1, rng);
  const Eigen::Vector3d seed = truth + Eigen::Vector3d(-0.5, -0.45, -25 * kDeg);
  sm::MatchOptions local_only;
  local_only.correlative = false;
  const sm::MatchResult without = sm::ReferenceScan(previous, local_only).match(current, seed);
  const sm::MatchResult m = sm::ReferenceScan(previous, sm::MatchOptions{}).match(current, seed);
  std::printf("far seed: local only %s, error %.3f m %.2f deg; with the search: correlative %d, pairs %d of %d\n",
              without.ok ? "ok" : "failed", (without.increment - truth).head<2>().norm(),
              std::abs(without.increment[2] - truth[2]) / kDeg, m.correlative ? 1 : 0, m.pairs, m.overlap);
  EXPECT_FALSE(without.ok);
  ASSERT_TRUE(m.ok);
  EXPECT_TRUE(m.correlative);
  EXPECT_LT((m.increment.head<2>() - truth.head<2>()).norm(), 0.02);
  EXPECT_LT(std::abs(m.increment[2] - truth[2]), 0.3 * kDeg);
}

// The mount: a laser 0.22 m ahead of the robot centre sees a turn on the spot
// as a sideways motion; LaserOdometry reports the robot's motion.
TEST(LaserOdometry, MountedLaserGivesRobotMotion) {
  const Eigen::Vector3d mount(0.22, 0.03, 2 * kDeg);
  const sm::LaserOdometry odo(mount, sm::MatchOptions{});
  const Eigen::Vector3d d_r(0.4, -0.1, 30 * kDeg);
  const Eigen::Vector3d d_l = odo.laser_increment(d_r);
  // Laser poses L = R ⊕ m: L1⁻¹ ⊕ L2 with R1 = 0, R2 = d_r.
  const Eigen::Vector3d expected = sm::compose(sm::inverse(mount), sm::compose(d_r, mount));
  EXPECT_LT((d_l - expected).norm(), 1e-12);
  Eigen::Matrix3d J;
  EXPECT_LT((odo.robot_increment(d_l, &J) - d_r).norm(), 1e-12);
  // Jacobian against central differences.
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d h = Eigen::Vector3d::Zero();
    h[k] = 1e-6;
    const Eigen::Vector3d numeric = (odo.robot_increment(d_l + h) - odo.robot_increment(d_l - h)) / 2e-6;
    EXPECT_LT((J.col(k) - numeric).norm(), 1e-8) << "column " << k;
  }
  // On simulated scans: a turn on the spot, laser 0.22 m ahead.
  std::mt19937_64 rng(2);
  tl::Laser laser = intel_like(0.01);
  laser.mount_x = 0.22;
  const sm::LaserOdometry mounted({0.22, 0, 0}, sm::MatchOptions{});
  const Eigen::Vector3d a(0, 0, 0), b(0, 0, 40 * kDeg);
  const sm::OdometryResult r = mounted.match(points(tl::l_room(), laser, a, 0, rng),
                                             points(tl::l_room(), laser, b, 1, rng), Eigen::Vector3d(0.03, 0.02, 0.6));
  ASSERT_TRUE(r.match.ok);
  EXPECT_LT(r.increment.head<2>().norm(), 0.01);  // the robot did not move…
  EXPECT_NEAR(r.increment[2], 40 * kDeg, 0.2 * kDeg);
  EXPECT_GT(r.match.increment.head<2>().norm(), 0.1);  // …the laser did
}

// A box (0.4 m, a person's size) moving along a plain corridor at 0.2 m per
// scan while the robot drives 0.1 m, 1 m ahead: the walls say nothing along the
// corridor, so the box's points drag the match with them (by its 0.2 m, less
// what the weak seed prior holds back). Two remedies, each enough here: the
// seed's real uncertainty with the consistency check (the match moved
// further from the seed than σ = 1 cm allows; the tight match from the seed
// leaves the box, 0.2 m off, unpaired), and dropping the reference points
// that the scan before did not see there (the box's).
TEST(ScanMatcher, AMovingBoxInACorridorNeitherDragsTheCheckedNorTheFilteredMatch) {
  auto world_at = [](double box_x) {
    tl::World w = plain_corridor();
    w.walls.push_back(tl::wall(box_x, -0.2, box_x + 0.4, -0.2));
    w.walls.push_back(tl::wall(box_x + 0.4, -0.2, box_x + 0.4, 0.2));
    w.walls.push_back(tl::wall(box_x + 0.4, 0.2, box_x, 0.2));
    w.walls.push_back(tl::wall(box_x, 0.2, box_x, -0.2));
    return w;
  };
  std::mt19937_64 rng(5);
  const tl::Laser laser = intel_like(0.01);
  const sm::ScanPoints older = points(world_at(1.0), laser, {0.0, 0.0, 0.0}, 0, rng);
  const sm::ScanPoints previous = points(world_at(1.2), laser, {0.1, 0.0, 0.0}, 1, rng);
  const sm::ScanPoints current = points(world_at(1.4), laser, {0.2, 0.0, 0.0}, 2, rng);
  const Eigen::Vector3d truth(0.1, 0.0, 0.0), seed = truth;  // an exact wheel seed

  const sm::MatchOptions defaults;
  const sm::MatchResult dragged = sm::ReferenceScan(previous, defaults).match(current, seed);
  sm::MatchOptions checked = defaults;
  checked.seed_sigma_xy = 0.01;
  checked.seed_sigma_theta = 0.01;
  checked.seed_gate = 16.27;
  const sm::MatchResult check = sm::ReferenceScan(previous, checked).match(current, seed);
  sm::ReferenceScan filtered(previous, defaults);
  const int dropped = filtered.drop_moving(older, {-0.1, 0.0, 0.0});
  const sm::MatchResult filter = filtered.match(current, seed);
  std::printf("along the corridor: defaults %.3f m, checked %.4f m (disagreed %d), filtered %.4f m (%d dropped)\n",
              dragged.increment[0] - truth[0], check.increment[0] - truth[0], check.disagreed ? 1 : 0,
              filter.increment[0] - truth[0], dropped);
  ASSERT_TRUE(dragged.ok);
  EXPECT_GT(std::abs(dragged.increment[0] - truth[0]), 0.1);
  ASSERT_TRUE(check.ok);
  EXPECT_TRUE(check.disagreed);
  EXPECT_LT((check.increment - truth).head<2>().norm(), 0.01);
  EXPECT_GT(dropped, 5);
  // Without the box nothing but the weak default prior (σ 0.1 m) holds the
  // match along the plain corridor: a few cm of slack (measured 3.1 cm), not
  // the box's 0.2 m.
  ASSERT_TRUE(filter.ok);
  EXPECT_LT((filter.increment - truth).head<2>().norm(), 0.05);
}

// ---- The sweep: lasers × worlds × logging rates ------------------------------

struct Motion {
  const char* name;
  double speed, turn_rate, dt;
};
const Motion kMotions[] = {{"0.3 m/s 30°/s every 0.1 s", 0.3, 30 * kDeg, 0.1},
                           {"0.6 m/s 60°/s every 0.6 s", 0.6, 60 * kDeg, 0.6},
                           {"1 m/s 60°/s every 2 s", 1.0, 60 * kDeg, 2.0}};

std::vector<tl::Laser> lasers() {
  std::vector<tl::Laser> out;
  tl::Laser l;
  l = {};
  l.name = "180x1deg_80m";  // SICK LMS as in the Intel data
  l.max_range = 80.0;
  out.push_back(l);
  l = {};
  l.name = "181x1deg_interleaved_12pc_noreturn_clutter_mount";  // the log
  l.beams = 181;
  l.clutter = 0.05;
  l.quantum = 0.01;
  l.interleave = 0.25 * kDeg;
  l.interleave_phases = 4;
  l.max_range = 80.0;
  l.dropout = 0.12;
  l.sigma = 0.02;
  l.mount_x = 0.22;
  out.push_back(l);
  l = {};
  l.name = "360x0.5deg_30m_3cm_mount";
  l.beams = 360;
  l.resolution = 0.5 * kDeg;
  l.sigma = 0.03;
  l.mount_x = 0.22;
  out.push_back(l);
  l = {};
  l.name = "541x0.5deg_270fov_30m";
  l.beams = 541;
  l.resolution = 0.5 * kDeg;
  l.start = -135 * kDeg;
  l.dropout = 0.05;
  out.push_back(l);
  l = {};
  l.name = "1080x0.25deg_270fov_80m_mount";
  l.beams = 1080;
  l.resolution = 0.25 * kDeg;
  l.start = -135 * kDeg;
  l.max_range = 80.0;
  l.sigma = 0.02;
  l.mount_x = 0.22;
  out.push_back(l);
  l = {};
  l.name = "181x1deg_8m_3cm_interleaved";
  l.beams = 181;
  l.interleave = 0.25 * kDeg;
  l.interleave_phases = 4;
  l.max_range = 8.0;
  l.no_return = 8.0;
  l.sigma = 0.03;
  out.push_back(l);
  return out;
}

std::vector<tl::World> worlds() { return {tl::office_floor(), tl::l_room(), tl::corridor(), tl::hall()}; }

/// Wheel odometry noise, like the Intel robot's (5 cm, 2.6° median on 0.67 m /
/// 23° steps): σ_xy = 0.05 d + 1 cm, σ_θ = 0.05 |dθ| + 1°/m d + 0.5°.
Eigen::Vector3d wheel_noise(const Eigen::Vector3d& truth, std::mt19937_64& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  const double d = truth.head<2>().norm();
  const double sxy = 0.05 * d + 0.01, sth = 0.05 * std::abs(truth[2]) + 1.0 * kDeg * d + 0.5 * kDeg;
  return {sxy * n(rng), sxy * n(rng), sth * n(rng)};
}

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const auto k = static_cast<std::size_t>(std::min<double>(static_cast<double>(v.size()) - 1, q * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

struct SweepFigures {
  int increments = 0, matched = 0, correlative = 0;
  std::vector<double> wheel_xy, wheel_th, laser_xy, laser_th;
  std::vector<double> nees;  ///< eᵀ C⁻¹ e of the matched increments (3 dof: 3 if C is right)
};

/// At most `limit` increments per motion, evenly spread over the route (turns
/// and straights alike).
SweepFigures sweep(const tl::Laser& laser, const tl::World& world, int limit, unsigned seed) {
  SweepFigures f;
  std::mt19937_64 rng(seed);
  const sm::LaserOdometry odo({laser.mount_x, 0.0, 0.0}, sm::MatchOptions{});
  for (const Motion& motion : kMotions) {
    const std::vector<Eigen::Vector3d> poses = tl::drive(world, motion.speed, motion.turn_rate, motion.dt);
    const int n = static_cast<int>(poses.size()) - 1;
    const int count = std::min(n, limit);
    for (int c = 0; c < count; ++c) {
      const int i = static_cast<int>(static_cast<long>(c) * n / count);
      const Eigen::Vector3d truth = relative(poses[static_cast<std::size_t>(i)], poses[static_cast<std::size_t>(i + 1)]);
      const Eigen::Vector3d wheel = truth + wheel_noise(truth, rng);
      const sm::ScanPoints previous = points(world, laser, poses[static_cast<std::size_t>(i)], i, rng);
      const sm::ScanPoints current = points(world, laser, poses[static_cast<std::size_t>(i + 1)], i + 1, rng);
      const sm::OdometryResult r = odo.match(previous, current, wheel);
      ++f.increments;
      f.matched += r.match.ok ? 1 : 0;
      f.correlative += r.match.correlative ? 1 : 0;
      f.wheel_xy.push_back((wheel - truth).head<2>().norm());
      f.wheel_th.push_back(std::abs(wheel[2] - truth[2]));
      f.laser_xy.push_back((r.increment - truth).head<2>().norm());
      f.laser_th.push_back(std::abs(std::remainder(r.increment[2] - truth[2], 2 * std::numbers::pi)));
      if (r.match.ok) {
        Eigen::Vector3d e = r.increment - truth;
        e[2] = std::remainder(e[2], 2 * std::numbers::pi);
        f.nees.push_back(e.dot(r.covariance.ldlt().solve(e)));
      }
    }
  }
  return f;
}

class LaserSweep : public ::testing::TestWithParam<int> {};

// Targets of issue 18 per laser and world: ≥ 98 % of increments matched; the
// median error ≤ 0.5 × the wheel odometry's, the 95th percentile no worse.
TEST_P(LaserSweep, MatchesAlmostAllIncrementsAndHalvesTheWheelError) {
  const tl::Laser laser = lasers()[static_cast<std::size_t>(GetParam())];
  for (const tl::World& world : worlds()) {
    if (laser.max_range < 10.0 && world.name == "hall") continue;  // nothing but pillars in 8 m of a 60 m hall
    const SweepFigures f = sweep(laser, world, 80, 17u + static_cast<unsigned>(GetParam()));
    const double matched = 100.0 * f.matched / f.increments;
    std::printf("%-42s %-9s %4d incr: matched %5.1f %% (correlative %3d) | xy median %.4f vs wheel %.4f m, "
                "p95 %.4f vs %.4f | θ median %.3f vs %.3f deg, p95 %.3f vs %.3f | NEES median %.2f\n",
                laser.name.c_str(), world.name.c_str(), f.increments, matched, f.correlative,
                quantile(f.laser_xy, 0.5), quantile(f.wheel_xy, 0.5), quantile(f.laser_xy, 0.95),
                quantile(f.wheel_xy, 0.95), quantile(f.laser_th, 0.5) / kDeg, quantile(f.wheel_th, 0.5) / kDeg,
                quantile(f.laser_th, 0.95) / kDeg, quantile(f.wheel_th, 0.95) / kDeg, quantile(f.nees, 0.5));
    EXPECT_GE(matched, 98.0) << world.name;
    EXPECT_LE(quantile(f.laser_xy, 0.5), 0.5 * quantile(f.wheel_xy, 0.5)) << world.name;
    EXPECT_LE(quantile(f.laser_th, 0.5), 0.5 * quantile(f.wheel_th, 0.5)) << world.name;
    EXPECT_LE(quantile(f.laser_xy, 0.95), quantile(f.wheel_xy, 0.95)) << world.name;
    EXPECT_LE(quantile(f.laser_th, 0.95), quantile(f.wheel_th, 0.95)) << world.name;
  }
}

INSTANTIATE_TEST_SUITE_P(Lasers, LaserSweep, ::testing::Range(0, static_cast<int>(lasers().size())),
                         [](const ::testing::TestParamInfo<int>& info) {
                           std::string name = lasers()[static_cast<std::size_t>(info.param)].name;
                           for (char& c : name)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return name;
                         });

// ---- Intel -------------------------------------------------------------------

// On the Intel scans, laser odometry against the GMapping increments: the
// figures the intel_walls configuration's motion noise is set from.
// Before issue 18's rework: 0.352° / 2.23 cm median, 0 of 909 failed.
TEST(ScanMatcher, IntelIncrementsAgainstGMapping) {
  const std::filesystem::path file =
      std::filesystem::path(MSPACE_SOURCE_DIR).parent_path() / "shared/datasets/intel_lab/intel_910_scans.txt";
  if (!std::filesystem::exists(file)) GTEST_SKIP() << "Intel Research Lab data not found at " << file;
  const auto log = mspace::carmen_log::read_log(file, {});
  ASSERT_EQ(log.scans.size(), 910u);
  std::vector<double> wheel_xy, wheel_th, laser_xy, laser_th;
  int failed = 0, correlative = 0;
  for (std::size_t i = 1; i < log.scans.size(); ++i) {
    const auto& p = log.scans[i - 1];
    const auto& c = log.scans[i];
    const Eigen::Vector3d gt = relative(*p.ground_truth, *c.ground_truth);
    const Eigen::Vector3d wheel = relative(p.odometry, c.odometry);
    const sm::ReferenceScan reference(sm::scan_to_points(p.ranges, p.bearings, 30.0), sm::MatchOptions{});
    const sm::MatchResult m = reference.match(sm::scan_to_points(c.ranges, c.bearings, 30.0), wheel);
    if (!m.ok) ++failed;
    correlative += m.correlative ? 1 : 0;
    const Eigen::Vector3d laser = m.ok ? m.increment : wheel;
    wheel_xy.push_back((wheel - gt).head<2>().norm());
    wheel_th.push_back(std::abs(std::remainder(wheel[2] - gt[2], 2 * std::numbers::pi)));
    laser_xy.push_back((laser - gt).head<2>().norm());
    laser_th.push_back(std::abs(std::remainder(laser[2] - gt[2], 2 * std::numbers::pi)));
  }
  auto rms = [](const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x * x;
    return std::sqrt(s / static_cast<double>(v.size()));
  };
  std::printf("wheel: xy rms %.4f m median %.4f m, heading rms %.3f deg median %.3f deg\n", rms(wheel_xy),
              quantile(wheel_xy, 0.5), rms(wheel_th) / kDeg, quantile(wheel_th, 0.5) / kDeg);
  std::printf("laser: xy rms %.4f m median %.4f m, heading rms %.3f deg median %.3f deg; %d matches failed, "
              "%d from the correlative search\n",
              rms(laser_xy), quantile(laser_xy, 0.5), rms(laser_th) / kDeg, quantile(laser_th, 0.5) / kDeg, failed,
              correlative);
  // Not worse than before the rework (0 failed, median 0.352° / 2.23 cm, rms
  // 0.678° / 3.87 cm): no failure, rms no larger, medians within 1 %
  // (measured after: median 0.353° / 2.23 cm, rms 0.676° / 3.86 cm).
  EXPECT_EQ(failed, 0);
  EXPECT_LE(quantile(laser_th, 0.5), 1.01 * 0.352 * kDeg);
  EXPECT_LE(quantile(laser_xy, 0.5), 1.01 * 0.0223);
  EXPECT_LE(rms(laser_th), 0.678 * kDeg);
  EXPECT_LE(rms(laser_xy), 0.0387);
}

}  // namespace

namespace {

struct IntelFigures {
  std::vector<double> xy, th;  ///< per-step errors against GMapping (m, rad)
  int failed = 0;
  double nees_mean = 0.0, nees_median = 0.0;          ///< of the matched increments' covariances
  double nees_ref_mean = 0.0, nees_ref_median = 0.0;  ///< with the reference's pose noise added
  Eigen::Vector3d lag1_correlation = Eigen::Vector3d::Zero();
};

/// Laser odometry over the Intel scans (the previous scan, plus `map_scans`
/// key scans 0.3 m apart), against the GMapping increments.
IntelFigures intel_laser_odometry(const std::vector<mspace::carmen_log::Scan>& scans, const sm::MatchOptions& options,
                                  int map_scans) {
  const sm::LaserOdometry odometry(Eigen::Vector3d::Zero(), options);
  sm::LocalMapOptions map_options;
  map_options.scans = map_scans;
  map_options.key_distance = 0.3;
  sm::LocalMap map(odometry, map_options);
  auto points_of = [](const mspace::carmen_log::Scan& s) { return sm::scan_to_points(s.ranges, s.bearings, 30.0); };
  Eigen::Vector3d pose = scans[0].odometry;
  map.add(0, points_of(scans[0]), pose);
  IntelFigures f;
  std::vector<Eigen::Vector3d> errors;
  std::vector<Eigen::Matrix3d> covariances;
  std::vector<double> nees;
  for (std::size_t i = 1; i < scans.size(); ++i) {
    const auto& p = scans[i - 1];
    const auto& c = scans[i];
    const Eigen::Vector3d gt = relative(*p.ground_truth, *c.ground_truth);
    const Eigen::Vector3d wheel = relative(p.odometry, c.odometry);
    const sm::ScanPoints current = points_of(c);
    const sm::OdometryResult r =
        odometry.match(sm::ReferenceScan(points_of(p), options), current, wheel, map.placed(i - 1, pose));
    pose = sm::compose(pose, r.increment);
    Eigen::Vector3d e = r.increment - gt;
    e[2] = std::remainder(e[2], 2 * std::numbers::pi);
    f.xy.push_back(e.head<2>().norm());
    f.th.push_back(std::abs(e[2]));
    if (r.match.ok) {
      map.add(i, current, pose);
      errors.push_back(e);
      covariances.push_back(r.covariance);
      nees.push_back(e.dot(r.covariance.ldlt().solve(e)));
    } else {
      ++f.failed;
      map.clear();
    }
  }
  // Why the NEES against GMapping is high: the reference's own pose errors.
  // An error ε_k of the k-th reference pose enters increments k and k + 1
  // with opposite signs, so the increment errors have lag-1 covariance
  // −Cov(ε) and variance Var(laser) + 2 Cov(ε), where the laser odometry's
  // errors of successive matches are independent (previous scan alone).
  Eigen::Vector3d var = Eigen::Vector3d::Zero(), lag1 = Eigen::Vector3d::Zero();
  for (std::size_t k = 1; k < errors.size(); ++k) {
    var += errors[k].cwiseProduct(errors[k]);
    lag1 += errors[k].cwiseProduct(errors[k - 1]);
  }
  f.lag1_correlation = lag1.cwiseQuotient(var);
  const Eigen::Matrix3d reference_share = (2.0 * (-lag1 / static_cast<double>(errors.size() - 1)).cwiseMax(0.0)).asDiagonal();
  std::vector<double> nees_ref;
  for (std::size_t k = 0; k < errors.size(); ++k)
    nees_ref.push_back(errors[k].dot((covariances[k] + reference_share).ldlt().solve(errors[k])));
  auto mean = [](const std::vector<double>& v) {
    double m = 0.0;
    for (double x : v) m += x / static_cast<double>(v.size());
    return m;
  };
  f.nees_mean = mean(nees);
  f.nees_median = quantile(nees, 0.5);
  f.nees_ref_mean = mean(nees_ref);
  f.nees_ref_median = quantile(nees_ref, 0.5);
  std::printf("local map %d: xy median %.4f m p95 %.4f m, heading median %.3f deg p95 %.3f deg; %d failed; NEES mean "
              "%.2f median %.2f; lag-1 correlation x %.2f y %.2f θ %.2f; NEES with the reference's pose noise "
              "(σ %.4f m, %.4f m, %.3f deg) mean %.2f median %.2f\n",
              map_scans, quantile(f.xy, 0.5), quantile(f.xy, 0.95), quantile(f.th, 0.5) / kDeg,
              quantile(f.th, 0.95) / kDeg, f.failed, f.nees_mean, f.nees_median, f.lag1_correlation[0],
              f.lag1_correlation[1], f.lag1_correlation[2], std::sqrt(0.5 * reference_share(0, 0)),
              std::sqrt(0.5 * reference_share(1, 1)), std::sqrt(0.5 * reference_share(2, 2)) / kDeg, f.nees_ref_mean,
              f.nees_ref_median);
  return f;
}

// Intel with the local map (issue 18): each scan matched against the previous
// one and the last 4 key scans (weight 0.3), with the free-space check, as a
// log whose wheels cannot vouch for a centimetre would be run: per step
// against GMapping unchanged (medians within 1 % of the previous scan alone,
// IntelIncrementsAgainstGMapping's figures; measured 2.24 cm / 0.349°), all
// matched. And why the increments' NEES against GMapping is high: with the
// previous scan alone successive errors are anti-correlated (lag-1 −0.15 to
// −0.20), the signature of GMapping's own pose noise (≈ 1.1 cm, 0.26° per
// pose); with that share added the NEES falls from ≈ 370 to ≈ 7.6 (mean).
TEST(ScanMatcher, IntelIncrementsWithTheLocalMap) {
  const std::filesystem::path file =
      std::filesystem::path(MSPACE_SOURCE_DIR).parent_path() / "shared/datasets/intel_lab/intel_910_scans.txt";
  if (!std::filesystem::exists(file)) GTEST_SKIP() << "Intel Research Lab data not found at " << file;
  const auto log = mspace::carmen_log::read_log(file, {});
  ASSERT_EQ(log.scans.size(), 910u);
  const IntelFigures plain = intel_laser_odometry(log.scans, sm::MatchOptions{}, 0);
  EXPECT_LT(plain.lag1_correlation.maxCoeff(), -0.1);  // the reference's pose noise is in the errors
  EXPECT_LT(plain.nees_ref_mean, 0.1 * plain.nees_mean);
  sm::MatchOptions options;
  options.free_space_margin = 0.15;
  options.local_map_weight = 0.3;
  const IntelFigures mapped = intel_laser_odometry(log.scans, options, 4);
  EXPECT_EQ(mapped.failed, 0);
  EXPECT_LE(quantile(mapped.th, 0.5), 1.01 * quantile(plain.th, 0.5));
  EXPECT_LE(quantile(mapped.xy, 0.5), 1.01 * quantile(plain.xy, 0.5));
}

}  // namespace
