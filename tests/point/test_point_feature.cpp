// Tests of the `point` feature type (T-RO §IV-E): projection matrices
// (eqs. 10–12), the innovation and its Jacobians (eq. 16), creation,
// dense information and the M-space extension.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <memory>
#include <numbers>
#include <random>
#include <vector>

#include "mspace/pose.hpp"
#include "mspace/transform.hpp"
#include "point_feature.hpp"

namespace mspace::point {
namespace {

constexpr double kPi = std::numbers::pi;

PluginArgs point_args(std::int64_t min_observations = 3, std::int64_t max_dense = 10,
                      double min_range_for_init = 0.0) {
  PluginArgs args;
  args.instance_name = "points";
  args.params = Params::defaults(PointType::param_specs());
  args.params.set("min_observations", min_observations);
  args.params.set("max_dense", max_dense);
  args.params.set("min_range_for_init", min_range_for_init);
  return args;
}

Measurement rbe(double r, double b, double e, double sr = 0.05, double sb = 0.01,
                double se = 0.02) {
  Measurement m;
  m.kind = kRangeBearingElevation;
  m.v = Eigen::Vector3d(r, b, e);
  m.C_v = Eigen::Vector3d(sr * sr, sb * sb, se * se).asDiagonal();
  return m;
}

SensorView view_at(const Pose6& x_ms, double t = 1.0, int sensor = 0,
                   const Mat6& C_ms = Mat6::Zero()) {
  SensorView view;
  view.t = t;
  view.sensor = sensor;
  view.x_ms = x_ms;
  view.C_ms = C_ms;
  return view;
}

/// Reference back-projection written independently of the plugin and of
/// to_map_frame: p = r (cos e cos b, cos e sin b, sin e), x_f = R p + t.
Eigen::Vector3d reference_back_projection(const Eigen::Vector3d& v, const Pose6& x_ms) {
  const Eigen::Vector3d p(v[0] * std::cos(v[2]) * std::cos(v[1]),
                          v[0] * std::cos(v[2]) * std::sin(v[1]), v[0] * std::sin(v[2]));
  return rotation(x_ms) * p + x_ms.head<3>();
}

class Random {
 public:
  explicit Random(unsigned seed) : gen_(seed) {}
  double uniform(double lo, double hi) { return std::uniform_real_distribution<>(lo, hi)(gen_); }
  /// A sensor pose with arbitrary yaw and tilts up to ±0.6 rad.
  Pose6 tilted_pose() {
    return make_pose(uniform(-10, 10), uniform(-10, 10), uniform(-2, 2), uniform(-kPi, kPi),
                     uniform(-0.6, 0.6), uniform(-0.6, 0.6));
  }
  /// A measurement well away from the sensor's z axis.
  Eigen::Vector3d measurement() {
    return {uniform(0.5, 30.0), uniform(-kPi, kPi), uniform(-1.2, 1.2)};
  }

