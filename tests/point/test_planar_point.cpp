// Tests of the planar `point`: M-space dimension 2 (B = [I₂ 0], eqs. 10–12),
// the planar range/bearing innovation and its Jacobians (eq. 16), the
// extensions 0 → 2 and 2 → 3 (J_sensor, J_own, C_new against independent
// reference formulas and central differences), and save/restore of the new
// state. The reference formulas below are written without the plugin's or the
// SDK placement's code.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <optional>
#include <random>
#include <stdexcept>
#include <vector>

#include "mspace/pose.hpp"
#include "mspace/transform.hpp"
#include "point_feature.hpp"

namespace mspace::point {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kStep = 1e-6;

PointType make_type(std::int64_t min_observations = 3) {
  PluginArgs args;
  args.instance_name = "points";
  args.params = Params::defaults(PointType::param_specs());
  args.params.set("min_observations", min_observations);
  return PointType(args);
}

PointConfig config() { return make_type().config(); }

Measurement planar(double r, double b, double sr = 0.05, double sb = 0.01) {
  Measurement m;
  m.kind = kRangeBearing;
  m.v = Eigen::Vector2d(r, b);
  m.C_v = Eigen::Vector2d(sr * sr, sb * sb).asDiagonal();
  return m;
}

Measurement rbe(double r, double b, double e, double sr = 0.05, double sb = 0.01, double se = 0.02) {
  Measurement m;
  m.kind = kRangeBearingElevation;
  m.v = Eigen::Vector3d(r, b, e);
  m.C_v = Eigen::Vector3d(sr * sr, sb * sb, se * se).asDiagonal();
  return m;
}

Measurement bearing(const Eigen::Vector3d& direction) {
  Measurement m;
  m.kind = kBearing3d;
  m.v = direction.normalized();
  m.C_v = 1e-4 * (Eigen::Matrix3d::Identity() - m.v * m.v.transpose());
  return m;
}

SensorView view_at(const Pose6& x_ms, double t = 1.0, int sensor = 0) {
  SensorView view;
  view.t = t;
  view.sensor = sensor;
  view.x_ms = x_ms;
  view.C_ms = Mat6::Zero();
  return view;
}

// ---- independent references

/// Map-frame point of a planar (r, b): R (r cos b, r sin b, 0) + t.
Eigen::Vector3d ref_planar_back_projection(const Eigen::Vector2d& v, const Pose6& x_ms) {
  return rotation(x_ms) * Eigen::Vector3d(v[0] * std::cos(v[1]), v[0] * std::sin(v[1]), 0.0) + x_ms.head<3>();
}

/// The measurement (r, b, e) of a map-frame point seen from x_ms.
Eigen::Vector3d ref_measure(const Eigen::Vector3d& p, const Pose6& x_ms) {
  const Eigen::Vector3d q = rotation(x_ms).transpose() * (p - x_ms.head<3>());
  return {q.norm(), std::atan2(q.y(), q.x()), std::atan2(q.z(), std::hypot(q.x(), q.y()))};
}

/// The height where the ray (b, e) from x_ms passes the vertical line through
/// (x, y): closest approach in the horizontal plane.
double ref_ray_height(const Eigen::Vector2d& xy, const Eigen::Vector3d& v, const Pose6& x_ms) {
  const Eigen::Vector3d u =
      rotation(x_ms) *
      Eigen::Vector3d(std::cos(v[2]) * std::cos(v[1]), std::cos(v[2]) * std::sin(v[1]), std::sin(v[2]));
  const Eigen::Vector2d u_h = u.head<2>();
  const double lambda = u_h.dot(xy - x_ms.head<2>()) / u_h.squaredNorm();
  return x_ms[2] + u.z() * lambda;
}

/// Central differences of f: R^n → R^m at x.
template <class F>
Eigen::MatrixXd numeric(F&& f, const Eigen::VectorXd& x) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (Eigen::Index k = 0; k < x.size(); ++k) {
    Eigen::VectorXd xp = x, xm = x;
    xp[k] += kStep;
    xm[k] -= kStep;
    J.col(k) = (f(xp) - f(xm)) / (2 * kStep);
  }
  return J;
}

