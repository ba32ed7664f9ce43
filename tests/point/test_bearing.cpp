// Tests of the `point` feature type with bearing-only ("bearing3d")
// measurements (T-RO §IV-E, ICRA §VI: ceiling lamps seen by an upward camera):
// the bearing innovation and its Jacobians (eq. 16), the rays as dense
// information, gating a tentative point at unknown depth, and the 0 → 3
// extension by triangulation.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <numbers>
#include <optional>
#include <random>
#include <vector>

#include "mspace/pose.hpp"
#include "mspace/transform.hpp"
#include "point_feature.hpp"

namespace mspace::point {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kPixelSigma = 0.5 / 250.0;  ///< 0.5 px at f = 250 px (rad)
constexpr double kGateChi2 = 9.2103;         ///< χ²(2) at 0.99, the kernel's default gate: −2 ln 0.01

const CoordLayout& layout() {
  static const CoordLayout l{BlockKind::Point3D};
  return l;
}

double deg(double radians) { return radians * 180.0 / kPi; }

PluginArgs point_args() {
  PluginArgs args;
  args.instance_name = "lamps";
  args.params = Params::defaults(PointType::param_specs());
  return args;
}

SensorView view_at(const Pose6& x_ms, double t = 0.0, double path_distance = 0.0, int sensor = 0) {
  SensorView view;
  view.t = t;
  view.sensor = sensor;
  view.x_ms = x_ms;
  view.C_ms = Mat6::Zero();
  view.path_distance = path_distance;
  return view;
}

/// A bearing with the extractor's covariance shape: σ² across b, none along it.
Measurement bearing(const Eigen::Vector3d& b, double sigma = kPixelSigma) {
  Measurement m;
  m.kind = kBearing3d;
  m.v = b;
  const Eigen::Vector3d n = b.normalized();
  m.C_v = sigma * sigma * (Eigen::Matrix3d::Identity() - n * n.transpose());
  return m;
}

/// Reference sensor-frame coordinates written independently of the SDK: R_msᵀ (p − t).
Eigen::Vector3d in_camera(const Eigen::Vector3d& p, const Pose6& x_ms) {
  return rotation(x_ms).transpose() * (p - x_ms.head<3>());
}

class Random {
 public:
  explicit Random(unsigned seed) : gen_(seed) {}
  double uniform(double lo, double hi) { return std::uniform_real_distribution<>(lo, hi)(gen_); }
  double normal() { return std::normal_distribution<>(0.0, 1.0)(gen_); }
  /// A camera pose with arbitrary yaw and tilts up to ±0.6 rad.
  Pose6 tilted_pose() {
    return make_pose(uniform(-10, 10), uniform(-10, 10), uniform(-2, 2), uniform(-kPi, kPi), uniform(-0.6, 0.6),
                     uniform(-0.6, 0.6));
  }
  /// A unit vector uniform on the sphere.
  Eigen::Vector3d direction() {
    const Eigen::Vector3d d(normal(), normal(), normal());
    return d.normalized();
  }
  /// The noisy bearing of camera-frame point p: the true direction moved by
  /// σ-noise in its tangent plane, with the matching rank-2 covariance.
  Measurement noisy_bearing(const Eigen::Vector3d& p, double sigma = kPixelSigma) {
    const Eigen::Vector3d b = p.normalized();
    const Eigen::Matrix<double, 3, 2> E = tangent_basis(b).E;
    return bearing((b + sigma * E * Eigen::Vector2d(normal(), normal())).normalized(), sigma);
  }

 private:
  std::mt19937 gen_;
};

/// Central differences of f: R^k → R^m at x.
template <class F>
Eigen::MatrixXd numeric_jacobian(F&& f, const Eigen::VectorXd& x, double step = 1e-6) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (Eigen::Index k = 0; k < x.size(); ++k) {
    Eigen::VectorXd xp = x, xm = x;
    xp[k] += step;
    xm[k] -= step;
    J.col(k) = (f(xp) - f(xm)) / (2 * step);
  }
  return J;
}

/// η of a feature at map point p seen from x_ms (asserting it is accepted).
Eigen::VectorXd eta_of(const Feature& f, const Eigen::Vector3d& p, const Pose6& x_ms, const Measurement& m) {
  Innovation inn;
  EXPECT_TRUE(f.innovation(to_sensor_frame(layout(), p, x_ms), m, inn));
  return inn.eta;
}