 private:
  std::mt19937 gen_;
};

/// A point initialised (dim 3) from three observations of v from x_ms.
std::unique_ptr<Feature> initialised_point(PointType& type, const Measurement& m, const Pose6& x_ms,
                                           std::optional<Extension>* ext) {
  std::unique_ptr<Feature> f = type.create(m, view_at(x_ms, 0.0));
  for (int i = 0; i < 3; ++i) f->add_dense_information(m, view_at(x_ms, i));
  *ext = f->extend(view_at(x_ms, 2));
  return f;
}

/// Numerical rank (0 for an empty matrix, which Eigen's LU does not accept).
int rank(const Eigen::MatrixXd& M) {
  if (M.size() == 0) return 0;
  return static_cast<int>(Eigen::FullPivLU<Eigen::MatrixXd>(M).rank());
}

// ---------------------------------------------------------------- spherical maps

TEST(PointSpherical, KnownValues) {
  const Eigen::Vector3d h = cartesian_to_spherical(Eigen::Vector3d(1.0, 1.0, std::sqrt(2.0)));
  EXPECT_NEAR(h[0], 2.0, 1e-15);
  EXPECT_NEAR(h[1], kPi / 4, 1e-15);
  EXPECT_NEAR(h[2], kPi / 4, 1e-15);
  const Eigen::Vector3d p = spherical_to_cartesian(Eigen::Vector3d(2.0, kPi / 2, -kPi / 6));
  EXPECT_NEAR(p.x(), 0.0, 1e-15);
  EXPECT_NEAR(p.y(), std::sqrt(3.0), 1e-15);
  EXPECT_NEAR(p.z(), -1.0, 1e-15);
}

// ---------------------------------------------------------------- B and B̃

TEST(PointProjection, BTimesDualIsIdentityAtEveryDimension) {
  PointType type(point_args());
  const Measurement m = rbe(4.0, 0.3, 0.1);
  const Pose6 x_ms = make_pose(1, 2, 0.5, 0.4, 0.1, -0.2);
  std::unique_ptr<Feature> f = type.create(m, view_at(x_ms));
  ASSERT_NE(f, nullptr);

  // dim 0: B is 0×3, B̃ is 3×0, B B̃ = I₀ (eq. 12), B̃ trivially full column rank.
  ASSERT_EQ(f->mspace_dim(), 0);
  EXPECT_EQ(f->B().rows(), 0);
  EXPECT_EQ(f->B().cols(), 3);
  EXPECT_EQ(f->B_dual().rows(), 3);
  EXPECT_EQ(f->B_dual().cols(), 0);
  EXPECT_EQ((f->B() * f->B_dual()).size(), 0);
  EXPECT_EQ(rank(f->B_dual()), 0);

  std::optional<Extension> ext;
  f = initialised_point(type, m, x_ms, &ext);
  ASSERT_TRUE(ext.has_value());
  ASSERT_EQ(f->mspace_dim(), type.max_mspace_dim());
  // dim 3 (Table II): B = B̃ = I₃.
  EXPECT_TRUE(f->B().isApprox(Eigen::Matrix3d::Identity(), 0.0));
  EXPECT_TRUE((f->B() * f->B_dual()).isIdentity(0.0));
  EXPECT_EQ(rank(f->B_dual()), 3);
}

TEST(PointProjection, ApplyPerturbationMovesThePoint) {
  PointType type(point_args());
  std::optional<Extension> ext;
  auto f = initialised_point(type, rbe(5.0, 0.0, 0.0), make_pose(0, 0, 0, 0, 0, 0), &ext);
  ASSERT_EQ(f->mspace_dim(), 3);
  f->apply_perturbation(Eigen::Vector3d(0.1, -0.2, 0.3));  // eq. 24 with B̃ = I
  EXPECT_NEAR(f->coords()[0], 5.1, 1e-12);
  EXPECT_NEAR(f->coords()[1], -0.2, 1e-12);
  EXPECT_NEAR(f->coords()[2], 0.3, 1e-12);
}

// ---------------------------------------------------------------- innovation

TEST(PointInnovation, KnownValuesAndJacobianOfV) {
  PointType type(point_args());
  auto f = type.create(rbe(5, 0, 0), view_at(make_pose(0, 0, 0, 0, 0, 0)));
  Innovation inn;
  ASSERT_TRUE(f->innovation(Eigen::Vector3d(3.0, 4.0, 0.0), rbe(4.5, 0.9, 0.1), inn));
  EXPECT_NEAR(inn.eta[0], 0.5, 1e-15);
  EXPECT_NEAR(inn.eta[1], std::atan2(4.0, 3.0) - 0.9, 1e-15);
  EXPECT_NEAR(inn.eta[2], -0.1, 1e-15);
  EXPECT_TRUE(inn.J_eta_v.isApprox(-Eigen::Matrix3d::Identity(), 0.0));
  // ∂h/∂x_o at (3, 4, 0): range row (0.6, 0.8, 0), bearing row (−4, 3, 0)/25,
  // elevation row (0, 0, 1/5).
  Eigen::Matrix3d expected;
  expected << 0.6, 0.8, 0.0, -0.16, 0.12, 0.0, 0.0, 0.0, 0.2;
  EXPECT_TRUE(inn.J_eta_o.isApprox(expected, 1e-14));
}

TEST(PointInnovation, AnglesAreWrapped) {
  PointType type(point_args());
  auto f = type.create(rbe(5, 0, 0), view_at(make_pose(0, 0, 0, 0, 0, 0)));
  // Bearing of x_o is π − 0.001; the measured bearing −π + 0.001 is 0.002 away.
  const Eigen::Vector3d x_o(-1.0, std::tan(0.001), 0.0);
  Innovation inn;
  ASSERT_TRUE(f->innovation(x_o, rbe(std::hypot(1.0, std::tan(0.001)), -kPi + 0.001, 0), inn));
  EXPECT_NEAR(inn.eta[1], -0.002, 1e-12);
}

TEST(PointInnovation, RejectsOtherKindsAndPointsOnTheSensorAxis) {
  PointType type(point_args());
  auto f = type.create(rbe(5, 0, 0), view_at(make_pose(0, 0, 0, 0, 0, 0)));
  Innovation inn;
  Measurement line = rbe(5, 0, 0);
  line.kind = "line2d";
  EXPECT_FALSE(f->innovation(Eigen::Vector3d(5, 0, 0), line, inn));
  EXPECT_FALSE(f->innovation(Eigen::Vector3d(0.0, 0.0, 3.0), rbe(3, 0, kPi / 2), inn));
  EXPECT_FALSE(f->innovation(Eigen::Vector3d(1e-4, 0.0, 0.0), rbe(1e-4, 0, 0), inn));
  EXPECT_FALSE(f->innovation(Eigen::Vector2d(5, 0), rbe(5, 0, 0), inn));
}

TEST(PointInnovation, JacobianMatchesCentralDifferences) {
  PointType type(point_args());
  auto f = type.create(rbe(5, 0, 0), view_at(make_pose(0, 0, 0, 0, 0, 0)));
  Random rnd(7);
  constexpr double kStep = 1e-6;
  int checked = 0;
  for (int trial = 0; trial < 1500; ++trial) {
    const Eigen::Vector3d x_o(rnd.uniform(-20, 20), rnd.uniform(-20, 20), rnd.uniform(-10, 10));
    if (std::hypot(x_o.x(), x_o.y()) < 0.5) continue;
    // A measurement near the prediction, so η is small but not zero.
    const Eigen::Vector3d h = cartesian_to_spherical(x_o);
    const Measurement m =
        rbe(h[0] + rnd.uniform(-0.2, 0.2), wrap_angle(h[1] + rnd.uniform(-0.1, 0.1)),
            h[2] + rnd.uniform(-0.1, 0.1));
    Innovation inn;
    ASSERT_TRUE(f->innovation(x_o, m, inn));
    for (int k = 0; k < 3; ++k) {
      Innovation plus, minus;
      ASSERT_TRUE(f->innovation(x_o + kStep * Eigen::Vector3d::Unit(k), m, plus));
      ASSERT_TRUE(f->innovation(x_o - kStep * Eigen::Vector3d::Unit(k), m, minus));
      const Eigen::Vector3d numeric = (plus.eta - minus.eta) / (2 * kStep);
      EXPECT_LT((numeric - inn.J_eta_o.col(k)).norm(), 1e-7) << "x_o = " << x_o.transpose();

      Measurement mp = m, mm = m;
      mp.v[k] += kStep;
      mm.v[k] -= kStep;
      ASSERT_TRUE(f->innovation(x_o, mp, plus));
      ASSERT_TRUE(f->innovation(x_o, mm, minus));
      const Eigen::Vector3d numeric_v = (plus.eta - minus.eta) / (2 * kStep);
      EXPECT_LT((numeric_v - inn.J_eta_v.col(k)).norm(), 1e-8);
    }
    ++checked;
  }
  EXPECT_GE(checked, 1000);
}

// ---------------------------------------------------------------- create

TEST(PointCreate, BackProjectionReproducesTheMeasurement) {
  PointType type(point_args());
  Random rnd(11);
  for (int trial = 0; trial < 1000; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    const Eigen::Vector3d v = rnd.measurement();
    const Measurement m = rbe(v[0], v[1], v[2]);
    auto f = type.create(m, view_at(x_ms));
    ASSERT_NE(f, nullptr);
    EXPECT_EQ(f->mspace_dim(), 0);
    EXPECT_LT((f->coords() - reference_back_projection(v, x_ms)).norm(), 1e-9);
    const Eigen::VectorXd x_o = to_sensor_frame(f->layout(), f->coords(), x_ms);
    Innovation inn;
    ASSERT_TRUE(f->innovation(x_o, m, inn));
    EXPECT_LT(inn.eta.norm(), 1e-9) << "v = " << v.transpose();
  }
}

TEST(PointCreate, RejectsWhatCannotStartAPoint) {
  PointType type(point_args());
  const SensorView view = view_at(make_pose(0, 0, 0, 0, 0, 0));
  Measurement other = rbe(5, 0, 0);
  other.kind = "line2d";
  EXPECT_EQ(type.create(other, view), nullptr);
  EXPECT_EQ(type.create(rbe(5, 0, kPi / 2), view), nullptr);  // on the sensor's z axis
  EXPECT_EQ(type.create(rbe(std::nan(""), 0, 0), view), nullptr);
  EXPECT_EQ(type.create(rbe(-5, 0, 0), view), nullptr);
  Measurement short_v = rbe(5, 0, 0);
  short_v.v = Eigen::Vector2d(5, 0);
  EXPECT_EQ(type.create(short_v, view), nullptr);
}

TEST(PointCreate, GatingCovarianceKnownValues) {
  PointType type(point_args());
  // Sensor at the origin looking along x, point straight ahead at 4 m:
  // J_v = diag(1, r, r), so the measurement part is diag(σr², r²σb², r²σe²);
  // a translation-only sensor-pose covariance σ²I adds σ²I.
  Mat6 C_ms = Mat6::Zero();
  C_ms.topLeftCorner<3, 3>() = 0.01 * Eigen::Matrix3d::Identity();
  auto f = type.create(rbe(4.0, 0.0, 0.0, 0.1, 0.02, 0.03),
                       view_at(make_pose(0, 0, 0, 0, 0, 0), 0, 0, C_ms));
  const Eigen::MatrixXd C = f->gating_covariance();
  ASSERT_EQ(C.rows(), 3);
  ASSERT_EQ(C.cols(), 3);
  Eigen::Matrix3d expected =
      Eigen::Vector3d(0.01 + 0.01, 0.0064 + 0.01, 0.0144 + 0.01).asDiagonal();
  EXPECT_TRUE(C.isApprox(expected, 1e-12)) << C;

  // Yaw uncertainty σθ² moves the point sideways by r·δθ: + r²σθ² on y.
  C_ms = Mat6::Zero();
  C_ms(kTheta, kTheta) = 0.0025;
  f = type.create(rbe(4.0, 0.0, 0.0, 0.1, 0.02, 0.03),
                  view_at(make_pose(0, 0, 0, 0, 0, 0), 0, 0, C_ms));
  expected = Eigen::Vector3d(0.01, 0.0064 + 16 * 0.0025, 0.0144).asDiagonal();
  EXPECT_TRUE(f->gating_covariance().isApprox(expected, 1e-12)) << f->gating_covariance();
}

// ---------------------------------------------------------------- dense information and extension

TEST(PointExtend, WaitsForMinObservationsAndTheCurrentView) {
  PointType type(point_args(3, 10));
  const Pose6 x_ms = make_pose(1, 0, 0.3, 0.5, 0, 0);
  auto f = type.create(rbe(4, 0.2, 0.1), view_at(x_ms, 0.0));
  f->add_dense_information(rbe(4, 0.2, 0.1), view_at(x_ms, 0.0));
  EXPECT_FALSE(f->extend(view_at(x_ms, 0.0)).has_value());
  f->add_dense_information(rbe(4.1, 0.21, 0.1), view_at(x_ms, 1.0));
  EXPECT_FALSE(f->extend(view_at(x_ms, 1.0)).has_value());
  f->add_dense_information(rbe(4.2, 0.22, 0.1), view_at(x_ms, 2.0, 1));
  // Three observations, but the latest was not taken at this step / sensor.
  EXPECT_FALSE(f->extend(view_at(x_ms, 3.0, 1)).has_value());
  EXPECT_FALSE(f->extend(view_at(x_ms, 2.0, 0)).has_value());
  EXPECT_EQ(f->mspace_dim(), 0);
  // While tentative the point follows the latest back-projection.
  EXPECT_LT((f->coords() - reference_back_projection({4.2, 0.22, 0.1}, x_ms)).norm(), 1e-12);

  const std::optional<Extension> ext = f->extend(view_at(x_ms, 2.0, 1));
  ASSERT_TRUE(ext.has_value());
  EXPECT_EQ(ext->new_dims, 3);
  EXPECT_EQ(ext->sensor, 1);
  EXPECT_EQ(ext->J_sensor.rows(), 3);
  EXPECT_EQ(ext->J_sensor.cols(), 6);
  EXPECT_EQ(ext->J_own.rows(), 3);
  EXPECT_EQ(ext->J_own.cols(), 0);
  EXPECT_EQ(f->mspace_dim(), 3);
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 0);
  EXPECT_EQ(f->gating_covariance().size(), 0);
  EXPECT_LT((f->coords() - reference_back_projection({4.2, 0.22, 0.1}, x_ms)).norm(), 1e-12);
  // Once initialised nothing more is stored or extended.
  f->add_dense_information(rbe(4, 0.2, 0.1), view_at(x_ms, 3.0));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 0);
  EXPECT_FALSE(f->extend(view_at(x_ms, 3.0)).has_value());
}