class Random {
 public:
  explicit Random(unsigned seed) : gen_(seed) {}
  double uniform(double lo, double hi) { return std::uniform_real_distribution<>(lo, hi)(gen_); }
  Pose6 tilted_pose() {
    return make_pose(uniform(-10, 10), uniform(-10, 10), uniform(-1, 1), uniform(-kPi, kPi), uniform(-0.3, 0.3),
                     uniform(-0.3, 0.3));
  }

 private:
  std::mt19937 gen_;
};

/// A point brought to dim 2 by planar observations of v from x_ms.
std::unique_ptr<Feature> planar_point(PointType& type, const Measurement& m, const Pose6& x_ms,
                                      std::optional<Extension>* ext = nullptr) {
  std::unique_ptr<Feature> f = type.create(m, view_at(x_ms, 0.0));
  std::optional<Extension> e;
  for (int k = 0; k < 3 && !e; ++k) {
    f->add_dense_information(m, view_at(x_ms, k));
    e = f->extend(view_at(x_ms, k));
  }
  if (ext != nullptr) *ext = e;
  return f;
}

// ---------------------------------------------------------------- B and B̃

TEST(PlanarPoint, BIsTheHorizontalPartAndBTimesDualIsIdentity) {
  PointType type = make_type();
  const Pose6 x_ms = make_pose(1, 2, 0.5, 0.4, 0, 0);
  std::unique_ptr<Feature> f = planar_point(type, planar(4.0, 0.3), x_ms);
  ASSERT_EQ(f->mspace_dim(), 2);
  Eigen::Matrix<double, 2, 3> B;
  B << 1, 0, 0, 0, 1, 0;
  EXPECT_TRUE(f->B().isApprox(B, 0.0)) << f->B();
  EXPECT_TRUE(f->B_dual().isApprox(B.transpose(), 0.0)) << f->B_dual();
  EXPECT_TRUE((f->B() * f->B_dual()).isIdentity(0.0));  // eq. 12
  // eq. 24: x_f += B̃ δx_p moves x and y; z is outside the M-space.
  const Eigen::Vector3d before = f->coords();
  f->apply_perturbation(Eigen::Vector2d(0.1, -0.2));
  EXPECT_NEAR(f->coords()[0], before[0] + 0.1, 1e-12);
  EXPECT_NEAR(f->coords()[1], before[1] - 0.2, 1e-12);
  EXPECT_EQ(f->coords()[2], before[2]);
  EXPECT_EQ(f->gating_covariance().size(), 0);
}

// ---------------------------------------------------------------- innovation

