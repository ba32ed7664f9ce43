// Map matching for loop closure (kernel/src/loop_closing.cpp) on hand-built
// maps: point features, and line segments whose unmeasured end points slide
// (the symmetry directions a wall declares). The local map is a copy of part
// of the old map moved by a known motion; the matcher must find the inverse
// motion, pair the right features, and refuse when the answer is ambiguous
// (a symmetric map), not determined (parallel lines only) or absent.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "loop_closing.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

const CoordLayout kPoint{BlockKind::Point2D};
const CoordLayout kSegment{BlockKind::Point2D, BlockKind::Point2D};

FeatureShape point(double x, double y) {
  FeatureShape s;
  s.type = 0;
  s.layout = &kPoint;
  s.x = Eigen::Vector2d(x, y);
  s.free = Eigen::MatrixXd::Zero(2, 0);
  s.cov = Eigen::Matrix2d::Identity() * 1e-4;
  return s;
}

/// A segment from a to b; an end that is not `fixed` slides along the line.
FeatureShape segment(Eigen::Vector2d a, Eigen::Vector2d b, bool fixed_a, bool fixed_b) {
  FeatureShape s;
  s.type = 1;
  s.layout = &kSegment;
  s.x.resize(4);
  s.x << a, b;
  const Eigen::Vector2d t = (b - a).normalized();
  s.free = Eigen::MatrixXd::Zero(4, 0);
  for (int e = 0; e < 2; ++e) {
    if (e == 0 ? fixed_a : fixed_b) continue;
    s.free.conservativeResize(4, s.free.cols() + 1);
    s.free.col(s.free.cols() - 1).setZero();
    s.free.col(s.free.cols() - 1).segment<2>(2 * e) = t;
  }
  s.cov = Eigen::Matrix4d::Identity() * 1e-4;
  return s;
}

/// `shapes` moved by `T`, with independent noise of σ on every coordinate.
std::vector<FeatureShape> moved(const std::vector<FeatureShape>& shapes, const PlanarMotion& T, double sigma,
                                std::mt19937& rng) {
  std::normal_distribution<double> noise(0.0, sigma);
  std::vector<FeatureShape> out;
  for (const FeatureShape& s : shapes) {
    FeatureShape m = s;
    m.x = T.apply(*s.layout, s.x);
    for (Eigen::Index i = 0; i < m.x.size(); ++i) m.x[i] += noise(rng);
    m.free = T.rotate(*s.layout, s.free);
    out.push_back(m);
  }
  return out;
}

/// An office-like room: four walls with real corners, a door gap, a pillar row.
std::vector<FeatureShape> room(Eigen::Vector2d origin) {
  const Eigen::Vector2d o = origin;
  std::vector<FeatureShape> s;
  s.push_back(segment(o + Eigen::Vector2d(0, 0), o + Eigen::Vector2d(7, 0), true, true));
  s.push_back(segment(o + Eigen::Vector2d(7, 0), o + Eigen::Vector2d(7, 4), true, false));
  s.push_back(segment(o + Eigen::Vector2d(7, 4), o + Eigen::Vector2d(3, 4), false, true));
  s.push_back(segment(o + Eigen::Vector2d(2, 4), o + Eigen::Vector2d(0, 4), true, true));
  s.push_back(segment(o + Eigen::Vector2d(0, 4), o + Eigen::Vector2d(0, 0), false, true));
  s.push_back(point(o.x() + 2.0, o.y() + 2.0));
  s.push_back(point(o.x() + 5.5, o.y() + 1.0));
  return s;
}

/// A corridor: two pairs of long parallel walls (2 m apart) with sliding ends, a gap between the pairs.
std::vector<FeatureShape> corridor() {
  std::vector<FeatureShape> old;
  for (double x0 : {0.0, 12.0}) {
    old.push_back(segment({x0, 0}, {x0 + 10, 0}, false, false));
    old.push_back(segment({x0 + 10, 2}, {x0, 2}, false, false));
  }
  return old;
}

/// The motion that undoes `T` (both about the same pivot).
PlanarMotion inverse(const PlanarMotion& T) {
  PlanarMotion inv{-T.theta, Eigen::Vector2d::Zero(), T.pivot};
  inv.t = -(inv.apply(T.pivot + T.t) - T.pivot);
  return inv;
}