TEST(PointExtend, KeepsAtMostMaxDenseObservations) {
  PointType type(point_args(5, 6));
  const Pose6 x_ms = make_pose(0, 0, 0, 0, 0, 0);
  auto f = type.create(rbe(4, 0.2, 0.1), view_at(x_ms));
  for (int i = 0; i < 9; ++i)
    f->add_dense_information(rbe(4 + 0.01 * i, 0.2, 0.1), view_at(x_ms, i));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 6);
  EXPECT_NEAR(f->coords()[0], reference_back_projection({4.08, 0.2, 0.1}, x_ms)[0], 1e-12);
}

TEST(PointExtend, MinRangeForInit) {
  PointType type(point_args(1, 10, 3.0));
  const Pose6 x_ms = make_pose(0, 0, 0, 0, 0, 0);
  auto f = type.create(rbe(2.5, 0.2, 0.1), view_at(x_ms, 0.0));
  f->add_dense_information(rbe(2.5, 0.2, 0.1), view_at(x_ms, 0.0));
  EXPECT_FALSE(f->extend(view_at(x_ms, 0.0)).has_value());
  f->add_dense_information(rbe(3.5, 0.2, 0.1), view_at(x_ms, 1.0));
  EXPECT_TRUE(f->extend(view_at(x_ms, 1.0)).has_value());
}