/// The kernel's association distance for a tentative feature with an exactly
/// known robot: S = J_ηo J_of Σ_gate J_ofᵀ J_ηoᵀ + J_ηv C_v J_ηvᵀ (eq. 29), d² = ηᵀS⁻¹η.
double gate_distance(const Feature& f, const Pose6& x_ms, const Measurement& m) {
  Eigen::MatrixXd J_of;
  const Eigen::VectorXd x_o = to_sensor_frame(layout(), f.coords(), x_ms, &J_of);
  Innovation inn;
  if (!f.innovation(x_o, m, inn)) return std::numeric_limits<double>::infinity();
  const Eigen::MatrixXd J = inn.J_eta_o * J_of;
  const Eigen::MatrixXd S =
      J * f.gating_covariance() * J.transpose() + inn.J_eta_v * m.C_v * inn.J_eta_v.transpose();
  return inn.eta.dot(S.ldlt().solve(inn.eta));
}

// ---------------------------------------------------------------- the tangent basis

TEST(BearingBasis, OrthonormalAcrossTheDirectionInBothHemispheres) {
  Random rnd(3);
  for (int trial = 0; trial < 2000; ++trial) {
    const Eigen::Vector3d n = rnd.direction();
    const TangentBasis t = tangent_basis(n);
    EXPECT_LT((t.E.transpose() * t.E - Eigen::Matrix2d::Identity()).norm(), 1e-12) << n.transpose();
    EXPECT_LT((t.E.transpose() * n).norm(), 1e-12) << n.transpose();
  }
  // The optical axis itself: E = (x, y).
  const TangentBasis z = tangent_basis(Eigen::Vector3d::UnitZ());
  EXPECT_TRUE(z.E.col(0).isApprox(Eigen::Vector3d::UnitX(), 0.0));
  EXPECT_TRUE(z.E.col(1).isApprox(Eigen::Vector3d::UnitY(), 0.0));
}

TEST(BearingBasis, DerivativesMatchCentralDifferences) {
  Random rnd(5);
  for (int trial = 0; trial < 500; ++trial) {
    Eigen::Vector3d n = rnd.direction();
    if (std::abs(n.z()) < 0.05) continue;  // the hemisphere switch is not differentiable
    const TangentBasis t = tangent_basis(n);
    const auto e1 = [](const Eigen::VectorXd& x) -> Eigen::VectorXd { return tangent_basis(x).E.col(0); };
    const auto e2 = [](const Eigen::VectorXd& x) -> Eigen::VectorXd { return tangent_basis(x).E.col(1); };
    EXPECT_LT((numeric_jacobian(e1, n) - t.dE1).norm(), 1e-8) << n.transpose();
    EXPECT_LT((numeric_jacobian(e2, n) - t.dE2).norm(), 1e-8) << n.transpose();
  }
}

// ---------------------------------------------------------------- innovation (eq. 16)

TEST(BearingInnovation, KnownValues) {
  // Measured straight up the optical axis: E = (x, y), so η is the x, y of p̂.
  Innovation inn;
  ASSERT_TRUE(bearing_innovation(Eigen::Vector3d(0.3, -0.4, 1.2), Eigen::Vector3d::UnitZ(), inn));
  ASSERT_EQ(inn.eta.size(), 2);
  EXPECT_NEAR(inn.eta[0], 0.3 / 1.3, 1e-15);
  EXPECT_NEAR(inn.eta[1], -0.4 / 1.3, 1e-15);
  // On the ray, at any depth, η = 0.
  ASSERT_TRUE(bearing_innovation(Eigen::Vector3d(0.6, 0.0, 0.8) * 7.0, Eigen::Vector3d(0.6, 0.0, 0.8), inn));
  EXPECT_LT(inn.eta.norm(), 1e-15);
  // J_ηo at p = (0, 0, 2) with v = z: Eᵀ(I − zzᵀ)/2 = [I₂ 0]/2.
  ASSERT_TRUE(bearing_innovation(Eigen::Vector3d(0, 0, 2), Eigen::Vector3d::UnitZ(), inn));
  Eigen::Matrix<double, 2, 3> expected;
  expected << 0.5, 0, 0, 0, 0.5, 0;
  EXPECT_TRUE(inn.J_eta_o.isApprox(expected, 1e-15)) << inn.J_eta_o;
}