TEST(PlanarPoint, InnovationKnownValues) {
  PointType type = make_type();
  for (int dim : {0, 2, 3}) {
    PointFeature f(config(), Eigen::Vector3d(1, 2, 3), dim);
    Innovation inn;
    ASSERT_TRUE(f.innovation(Eigen::Vector3d(3.0, 4.0, 1.5), planar(4.5, 0.9), inn)) << dim;
    ASSERT_EQ(inn.eta.size(), 2);
    EXPECT_NEAR(inn.eta[0], 0.5, 1e-15);
    EXPECT_NEAR(inn.eta[1], std::atan2(4.0, 3.0) - 0.9, 1e-15);
    Eigen::Matrix<double, 2, 3> J;
    J << 0.6, 0.8, 0.0, -0.16, 0.12, 0.0;  // the height does not enter
    EXPECT_TRUE(inn.J_eta_o.isApprox(J, 1e-14)) << inn.J_eta_o;
    EXPECT_TRUE(inn.J_eta_v.isApprox(-Eigen::Matrix2d::Identity(), 0.0));
  }
  // At dim 2 a range/bearing/elevation contributes its planar part (r cos e, b).
  PointFeature f(config(), Eigen::Vector3d(1, 2, 3), 2);
  Innovation inn;
  ASSERT_TRUE(f.innovation(Eigen::Vector3d(3.0, 4.0, 1.5), rbe(5.0, 0.9, 0.3), inn));
  ASSERT_EQ(inn.eta.size(), 2);
  EXPECT_NEAR(inn.eta[0], 5.0 - 5.0 * std::cos(0.3), 1e-15);
  EXPECT_NEAR(inn.eta[1], std::atan2(4.0, 3.0) - 0.9, 1e-15);
  Eigen::Matrix<double, 2, 3> J_v;
  J_v << -std::cos(0.3), 0.0, 5.0 * std::sin(0.3), 0.0, -1.0, 0.0;
  EXPECT_TRUE(inn.J_eta_v.isApprox(J_v, 1e-15)) << inn.J_eta_v;
  // At dims 0 and 3 it is the full 3-row innovation; bearings are not used at dim 2.
  for (int dim : {0, 3}) {
    PointFeature g(config(), Eigen::Vector3d(1, 2, 3), dim);
    ASSERT_TRUE(g.innovation(Eigen::Vector3d(3.0, 4.0, 1.5), rbe(5.0, 0.9, 0.3), inn));
    EXPECT_EQ(inn.eta.size(), 3);
    EXPECT_TRUE(g.innovation(Eigen::Vector3d(3.0, 4.0, 1.5), bearing(Eigen::Vector3d(3.0, 4.0, 1.6)), inn));
  }
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(3.0, 4.0, 1.5), bearing(Eigen::Vector3d(3.0, 4.0, 1.6)), inn));
  // Wrong sizes and points on the sensor axis are refused.
  Measurement bad = planar(4.5, 0.9);
  bad.v = Eigen::Vector3d(4.5, 0.9, 0.0);
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(3.0, 4.0, 1.5), bad, inn));
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(0.0, 0.0, 1.5), planar(1.5, 0.0), inn));
}