TEST(MapMatching, CoincidenceOfCrossingLinesIsNotFree) {
  // Two lines through the same point at 90°, both ends sliding: if the free
  // directions of both were used on each end, any two lines would coincide.
  const FeatureShape a = segment({-1, 0}, {1, 0}, false, false);
  const FeatureShape b = segment({0, -1}, {0, 1}, false, false);
  CoincidenceResidual r;
  ASSERT_TRUE(coincidence_residual(a, b, PlanarMotion{}, 0.0, r));
  EXPECT_EQ(r.r.size(), 2);  // the normal offsets of b's two ends
  EXPECT_GT(r.r.norm(), 0.5);
  // The same line, its ends elsewhere along it, coincides exactly.
  const FeatureShape c = segment({-3, 0}, {5, 0}, false, false);
  ASSERT_TRUE(coincidence_residual(a, c, PlanarMotion{}, 0.0, r));
  EXPECT_NEAR(r.r.norm(), 0.0, 1e-12);
  // A measured end counts along the line too.
  const FeatureShape d = segment({-3, 0}, {5, 0}, true, false);
  const FeatureShape e = segment({-1, 0}, {5, 0}, true, false);
  ASSERT_TRUE(coincidence_residual(d, e, PlanarMotion{}, 0.0, r));
  EXPECT_NEAR(r.r.norm(), 2.0, 1e-12);
}

TEST(MapMatching, RecoversTheMotionOfADriftedLocalMap) {
  std::mt19937 rng(7);
  std::vector<FeatureShape> old = room({0, 0});
  for (const FeatureShape& s : room({9, 0})) old.push_back(s);  // a room like it beside it, three of
  old.erase(old.begin() + 7, old.begin() + 10);                  // its walls missing: it pairs 4 of 7
  old.push_back(point(12.0, 3.2));
  for (int trial = 0; trial < 5; ++trial) {
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    const PlanarMotion drift{0.25 * u(rng), Eigen::Vector2d(4.0 * u(rng), 4.0 * u(rng)), Eigen::Vector2d(3.5, 2.0)};
    const std::vector<FeatureShape> first_room(old.begin(), old.begin() + 7);
    const std::vector<FeatureShape> local = moved(first_room, drift, 0.01, rng);
    MapMatchOptions o;
    o.max_translation = 8.0;
    o.max_rotation = 0.3;
    const MapMatch m = match_local_map(local, old, drift.pivot, o);
    ASSERT_TRUE(m.accepted) << "trial " << trial << ": " << m.reason;
    const PlanarMotion want = inverse(drift);
    EXPECT_NEAR(m.best.motion.theta, want.theta, 0.01) << "trial " << trial;
    EXPECT_NEAR((m.best.motion.t - want.t).norm(), 0.0, 0.05) << "trial " << trial;
    ASSERT_EQ(m.best.pairs.size(), 7u);
    for (const auto& [i, j] : m.best.pairs) EXPECT_EQ(i, j);
  }
}

TEST(MapMatching, RefusesASymmetricMap) {
  // The same room twice, 9 m apart: the local copy fits both.
  std::mt19937 rng(3);
  std::vector<FeatureShape> old = room({0, 0});
  for (const FeatureShape& s : room({9, 0})) old.push_back(s);
  const std::vector<FeatureShape> first_room(old.begin(), old.begin() + 7);
  const PlanarMotion drift{0.05, Eigen::Vector2d(1.0, -0.5), Eigen::Vector2d(3.5, 2.0)};
  const std::vector<FeatureShape> local = moved(first_room, drift, 0.01, rng);
  MapMatchOptions o;
  o.max_translation = 12.0;
  o.max_rotation = 0.2;
  MapMatch m = match_local_map(local, old, drift.pivot, o);
  EXPECT_FALSE(m.accepted);
  EXPECT_EQ(m.best_matches, 7);
  EXPECT_EQ(m.rival_matches, 7);
  EXPECT_NE(m.reason.find("ambiguous"), std::string::npos) << m.reason;
  // A window that the drift bounds (2 m) holds one placement only.
  o.max_translation = 2.0;
  m = match_local_map(local, old, drift.pivot, o);
  ASSERT_TRUE(m.accepted) << m.reason;
  EXPECT_NEAR((m.best.motion.t - inverse(drift).t).norm(), 0.0, 0.05);
}