TEST(BearingInnovation, IsZeroAtTheTruthAndHasTheMeasurementCovariance) {
  PointType type(point_args());
  Random rnd(7);
  for (int trial = 0; trial < 1000; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    // A lamp up to 60° off the optical axis, 1–5 m away.
    const double off = rnd.uniform(0, kPi / 3), az = rnd.uniform(-kPi, kPi), d = rnd.uniform(1, 5);
    const Eigen::Vector3d b(std::sin(off) * std::cos(az), std::sin(off) * std::sin(az), std::cos(off));
    const Eigen::Vector3d lamp = rotation(x_ms) * (d * b) + x_ms.head<3>();
    const PointFeature f(type.config(), lamp, 3);
    const Measurement m = bearing(b);
    Innovation inn;
    ASSERT_TRUE(f.innovation(to_sensor_frame(layout(), lamp, x_ms), m, inn));
    EXPECT_LT(inn.eta.norm(), 1e-12);
    // A rank-2 C_v = σ²(I − bbᵀ) becomes the full-rank σ² I₂.
    const Eigen::Matrix2d C_eta = inn.J_eta_v * m.C_v * inn.J_eta_v.transpose();
    EXPECT_LT((C_eta - kPixelSigma * kPixelSigma * Eigen::Matrix2d::Identity()).norm(), 1e-18);
  }
}

TEST(BearingInnovation, JacobiansMatchCentralDifferences) {
  PointType type(point_args());
  Random rnd(11);
  int checked = 0;
  for (int trial = 0; trial < 1000; ++trial) {
    const Pose6 x_ms = rnd.tilted_pose();
    // Any direction (also behind a camera: a bearing sensor need not look up).
    const Eigen::Vector3d p_s = rnd.uniform(0.5, 10.0) * rnd.direction();
    const Eigen::Vector3d x_f = rotation(x_ms) * p_s + x_ms.head<3>();
    // A measurement a few degrees off, not of unit length (J_ηv includes the normalisation).
    Measurement m = rnd.noisy_bearing(p_s, 0.05);
    m.v *= rnd.uniform(0.5, 2.0);
    if (std::abs(m.v.normalized().z()) < 0.05) continue;  // the basis switches hemisphere there
    const PointFeature f(type.config(), x_f, 3);
    Eigen::MatrixXd J_of, J_os;
    const Eigen::VectorXd x_o = to_sensor_frame(layout(), x_f, x_ms, &J_of, &J_os);
    Innovation inn;
    ASSERT_TRUE(f.innovation(x_o, m, inn));
    ASSERT_GT(inn.eta.norm(), 1e-4);  // away from the truth
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
    const auto eta_of_xf = [&](const Eigen::VectorXd& x) { return eta_of(f, x, x_ms, m); };
    const auto eta_of_pose = [&](const Eigen::VectorXd& x) { return eta_of(f, x_f, Pose6(x), m); };
    EXPECT_LT((numeric_jacobian(eta_of_xo, x_o) - inn.J_eta_o).norm(), 1e-8);
    EXPECT_LT((numeric_jacobian(eta_of_v, m.v) - inn.J_eta_v).norm(), 1e-8);
    // The chain of eq. 30 through the SDK transform (eqs. 7, 19).
    EXPECT_LT((numeric_jacobian(eta_of_xf, x_f) - inn.J_eta_o * J_of).norm(), 1e-8);
    EXPECT_LT((numeric_jacobian(eta_of_pose, x_ms) - inn.J_eta_o * J_os).norm(), 1e-7);
    ++checked;
  }
  EXPECT_GE(checked, 900);
}

TEST(BearingInnovation, RejectsOppositeDirectionsMalformedAndOtherKinds) {
  PointType type(point_args());
  const PointFeature f(type.config(), Eigen::Vector3d(0, 0, 2), 3);
  Innovation inn;
  // Eᵀp̂ is also 0 for p = −n: a point behind the measured direction is refused.
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(0, 0, -2), bearing(Eigen::Vector3d::UnitZ()), inn));
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(2, 0, 0), bearing(Eigen::Vector3d::UnitZ()), inn));  // 90° away
  EXPECT_FALSE(f.innovation(Eigen::Vector3d::Zero(), bearing(Eigen::Vector3d::UnitZ()), inn));
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(0, 0, 2), bearing(Eigen::Vector3d::Zero()), inn));
  Measurement other = bearing(Eigen::Vector3d::UnitZ());
  other.kind = "line2d";
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(0, 0, 2), other, inn));
  Measurement short_v = bearing(Eigen::Vector3d::UnitZ());
  short_v.v = Eigen::Vector2d(0, 1);
  EXPECT_FALSE(f.innovation(Eigen::Vector3d(0, 0, 2), short_v, inn));
  EXPECT_TRUE(f.innovation(Eigen::Vector3d(0.1, 0, 2), bearing(Eigen::Vector3d::UnitZ()), inn));
}