TEST(PlanarPoint, InnovationJacobiansMatchCentralDifferences) {
  Random rnd(5);
  int checked = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const Eigen::Vector3d x_o(rnd.uniform(-20, 20), rnd.uniform(-20, 20), rnd.uniform(-5, 5));
    if (std::hypot(x_o.x(), x_o.y()) < 0.5) continue;
    const double rho = std::hypot(x_o.x(), x_o.y()), b = std::atan2(x_o.y(), x_o.x());
    const Measurement measurements[] = {
        planar(rho + rnd.uniform(-0.2, 0.2), wrap_angle(b + rnd.uniform(-0.1, 0.1))),
        rbe(x_o.norm() + rnd.uniform(-0.2, 0.2), wrap_angle(b + rnd.uniform(-0.1, 0.1)), rnd.uniform(-0.5, 0.5))};
    for (int dim : {0, 2, 3}) {
      PointFeature f(config(), Eigen::Vector3d::Zero(), dim);
      for (const Measurement& m : measurements) {
        Innovation inn;
        ASSERT_TRUE(f.innovation(x_o, m, inn));
        const auto eta_of_xo = [&](const Eigen::VectorXd& x) {
          Innovation i;
          EXPECT_TRUE(f.innovation(x, m, i));
          return Eigen::VectorXd(i.eta);
        };
        const auto eta_of_v = [&](const Eigen::VectorXd& v) {
          Measurement mv = m;
          mv.v = v;
          Innovation i;
          EXPECT_TRUE(f.innovation(x_o, mv, i));
          return Eigen::VectorXd(i.eta);
        };
        EXPECT_LT((numeric(eta_of_xo, x_o) - inn.J_eta_o).norm(), 1e-7) << "dim " << dim << " kind " << m.kind;
        EXPECT_LT((numeric(eta_of_v, m.v) - inn.J_eta_v).norm(), 1e-7) << "dim " << dim << " kind " << m.kind;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1500);
}

// For a level sensor the planar innovation does not depend on the height:
// z is a true symmetry there (for a tilted sensor it is the value the M-space
// approximation holds fixed).
TEST(PlanarPoint, LevelSensorInnovationDoesNotDependOnTheHeight) {
  PointFeature f(config(), Eigen::Vector3d(4, 1, 0.2), 2);
  const Pose6 level = make_pose(0.5, -0.5, 0.3, 0.7, 0, 0);
  const Measurement m = planar(3.9, 0.6);
  Innovation a, b;
  const Eigen::Vector3d low(4, 1, 0.2), high(4, 1, 7.0);
  ASSERT_TRUE(f.innovation(to_sensor_frame(f.layout(), low, level), m, a));
  ASSERT_TRUE(f.innovation(to_sensor_frame(f.layout(), high, level), m, b));
  EXPECT_LT((a.eta - b.eta).norm(), 1e-14);
}

// ---------------------------------------------------------------- 0 → 2

TEST(PlanarPoint, ExtendsFromZeroToTwoInTheScanPlane) {
  PointType type = make_type();
  Random rnd(17);
  for (int trial = 0; trial < 200; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    const Eigen::Vector2d v(rnd.uniform(0.5, 30), rnd.uniform(-kPi, kPi));
    const Measurement m = planar(v[0], v[1], 0.04, 0.008);
    std::optional<Extension> ext;
    std::unique_ptr<Feature> f = planar_point(type, m, x_ms, &ext);
    ASSERT_TRUE(ext.has_value());
    EXPECT_EQ(ext->new_dims, 2);
    EXPECT_EQ(f->mspace_dim(), 2);
    EXPECT_EQ(ext->J_own.size(), 0);
    ASSERT_EQ(ext->J_sensor.rows(), 2);
    ASSERT_EQ(ext->J_sensor.cols(), 6);
    ASSERT_EQ(ext->C_new.rows(), 2);
    EXPECT_LT((f->coords() - ref_planar_back_projection(v, x_ms)).norm(), 1e-9);
    // δ(x, y) = B(J_s δx_ms + J_v δv): both against differences of the reference.
    const auto xy_of_pose = [&](const Eigen::VectorXd& p) {
      return Eigen::VectorXd(ref_planar_back_projection(v, Pose6(p)).head<2>());
    };
    const auto xy_of_v = [&](const Eigen::VectorXd& w) {
      return Eigen::VectorXd(ref_planar_back_projection(w, x_ms).head<2>());
    };
    EXPECT_LT((numeric(xy_of_pose, x_ms) - ext->J_sensor).norm(), 1e-6);
    const Eigen::MatrixXd J_v = numeric(xy_of_v, v);
    const Eigen::Matrix2d expected = J_v * m.C_v * J_v.transpose();
    EXPECT_LT((ext->C_new - expected).norm(), 1e-7 * expected.norm());
    EXPECT_EQ(Eigen::LLT<Eigen::MatrixXd>(ext->C_new).info(), Eigen::Success);
    EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 0);
  }
}

// ---------------------------------------------------------------- 2 → 3

// A level sensor 0.5 m up sees a point at height 2 m first in its scan plane
// (dim 2, z = 0.5), then with an elevation: z becomes exactly 2 m.
TEST(PlanarPoint, AnElevationExtendsTwoToThreeAtTheMeasuredHeight) {
  PointType type = make_type();
  const Pose6 x_ms = make_pose(1.0, -2.0, 0.5, 0.3, 0, 0);
  const Eigen::Vector3d truth(7.0, 1.0, 2.0);
  const Eigen::Vector3d v = ref_measure(truth, x_ms);
  const Eigen::Vector2d v_planar(std::hypot(v[0] * std::cos(v[2]), 0.0), v[1]);
  std::unique_ptr<Feature> f = planar_point(type, planar(v_planar[0], v_planar[1]), x_ms);
  ASSERT_EQ(f->mspace_dim(), 2);
  EXPECT_LT((f->coords() - Eigen::Vector3d(7.0, 1.0, 0.5)).norm(), 1e-12);

  // The elevation measurement's planar part agrees with the planar point.
  const Measurement m = rbe(v[0], v[1], v[2]);
  Innovation inn;
  ASSERT_TRUE(f->innovation(to_sensor_frame(f->layout(), f->coords(), x_ms), m, inn));
  EXPECT_LT(inn.eta.norm(), 1e-12);
  // Taken at another time it is stored but does not extend.
  f->add_dense_information(m, view_at(x_ms, 5.0));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 1);
  EXPECT_FALSE(f->extend(view_at(x_ms, 6.0)).has_value());
  // A planar measurement at dim 2 stores nothing.
  f->add_dense_information(planar(v_planar[0], v_planar[1]), view_at(x_ms, 6.0));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 1);

  f->add_dense_information(m, view_at(x_ms, 7.0));
  const std::optional<Extension> ext = f->extend(view_at(x_ms, 7.0));
  ASSERT_TRUE(ext.has_value());
  EXPECT_EQ(ext->new_dims, 1);
  EXPECT_EQ(f->mspace_dim(), 3);
  EXPECT_LT((f->coords() - truth).norm(), 1e-12);
  EXPECT_TRUE(f->B().isIdentity(0.0));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_observations(), 0);
  // The 3-row innovation is used from now on, and it is zero.
  ASSERT_TRUE(f->innovation(to_sensor_frame(f->layout(), f->coords(), x_ms), m, inn));
  EXPECT_EQ(inn.eta.size(), 3);
  EXPECT_LT(inn.eta.norm(), 1e-12);
  EXPECT_FALSE(f->extend(view_at(x_ms, 7.0)).has_value());
}