TEST(MapMatching, RefusesParallelWallsThatLeaveTheMotionFree) {
  // A corridor: two long parallel walls with sliding ends fix the rotation
  // and the offset across it, never the position along it.
  std::mt19937 rng(5);
  const std::vector<FeatureShape> old = corridor();
  const std::vector<FeatureShape> local =
      moved({old[0], old[1], old[2], old[3]}, PlanarMotion{0.02, Eigen::Vector2d(0.7, 0.3), {5, 1}}, 0.005, rng);
  MapMatchOptions o;
  o.min_matches = 2;
  const MapMatch m = match_local_map(local, old, {5, 1}, o);
  EXPECT_FALSE(m.accepted);
  EXPECT_NE(m.reason.find("does not fix"), std::string::npos) << m.reason;
}

// Other evidence (MapMatchOptions::seeds, dense_score; Slam's scans): a
// seed at the true placement of the same corridor is accepted with the
// position along the corridor the seed gave, which the walls leave free.
TEST(MapMatching, ASeedFixesWhatParallelWallsLeaveFree) {
  std::mt19937 rng(5);
  const std::vector<FeatureShape> old = corridor();
  const PlanarMotion drift{0.02, Eigen::Vector2d(0.7, 0.3), {5, 1}};
  const std::vector<FeatureShape> local = moved({old[0], old[1]}, drift, 0.005, rng);
  const PlanarMotion want = inverse(drift);
  MapMatchOptions o;
  o.min_matches = 2;
  // The seed is off by 4 cm and 0.3° (a scan search's grid); the dense
  // score peaks at the seed.
  PlanarMotion seed = want;
  seed.t += Eigen::Vector2d(0.04, 0.0);
  seed.theta += 0.005;
  o.seeds = {seed};
  o.dense_score = [&](const PlanarMotion& T) { return 1.0 - (T.t - seed.t).norm(); };
  o.dense_floor = 0.8;
  const MapMatch m = match_local_map(local, old, {5, 1}, o);
  ASSERT_TRUE(m.accepted) << m.reason;
  EXPECT_TRUE(m.best.seeded);
  EXPECT_FALSE(m.best.determined);
  EXPECT_EQ(m.best.pairs.size(), 2u);
  // Across the corridor and in heading the walls refine the seed; along it the seed stands.
  EXPECT_NEAR(m.best.motion.theta, want.theta, 0.002);
  EXPECT_NEAR(m.best.motion.t.x(), seed.t.x(), 0.02);
  EXPECT_NEAR((m.best.motion.apply(Eigen::Vector2d(5, 1)) - want.apply(Eigen::Vector2d(5, 1))).y(), 0.0, 0.02);
  // A seed turned 3° from the truth: the walls turn it back, further than
  // seed_tolerance_rotation (2°) — they disagree with the seed's evidence,
  // so it is dropped; with a looser tolerance the same seed is accepted.
  PlanarMotion turned = want;
  turned.theta += 3.0 * std::numbers::pi / 180.0;
  o.seeds = {turned};
  o.dense_score = [&](const PlanarMotion& T) { return 1.0 - (T.t - turned.t).norm(); };
  ASSERT_NEAR(o.seed_tolerance_rotation, 0.035, 1e-12);
  const MapMatch refused = match_local_map(local, old, {5, 1}, o);
  EXPECT_FALSE(refused.accepted);
  // The refusal says what became of the seed: how far its pairs pulled it.
  EXPECT_NE(refused.reason.find("the other evidence's placement dropped: its 2 feature pairs pull it"),
            std::string::npos)
      << refused.reason;
  o.seed_tolerance_rotation = 0.1;
  const MapMatch loose = match_local_map(local, old, {5, 1}, o);
  ASSERT_TRUE(loose.accepted) << loose.reason;
  EXPECT_NEAR(loose.best.motion.theta, want.theta, 0.002);
  o.seed_tolerance_rotation = 0.035;
  // Without the seed: refused, as in the test above.
  o.seeds.clear();
  EXPECT_FALSE(match_local_map(local, old, {5, 1}, o).accepted);
}