// ---------------------------------------------------------------- rays and triangulation

TEST(BearingRays, RayOfAMeasurement) {
  // Camera turned 90° in yaw and tilted: the ray is R b from the camera centre,
  // its information σ⁻²(I − uuᵀ).
  const Pose6 x_ms = make_pose(1, 2, 0.5, kPi / 2, 0.2, -0.1);
  const Eigen::Vector3d b = Eigen::Vector3d(0.2, -0.1, 1.0).normalized();
  const Ray r = make_ray(b, bearing(b).C_v, x_ms);
  EXPECT_TRUE(r.centre.isApprox(Eigen::Vector3d(1, 2, 0.5), 0.0));
  EXPECT_LT((r.direction - rotation(x_ms) * b).norm(), 1e-15);
  const Eigen::Matrix3d expected =
      (Eigen::Matrix3d::Identity() - r.direction * r.direction.transpose()) / (kPixelSigma * kPixelSigma);
  EXPECT_LT((r.information - expected).norm(), 1e-9 * expected.norm());
  // No variance across the bearing: no ray.
  Measurement flat = bearing(Eigen::Vector3d::UnitZ());
  flat.C_v(1, 1) = 0.0;
  EXPECT_FALSE(tangent_covariance(flat.v, flat.C_v).has_value());
  EXPECT_THROW(make_ray(flat.v, flat.C_v, x_ms), std::invalid_argument);
}

TEST(BearingRays, TriangulationKnownValues) {
  // Two perpendicular rays meeting at the origin at depth L: ray 1 along z
  // from (0, 0, −L), ray 2 along x from (−L, 0, 0), both with isotropic σ.
  // Information σ⁻²L⁻² (diag(1, 1, 0) + diag(0, 1, 1)) → covariance σ²L² diag(1, ½, 1).
  const double L = 3.0, sigma = 0.01;
  const Ray r1 = make_ray(Eigen::Vector3d::UnitZ(), bearing(Eigen::Vector3d::UnitZ(), sigma).C_v,
                          make_pose(0, 0, -L, 0, 0, 0));
  const Ray r2 = make_ray(Eigen::Vector3d::UnitZ(), bearing(Eigen::Vector3d::UnitZ(), sigma).C_v,
                          make_pose(-L, 0, 0, 0, kPi / 2, 0));  // pitch 90°: the camera's z is the map's x
  ASSERT_LT((r2.direction - Eigen::Vector3d::UnitX()).norm(), 1e-15);
  const std::optional<Triangulation> t = triangulate({r1, r2});
  ASSERT_TRUE(t.has_value());
  EXPECT_LT(t->point.norm(), 1e-12);
  EXPECT_NEAR(t->min_depth, L, 1e-12);
  const Eigen::Matrix3d expected = sigma * sigma * L * L * Eigen::Vector3d(1.0, 0.5, 1.0).asDiagonal();
  EXPECT_LT((t->covariance - expected).norm(), 1e-12 * expected.norm()) << t->covariance;
  EXPECT_NEAR(deg(max_parallax({r1, r2})), 90.0, 1e-12);

  // One ray: no point without a prior; with the prior at depth d ± s the point
  // is on the ray at d, with variance s² along it and d²σ² across it.
  EXPECT_FALSE(triangulate({r1}).has_value());
  EXPECT_FALSE(triangulate({r1, r1}).has_value());  // parallel rays
  const std::optional<Triangulation> prior = triangulate({r1}, DepthPrior{2.0, 0.5});
  ASSERT_TRUE(prior.has_value());
  EXPECT_LT((prior->point - Eigen::Vector3d(0, 0, 2.0 - L)).norm(), 1e-12);
  const Eigen::Matrix3d expected_prior = Eigen::Vector3d(4 * sigma * sigma, 4 * sigma * sigma, 0.25).asDiagonal();
  EXPECT_LT((prior->covariance - expected_prior).norm(), 1e-12) << prior->covariance;
}

// ---------------------------------------------------------------- create and dense information