// δz = J_own δ(x, y) + J_sensor δx_ms + J_v δv, C_new = J_v C_v J_vᵀ, all
// against central differences of the reference ray height, on tilted sensors.
TEST(PlanarPoint, ElevationExtensionJacobiansMatchTheReference) {
  Random rnd(29);
  int checked = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    const Eigen::Vector3d p_s(rnd.uniform(-15, 15), rnd.uniform(-15, 15), rnd.uniform(-3, 3));
    if (std::hypot(p_s.x(), p_s.y()) < 1.0) continue;
    const Eigen::Vector3d truth = rotation(x_ms) * p_s + x_ms.head<3>();
    const Eigen::Vector3d v = ref_measure(truth, x_ms) + Eigen::Vector3d(0.01, 0.003, -0.004);
    const Eigen::Vector2d xy = truth.head<2>() + Eigen::Vector2d(0.02, -0.03);
    PointFeature f(config(), Eigen::Vector3d(xy.x(), xy.y(), x_ms[2]), 2);
    const Measurement m = rbe(v[0], v[1], v[2], 0.05, 0.01, 0.03);
    f.add_dense_information(m, view_at(x_ms, 3.0, 1));
    const std::optional<Extension> ext = f.extend(view_at(x_ms, 3.0, 1));
    ASSERT_TRUE(ext.has_value());
    EXPECT_EQ(ext->sensor, 1);
    EXPECT_NEAR(f.coords()[2], ref_ray_height(xy, v, x_ms), 1e-9);
    EXPECT_EQ(f.coords().head<2>(), xy);
    const auto one = [](double z) { return Eigen::VectorXd::Constant(1, z); };
    const auto z_of_xy = [&](const Eigen::VectorXd& w) { return one(ref_ray_height(w, v, x_ms)); };
    const auto z_of_pose = [&](const Eigen::VectorXd& p) { return one(ref_ray_height(xy, v, Pose6(p))); };
    const auto z_of_v = [&](const Eigen::VectorXd& w) { return one(ref_ray_height(xy, w, x_ms)); };
    ASSERT_EQ(ext->J_own.rows(), 1);
    ASSERT_EQ(ext->J_own.cols(), 2);
    EXPECT_LT((numeric(z_of_xy, xy) - ext->J_own).norm(), 1e-6 * (1.0 + ext->J_own.norm()));
    EXPECT_LT((numeric(z_of_pose, x_ms) - ext->J_sensor).norm(), 1e-6 * (1.0 + ext->J_sensor.norm()));
    const Eigen::MatrixXd J_v = numeric(z_of_v, v);
    EXPECT_NEAR(J_v(0, 0), 0.0, 1e-9);  // the range is not used
    const double expected = (J_v * m.C_v * J_v.transpose())(0, 0);
    ASSERT_EQ(ext->C_new.rows(), 1);
    EXPECT_NEAR(ext->C_new(0, 0), expected, 1e-6 * expected);
    EXPECT_GT(ext->C_new(0, 0), 0.0);
    ++checked;
  }
  EXPECT_GT(checked, 250);
}

