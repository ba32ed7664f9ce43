// Range scans as evidence for loop closing (kernel/src/scan_evidence.cpp):
// the end points a scan yields, the exactness of the multi-resolution search
// against a brute-force one, and what it says where a place repeats.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include <Eigen/Core>

#include "scan_evidence.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

constexpr double kDeg = std::numbers::pi / 180.0;

/// Beams from `from` to every sample (5 cm apart) of the segments.
std::vector<ScanRay> rays_to(const Eigen::Vector2d& from, const std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>>& walls) {
  std::vector<ScanRay> out;
  for (const auto& [a, b] : walls) {
    const int n = static_cast<int>((b - a).norm() / 0.05);
    for (int i = 0; i <= n; ++i) out.push_back({from, a + (b - a) * (static_cast<double>(i) / n)});
  }
  return out;
}

/// A room with an irregular outline (nothing repeats), seen from two places.
std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> irregular_room() {
  return {{{0, 0}, {7, 0}},   {{7, 0}, {7, 2.5}}, {{7, 2.5}, {9, 2.5}}, {{9, 2.5}, {9, 6}},
          {{9, 6}, {3, 6}},   {{3, 6}, {3, 4.5}}, {{3, 4.5}, {0, 4.5}}, {{0, 4.5}, {0, 0}},
          {{4, 2}, {4.6, 2}}, {{4.6, 2}, {4.6, 2.8}}};
}

std::vector<Eigen::Vector2d> ends(const std::vector<ScanRay>& rays, std::size_t stride) {
  std::vector<Eigen::Vector2d> out;
  for (std::size_t i = 0; i < rays.size(); i += stride) out.push_back(rays[i].to);
  return out;
}

TEST(ScanEvidence, EndPointsLeaveOutBeamsWithoutAReturnAndApplyTheMount) {
  Eigen::MatrixXd scan(5, 2);
  scan << 2.0, 0.0,  //
      0.0, 0.1,      // no return
      std::nan(""), 0.2, 8.0, 0.3,  // at the maximum range
      2.0, std::numbers::pi / 2;
  const Pose6 mount = make_pose2d(0.5, 0.1, std::numbers::pi / 2);
  const std::vector<Eigen::Vector2f> p = scan_end_points(scan, mount, 8.0, 0.0);
  ASSERT_EQ(p.size(), 2u);
  EXPECT_NEAR(p[0].x(), 0.5, 1e-6);  // straight ahead of a sensor turned 90°: +y of the robot
  EXPECT_NEAR(p[0].y(), 2.1, 1e-6);
  EXPECT_NEAR(p[1].x(), -1.5, 1e-6);
  EXPECT_NEAR(p[1].y(), 0.1, 1e-6);
  // Thinning: a point closer than the spacing to the last one kept is left out.
  Eigen::MatrixXd dense(3, 2);
  dense << 2.0, 0.0, 2.0, 0.01, 2.0, 0.2;
  EXPECT_EQ(scan_end_points(dense, Pose6::Zero(), 0.0, 0.1).size(), 2u);
}

