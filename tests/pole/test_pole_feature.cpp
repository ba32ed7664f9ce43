// Tests of the `pole` feature type (T-RO §IV-H): h and its inverse, the
// innovation and J_ηo (eq. 16) against central differences, B B̃ = I
// (eq. 12), tentative life cycle and initialisation, gating, sample/restore.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <functional>
#include <numbers>
#include <random>

#include "mspace/pose.hpp"
#include "mspace/transform.hpp"
#include "pole_feature.hpp"

namespace mspace::pole {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kStep = 1e-6;
constexpr double kJacobianTol = 1e-7;

Measurement rbd(double r, double b, double d, double sr = 0.1, double sb = 0.01, double sd = 0.05) {
  Measurement m;
  m.kind = kRangeBearingDiameter;
  m.v = Eigen::Vector3d(r, b, d);
  m.C_v = Eigen::Vector3d(sr * sr, sb * sb, sd * sd).asDiagonal();
  return m;
}

SensorView view_at(const Pose6& x_ms, double t = 0.0, double sigma = 0.0) {
  SensorView v;
  v.t = t;
  v.x_ms = x_ms;
  v.C_ms = Mat6::Identity() * sigma * sigma;
  return v;
}

Eigen::MatrixXd central_difference(const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& f,
                                   const Eigen::VectorXd& x) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    Eigen::VectorXd xp = x, xm = x;
    xp[i] += kStep;
    xm[i] -= kStep;
    J.col(i) = (f(xp) - f(xm)) / (2 * kStep);
  }
  return J;
}

double relative_error(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).norm() / std::max(1.0, b.norm());
}

TEST(PoleMaths, ObserveOfKnownPole) {
  // A pole of radius 0.3 at (3, 4) in the sensor frame: r = 5, b = atan2(4, 3), d = 0.6.
  const Eigen::Vector3d v = observe(Eigen::Vector3d(0.3, 3.0, 4.0));
  EXPECT_NEAR(v[0], 5.0, 1e-12);
  EXPECT_NEAR(v[1], std::atan2(4.0, 3.0), 1e-12);
  EXPECT_NEAR(v[2], 0.6, 1e-12);
  const Eigen::Vector3d back = sensor_coords(v);
  EXPECT_LT((back - Eigen::Vector3d(0.3, 3.0, 4.0)).norm(), 1e-12);
}

TEST(PoleMaths, JacobiansMatchCentralDifferences) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double worst = 0.0;
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3d x_o(0.5 + 0.4 * u(rng), 20 * u(rng), 20 * u(rng));
    Eigen::Matrix3d J;
    observe(x_o, &J);
    worst = std::max(worst, relative_error(J, central_difference([](const Eigen::VectorXd& x) -> Eigen::VectorXd {
                                                   return observe(x);
                                                 }, x_o)));
    const Eigen::Vector3d v(1 + 30 * std::abs(u(rng)), kPi * u(rng), 1 + u(rng));
    Eigen::Matrix3d J_ov;
    sensor_coords(v, &J_ov);
    worst = std::max(worst, relative_error(J_ov, central_difference([](const Eigen::VectorXd& x) -> Eigen::VectorXd {
                                                    return sensor_coords(x);
                                                  }, v)));
  }
  EXPECT_LT(worst, kJacobianTol);
}

TEST(PoleFeature, ProjectionMatricesAtBothDimensions) {
  PoleType type(PoleConfig{});
  for (int dim : {0, 3}) {
    const auto s = type.sample(dim, 11);
    ASSERT_TRUE(s.has_value());
    const Eigen::MatrixXd B = s->feature->B(), Bd = s->feature->B_dual();
    EXPECT_EQ(B.rows(), dim);
    EXPECT_EQ(B.cols(), 3);
    EXPECT_EQ(Bd.rows(), 3);
    EXPECT_EQ(Bd.cols(), dim);
    EXPECT_TRUE((B * Bd).isApprox(Eigen::MatrixXd::Identity(dim, dim)) || dim == 0);  // eq. 12
  }
  EXPECT_FALSE(type.sample(2, 1).has_value());
  EXPECT_EQ(type.reachable_dims(), (std::vector<int>{0, 3}));
  EXPECT_EQ(type.layout(), (CoordLayout{BlockKind::Scalar, BlockKind::Point2D}));
}