// A placement the features alone accept is refused when the other evidence
// scores it below dense_floor, and it is no rival of one it does not contradict.
TEST(MapMatching, OtherEvidenceVetoesAPlacementItContradicts) {
  std::mt19937 rng(3);
  const std::vector<FeatureShape> old = room({0, 0});
  const PlanarMotion drift{0.05, Eigen::Vector2d(1.0, -0.5), {3.5, 2.0}};
  const std::vector<FeatureShape> local = moved(old, drift, 0.01, rng);
  MapMatchOptions o;
  o.max_translation = 4.0;
  ASSERT_TRUE(match_local_map(local, old, drift.pivot, o).accepted);
  const PlanarMotion want = inverse(drift);
  o.dense_score = [&](const PlanarMotion& T) { return (T.t - want.t).norm() < 0.2 ? 0.3 : 1.0; };
  o.dense_floor = 0.8;
  const MapMatch m = match_local_map(local, old, drift.pivot, o);
  EXPECT_FALSE(m.accepted);
  EXPECT_NE(m.reason.find("contradicts"), std::string::npos) << m.reason;
}

TEST(MapMatching, PairsOnlyCopiesThatOverlapTheSameWayRound) {
  // A residual that projects sliding ends out sees only lines. Two walls on
  // one line a door apart, and one wall with its ends the other way round,
  // pass it; neither is a copy of the old wall. The local map here is the
  // room without its bottom wall, plus a wall on the bottom wall's line past
  // a door (x 9–12) and the left wall stored the other way round (both ends
  // sliding): the five true copies place it, those two are left unpaired.
  std::mt19937 rng(13);
  const std::vector<FeatureShape> old = room({0, 0});
  std::vector<FeatureShape> copies = {old[1], old[2], old[3], old[5], old[6]};
  copies.push_back(segment({0, 0}, {0, 4}, false, false));   // old[4] the other way round
  copies.push_back(segment({9, 0}, {12, 0}, false, false));  // past the door on old[0]'s line
  const PlanarMotion drift{0.04, Eigen::Vector2d(0.8, -0.6), Eigen::Vector2d(3.5, 2.0)};
  const std::vector<FeatureShape> local = moved(copies, drift, 0.005, rng);
  MapMatchOptions o;
  o.max_translation = 3.0;
  o.max_rotation = 0.2;
  const MapMatch m = match_local_map(local, old, drift.pivot, o);
  ASSERT_TRUE(m.accepted) << m.reason;
  const std::vector<std::pair<int, int>> right = {{0, 1}, {1, 2}, {2, 3}, {3, 5}, {4, 6}};
  std::vector<std::pair<int, int>> got = m.best.pairs;
  std::sort(got.begin(), got.end());
  EXPECT_EQ(got, right);
  EXPECT_NEAR((m.best.motion.t - inverse(drift).t).norm(), 0.0, 0.05);
}