TEST(BearingCreate, TentativePointOnTheRayAtTheInitialDepth) {
  PointType type(point_args());
  const Pose6 x_ms = make_pose(2, -1, 0.3, 0.7, 0.1, -0.05);
  const Eigen::Vector3d b = Eigen::Vector3d(0.3, 0.1, 1.0).normalized();
  std::unique_ptr<Feature> f = type.create(bearing(b), view_at(x_ms));
  ASSERT_NE(f, nullptr);
  EXPECT_EQ(f->mspace_dim(), 0);
  const double d0 = type.config().initial_depth, s0 = type.config().initial_depth_sigma;
  EXPECT_LT((in_camera(f->coords(), x_ms) - d0 * b).norm(), 1e-12);
  // Gating covariance (no camera-pose uncertainty): s0² along the ray, d0²σ² across it.
  const Eigen::Vector3d u = rotation(x_ms) * b;
  const Eigen::Matrix3d across = Eigen::Matrix3d::Identity() - u * u.transpose();
  const Eigen::Matrix3d expected = s0 * s0 * u * u.transpose() + d0 * d0 * kPixelSigma * kPixelSigma * across;
  EXPECT_LT((f->gating_covariance() - expected).norm(), 1e-12) << f->gating_covariance();

  // The camera's pose uncertainty is added with the point held in its frame:
  // a translation variance τ² adds τ² I.
  SensorView uncertain = view_at(x_ms);
  uncertain.C_ms.topLeftCorner<3, 3>() = 0.01 * Eigen::Matrix3d::Identity();
  f = type.create(bearing(b), uncertain);
  EXPECT_LT((f->gating_covariance() - expected - 0.01 * Eigen::Matrix3d::Identity()).norm(), 1e-12);
}

TEST(BearingCreate, RejectsWhatCannotStartARay) {
  PointType type(point_args());
  const SensorView view = view_at(make_pose(0, 0, 0, 0, 0, 0));
  Measurement flat = bearing(Eigen::Vector3d::UnitZ());
  flat.C_v.setZero();
  EXPECT_EQ(type.create(flat, view), nullptr);
  EXPECT_EQ(type.create(bearing(Eigen::Vector3d::Zero()), view), nullptr);
  Measurement nan = bearing(Eigen::Vector3d::UnitZ());
  nan.v[0] = std::nan("");
  EXPECT_EQ(type.create(nan, view), nullptr);
  // add_dense_information refuses such bearings loudly.
  std::unique_ptr<Feature> f = type.create(bearing(Eigen::Vector3d::UnitZ()), view);
  ASSERT_NE(f, nullptr);
  EXPECT_THROW(f->add_dense_information(flat, view), std::invalid_argument);
}

TEST(BearingDense, RaysAreSpacedByPathDistanceAndCapped) {
  PluginArgs args = point_args();
  args.params.set("ray_spacing", 0.1);
  args.params.set("max_rays", std::int64_t{4});
  args.params.set("min_rays", std::int64_t{2});
  args.params.set("min_parallax_deg", 89.0);  // never triangulates here
  PointType type(args);
  const Eigen::Vector3d lamp(0.2, 0.0, 2.0);
  // A camera moving along x, path distance = x, in steps of 3 cm.
  std::unique_ptr<Feature> f;
  for (int i = 0; i < 14; ++i) {
    const double x = 0.03 * i;
    const Pose6 x_ms = make_pose(x, 0, 0, 0, 0, 0);
    const SensorView view = view_at(x_ms, i, x);
    const Measurement m = bearing(in_camera(lamp, x_ms).normalized());
    if (!f) f = type.create(m, view);
    f->add_dense_information(m, view);
    EXPECT_FALSE(f->extend(view).has_value());
  }
  // Stored rays stay ≥ ray_spacing apart but for the newest; over max_rays the
  // second oldest goes (the first, widest-baseline ray stays).
  const std::vector<Ray> rays = dynamic_cast<const PointFeature&>(*f).rays();
  const std::vector<double> expected = {0.0, 0.24, 0.36, 0.39};
  ASSERT_EQ(rays.size(), expected.size());
  for (std::size_t i = 0; i < rays.size(); ++i) EXPECT_NEAR(rays[i].centre.x(), expected[i], 1e-12);

  // A camera standing still keeps two rays: the first and the newest.
  f = type.create(bearing(Eigen::Vector3d::UnitZ()), view_at(Pose6::Zero()));
  for (int i = 0; i < 10; ++i) f->add_dense_information(bearing(Eigen::Vector3d::UnitZ()), view_at(Pose6::Zero(), i));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_rays(), 2);
}