TEST(PoleFeature, InnovationIsZeroForSamplesAndJacobianMatches) {
  PoleType type(PoleConfig{});
  double worst = 0.0;
  for (std::uint64_t seed = 0; seed < 200; ++seed) {
    for (int dim : {0, 3}) {
      const auto s = type.sample(dim, seed);
      const Feature& f = *s->feature;
      const Eigen::VectorXd x_o = to_sensor_frame(f.layout(), f.coords(), s->x_ms);
      Innovation in;
      ASSERT_TRUE(f.innovation(x_o, s->measurement, in));
      EXPECT_LT(in.eta.norm(), 1e-9) << "seed " << seed << " dim " << dim;
      EXPECT_TRUE(in.J_eta_v.isApprox(-Eigen::MatrixXd::Identity(3, 3)));
      const auto eta = [&](const Eigen::VectorXd& x) -> Eigen::VectorXd {
        Innovation i2;
        f.innovation(x, s->measurement, i2);
        return i2.eta;
      };
      worst = std::max(worst, relative_error(in.J_eta_o, central_difference(eta, x_o)));
    }
  }
  EXPECT_LT(worst, kJacobianTol);
}

TEST(PoleFeature, InnovationIsTheReferenceFormulaBitForBit) {
  // innovation() skips hypot away from the minimum range and wrap_angle's
  // remainder inside (−π, π]: the same bits as the plain formulas
  // (h of eq. 16, η = h − v with the bearing wrapped), near the minimum range
  // and far from it, with bearings on both sides of ±π.
  PoleType type(PoleConfig{});
  const auto f = type.create(rbd(5, 0, 0.4), view_at(Pose6::Zero()));
  ASSERT_NE(f, nullptr);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int rejected = 0, accepted = 0;
  for (int i = 0; i < 20000; ++i) {
    const double scale = i % 4 == 0 ? 3e-3 : (i % 4 == 1 ? 1e-6 : 30.0);
    const Eigen::Vector3d x_o(0.3 + 0.1 * u(rng), scale * u(rng), scale * u(rng));
    const Measurement m = rbd(scale * (1.0 + u(rng)), kPi * u(rng) * 1.2, 0.5 + 0.1 * u(rng));
    const bool expected = std::hypot(x_o[1], x_o[2]) >= kMinRange;
    Innovation in;
    ASSERT_EQ(f->innovation(x_o, m, in), expected) << x_o.transpose();
    if (!expected) {
      ++rejected;
      continue;
    }
    ++accepted;
    const double x = x_o[1], y = x_o[2], r2 = x * x + y * y;
    Eigen::Vector3d eta(std::sqrt(r2) - m.v[0], std::atan2(y, x) - m.v[1], 2.0 * x_o[0] - m.v[2]);
    double w = std::remainder(eta[1], 2.0 * kPi);
    if (w <= -kPi) w += 2.0 * kPi;
    eta[1] = w;
    ASSERT_EQ(in.eta.size(), 3);
    for (int k = 0; k < 3; ++k) ASSERT_EQ(in.eta[k], eta[k]) << k << " at " << x_o.transpose();
  }
  EXPECT_GT(rejected, 1000);
  EXPECT_GT(accepted, 10000);
}

TEST(PoleFeature, RejectsOtherKindsAndDegenerateGeometry) {
  PoleType type(PoleConfig{});
  const SensorView view = view_at(Pose6::Zero());
  Measurement wrong = rbd(5, 0, 0.4);
  wrong.kind = "range_bearing_elevation";
  EXPECT_EQ(type.create(wrong, view), nullptr);
  EXPECT_EQ(type.create(rbd(0.0, 0, 0.4), view), nullptr);   // no bearing
  EXPECT_EQ(type.create(rbd(5.0, 0, -0.1), view), nullptr);  // negative diameter
  auto f = type.create(rbd(5, 0, 0.4), view);
  ASSERT_NE(f, nullptr);
  Innovation in;
  EXPECT_FALSE(f->innovation(Eigen::Vector3d(0.2, 0.0, 0.0), rbd(5, 0, 0.4), in));  // centre at the sensor
  EXPECT_THROW(f->add_dense_information(wrong, view), std::invalid_argument);
}