TEST(PointExtend, SensorJacobianMatchesCentralDifferences) {
  PointType type(point_args());
  Random rnd(23);
  constexpr double kStep = 1e-6;
  for (int trial = 0; trial < 500; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    const Eigen::Vector3d v = rnd.measurement();
    std::optional<Extension> ext;
    auto f = initialised_point(type, rbe(v[0], v[1], v[2]), x_ms, &ext);
    ASSERT_TRUE(ext.has_value());
    for (int k = 0; k < 6; ++k) {
      const Pose6 dx = kStep * Pose6::Unit(k);
      const Eigen::Vector3d numeric =
          (reference_back_projection(v, x_ms + dx) - reference_back_projection(v, x_ms - dx)) /
          (2 * kStep);
      EXPECT_LT((numeric - ext->J_sensor.col(k)).norm(), 1e-7)
          << "pose " << x_ms.transpose() << " column " << k;
    }
  }
}

TEST(PointExtend, NewCovarianceIsTheMeasurementPartAndPositiveDefinite) {
  PointType type(point_args());
  Random rnd(31);
  constexpr double kStep = 1e-6;
  for (int trial = 0; trial < 500; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    const Eigen::Vector3d v = rnd.measurement();
    const Measurement m = rbe(v[0], v[1], v[2], 0.03, 0.005, 0.03);
    std::optional<Extension> ext;
    auto f = initialised_point(type, m, x_ms, &ext);
    ASSERT_TRUE(ext.has_value());
    // J_v by central differences of the independent back-projection.
    Eigen::Matrix3d J_v;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d dv = kStep * Eigen::Vector3d::Unit(k);
      J_v.col(k) =
          (reference_back_projection(v + dv, x_ms) - reference_back_projection(v - dv, x_ms)) /
          (2 * kStep);
    }
    const Eigen::Matrix3d expected = J_v * m.C_v * J_v.transpose();
    EXPECT_LT((ext->C_new - expected).norm(), 1e-7 * expected.norm());
    EXPECT_TRUE(ext->C_new.isApprox(ext->C_new.transpose(), 0.0));
    const Eigen::Matrix3d C_new = ext->C_new;
    EXPECT_EQ(Eigen::LLT<Eigen::Matrix3d>(C_new).info(), Eigen::Success);
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(C_new).eigenvalues().minCoeff(), 0.0);
  }
}

TEST(PointType, DescribesItselfAndValidatesParameters) {
  PointType type(point_args());
  EXPECT_EQ(type.max_mspace_dim(), 3);
  EXPECT_EQ(type.layout().size(), 3);
  EXPECT_EQ(type.layout().kind(0), BlockKind::Point3D);
  EXPECT_EQ(type.reachable_dims(), (std::vector<int>{0, 2, 3}));
  ASSERT_EQ(type.measurement_kinds().size(), 3u);
  EXPECT_EQ(type.measurement_kinds()[0], "range_bearing_elevation");
  EXPECT_EQ(type.measurement_kinds()[1], "range_bearing");
  EXPECT_EQ(type.measurement_kinds()[2], "bearing3d");
  const Params defaults = Params::defaults(PointType::param_specs());
  EXPECT_EQ(defaults.get_int("min_observations"), 3);
  EXPECT_THROW(PointType(point_args(5, 4)), std::invalid_argument);
}

}  // namespace
}  // namespace mspace::point