// No extension for a ray that does not reach the vertical line in front of the sensor.
TEST(PlanarPoint, NoElevationExtensionBehindTheSensor) {
  PointFeature f(config(), Eigen::Vector3d(-5.0, 0.0, 0.0), 2);
  const Pose6 x_ms = make_pose(0, 0, 0, 0, 0, 0);
  f.add_dense_information(rbe(5.0, 0.0, 0.2), view_at(x_ms));  // looks along +x, the point is at −x
  EXPECT_FALSE(f.extend(view_at(x_ms)).has_value());
  EXPECT_EQ(f.mspace_dim(), 2);
}

// ---------------------------------------------------------------- save / restore

/// Bitwise equality of two extensions.
void expect_same(const std::optional<Extension>& a, const std::optional<Extension>& b) {
  ASSERT_EQ(a.has_value(), b.has_value());
  if (!a) return;
  EXPECT_EQ(a->new_dims, b->new_dims);
  EXPECT_EQ(a->sensor, b->sensor);
  EXPECT_TRUE(a->J_sensor == b->J_sensor);
  EXPECT_TRUE(a->J_own == b->J_own);
  EXPECT_TRUE(a->C_new == b->C_new);
}

TEST(PlanarPoint, SaveRestoreCarriesThePlanarStateExactly) {
  PointType type = make_type(4);
  const Pose6 x_ms = make_pose(1, 2, 0.5, 0.4, 0.05, -0.03);
  // A tentative point with planar and elevation observations mixed.
  std::unique_ptr<Feature> f = type.create(planar(4.0, 0.3), view_at(x_ms, 0.0));
  f->add_dense_information(planar(4.0, 0.3), view_at(x_ms, 0.0));
  f->add_dense_information(rbe(4.1, 0.31, 0.1), view_at(x_ms, 1.0));
  f->add_dense_information(planar(4.02, 0.3), view_at(x_ms, 2.0));
  SavedFeature s = f->save();
  EXPECT_EQ(s.version, 2);
  ASSERT_NE(s.find("observations"), nullptr);
  EXPECT_EQ(s.find("observations")->rows(), 58);
  EXPECT_EQ(s.find("observations")->cols(), 3);
  std::unique_ptr<Feature> copy = type.restore(s);
  EXPECT_TRUE(copy->coords() == f->coords());
  EXPECT_TRUE(copy->gating_covariance() == f->gating_covariance());
  // The fourth (planar) observation makes both dim 2, identically.
  for (Feature* g : {f.get(), copy.get()}) g->add_dense_information(planar(4.01, 0.3), view_at(x_ms, 3.0));
  expect_same(f->extend(view_at(x_ms, 3.0)), copy->extend(view_at(x_ms, 3.0)));
  ASSERT_EQ(f->mspace_dim(), 2);
  ASSERT_EQ(copy->mspace_dim(), 2);

  // At dim 2 the stored elevation is carried over and extends both alike.
  f->add_dense_information(rbe(4.1, 0.3, 0.12), view_at(x_ms, 4.0));
  s = f->save();
  EXPECT_EQ(s.mspace_dim, 2);
  ASSERT_NE(s.find("observations"), nullptr);
  EXPECT_EQ(s.find("observations")->cols(), 1);
  EXPECT_EQ(s.find("gating_covariance"), nullptr);
  copy = type.restore(s);
  EXPECT_TRUE(copy->save().find("observations")->isApprox(*s.find("observations"), 0.0));
  expect_same(f->extend(view_at(x_ms, 4.0)), copy->extend(view_at(x_ms, 4.0)));
  EXPECT_EQ(copy->mspace_dim(), 3);
  EXPECT_TRUE(copy->coords() == f->coords());
}