// MapMatchOptions::pass_gap. The old map holds the room as the robot's
// first pass observed it (at 100–107 m of travel), except that its top-left
// wall was only observed on a later pass (400 m), when the drift of a loop
// not yet closed had put it — in the estimate — exactly where the local
// map's top-left wall now lands; in truth it is another object (long_loop 2
// in tests/sim_building: a room's back wall paired with the corridor wall
// above it, 4.3 m away). The estimate cannot tell: the pair fits to the
// noise. What it can tell is that nothing observed ties features observed
// 300 m of travel apart: they may disagree by the whole drift in between,
// so their coincidence in the estimate is no evidence. With pass_gap the
// pass that holds most pairs is kept and the other pass's feature is not paired.
TEST(MapMatching, PairsWithinOnePassOfTheOldMap) {
  std::mt19937 rng(17);
  std::vector<FeatureShape> old = room({0, 0});
  const auto seen = [&](std::size_t k, double first, double last) {
    old[k].seen_first = first;
    old[k].seen_last = last;
  };
  for (std::size_t k = 0; k < old.size(); ++k) seen(k, 100.0 + old[k].x[0], 100.0 + old[k].x[0]);
  seen(3, 400.0, 401.0);
  const PlanarMotion drift{0.03, Eigen::Vector2d(0.9, -0.7), Eigen::Vector2d(3.5, 2.0)};
  const std::vector<FeatureShape> local = moved(old, drift, 0.005, rng);
  MapMatchOptions o;
  o.max_translation = 3.0;
  o.max_rotation = 0.2;
  const MapMatch all = match_local_map(local, old, drift.pivot, o);  // pass_gap 0: off
  ASSERT_TRUE(all.accepted) << all.reason;
  EXPECT_EQ(all.best.pairs.size(), 7u);
  o.pass_gap = 30.0;
  const MapMatch one_pass = match_local_map(local, old, drift.pivot, o);
  ASSERT_TRUE(one_pass.accepted) << one_pass.reason;
  ASSERT_EQ(one_pass.best.pairs.size(), 6u);
  for (const auto& [i, j] : one_pass.best.pairs) {
    EXPECT_EQ(i, j);
    EXPECT_NE(j, 3);
  }
  EXPECT_NEAR((one_pass.best.motion.t - inverse(drift).t).norm(), 0.0, 0.05);
  // A feature observed on both passes ties them: all seven pair again.
  seen(0, 100.0, 395.0);
  EXPECT_EQ(match_local_map(local, old, drift.pivot, o).best.pairs.size(), 7u);
  seen(0, 100.0, 100.0);
  // Observations within pass_gap of each other chain into one pass (100–107
  // m, then 125 m), and a feature never timed (a loaded map) joins any pass.
  seen(3, 125.0, 125.0);
  seen(5, std::nan(""), std::nan(""));
  const MapMatch chained = match_local_map(local, old, drift.pivot, o);
  ASSERT_TRUE(chained.accepted) << chained.reason;
  EXPECT_EQ(chained.best.pairs.size(), 7u);
  // The pass with the most pairs is kept, whichever is older: four features
  // observed at 400 m against three at 100 m.
  for (std::size_t k : {0u, 1u, 2u, 4u}) seen(k, 400.0 + static_cast<double>(k), 400.0 + static_cast<double>(k));
  for (std::size_t k : {3u, 5u, 6u}) seen(k, 100.0, 100.0);
  const MapMatch later = match_local_map(local, old, drift.pivot, o);
  ASSERT_EQ(later.best.pairs.size(), 4u) << later.reason;
  for (const auto& [i, j] : later.best.pairs) EXPECT_GE(old[static_cast<std::size_t>(j)].seen_first, 400.0);
}

// MapMatchOptions::drift_per_metre: an old feature may be moved onto only
// as far as the odometry can have drifted since the robot last saw it. The
// local copy of the room lies 2.5 m off: 10 m of travel after the room was
// last seen the placement is refused (0.1 + 0.05 × 10 = 0.6 m of reach),
// 100 m after it accepted (5.1 m); refused again when three of the seven
// were seen 5 m ago (0.35 m: the pairing as a whole is held to it), and
// accepted when those three are not timed (a loaded map's features).
TEST(MapMatching, AcceptsOnlyWithinTheDriftSinceTheOldFeaturesWereSeen) {
  std::mt19937 rng(23);
  std::vector<FeatureShape> old = room({0, 0});
  const PlanarMotion drift{0.03, Eigen::Vector2d(2.0, -1.5), Eigen::Vector2d(3.5, 2.0)};
  const std::vector<FeatureShape> local = moved(old, drift, 0.005, rng);
  MapMatchOptions o;
  o.max_translation = 6.0;
  o.max_rotation = 0.2;
  ASSERT_TRUE(match_local_map(local, old, drift.pivot, o).accepted);  // drift_per_metre 0: off
  o.drift_per_metre = 0.05;
  o.drift_rad_per_metre = 0.005;
  o.pair_base_translation = 0.1;
  o.pair_base_rotation = 0.01;
  const auto seen = [&](std::initializer_list<std::size_t> which, double travel) {
    for (std::size_t k : which) old[k].travel_unseen = travel;
  };
  seen({0, 1, 2, 3, 4, 5, 6}, 10.0);
  const MapMatch soon = match_local_map(local, old, drift.pivot, o);
  EXPECT_FALSE(soon.accepted);
  EXPECT_NE(soon.reason.find("drifted since it was last seen"), std::string::npos) << soon.reason;
  seen({0, 1, 2, 3, 4, 5, 6}, 100.0);
  const MapMatch later = match_local_map(local, old, drift.pivot, o);
  ASSERT_TRUE(later.accepted) << later.reason;
  EXPECT_EQ(later.best.pairs.size(), 7u);
  EXPECT_NEAR((later.best.motion.t - inverse(drift).t).norm(), 0.0, 0.05);
  seen({1, 3, 5}, 5.0);
  EXPECT_FALSE(match_local_map(local, old, drift.pivot, o).accepted);
  seen({1, 3, 5}, std::nan(""));
  const MapMatch untimed = match_local_map(local, old, drift.pivot, o);
  ASSERT_TRUE(untimed.accepted) << untimed.reason;
  EXPECT_EQ(untimed.best.pairs.size(), 7u);
}