// ---------------------------------------------------------------- a lamp passed under

/// A camera at height 0 looking up, moving 1 m along x in 5 cm steps (path
/// distance = x), under a lamp at 2.2 m, with a small yaw and tilt; 0.5-px
/// bearing noise at f = 250 px.
struct LampPass {
  Eigen::Vector3d lamp{0.05, 0.3, 2.2};
  static constexpr int kFrames = 21;
  static constexpr double kStep = 0.05;

  static Pose6 camera(int i) { return make_pose(-0.5 + kStep * i, 0.0, 0.0, 0.3, 0.02, -0.03); }
  static SensorView view(int i) { return view_at(camera(i), 0.1 * i, kStep * i); }
  Measurement seen(const Eigen::Vector3d& point, int i, Random& rnd) const {
    return rnd.noisy_bearing(in_camera(point, camera(i)));
  }
  /// True angle between the rays from camera 0 and camera i.
  double true_parallax(int i) const {
    const Eigen::Vector3d a = (lamp - camera(0).head<3>()).normalized();
    const Eigen::Vector3d b = (lamp - camera(i).head<3>()).normalized();
    return std::atan2(a.cross(b).norm(), a.dot(b));
  }
};

/// What one noisy pass gives: the extension and the frame it happened at.
struct PassResult {
  std::unique_ptr<Feature> feature;
  std::optional<Extension> extension;
  int frame = -1;
  Triangulation rays_only;  ///< triangulate() of the stored rays just before the extension
};

PassResult pass_under_lamp(PointType& type, const LampPass& pass, unsigned seed) {
  Random rnd(seed);
  PassResult r;
  for (int i = 0; i < LampPass::kFrames && !r.extension; ++i) {
    const Measurement m = pass.seen(pass.lamp, i, rnd);
    if (i == 0) r.feature = type.create(m, LampPass::view(0));  // then its dense information, as the kernel does
    r.feature->add_dense_information(m, LampPass::view(i));
    const std::vector<Ray> rays = dynamic_cast<const PointFeature&>(*r.feature).rays();
    if (rays.size() >= 2) {
      if (const auto t = triangulate(rays)) r.rays_only = *t;
    }
    r.extension = r.feature->extend(LampPass::view(i));
    if (r.extension) r.frame = i;
  }
  return r;
}

TEST(BearingExtend, TentativeUntilTheParallaxThresholdThenTriangulatedWithinItsCovariance) {
  PointType type(point_args());
  const LampPass pass;
  const double threshold = type.config().min_parallax_deg * kPi / 180.0;
  Random rnd(2024);
  std::unique_ptr<Feature> f;
  std::optional<Extension> ext;
  int frame = 0;
  for (; frame < LampPass::kFrames; ++frame) {
    const Measurement m = pass.seen(pass.lamp, frame, rnd);
    if (frame == 0) f = type.create(m, LampPass::view(0));
    ASSERT_NE(f, nullptr);
    f->add_dense_information(m, LampPass::view(frame));
    const auto& point = dynamic_cast<const PointFeature&>(*f);
    const bool ready = point.num_rays() >= type.config().min_rays && max_parallax(point.rays()) >= threshold;
    ext = f->extend(LampPass::view(frame));
    ASSERT_EQ(ext.has_value(), ready) << "frame " << frame;
    if (ext) break;
    EXPECT_EQ(f->mspace_dim(), 0);
  }
  ASSERT_TRUE(ext.has_value()) << "never triangulated";
  // It happened as the true parallax crossed the threshold (≈1.2° per step here).
  EXPECT_GE(deg(pass.true_parallax(frame)), type.config().min_parallax_deg - 0.5);
  EXPECT_LE(deg(pass.true_parallax(frame - 1)), type.config().min_parallax_deg + 0.5);
  EXPECT_EQ(f->mspace_dim(), 3);
  EXPECT_EQ(ext->new_dims, 3);
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_rays(), 0);

  // The triangulated point is within 3σ of the lamp on every axis, with σ < 5 cm.
  const Eigen::Vector3d error = f->coords() - pass.lamp;
  const Eigen::Vector3d sigma = ext->C_new.diagonal().cwiseSqrt();
  for (int k = 0; k < 3; ++k) EXPECT_LT(std::abs(error[k]), 3.0 * sigma[k]) << "axis " << k << ": " << error.transpose();
  const double largest_sigma = std::sqrt(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(
                                             Eigen::Matrix3d(ext->C_new)).eigenvalues().maxCoeff());
  EXPECT_LT(largest_sigma, 0.05);
  EXPECT_GT(largest_sigma, 0.002);  // but not absurdly small: the depth is the weak direction

  // Once initialised nothing more is stored or extended.
  f->add_dense_information(pass.seen(pass.lamp, frame, rnd), LampPass::view(frame + 1));
  EXPECT_EQ(dynamic_cast<const PointFeature&>(*f).num_rays(), 0);
  EXPECT_FALSE(f->extend(LampPass::view(frame + 1)).has_value());
}