TEST(PlanarPoint, RestoreReadsVersionOneAndRefusesBadPlanarState) {
  PointType type = make_type();
  const Pose6 x_ms = make_pose(1, 2, 0.5, 0.4, 0, 0);
  // Version 1: 57-row records (v, C_v, view) of range/bearing/elevation observations.
  std::unique_ptr<Feature> f = type.create(rbe(4.0, 0.3, 0.1), view_at(x_ms, 0.0));
  f->add_dense_information(rbe(4.0, 0.3, 0.1), view_at(x_ms, 0.0));
  f->add_dense_information(rbe(4.1, 0.3, 0.1), view_at(x_ms, 1.0));
  const SavedFeature v2 = f->save();
  SavedFeature v1 = v2;
  v1.version = 1;
  v1.put("observations", v2.find("observations")->bottomRows(57).eval());
  std::unique_ptr<Feature> old = type.restore(v1);
  EXPECT_TRUE(old->save().find("observations")->isApprox(*v2.find("observations"), 0.0));
  for (Feature* g : {f.get(), old.get()}) g->add_dense_information(rbe(4.2, 0.3, 0.1), view_at(x_ms, 2.0));
  expect_same(f->extend(view_at(x_ms, 2.0)), old->extend(view_at(x_ms, 2.0)));
  EXPECT_EQ(old->mspace_dim(), 3);

  // Refused: a record size other than 2 or 3, a planar observation at dim 2,
  // a dimension the point cannot have.
  SavedFeature bad = v2;
  Eigen::MatrixXd obs = *v2.find("observations");
  obs(0, 0) = 4.0;
  bad.put("observations", obs);
  EXPECT_THROW(type.restore(bad), std::invalid_argument);
  std::unique_ptr<Feature> p = planar_point(type, planar(4.0, 0.3), x_ms);
  bad = p->save();
  Eigen::MatrixXd planar_record = Eigen::MatrixXd::Zero(58, 1);
  planar_record(0, 0) = 2.0;
  bad.put("observations", planar_record);
  EXPECT_THROW(type.restore(bad), std::invalid_argument);
  bad = p->save();
  bad.mspace_dim = 1;
  EXPECT_THROW(type.restore(bad), std::invalid_argument);
}

// ---------------------------------------------------------------- conformance samples

// `mspace check` reaches every dimension and both extensions from the samples.
TEST(PlanarPoint, ConformanceSamplesCoverEveryDimensionAndExtension) {
  PointType type = make_type();
  EXPECT_EQ(type.reachable_dims(), (std::vector<int>{0, 2, 3}));
  EXPECT_FALSE(type.sample(1, 0).has_value());
  std::vector<int> reached_from_0, reached_from_2;
  bool planar_at_2 = false, elevation_at_2 = false;
  for (std::uint64_t seed = 0; seed < 6; ++seed) {
    for (int dim : {0, 2, 3}) {
      std::optional<FeatureSample> s = type.sample(dim, seed);
      ASSERT_TRUE(s.has_value());
      ASSERT_EQ(s->feature->mspace_dim(), dim);
      if (dim == 2) (s->measurement.kind == kRangeBearing ? planar_at_2 : elevation_at_2) = true;
      if (dim == 3) continue;
      for (int k = 1; k <= 10 && s->feature->mspace_dim() == dim; ++k) {
        SensorView view = view_at(s->x_ms, 0.1 * k);
        s->feature->add_dense_information(s->measurement, view);
        s->feature->extend(view);
      }
      (dim == 0 ? reached_from_0 : reached_from_2).push_back(s->feature->mspace_dim());
    }
  }
  EXPECT_TRUE(planar_at_2 && elevation_at_2);
  const auto reaches = [](const std::vector<int>& dims, int d) { return std::find(dims.begin(), dims.end(), d) != dims.end(); };
  for (int d : {0, 2, 3}) EXPECT_TRUE(reaches(reached_from_0, d)) << d;
  for (int d : {2, 3}) EXPECT_TRUE(reaches(reached_from_2, d)) << d;
}

}  // namespace
}  // namespace mspace::point