TEST(MapMatching, FindsNothingWhereThereIsNothing) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 15.0);
  std::vector<FeatureShape> old, local;
  for (int i = 0; i < 25; ++i) old.push_back(point(u(rng), u(rng)));
  for (int i = 0; i < 8; ++i) local.push_back(point(u(rng), u(rng)));
  MapMatchOptions o;
  o.max_translation = 5.0;
  o.max_rotation = 0.3;
  const MapMatch m = match_local_map(local, old, {7, 7}, o);
  EXPECT_FALSE(m.accepted) << m.best_matches << " matches";
}

// The ground-truth check of a closure's pairs (distance_apart): each feature
// is moved to the true frame by its own motion. Two copies of one wall,
// mapped in frames that have drifted 3 m and 10° apart, land on each other;
// a wall and the parallel one across a 2 m corridor stay 2 m apart; a copy
// that slid along the wall (its ends unmeasured) is still the same wall.
TEST(MapMatching, TheTruthCheckSeesObjectsNotTheMapsDistortion) {
  const FeatureShape wall = segment({0, 0}, {6, 0}, true, false);
  const FeatureShape across = segment({0, 2}, {6, 2}, true, false);
  const PlanarMotion identity{};
  // The same wall as a drifted frame sees it: est = D(true), so true = D⁻¹(est).
  const PlanarMotion drift{0.1745, Eigen::Vector2d(3.0, -1.0), Eigen::Vector2d(1.0, 1.0)};
  std::mt19937 rng(3);
  const FeatureShape drifted = moved({wall}, drift, 0.0, rng).front();
  const auto same = distance_apart(wall, identity, drifted, inverse(drift));
  ASSERT_TRUE(same.has_value());
  EXPECT_LT(*same, 1e-9);
  // Without undoing the drift the copies are metres apart: the check would see the distortion.
  EXPECT_GT(*distance_apart(wall, identity, drifted, identity), 1.0);
  const auto other = distance_apart(wall, identity, across, identity);
  ASSERT_TRUE(other.has_value());
  EXPECT_NEAR(*other, 2.0, 1e-9);
  const FeatureShape slid = segment({0, 0}, {4, 0}, true, false);
  EXPECT_LT(*distance_apart(wall, identity, slid, identity), 1e-9);
  // The same line is not the same object: with neither end measured, a
  // segment 40 m further along the corridor wall has distance 0 but lies
  // elsewhere (footprints_overlap).
  const FeatureShape line = segment({0, 0}, {6, 0}, false, false);
  const FeatureShape far_along = segment({40, 0}, {46, 0}, false, false);
  EXPECT_LT(*distance_apart(line, identity, far_along, identity), 1e-9);
  EXPECT_FALSE(footprints_overlap(line, identity, far_along, identity, 0.3));
  EXPECT_TRUE(footprints_overlap(wall, identity, slid, identity, 0.3));
  EXPECT_TRUE(footprints_overlap(wall, identity, drifted, inverse(drift), 0.3));
  // The other face of a wall 0.2 m thick: on the same footprint, within the
  // check's 0.3 m, but its ends run the other way — another object.
  // (Neither end measured, as a door's side wall seen through it often is.)
  const FeatureShape other_face = segment({6, 0.2}, {0, 0.2}, false, false);
  EXPECT_NEAR(*distance_apart(line, identity, other_face, identity), 0.2, 1e-9);
  EXPECT_TRUE(footprints_overlap(line, identity, other_face, identity, 0.3));
  EXPECT_FALSE(arranged_alike(line, identity, other_face, identity, 0.3));
  EXPECT_FALSE(pair_refusal(line, other_face, identity, MapMatchOptions{}).empty());
  EXPECT_EQ(pair_refusal(line, segment({0.5, 0.02}, {5.5, 0.02}, false, false), identity, MapMatchOptions{}), "");
  EXPECT_TRUE(arranged_alike(wall, identity, drifted, inverse(drift), 0.3));
  EXPECT_TRUE(arranged_alike(wall, identity, slid, identity, 0.3));
}

}  // namespace