TEST(BearingExtend, TriangulationIsConsistentOverManyPasses) {
  // NEES of the triangulated point against C_new over 200 noisy passes: the
  // mean of χ²(3) draws, whose 99.9 % interval for 200 passes is ≈ [2.43, 3.57].
  PointType type(point_args());
  const LampPass pass;
  constexpr int kPasses = 200;
  double nees = 0.0;
  for (int s = 0; s < kPasses; ++s) {
    const PassResult r = pass_under_lamp(type, pass, 1000 + s);
    ASSERT_TRUE(r.extension.has_value()) << "seed " << 1000 + s;
    const Eigen::Vector3d e = r.feature->coords() - pass.lamp;
    nees += e.dot(Eigen::Matrix3d(r.extension->C_new).ldlt().solve(e));
  }
  nees /= kPasses;
  EXPECT_GT(nees, 2.43);
  EXPECT_LT(nees, 3.57);
}

TEST(BearingExtend, ThroughTheLastCameraWithTheLeastSquaresCovariance) {
  PointType type(point_args());
  const LampPass pass;
  const PassResult r = pass_under_lamp(type, pass, 77);
  ASSERT_TRUE(r.extension.has_value());
  const Extension& ext = *r.extension;
  // x_f and C_new are the rays' least squares (no prior).
  EXPECT_LT((r.feature->coords() - r.rays_only.point).norm(), 1e-12);
  EXPECT_LT((Eigen::Matrix3d(ext.C_new) - r.rays_only.covariance).norm(), 1e-12 * r.rays_only.covariance.norm());
  EXPECT_EQ(ext.sensor, 0);
  EXPECT_EQ(ext.J_own.size(), 0);
  // J_sensor = ∂(x_ms ⊕ p_s)/∂x_ms with p_s fixed in the last camera's frame.
  const Pose6 x_ms = LampPass::camera(r.frame);
  const Eigen::Vector3d p_s = in_camera(r.feature->coords(), x_ms);
  const auto attached = [&](const Eigen::VectorXd& x) -> Eigen::VectorXd {
    const Pose6 pose(x);
    return rotation(pose) * p_s + pose.head<3>();
  };
  ASSERT_EQ(ext.J_sensor.rows(), 3);
  ASSERT_EQ(ext.J_sensor.cols(), 6);
  EXPECT_LT((numeric_jacobian(attached, x_ms) - ext.J_sensor).norm(), 1e-8) << ext.J_sensor;
}

TEST(BearingExtend, OnlyFromTheCurrentViewAndWithEnoughRays) {
  PluginArgs args = point_args();
  args.params.set("min_rays", std::int64_t{4});
  PointType type(args);
  // Two widely separated views: parallax enough, rays not.
  const Eigen::Vector3d lamp(0, 0, 2);
  const Pose6 a = make_pose(-1, 0, 0, 0, 0, 0), b = make_pose(1, 0, 0, 0, 0, 0);
  std::unique_ptr<Feature> f = type.create(bearing(in_camera(lamp, a)), view_at(a, 0, 0));
  f->add_dense_information(bearing(in_camera(lamp, a)), view_at(a, 0, 0));
  f->add_dense_information(bearing(in_camera(lamp, b)), view_at(b, 1, 2));
  EXPECT_FALSE(f->extend(view_at(b, 1, 2)).has_value());
  // Two rays with parallax place the tentative point at their intersection.
  EXPECT_LT((f->coords() - lamp).norm(), 1e-3);
  f->add_dense_information(bearing(in_camera(lamp, a)), view_at(a, 2, 4));
  f->add_dense_information(bearing(in_camera(lamp, b)), view_at(b, 3, 6));
  EXPECT_FALSE(f->extend(view_at(b, 4, 6)).has_value());    // not the newest ray's time
  EXPECT_FALSE(f->extend(view_at(b, 3, 6, 1)).has_value());  // nor its sensor
  const std::optional<Extension> ext = f->extend(view_at(b, 3, 6));
  ASSERT_TRUE(ext.has_value());
  EXPECT_LT((f->coords() - lamp).norm(), 1e-9);
}