TEST(ScanEvidence, SearchFindsTheMotionAndEqualsBruteForce) {
  const auto walls = irregular_room();
  std::vector<ScanRay> old = rays_to({2, 2}, walls);
  for (const ScanRay& r : rays_to({6, 4}, walls)) old.push_back(r);
  const ScanField field(old, 0.1, 0.15, 0.5);
  // The recent end points: the room seen from elsewhere, then displaced (the
  // drift the search must undo).
  const PlanarMotion drift{3.0 * kDeg, Eigen::Vector2d(0.8, -0.5), Eigen::Vector2d(5, 3)};
  std::vector<Eigen::Vector2d> local;
  for (const Eigen::Vector2d& p : ends(rays_to({5, 3}, walls), 4)) local.push_back(drift.apply(p));
  ScanSearchOptions o;
  o.max_translation = 1.5;
  o.max_rotation = 6.0 * kDeg;
  o.rotation_step = 1.0 * kDeg;
  const ScanPlacement sp = field.search(local, {5, 3}, o);
  ASSERT_TRUE(sp.found);
  // It undoes the drift: the robot's position maps back to within a cell and a step.
  const Eigen::Vector2d robot = drift.apply(Eigen::Vector2d(5, 3));
  EXPECT_LT((sp.best.apply(robot) - Eigen::Vector2d(5, 3)).norm(), 0.15);
  EXPECT_NEAR(sp.best.theta, -3.0 * kDeg, 1.01 * kDeg);
  // Exact: no translation cell and rotation step of the window scores more.
  double brute = -1e9;
  const int n = static_cast<int>(std::ceil(o.max_translation / 0.1));
  for (int k = -6; k <= 6; ++k)
    for (int i = -n; i <= n; ++i)
      for (int j = -n; j <= n; ++j) {
        if (i * i + j * j > n * n) continue;
        brute = std::max(brute, field.score(local, PlanarMotion{k * kDeg, 0.1 * Eigen::Vector2d(i, j), {5, 3}}));
      }
  // (score() adds the translation before it finds a point's cell, the search
  // after: a point on a cell boundary may fall either way — one point's worth.)
  const double one_point = 1.0 / static_cast<double>(local.size());
  EXPECT_NEAR(sp.score, brute, one_point);
  EXPECT_NEAR(field.score(local, sp.best), sp.score, one_point);
  // Nothing else in the room fits nearly as well.
  EXPECT_LT(sp.rival_score, 0.9 * sp.score);
}

/// A corridor 2 m wide with a door every 4 m along both walls, scanned from
/// every metre along its middle (the old scans' field).
struct DoorCorridor {
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls = [] {
    std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> w;
    for (int d = 0; d < 10; ++d) {
      w.push_back({{4.0 * d, 0}, {4.0 * d + 3.0, 0}});
      w.push_back({{4.0 * d, 2}, {4.0 * d + 3.0, 2}});
    }
    return w;
  }();
  ScanField field = [this] {
    std::vector<ScanRay> old;
    for (double x = 1.0; x < 40.0; x += 1.0)
      for (const ScanRay& r : rays_to({x, 1}, walls))
        if ((r.to - r.from).norm() < 8.0) old.push_back(r);
    return ScanField(old, 0.1, 0.15, 0.5);
  }();
  /// The end points a scan from `where` sees within 6 m, all moved by `offset`.
  std::vector<Eigen::Vector2d> seen_from(const Eigen::Vector2d& where, const Eigen::Vector2d& offset) const {
    std::vector<Eigen::Vector2d> out;
    for (const ScanRay& r : rays_to(where, walls))
      if ((r.to - r.from).norm() < 6.0) out.push_back(r.to + offset);
    return out;
  }
};

TEST(ScanEvidence, ARepeatingCorridorHasARivalAsGoodAsTheBest) {
  // A corridor with a door every 4 m: shifted by one door spacing the recent
  // scans fit as well; the search must report that rival.
  const DoorCorridor corridor;
  const ScanField& field = corridor.field;
  const std::vector<Eigen::Vector2d> local = corridor.seen_from({18.5, 1}, {0.3, 0.0});
  ScanSearchOptions o;
  o.max_translation = 6.0;
  o.max_rotation = 3.0 * kDeg;
  const ScanPlacement sp = field.search(local, {18.5, 1}, o);
  ASSERT_TRUE(sp.found);
  EXPECT_GE(sp.rival_score, 0.9 * sp.score);
  EXPECT_GT((sp.rival.t - sp.best.t).norm(), 3.5);  // a door spacing away
}

