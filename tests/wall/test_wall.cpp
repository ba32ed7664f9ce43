// Tests of the `wall` feature type: B·B̃ = I at every dimension (eqs. 12,
// 14, 15, Table II), Jacobians against central differences, the innovation,
// conformance hooks (sample/save/restore/symmetry directions) and the life
// cycle 0 → 2 → 3 → 4 with sliding end points.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <numbers>

#include "mspace/measurements/line_segment2d.hpp"
#include "mspace/pose.hpp"
#include "mspace/transform.hpp"
#include "wall_feature.hpp"

namespace mspace::wall {
namespace {

namespace ls = line_segment;
constexpr double kStep = 1e-6;

const CoordLayout kLayout{BlockKind::Point2D, BlockKind::Point2D};

Eigen::Vector4d some_wall() { return Eigen::Vector4d(1.0, 2.0, 4.0, 6.0); }

TEST(Wall, ProjectionMatricesAreDualAtEveryDimension) {
  const Eigen::Vector4d x = some_wall();
  for (const std::vector<int>& ends : {std::vector<int>{}, {kStart}, {kEnd}, {kEnd, kStart}, {kStart, kEnd}}) {
    const Eigen::MatrixXd B = wall_B(x, ends), Bd = wall_B_dual(x, ends);
    ASSERT_EQ(B.rows(), 2 + static_cast<int>(ends.size()));
    EXPECT_LT((B * Bd - Eigen::MatrixXd::Identity(B.rows(), B.rows())).norm(), 1e-12);
  }
  // Eq. 14 row 2 is the mean normal move: moving both points by γ gives √2.
  const Eigen::Vector2d t = (x.tail<2>() - x.head<2>()).normalized(), gamma(t.y(), -t.x());
  Eigen::Vector4d move;
  move << gamma, gamma;
  EXPECT_NEAR((wall_B(x, {}) * move)[1], std::numbers::sqrt2, 1e-12);
  EXPECT_NEAR((wall_B(x, {}) * move)[0], 0.0, 1e-12);
}

TEST(Wall, PredictedLineJacobianMatchesCentralDifferences) {
  const Eigen::Vector4d x_o(2.0, 1.5, 1.0, -2.5);
  const PredictedLine p = predict_line(x_o);
  Eigen::Matrix4d numeric;
  for (int i = 0; i < 4; ++i) {
    Eigen::Vector4d d = Eigen::Vector4d::Zero();
    d[i] = kStep;
    Eigen::Vector4d diff = predict_line(x_o + d).h - predict_line(x_o - d).h;
    diff[1] = wrap_angle(diff[1]);
    numeric.col(i) = diff / (2 * kStep);
  }
  EXPECT_LT((numeric - p.J).norm(), 1e-6) << p.J << "\n" << numeric;
  // The line x = 2 − … : ρ̂ is the distance of the origin to the line.
  const Eigen::Vector2d d = x_o.tail<2>() - x_o.head<2>();
  EXPECT_NEAR(p.h[0], std::abs(d.x() * x_o[1] - d.y() * x_o[0]) / d.norm(), 1e-12);
  EXPECT_GT(p.h[0], 0.0);
}

TEST(Wall, PlacementJacobiansMatchCentralDifferences) {
  const Pose6 x_ms = make_pose2d(0.5, -1.0, 0.4);
  const double rho = 3.0, alpha = 0.3;
  const Eigen::Vector2d near1(0.0, 5.0), near2(5.0, 0.0);  // start first along t
  auto place = [&](double r, double a, const Pose6& s) {
    return place_on_line(r, a, s, near1, near2);
  };
  const Eigen::Vector4d x0 = place(rho, alpha, x_ms);
  Eigen::Matrix2d J_v;
  Eigen::Matrix<double, 2, 6> J_s;
  line_placement_jacobians(x0, alpha, x_ms, J_v, J_s);
  const Eigen::MatrixXd B = wall_B(x0, {});
  for (int i = 0; i < 2; ++i) {
    const double dr = i == 0 ? kStep : 0.0, da = i == 1 ? kStep : 0.0;
    const Eigen::Vector2d col = B * (place(rho + dr, alpha + da, x_ms) - place(rho - dr, alpha - da, x_ms)) / (2 * kStep);
    EXPECT_LT((col - J_v.col(i)).norm(), 1e-6) << "v column " << i;
  }
  for (int i : {kX, kY, kTheta}) {
    Pose6 d = Pose6::Zero();
    d[i] = kStep;
    const Eigen::Vector2d col = B * (place(rho, alpha, x_ms + d) - place(rho, alpha, x_ms - d)) / (2 * kStep);
    EXPECT_LT((col - J_s.col(i)).norm(), 1e-6) << "pose column " << i;
  }
}

WallConfig quick_config() {
  WallConfig c;
  c.min_observations = 3;
  c.min_points = 10;
  c.min_length = 1.0;
  c.min_end_observations = 2;
  return c;
}

TEST(Wall, SampleIsConsistentAtEveryReachableDimension) {
  const WallType type(quick_config());
  for (int dim : type.reachable_dims()) {
    for (std::uint64_t seed = 1; seed <= 20; ++seed) {
      auto s = type.sample(dim, seed);
      ASSERT_TRUE(s);
      const Feature& f = *s->feature;
      ASSERT_EQ(f.mspace_dim(), dim);
      EXPECT_LT((f.B() * f.B_dual() - Eigen::MatrixXd::Identity(dim, dim)).norm(), 1e-12);
      Eigen::MatrixXd J_of;
      const Eigen::VectorXd x_o = to_sensor_frame(kLayout, f.coords(), s->x_ms, &J_of);
      Innovation in;
      ASSERT_TRUE(f.innovation(x_o, s->measurement, in));
      EXPECT_EQ(in.eta.size(), dim <= 2 ? 2 : dim);
      EXPECT_LT(in.eta.norm(), 1e-9);
      // J_ηo against central differences of the innovation.
      for (int i = 0; i < 4; ++i) {
        Eigen::VectorXd d = Eigen::VectorXd::Zero(4);
        d[i] = kStep;
        Innovation plus, minus;
        ASSERT_TRUE(f.innovation(x_o + d, s->measurement, plus));
        ASSERT_TRUE(f.innovation(x_o - d, s->measurement, minus));
        EXPECT_LT(((plus.eta - minus.eta) / (2 * kStep) - in.J_eta_o.col(i)).norm(), 1e-6);
      }
      // Sliding along the symmetry directions changes no innovation.
      const Eigen::MatrixXd sym = f.symmetry_directions();
      EXPECT_EQ(sym.cols(), dim == 0 ? 2 : 4 - std::max(dim, 2));
      for (Eigen::Index c = 0; c < sym.cols(); ++c) {
        Innovation moved;
        const Eigen::VectorXd x_moved = to_sensor_frame(kLayout, f.coords() + 0.2 * sym.col(c), s->x_ms);
        ASSERT_TRUE(f.innovation(x_moved, s->measurement, moved));
        EXPECT_LT((moved.eta - in.eta).norm(), 1e-9);
      }
      // Save / restore round trip.
      const auto back = type.restore(f.save());
      EXPECT_EQ(back->mspace_dim(), dim);
      EXPECT_LT((back->coords() - f.coords()).norm(), 1e-15);
      EXPECT_LT((back->B() - f.B()).norm(), 1e-15);
    }
  }
  EXPECT_FALSE(type.sample(1, 1));
}

TEST(Wall, NotMatchedFromBehindOrWithoutOverlap) {
  const WallType type(quick_config());
  auto s = type.sample(2, 7);
  const Feature& f = *s->feature;
  Innovation in;
  // From behind: mirror the sensor through the wall.
  const Eigen::Vector2d p1 = f.coords().head<2>(), p2 = f.coords().tail<2>();
  const Eigen::Vector2d t = (p2 - p1).normalized(), gamma(t.y(), -t.x());
  Pose6 behind = s->x_ms;
  const double dist = gamma.dot(s->x_ms.head<2>() - p1);
  behind.head<2>() -= 2.0 * dist * gamma;
  EXPECT_FALSE(f.innovation(to_sensor_frame(kLayout, f.coords(), behind), s->measurement, in));
  // A segment far along the same line.
  Measurement far = s->measurement;
  far.v[ls::kSa] += 50.0;
  far.v[ls::kSb] += 50.0;
  EXPECT_FALSE(f.innovation(to_sensor_frame(kLayout, f.coords(), s->x_ms), far, in));
}

/// A measurement of the wall y = 3 (x from 0 to 6, seen from below: γ = (0, −1)),
/// seen from the planar pose (x, 0, 0) with the visible part [lo, hi] in x.
Measurement see_wall(double robot_x, double lo, double hi, std::uint32_t flags) {
  const double rho = 3.0, alpha = std::numbers::pi / 2;  // u = (0, 1)
  // t = (sin α, −cos α) = (1, 0): s along +x, relative to the robot.
  Measurement m;
  m.kind = ls::kKind;
  m.v = Eigen::Vector4d(rho, alpha, lo - robot_x, hi - robot_x);
  m.C_v = Eigen::Vector4d(1e-4, 1e-5, 1e-3, 1e-3).asDiagonal();
  m.flags = flags;
  const int n = 20;
  m.dense.resize(2, n);
  for (int i = 0; i < n; ++i) m.dense.col(i) << lo - robot_x + (hi - lo) * i / (n - 1), rho;
  return m;
}

SensorView view_at(double x, double t) {
  SensorView v;
  v.t = t;
  v.x_ms = make_pose2d(x, 0.0, 0.0);
  v.C_ms = Mat6::Identity() * 1e-4;
  v.path_distance = x;
  return v;
}

TEST(Wall, LifeCycleGrowsMspaceAndSlidesEnds) {
  WallType type(quick_config());
  const std::uint32_t start_real = ls::make_flags(ls::EndReason::Depth, ls::EndReason::Fov);
  const std::uint32_t both_real = ls::make_flags(ls::EndReason::Corner, ls::EndReason::Depth);
  auto f = type.create(see_wall(0.0, 0.0, 2.0, start_real), view_at(0.0, 0.0));
  ASSERT_TRUE(f);
  f->add_dense_information(see_wall(0.0, 0.0, 2.0, start_real), view_at(0.0, 0.0));
  EXPECT_EQ(f->mspace_dim(), 0);
  EXPECT_FALSE(f->extend(view_at(0.0, 0.0)));  // one observation
  EXPECT_EQ(f->gating_covariance().rows(), 4);
  f->add_dense_information(see_wall(0.5, 0.0, 3.0, start_real), view_at(0.5, 1.0));
  f->add_dense_information(see_wall(1.0, 0.0, 4.0, start_real), view_at(1.0, 2.0));
  const auto ext = f->extend(view_at(1.0, 2.0));
  ASSERT_TRUE(ext);
  EXPECT_EQ(ext->new_dims, 2);
  EXPECT_EQ(f->mspace_dim(), 2);
  EXPECT_EQ(f->gating_covariance().size(), 0);
  EXPECT_NEAR(f->coords()[1], 3.0, 1e-12);
  EXPECT_NEAR(f->coords()[3], 3.0, 1e-12);
  // The start was seen as real 3 times within 0 m: it enters at once (dim 3).
  const auto ext3 = f->extend(view_at(1.0, 2.0));
  ASSERT_TRUE(ext3);
  EXPECT_EQ(ext3->new_dims, 1);
  EXPECT_EQ(f->mspace_dim(), 3);
  EXPECT_NEAR(f->coords()[0], 0.0, 1e-12);
  // The end slides outwards with the observed extent; the line does not move.
  f->add_dense_information(see_wall(2.0, 0.0, 5.5, start_real), view_at(2.0, 3.0));
  EXPECT_NEAR(f->coords()[2], 5.5, 1e-12);
  EXPECT_NEAR(f->coords()[3], 3.0, 1e-12);
  EXPECT_NEAR(f->coords()[0], 0.0, 1e-12);
  // The far end becomes real (corner at x = 6) twice → dim 4.
  f->add_dense_information(see_wall(3.0, 0.0, 6.0, both_real), view_at(3.0, 4.0));
  EXPECT_FALSE(f->extend(view_at(3.0, 4.0)));  // once so far
  f->add_dense_information(see_wall(3.5, 0.0, 6.0, both_real), view_at(3.5, 5.0));
  const auto ext4 = f->extend(view_at(3.5, 5.0));
  ASSERT_TRUE(ext4);
  EXPECT_EQ(f->mspace_dim(), 4);
  EXPECT_NEAR(f->coords()[2], 6.0, 1e-12);
  // Measured ends now add innovation rows.
  WallFeature& w = dynamic_cast<WallFeature&>(*f);
  Innovation in;
  const Measurement m = see_wall(3.5, 0.0, 6.0, both_real);
  ASSERT_TRUE(w.innovation(to_sensor_frame(kLayout, w.coords(), view_at(3.5, 5.0).x_ms), m, in));
  EXPECT_EQ(in.eta.size(), 4);
  EXPECT_LT(in.eta.norm(), 1e-9);
}

// A copy of the wall mapped beyond its free end (x 3–5, end seen as a real
// corner three times) and merged into it: the wall slides its free end over
// the copy's extent, keeps its line, measured start and M-space dimension,
// and the copy's real-end sightings extend it to dimension 4 at the corner.
TEST(Wall, AbsorbTakesTheCopysExtentAndRealEnds) {
  WallType type(quick_config());
  const std::uint32_t start_real = ls::make_flags(ls::EndReason::Depth, ls::EndReason::Fov);
  const std::uint32_t end_real = ls::make_flags(ls::EndReason::Fov, ls::EndReason::Corner);
  auto wall = type.create(see_wall(0.0, 0.0, 2.0, start_real), view_at(0.0, 0.0));
  auto copy = type.create(see_wall(3.0, 3.0, 5.0, end_real), view_at(3.0, 3.0));
  ASSERT_TRUE(wall && copy);
  for (int k = 0; k < 3; ++k) {
    wall->add_dense_information(see_wall(0.5 * k, 0.0, 2.0, start_real), view_at(0.5 * k, k));
    copy->add_dense_information(see_wall(3.0 + 0.5 * k, 3.0, 5.0, end_real), view_at(3.0 + 0.5 * k, 3.0 + k));
  }
  ASSERT_TRUE(wall->extend(view_at(1.0, 2.0)));  // 0 → 2
  ASSERT_TRUE(wall->extend(view_at(1.0, 2.0)));  // + the start: 3
  ASSERT_EQ(wall->mspace_dim(), 3);
  ASSERT_NEAR(wall->coords()[2], 2.0, 1e-12);

  wall->absorb(*wall);  // itself: nothing to take
  EXPECT_EQ(dynamic_cast<WallFeature&>(*wall).num_observations(), 3);
  wall->absorb(*copy);
  EXPECT_EQ(dynamic_cast<WallFeature&>(*wall).num_observations(), 6);
  EXPECT_EQ(wall->mspace_dim(), 3);
  EXPECT_NEAR(wall->coords()[0], 0.0, 1e-12);  // the measured start stays
  EXPECT_NEAR(wall->coords()[1], 3.0, 1e-12);  // the line stays
  EXPECT_NEAR(wall->coords()[3], 3.0, 1e-12);
  EXPECT_NEAR(wall->coords()[2], 5.0, 1e-12);  // the free end slid over the copy
  const auto ext = wall->extend(view_at(4.0, 5.0));
  ASSERT_TRUE(ext);
  EXPECT_EQ(ext->new_dims, 1);
  EXPECT_EQ(wall->mspace_dim(), 4);
  EXPECT_NEAR(wall->coords()[2], 5.0, 1e-12);
}

// Rotating the whole world (robot and wall) about the origin changes no
// innovation: J_η,state (eq. 30) must annihilate that direction, or relative
// measurements would create absolute heading information.
TEST(Wall, InnovationJacobianAnnihilatesGlobalRotation) {
  const Eigen::Vector4d x_f(13.628, 0.0819, 1.4999, 0.0157);
  const Pose6 x_ms = make_pose2d(6.3, 1.5, 0.005);
  const WallFeature w(WallConfig{}, x_f, 2, {});
  Eigen::MatrixXd J_of, J_os;
  const Eigen::VectorXd x_o = to_sensor_frame(kLayout, x_f, x_ms, &J_of, &J_os);
  const PredictedLine p = predict_line(x_o);
  Eigen::VectorXd dpose = Eigen::VectorXd::Zero(6);
  dpose[kX] = -x_ms[kY];
  dpose[kY] = x_ms[kX];
  dpose[kTheta] = 1.0;
  Eigen::Vector4d dx_f;
  dx_f << -x_f[1], x_f[0], -x_f[3], x_f[2];
  const Eigen::Vector2d dp = w.B() * dx_f;
  const Eigen::Vector4d d_eta = p.J * (J_os * dpose + J_of * w.B_dual() * dp);
  EXPECT_LT(std::abs(d_eta[0]), 1e-9);
  EXPECT_LT(std::abs(d_eta[1]), 1e-9);
}

// The anchored B/B̃ (rotation about a point that stays put while unmeasured
// ends slide) are dual at every dimension, equal eq. 14/15 at the centre,
// and the anchor does not move under a rotation perturbation.
TEST(Wall, AnchoredProjectionsAreDualAndMatchEq14AtTheCentre) {
  const Eigen::Vector4d x = some_wall();
  const Eigen::Vector2d anchor = x.head<2>() + 0.2 * (x.tail<2>() - x.head<2>());
  for (const std::vector<int>& ends : {std::vector<int>{}, {kStart}, {kEnd, kStart}}) {
    const Eigen::MatrixXd B = wall_B(x, ends, anchor), Bd = wall_B_dual(x, ends, anchor);
    EXPECT_LT((B * Bd - Eigen::MatrixXd::Identity(B.rows(), B.rows())).norm(), 1e-12);
  }
  const Eigen::Vector2d centre = 0.5 * (x.head<2>() + x.tail<2>());
  EXPECT_LT((wall_B(x, {}, centre) - wall_B(x, {})).norm(), 1e-12);
  WallFeature w(WallConfig{}, x, 2, {});
  w.set_anchor(anchor);
  w.apply_perturbation(Eigen::Vector2d(0.05, 0.0));  // rotation only
  EXPECT_LT((w.anchor() - anchor).norm(), 1e-3 * 0.05);  // second order
  const Eigen::Vector2d t = (w.coords().tail<2>() - w.coords().head<2>()).normalized();
  EXPECT_NEAR(t.x() * (anchor.y() - w.coords()[1]) - t.y() * (anchor.x() - w.coords()[0]), 0.0, 1e-3);
}

// ---- Shared corners (T-RO §VI, eq. 33) -------------------------------------

// Every sharing configuration: B B̃ = I; with one shared end the angle column
// moves only the free end, by (L/L_s) γ (eq. 33); the shared end's columns
// are the identity (and, with one shared end, move the free end alike).
TEST(Wall, SharedProjectionMatricesAreDual) {
  const Eigen::Vector4d x = some_wall();  // L = 5
  const Eigen::Vector2d t(0.6, 0.8), gamma(0.8, -0.6);
  struct Case {
    std::vector<int> ends;
    std::array<bool, 2> shared;
    int dims;
  };
  for (const Case& c : {Case{{}, {false, true}, 3}, Case{{kStart}, {false, true}, 4}, Case{{}, {true, false}, 3},
                        Case{{}, {true, true}, 4}}) {
    const Eigen::MatrixXd B = shared_wall_B(x, c.ends, c.shared, 4.0), Bd = shared_wall_B_dual(x, c.ends, c.shared, 4.0);
    ASSERT_EQ(Bd.cols(), c.dims);
    EXPECT_LT((B * Bd - Eigen::MatrixXd::Identity(c.dims, c.dims)).norm(), 1e-12);
    EXPECT_LT((Bd.rightCols<2>().middleRows<2>(c.shared[kEnd] ? 2 : 0) - Eigen::Matrix2d::Identity()).norm(), 1e-12);
  }
  const Eigen::MatrixXd Bd = shared_wall_B_dual(x, {}, {false, true}, 4.0);
  EXPECT_LT((Bd.col(0).head<2>() - 1.25 * gamma).norm(), 1e-12);
  EXPECT_LT(Bd.col(0).tail<2>().norm(), 1e-12);
}

// Lines y = 0 and y = √3 (x − 1) (60°) cross at (1, 0); the Jacobians match
// central differences; at 20° (< 30°) the join is refused.
TEST(Wall, CornerIsTheIntersectionOfTheLines) {
  const Eigen::Vector4d a(-3.0, 0.0, 0.5, 0.0), b(1.2, std::sqrt(3.0) * 0.2, 3.0, std::sqrt(3.0) * 2.0);
  const std::optional<LineIntersection> c = intersect_lines(a, b, 30.0 * std::numbers::pi / 180.0);
  ASSERT_TRUE(c.has_value());
  EXPECT_LT((c->point - Eigen::Vector2d(1.0, 0.0)).norm(), 1e-12);
  for (int i = 0; i < 4; ++i) {
    Eigen::Vector4d d = Eigen::Vector4d::Zero();
    d[i] = kStep;
    const Eigen::Vector2d ja = (intersect_lines(a + d, b, 0.0)->point - intersect_lines(a - d, b, 0.0)->point) / (2 * kStep);
    const Eigen::Vector2d jb = (intersect_lines(a, b + d, 0.0)->point - intersect_lines(a, b - d, 0.0)->point) / (2 * kStep);
    EXPECT_LT((ja - c->J_a.col(i)).norm(), 1e-6) << "a coordinate " << i;
    EXPECT_LT((jb - c->J_b.col(i)).norm(), 1e-6) << "b coordinate " << i;
  }
  const Eigen::Vector4d shallow(0.0, 0.1, 3.0, 0.1 + 3.0 * std::tan(20.0 * std::numbers::pi / 180.0));
  EXPECT_FALSE(intersect_lines(a, shallow, 30.0 * std::numbers::pi / 180.0).has_value());

  WallFeature wa(WallConfig{}, a, 2, {}), wb(WallConfig{}, b, 2, {});
  const std::optional<JoinProposal> p = wa.propose_join(kEnd, wb, kStart);
  ASSERT_TRUE(p.has_value());
  EXPECT_LT((p->value - Eigen::Vector2d(1.0, 0.0)).norm(), 1e-12);
  EXPECT_FALSE(wa.propose_join(kEnd, WallFeature(WallConfig{}, shallow, 2, {}), kStart).has_value());
}

// A dim-2 wall (0, 0) → (4, 0), anchor at the centre, shares its end at (4, 0):
// γ = (0, −1); the old rotation column moves the start by 2√2 γ and the end
// by −2√2 γ, the offset column both by γ/√2, so the new angle (the start's
// normal move relative to the corner, L = L_s) is T = (4√2, 0).
TEST(Wall, ShareBlockCarriesTheOwnDimensionsOver) {
  WallFeature w(WallConfig{}, Eigen::Vector4d(0.0, 0.0, 4.0, 0.0), 2, {});
  ASSERT_TRUE(w.can_share(kEnd));
  const Eigen::MatrixXd T = w.share_block(kEnd, Eigen::Vector2d(4.0, 0.0));
  ASSERT_EQ(T.rows(), 1);
  ASSERT_EQ(T.cols(), 2);
  EXPECT_NEAR(T(0, 0), 4.0 * std::numbers::sqrt2, 1e-12);
  EXPECT_NEAR(T(0, 1), 0.0, 1e-12);
  EXPECT_EQ(w.mspace_dim(), 3);
  EXPECT_FALSE(w.can_share(kEnd));
  EXPECT_DOUBLE_EQ(w.shared_length(), 4.0);
  // The second end: no own dimension is left.
  const Eigen::MatrixXd T2 = w.share_block(kStart, Eigen::Vector2d(0.0, 0.1));
  EXPECT_EQ(T2.rows(), 0);
  EXPECT_EQ(T2.cols(), 3);
  EXPECT_EQ(w.mspace_dim(), 4);
  EXPECT_EQ(w.coords(), Eigen::Vector4d(0.0, 0.1, 4.0, 0.0));
}

// Scan points beyond both ends: the free start slides out to x = −1, the
// shared end stays at (4, 0), and the angle column grows to (L/L_s) γ = 1.25 γ,
// so one unit still turns the wall by 1/L_s (eq. 33).
TEST(Wall, SlidingNeverMovesASharedEnd) {
  WallFeature w(WallConfig{}, Eigen::Vector4d(0.0, 0.0, 4.0, 0.0), 2, {});
  w.share_block(kEnd, Eigen::Vector2d(4.0, 0.0));
  Measurement m;
  m.kind = ls::kKind;
  m.v = Eigen::Vector4d(2.0, std::numbers::pi / 2.0, -3.0, 3.0);  // seen from (2, −2), heading 0
  m.C_v = Eigen::Vector4d(1e-4, 1e-4, 1e-2, 1e-2).asDiagonal();
  m.dense.resize(2, 7);
  for (int i = 0; i < 7; ++i) m.dense.col(i) = Eigen::Vector2d(-3.0 + i, 2.0);  // map x from −1 to 5
  SensorView view;
  view.x_ms = make_pose2d(2.0, -2.0, 0.0);
  w.add_dense_information(m, view);
  EXPECT_LT((w.coords() - Eigen::Vector4d(-1.0, 0.0, 4.0, 0.0)).norm(), 1e-12);
  EXPECT_LT((w.B_dual().col(0).head<2>() - Eigen::Vector2d(0.0, -1.25)).norm(), 1e-12);
}

TEST(Wall, SaveRestoreKeepsSharedCorners) {
  WallType type(WallConfig{});
  WallFeature w(WallConfig{}, Eigen::Vector4d(0.0, 0.0, 4.0, 0.0), 3, {kStart});
  w.share_block(kEnd, Eigen::Vector2d(4.0, 0.0));
  const std::unique_ptr<Feature> back = type.restore(w.save());
  EXPECT_EQ(back->mspace_dim(), w.mspace_dim());
  EXPECT_EQ(back->coords(), w.coords());
  EXPECT_LT((back->B_dual() - w.B_dual()).norm(), 1e-12);
  EXPECT_FALSE(back->can_share(kEnd));
}

}  // namespace
}  // namespace mspace::wall