TEST(PoleFeature, TentativeUntilMinDetectionsThenInitialisedFromNewest) {
  PoleType type(PoleConfig{3, 0.0});
  // Sensor at (10, 5) facing +y; the pole 8 m ahead, radius 0.25: centre (10, 13).
  const Pose6 x_ms = make_pose2d(10, 5, kPi / 2);
  auto f = type.create(rbd(8, 0, 0.5), view_at(x_ms, 0.0, 0.1));
  ASSERT_NE(f, nullptr);
  EXPECT_EQ(f->mspace_dim(), 0);
  EXPECT_LT((f->coords() - Eigen::Vector3d(0.25, 10, 13)).norm(), 1e-12);
  EXPECT_EQ(f->gating_covariance().rows(), 3);

  for (int k = 0; k < 3; ++k) {
    const SensorView view = view_at(x_ms, 0.2 * k, 0.1);
    f->add_dense_information(rbd(8, 0, 0.5 + 0.1 * k), view);
    auto ext = f->extend(view);
    if (k < 2) {
      EXPECT_FALSE(ext.has_value()) << "after " << k + 1 << " detections";
      continue;
    }
    ASSERT_TRUE(ext.has_value());
    EXPECT_EQ(ext->new_dims, 3);
    // Initialised from the newest detection: diameter 0.7 → radius 0.35.
    EXPECT_LT((f->coords() - Eigen::Vector3d(0.35, 10, 13)).norm(), 1e-12);
    // δradius = δd/2 → variance σ_d²/4; the radius does not depend on the sensor pose.
    EXPECT_NEAR(ext->C_new(0, 0), 0.05 * 0.05 / 4, 1e-15);
    EXPECT_NEAR(ext->J_sensor.row(0).norm(), 0.0, 1e-15);
    // δcentre_x = δx_ms − 8 δθ (the pole is 8 m along +y): J_sensor row 1.
    EXPECT_NEAR(ext->J_sensor(1, kX), 1.0, 1e-12);
    EXPECT_NEAR(ext->J_sensor(1, kTheta), -8.0, 1e-12);
    EXPECT_EQ(f->mspace_dim(), 3);
    EXPECT_EQ(f->gating_covariance().size(), 0);
  }
  EXPECT_FALSE(f->extend(view_at(x_ms, 1.0)).has_value());  // already at full dimension
}

TEST(PoleFeature, DoesNotInitialiseFromAnOldDetectionOrTooClose) {
  PoleType type(PoleConfig{1, 5.0});
  const Pose6 x_ms = Pose6::Zero();
  auto near = type.create(rbd(3, 0, 0.5), view_at(x_ms, 1.0));
  near->add_dense_information(rbd(3, 0, 0.5), view_at(x_ms, 1.0));
  EXPECT_FALSE(near->extend(view_at(x_ms, 1.0)).has_value());  // 3 m < min_range_for_init
  auto far = type.create(rbd(8, 0, 0.5), view_at(x_ms, 1.0));
  far->add_dense_information(rbd(8, 0, 0.5), view_at(x_ms, 1.0));
  EXPECT_FALSE(far->extend(view_at(x_ms, 2.0)).has_value());  // detection not from this step
  EXPECT_TRUE(far->extend(view_at(x_ms, 1.0)).has_value());
}

TEST(PoleFeature, SaveRestoreRoundTrip) {
  PoleType type(PoleConfig{});
  for (int dim : {0, 3}) {
    const auto s = type.sample(dim, 3);
    const SavedFeature saved = s->feature->save();
    const auto restored = type.restore(saved);
    EXPECT_EQ(restored->mspace_dim(), dim);
    EXPECT_EQ(restored->coords(), s->feature->coords());
    const Eigen::MatrixXd g0 = s->feature->gating_covariance(), g1 = restored->gating_covariance();
    EXPECT_EQ(g0.size(), g1.size());
    if (g0.size() > 0) {
      EXPECT_EQ(g0, g1);
    }
    EXPECT_EQ(restored->save().extra, saved.extra);
  }
  EXPECT_THROW(type.restore(SavedFeature{Eigen::Vector2d(1, 2), 3, {}}), std::invalid_argument);
  EXPECT_THROW(type.restore(SavedFeature{Eigen::Vector3d(1, 2, 3), 2, {}}), std::invalid_argument);
  EXPECT_THROW(type.restore(SavedFeature{Eigen::Vector3d(1, 2, 3), 0, Eigen::VectorXd(3)}), std::invalid_argument);
}

TEST(PoleFeature, PerturbationMovesRadiusAndCentre) {
  PoleType type(PoleConfig{});
  auto f = type.restore(SavedFeature{Eigen::Vector3d(0.3, 1, 2), 3, {}});
  f->apply_perturbation(Eigen::Vector3d(0.05, -1, 0.5));  // eq. 24 with B̃ = I
  EXPECT_LT((f->coords() - Eigen::Vector3d(0.35, 0, 2.5)).norm(), 1e-15);
}

}  // namespace
}  // namespace mspace::pole