TEST(ScanEvidence, ACorridorsRivalsSlideAlongItAndTheHeadingAndCrossingAreFixed) {
  // The corridor above: every placement as good lies on the line along it,
  // at the best one's heading — the scans fix the heading and the position
  // across the corridor (the local scans were moved 0.3 m along it only).
  const DoorCorridor corridor;
  const ScanField& field = corridor.field;
  const std::vector<Eigen::Vector2d> local = corridor.seen_from({18.5, 1}, {0.3, -0.4});
  ScanSearchOptions o;
  o.max_translation = 6.0;
  o.max_rotation = 3.0 * kDeg;
  o.rival_ratio = 0.9;
  const ScanPlacement sp = field.search(local, {18.5, 1}, o);
  ASSERT_TRUE(sp.found);
  ASSERT_GE(sp.rival_score, 0.9 * sp.score);
  EXPECT_NEAR(std::abs(sp.slide.x()), 1.0, 1e-3);
  EXPECT_GE(sp.slide_extent, 3.5);               // a door spacing, at least
  EXPECT_NEAR(sp.best.t.y(), 0.4, 0.1);          // across: the 0.4 m it was moved
  EXPECT_LE(std::abs(sp.best.theta), 1.0 * kDeg);
}

TEST(ScanEvidence, RivalsOffTheLineMakeNoSlide) {
  // Pillars on a 4 m lattice: a placement one spacing along x or along y
  // fits as well, so no one direction holds the rivals — and the irregular
  // room has no rival at all.
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> walls;
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 8; ++j) {
      const Eigen::Vector2d c(4.0 * i, 4.0 * j);
      walls.push_back({c, c + Eigen::Vector2d(0.6, 0)});
      walls.push_back({c + Eigen::Vector2d(0.6, 0), c + Eigen::Vector2d(0.6, 0.6)});
      walls.push_back({c + Eigen::Vector2d(0.6, 0.6), c + Eigen::Vector2d(0, 0.6)});
      walls.push_back({c + Eigen::Vector2d(0, 0.6), c});
    }
  std::vector<ScanRay> old;
  for (double x = 2.0; x < 30.0; x += 2.0)
    for (double y = 2.0; y < 30.0; y += 2.0)
      for (const ScanRay& r : rays_to({x, y}, walls))
        if ((r.to - r.from).norm() < 5.0) old.push_back(r);
  const ScanField field(old, 0.1, 0.15, 0.5);
  std::vector<Eigen::Vector2d> local;
  for (const ScanRay& r : rays_to({14.0, 14.0}, walls))
    if ((r.to - r.from).norm() < 5.0) local.push_back(r.to + Eigen::Vector2d(0.2, 0.1));
  ScanSearchOptions o;
  o.max_translation = 6.0;
  o.max_rotation = 2.0 * kDeg;
  o.rival_ratio = 0.9;
  const ScanPlacement lattice = field.search(local, {14.0, 14.0}, o);
  ASSERT_TRUE(lattice.found);
  ASSERT_GE(lattice.rival_score, 0.9 * lattice.score);
  EXPECT_EQ(lattice.slide, Eigen::Vector2d::Zero());

  const std::vector<ScanRay> room_old = rays_to({2, 2}, irregular_room());
  const ScanField room(room_old, 0.1, 0.15, 0.5);
  const ScanPlacement unique = room.search(ends(rays_to({6, 4}, irregular_room()), 3), {6, 4}, o);
  ASSERT_TRUE(unique.found);
  EXPECT_LT(unique.rival_score, 0.9 * unique.score);
  EXPECT_EQ(unique.slide, Eigen::Vector2d::Zero());
}

TEST(ScanEvidence, EndPointsWhereTheOldScansSawThroughCostMoreThanUnexplainedOnes) {
  const auto walls = irregular_room();
  const ScanField field(rays_to({2, 2}, walls), 0.1, 0.15, 0.5);
  // A point in the middle of the room (seen empty) and one far outside (never seen).
  EXPECT_NEAR(field.score({Eigen::Vector2d(2.0, 3.0)}, PlanarMotion{}), -0.5, 1e-6);
  EXPECT_NEAR(field.score({Eigen::Vector2d(30.0, 30.0)}, PlanarMotion{}), 0.0, 1e-6);
  // One on a wall scores close to one.
  EXPECT_GT(field.score({Eigen::Vector2d(3.5, 0.0)}, PlanarMotion{}), 0.8);
}

}  // namespace