// ---------------------------------------------------------------- matching a tentative lamp

TEST(BearingGate, TentativePointAcceptsItsLampAndRejectsOneHalfAMetreAway) {
  PointType type(point_args());
  const LampPass pass;
  const std::vector<Eigen::Vector3d> neighbours = {
      pass.lamp + Eigen::Vector3d(0.5, 0, 0), pass.lamp + Eigen::Vector3d(-0.5, 0, 0),  // along the motion
      pass.lamp + Eigen::Vector3d(0, 0.5, 0), pass.lamp + Eigen::Vector3d(0, -0.5, 0),  // across it
      pass.lamp + Eigen::Vector3d(0, 0, -0.5)};                                         // below it
  Random rnd(99);
  const Measurement first = pass.seen(pass.lamp, 0, rnd);
  std::unique_ptr<Feature> f = type.create(first, LampPass::view(0));
  f->add_dense_information(first, LampPass::view(0));
  int gated = 0;
  for (int i = 1; i < LampPass::kFrames && f->mspace_dim() == 0; ++i, ++gated) {
    const Measurement own = pass.seen(pass.lamp, i, rnd);
    EXPECT_LT(gate_distance(*f, LampPass::camera(i), own), kGateChi2) << "frame " << i;
    for (const Eigen::Vector3d& other : neighbours) {
      EXPECT_GT(gate_distance(*f, LampPass::camera(i), pass.seen(other, i, rnd)), kGateChi2)
          << "frame " << i << ", lamp at " << other.transpose();
    }
    f->add_dense_information(own, LampPass::view(i));
    f->extend(LampPass::view(i));
  }
  EXPECT_GE(gated, 5);  // several frames were gated before the point was triangulated
}

// ---------------------------------------------------------------- the type

TEST(BearingType, KindsParametersAndSamples) {
  PointType type(point_args());
  ASSERT_EQ(type.measurement_kinds().size(), 3u);
  EXPECT_EQ(type.measurement_kinds()[2], "bearing3d");
  const Params defaults = Params::defaults(PointType::param_specs());
  EXPECT_EQ(defaults.get_int("min_rays"), 3);
  EXPECT_EQ(defaults.get_int("max_rays"), 20);
  EXPECT_DOUBLE_EQ(defaults.get_double("min_parallax_deg"), 10.0);
  EXPECT_DOUBLE_EQ(defaults.get_double("initial_depth"), 2.0);
  EXPECT_DOUBLE_EQ(defaults.get_double("initial_depth_sigma"), 1.0);
  EXPECT_DOUBLE_EQ(defaults.get_double("ray_spacing"), 0.05);
  PluginArgs bad = point_args();
  bad.params.set("min_rays", std::int64_t{5});
  bad.params.set("max_rays", std::int64_t{4});
  EXPECT_THROW(PointType{bad}, std::invalid_argument);

  // The conformance samples cover the three kinds at dims 0 and 3 (seed % 3)
  // and both ranged kinds at dim 2 (seed % 2), with η = 0.
  const char* kinds[] = {"range_bearing_elevation", "bearing3d", "range_bearing"};
  for (int dim : {0, 2, 3}) {
    for (std::uint64_t seed : {1u, 2u, 3u}) {
      const std::optional<FeatureSample> s = type.sample(dim, seed);
      ASSERT_TRUE(s.has_value());
      EXPECT_EQ(s->measurement.kind, dim == 2 ? (seed % 2 == 0 ? "range_bearing" : "range_bearing_elevation")
                                              : kinds[seed % 3]);
      EXPECT_EQ(s->feature->mspace_dim(), dim);
      Innovation inn;
      ASSERT_TRUE(s->feature->innovation(to_sensor_frame(layout(), s->feature->coords(), s->x_ms), s->measurement, inn));
      EXPECT_LT(inn.eta.norm(), 1e-12);
    }
  }
}

}  // namespace
}  // namespace mspace::point
