// Tests of the `hline` feature type (ICRA §V, eqs. 17–22; T-RO §IV-G):
// B·B̃ = I and eqs. 17/21 at the centre, the horizontal constraint under
// perturbations, η = 0 at the true line, J_ηo and J_ηv against central
// differences for random lines and tilted cameras, the extensions' J_sensor
// and J_own against differences of whole runs, a synthetic camera pass
// under a line 2.2 m up that grows the M-space 0 → 1 → 3 and slides the ends,
// and the tests that the planes are one line before they are triangulated
// (a parallel neighbour's planes, a ray meeting a neighbour's planes, two
// viewpoints alone).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <optional>
#include <random>
#include <vector>

#include "hline_feature.hpp"
#include "hline_geometry.hpp"
#include "mspace/pose.hpp"
#include "mspace/transform.hpp"

namespace mspace::hline {
namespace {

constexpr double kStep = 1e-6;
constexpr double kFocal = 500.0;
constexpr double kHalfWidth = 320.0, kHalfHeight = 240.0;  ///< image half size (px)
const double kSqrt2 = std::numbers::sqrt2;
const CoordLayout kLayout{BlockKind::Point3D, BlockKind::Point3D};

using Fn = std::function<Eigen::VectorXd(const Eigen::VectorXd&)>;

Eigen::MatrixXd numeric_jacobian(const Fn& f, const Eigen::VectorXd& x) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    Eigen::VectorXd d = Eigen::VectorXd::Zero(x.size());
    d[i] = kStep;
    J.col(i) = (f(x + d) - f(x - d)) / (2.0 * kStep);
  }
  return J;
}

/// Largest difference relative to the larger of 1 and the reference's largest entry.
double relative_error(const Eigen::MatrixXd& analytic, const Eigen::MatrixXd& numeric) {
  return (analytic - numeric).cwiseAbs().maxCoeff() / std::max(1.0, numeric.cwiseAbs().maxCoeff());
}

double uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

/// A line 1–3 m long, 1.5–2.5 m above a camera tilted up to 0.25 rad that
/// stands within 0.8 m of it.
struct Scene {
  Vec6 line;
  Pose6 x_ms;
};

Scene random_scene(std::mt19937_64& rng) {
  const Vec2 centre(uniform(rng, -4, 4), uniform(rng, -4, 4));
  const Vec2 t = direction(uniform(rng, -3.1, 3.1)), n(t.y(), -t.x());
  const double L = uniform(rng, 1.0, 3.0), camera_z = uniform(rng, -0.5, 1.0);
  Scene s;
  s.line = make_line(centre, t, camera_z + uniform(rng, 1.5, 2.5), -0.5 * L, 0.5 * L);
  const Vec2 camera = centre + uniform(rng, -0.8, 0.8) * n + uniform(rng, -0.2, 0.2) * L * t;
  s.x_ms = make_pose(camera.x(), camera.y(), camera_z, uniform(rng, -3.1, 3.1), uniform(rng, -0.25, 0.25),
                     uniform(rng, -0.25, 0.25));
  return s;
}

Measurement ceiling_line(const Eigen::VectorXd& v, double sigma_px) {
  Measurement m;
  m.kind = kCeilingLine;
  m.v = v;
  m.C_v = Eigen::VectorXd::Constant(kMeasurementSize, sigma_px * sigma_px).asDiagonal();
  m.C_v(4, 4) = 1e-4;  // the focal length is known
  return m;
}

Eigen::VectorXd add_noise(Eigen::VectorXd v, double sigma_px, std::mt19937_64& rng) {
  if (sigma_px == 0.0) return v;
  std::normal_distribution<double> noise(0.0, sigma_px);
  for (int i = 0; i < 4; ++i) v[i] += noise(rng);
  return v;
}

Eigen::VectorXd eta(const Feature& f, const Eigen::VectorXd& x_o, const Measurement& m) {
  Innovation in;
  if (!f.innovation(x_o, m, in)) return Eigen::VectorXd::Constant(f.mspace_dim() == 3 ? 2 : 1, std::nan(""));
  return in.eta;
}

// ---------------------------------------------------------------- B and B̃

TEST(HLine, ProjectionMatricesAreDualAndAreEqs17And21AtTheCentre) {
  std::mt19937_64 rng(3);
  for (int k = 0; k < 20; ++k) {
    const Scene s = random_scene(rng);
    const LineGeometry g = line_geometry(s.line);
    const Vec2 centre = 0.5 * (g.p1 + g.p2).head<2>();
    const Vec2 anchor = g.p1.head<2>() + uniform(rng, 0.0, 1.0) * g.L * g.t;
    for (int dim : {1, 3}) {
      for (const Vec2& a : {centre, anchor}) {
        const Eigen::MatrixXd B = hline_B(s.line, dim, a), Bd = hline_B_dual(s.line, dim, a);
        ASSERT_EQ(B.rows(), dim);
        ASSERT_EQ(Bd.cols(), dim);
        EXPECT_LT((B * Bd - Eigen::MatrixXd::Identity(dim, dim)).cwiseAbs().maxCoeff(), 1e-12);
      }
    }
    // Eq. 21 with (cos γ, sin γ) = n; its first row is eq. 17.
    const double cg = g.n.x(), sg = g.n.y(), L = g.L;
    Eigen::Matrix<double, 3, 6> eq21;
    eq21 << cg / L, sg / L, 0, -cg / L, -sg / L, 0,  //
        cg, sg, 0, cg, sg, 0,                        //
        0, 0, 1, 0, 0, 1;
    eq21 /= kSqrt2;
    EXPECT_LT((hline_B(s.line, 3, centre) - eq21).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((hline_B(s.line, 1, centre) - eq21.topRows(1)).cwiseAbs().maxCoeff(), 1e-12);
    // A turn by δα about any point of the line is δx_p,1 = δα/√2.
    const double turn = 1e-7;
    const Vec2 p1 = g.p1.head<2>(), p2 = g.p2.head<2>();
    const auto rotate = [&](const Vec2& p) { return Vec2(anchor + Eigen::Rotation2Dd(turn) * (p - anchor)); };
    Vec6 turned = s.line;
    turned.head<2>() = rotate(p1);
    turned.segment<2>(3) = rotate(p2);
    const Eigen::VectorXd dx_p = hline_B(s.line, 3, anchor) * (turned - s.line);
    EXPECT_NEAR(dx_p[0], turn / kSqrt2, 1e-12);
    EXPECT_NEAR(dx_p[1], 0.0, 1e-12);  // the anchor does not move
  }
}

TEST(HLine, StaysExactlyHorizontalUnderRandomPerturbations) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> gauss(0.0, 0.05);
  for (int dim : {1, 3}) {
    const Scene s = random_scene(rng);
    HLineFeature f(HLineConfig{}, s.line, dim, s.line.head<2>());
    for (int k = 0; k < 200; ++k) {
      const Eigen::MatrixXd Bd = f.B_dual();
      EXPECT_EQ((Bd.row(2) - Bd.row(5)).cwiseAbs().maxCoeff(), 0.0);  // B̃ raises both ends alike
      Eigen::VectorXd dx(dim);
      for (int i = 0; i < dim; ++i) dx[i] = gauss(rng);
      const double z_before = f.coords()[2];
      const Eigen::VectorXd raw = f.coords() + Bd * dx;  // eq. 24 before the feature's own rounding clean-up
      EXPECT_NEAR(raw[2], raw[5], 1e-15 * (1.0 + std::abs(raw[2])));
      f.apply_perturbation(dx);
      ASSERT_EQ(f.coords()[2], f.coords()[5]) << "after perturbation " << k;
      EXPECT_NEAR(f.coords()[2] - z_before, dim == 3 ? dx[2] / kSqrt2 : 0.0, 1e-12);
      EXPECT_LT((f.B() * f.B_dual() - Eigen::MatrixXd::Identity(dim, dim)).cwiseAbs().maxCoeff(), 1e-12);
    }
  }
}

// ---------------------------------------------------------------- eqs. 19–22

TEST(HLine, InnovationVanishesAtTheTrueLine) {
  std::mt19937_64 rng(7);
  for (int k = 0; k < 30; ++k) {
    const Scene s = random_scene(rng);
    const Measurement m = ceiling_line(project_line(s.line, s.x_ms, kFocal), 1.0);
    for (int dim : {1, 3}) {
      const HLineFeature f(HLineConfig{}, s.line, dim, s.line.head<2>());
      Innovation in;
      ASSERT_TRUE(f.innovation(to_sensor_frame(kLayout, s.line, s.x_ms), m, in)) << "scene " << k;
      ASSERT_EQ(in.eta.size(), dim == 3 ? 2 : 1);
      EXPECT_LT(in.eta.cwiseAbs().maxCoeff(), 1e-12);
    }
  }
}

TEST(HLine, InnovationJacobiansMatchCentralDifferences) {
  std::mt19937_64 rng(11);
  for (int k = 0; k < 30; ++k) {
    const Scene s = random_scene(rng);
    // Noisy, so that η ≠ 0 and every term of the Jacobians counts.
    const Measurement m = ceiling_line(add_noise(project_line(s.line, s.x_ms, kFocal), 2.0, rng), 2.0);
    const Eigen::VectorXd x_o = to_sensor_frame(kLayout, s.line, s.x_ms);
    for (int dim : {1, 3}) {
      const HLineFeature f(HLineConfig{}, s.line, dim, s.line.head<2>());
      Innovation in;
      ASSERT_TRUE(f.innovation(x_o, m, in));
      EXPECT_GT(in.eta.cwiseAbs().maxCoeff(), 1e-5);
      const Eigen::MatrixXd J_o = numeric_jacobian([&](const Eigen::VectorXd& x) { return eta(f, x, m); }, x_o);
      EXPECT_LT(relative_error(in.J_eta_o, J_o), 1e-7) << "J_ηo, scene " << k << ", dim " << dim;
      const Eigen::MatrixXd J_v = numeric_jacobian(
          [&](const Eigen::VectorXd& v) {
            Measurement mv = m;
            mv.v = v;
            return eta(f, x_o, mv);
          },
          m.v);
      EXPECT_LT(relative_error(in.J_eta_v, J_v), 1e-7) << "J_ηv, scene " << k << ", dim " << dim;
    }
  }
}

TEST(HLine, MeasurementsThatCannotBeTheLineAreRejected) {
  std::mt19937_64 rng(13);
  const Scene s = random_scene(rng);
  const LineGeometry g = line_geometry(s.line);
  const Eigen::VectorXd x_o = to_sensor_frame(kLayout, s.line, s.x_ms);
  Vec6 parallel = s.line, beyond = s.line;
  for (int e : {0, 3}) parallel.segment<2>(e) += 0.6 * g.n;  // a neighbour 0.6 m away
  beyond.head<2>() = g.p2.head<2>() + 1.0 * g.t;               // collinear, 1 m past the end
  beyond.segment<2>(3) = g.p2.head<2>() + 2.0 * g.t;
  const Measurement m_parallel = ceiling_line(project_line(parallel, s.x_ms, kFocal), 1.0);
  const Measurement m_beyond = ceiling_line(project_line(beyond, s.x_ms, kFocal), 1.0);
  Innovation in;
  for (int dim : {0, 1, 3}) {
    const HLineFeature f(HLineConfig{}, s.line, dim, s.line.head<2>());
    // While the position is a guess the plane must pass near it; at dim 3
    // the second innovation row (the association gate) tells them apart.
    if (dim < 3) {
      EXPECT_FALSE(f.innovation(x_o, m_parallel, in));
    } else {
      ASSERT_TRUE(f.innovation(x_o, m_parallel, in));
      EXPECT_GT(std::abs(in.eta[1]), 0.1);
    }
    EXPECT_FALSE(f.innovation(x_o, m_beyond, in)) << "no overlap, dim " << dim;
    Measurement other = m_parallel;
    other.kind = "line_segment2d";
    EXPECT_FALSE(f.innovation(x_o, other, in));
    Measurement no_focal = ceiling_line(project_line(s.line, s.x_ms, kFocal), 1.0);
    no_focal.v[4] = 0.0;
    EXPECT_FALSE(f.innovation(x_o, no_focal, in));
    // A camera looking down sees the line behind it.
    Pose6 down = s.x_ms;
    down[kPsi] = std::numbers::pi;
    const Measurement m = ceiling_line(project_line(s.line, s.x_ms, kFocal), 1.0);
    EXPECT_FALSE(f.innovation(to_sensor_frame(kLayout, s.line, down), m, in));
  }
}

// ---------------------------------------------------------------- observations

/// One observation of a camera pass: the measurement and the view.
struct Observation {
  Measurement m;
  SensorView view;
};

/// The part of `line` inside the camera's image (Liang–Barsky on the line
/// parameter λ ∈ [0, 1]: |f x| ≤ W z and |f y| ≤ H z are linear in λ), as
/// the λ of its ends; std::nullopt when less than 20 px of it shows.
std::optional<std::pair<double, double>> visible_part(const Vec6& line, const Pose6& x_ms) {
  const Eigen::VectorXd x_o = to_sensor_frame(kLayout, line, x_ms);
  const Vec3 a = x_o.head<3>(), d = x_o.tail<3>() - a;
  double lo = 0.0, hi = 1.0;
  const auto clip = [&](double g0, double g1) {  // g0 + g1 λ ≤ 0
    if (g1 == 0.0) {
      if (g0 > 0.0) hi = -1.0;
    } else if (g1 > 0.0) {
      hi = std::min(hi, -g0 / g1);
    } else {
      lo = std::max(lo, -g0 / g1);
    }
  };
  for (int axis : {0, 1}) {
    const double half = axis == 0 ? kHalfWidth : kHalfHeight;
    for (double sign : {1.0, -1.0}) clip(sign * kFocal * a[axis] - half * a.z(), sign * kFocal * d[axis] - half * d.z());
  }
  if (!(a.z() > 0.0 && a.z() + d.z() > 0.0) || !(hi > lo)) return std::nullopt;
  const Vec6 seen = make_line(line.head<2>(), line_geometry(line).t, line[2], lo * line_geometry(line).L,
                              hi * line_geometry(line).L);
  const Eigen::VectorXd v = project_line(seen, x_ms, kFocal);
  if ((v.segment<2>(2) - v.head<2>()).norm() < 20.0) return std::nullopt;
  return std::make_pair(lo, hi);
}

/// A camera at height 0 moving in a straight line from `from` to `to` in
/// `steps` steps, turning slowly and rocking by a few hundredths of a radian.
Pose6 pass_pose(const Vec2& from, const Vec2& to, int i, int steps) {
  const Vec2 p = from + (to - from) * static_cast<double>(i) / steps;
  return make_pose(p.x(), p.y(), 0.0, 0.3 + 0.2 * std::sin(i / 7.0), 0.03 * std::sin(i / 5.0), 0.03 * std::cos(i / 6.0));
}

struct Pass {
  std::vector<Observation> obs;
  std::vector<std::pair<double, double>> seen;  ///< the visible part of the line (λ) at each observation
};

/// Observations of `line` along a pass with noise σ_px on the end points
/// (C_v says 1 px whatever the noise).
Pass camera_pass(const Vec6& line, const Vec2& from, const Vec2& to, int steps, double sigma_px,
                 std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  Pass pass;
  double path = 0.0;
  for (int i = 0; i <= steps; ++i) {
    const Pose6 x_ms = pass_pose(from, to, i, steps);
    if (i > 0) path += (x_ms.head<2>() - pass_pose(from, to, i - 1, steps).head<2>()).norm();
    const auto part = visible_part(line, x_ms);
    if (!part) continue;
    const LineGeometry g = line_geometry(line);
    const Vec6 seen = make_line(g.p1.head<2>(), g.t, g.z, part->first * g.L, part->second * g.L);
    Observation o;
    o.m = ceiling_line(add_noise(project_line(seen, x_ms, kFocal), sigma_px, rng), 1.0);
    o.view.t = 0.1 * i;
    o.view.x_ms = x_ms;
    o.view.C_ms = Mat6::Zero();
    o.view.path_distance = path;
    pass.obs.push_back(o);
    pass.seen.push_back(*part);
  }
  return pass;
}

// ---------------------------------------------------------------- extension Jacobians

/// Feeds obs[0..last] into a feature (made by `start` from the first view),
/// every pose moved rigidly with the pose at `last` by `dpose`: the motion
/// J_sensor describes. Returns the feature and its first extension.
struct Fed {
  std::unique_ptr<Feature> feature;
  std::optional<Extension> extension;
  std::size_t at = 0;  ///< index of the observation that extended it
};

using Start = std::function<std::unique_ptr<Feature>(const Observation&)>;

Fed feed(const Start& start, const std::vector<Observation>& obs, std::size_t last, const Pose6& dpose) {
  const Pose6 reference = obs[last].view.x_ms;
  Fed fed;
  for (std::size_t i = 0; i <= last && !fed.extension; ++i) {
    Observation o = obs[i];
    o.view.x_ms = compound(reference + dpose, relative(reference, obs[i].view.x_ms));
    if (!fed.feature) fed.feature = start(o);
    fed.feature->add_dense_information(o.m, o.view);
    fed.extension = fed.feature->extend(o.view);
    fed.at = i;
  }
  return fed;
}

/// ∂(new M-space coordinates)/∂(input j) from runs perturbed by ±kStep, the
/// new coordinates being the nominal B's new rows applied to Δx_f.
Eigen::MatrixXd extension_jacobian(const Fed& nominal, int inputs, const std::function<Fed(int, double)>& run) {
  const int n = nominal.extension->new_dims;
  const Eigen::MatrixXd B_new = nominal.feature->B().bottomRows(n);
  Eigen::MatrixXd J(n, inputs);
  for (int j = 0; j < inputs; ++j) {
    const Fed plus = run(j, kStep), minus = run(j, -kStep);
    EXPECT_TRUE(plus.extension && minus.extension && plus.at == nominal.at && minus.at == nominal.at);
    J.col(j) = B_new * (plus.feature->coords() - minus.feature->coords()) / (2.0 * kStep);
  }
  return J;
}

Vec6 test_line() { return make_line(Vec2(0.0, 0.4), direction(20.0 * std::numbers::pi / 180.0), 2.2, -1.5, 1.5); }

// The extensions' Jacobians hold the fits' weights fixed (Gauss–Newton);
// the weights' own derivatives multiply residuals, which vanish for
// consistent observations. So whole runs are differentiated on noise-free
// passes here, and the fits on noisy planes with the weights held below.
TEST(HLine, DirectionEntersWithTheJacobianOfARigidMotion) {
  const Pass pass = camera_pass(test_line(), Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 0.0, 17);
  HLineType type(HLineConfig{});
  const Start create = [&](const Observation& o) { return type.create(o.m, o.view); };
  const Fed nominal = feed(create, pass.obs, pass.obs.size() - 1, Pose6::Zero());
  ASSERT_TRUE(nominal.extension);
  ASSERT_EQ(nominal.at, 2u);  // min_observations = 3
  EXPECT_EQ(nominal.feature->mspace_dim(), 1);
  const Eigen::MatrixXd numeric = extension_jacobian(nominal, 6, [&](int j, double h) {
    Pose6 d = Pose6::Zero();
    d[j] = h;
    return feed(create, pass.obs, nominal.at, d);
  });
  EXPECT_LT(relative_error(nominal.extension->J_sensor, numeric), 1e-6) << nominal.extension->J_sensor << "\n"
                                                                          << numeric;
  // A yaw error turns the line with it: ∂δx_p/∂θ = 1/√2 (δx_p = δα/√2).
  EXPECT_NEAR(nominal.extension->J_sensor(0, kTheta), 1.0 / kSqrt2, 1e-9);
  EXPECT_LT(nominal.extension->J_sensor.leftCols<3>().cwiseAbs().maxCoeff(), 1e-12);
}

TEST(HLine, PositionEntersWithTheJacobiansOfARigidMotionAndOfTheDirection) {
  const Vec6 truth = test_line();
  const Pass pass = camera_pass(truth, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 0.0, 19);
  HLineType type(HLineConfig{});
  // A line of dimension 1 at a guessed position.
  const LineGeometry g = line_geometry(truth);
  const Vec6 start_line = make_line(Vec2(0.3, -0.2), g.t, 2.0, -1.0, 1.0);
  const SavedFeature saved{start_line, 1, Vec2(0.3, -0.2)};
  const auto start = [&](double dx_old) -> Start {
    return [&, dx_old](const Observation&) {
      std::unique_ptr<Feature> f = type.restore(saved);
      f->apply_perturbation(Eigen::VectorXd::Constant(1, dx_old));
      return f;
    };
  };
  const Fed nominal = feed(start(0.0), pass.obs, pass.obs.size() - 1, Pose6::Zero());
  ASSERT_TRUE(nominal.extension);
  ASSERT_EQ(nominal.extension->new_dims, 2);
  EXPECT_EQ(nominal.feature->mspace_dim(), 3);
  const Eigen::MatrixXd numeric_sensor = extension_jacobian(nominal, 6, [&](int j, double h) {
    Pose6 d = Pose6::Zero();
    d[j] = h;
    return feed(start(0.0), pass.obs, nominal.at, d);
  });
  EXPECT_LT(relative_error(nominal.extension->J_sensor, numeric_sensor), 1e-6)
      << nominal.extension->J_sensor << "\n"
      << numeric_sensor;
  // Moving every camera by δz raises the triangulated line by δz: δx_p,3 = √2 δz.
  EXPECT_NEAR(nominal.extension->J_sensor(1, kZ), kSqrt2, 1e-9);
  const Eigen::MatrixXd numeric_own = extension_jacobian(nominal, 1, [&](int, double h) {
    return feed(start(h), pass.obs, nominal.at, Pose6::Zero());
  });
  EXPECT_LT(relative_error(nominal.extension->J_own, numeric_own), 1e-6) << nominal.extension->J_own << "\n"
                                                                          << numeric_own;
  EXPECT_GT(nominal.extension->J_own.cwiseAbs().maxCoeff(), 1e-3);  // the direction matters
}

std::vector<PlaneObservation> planes_of(const Pass& pass) {
  std::vector<PlaneObservation> planes;
  for (const Observation& o : pass.obs) planes.push_back(plane_in_map(*measured_line(o.m.v), o.m.C_v, o.view.x_ms));
  return planes;
}

/// The planes moved rigidly with the sensor pose x_ms → x_ms + d.
std::vector<PlaneObservation> moved(std::vector<PlaneObservation> planes, const Pose6& x_ms, const Pose6& d) {
  const Mat3 R = rotation(x_ms + d) * rotation(x_ms).transpose();
  for (PlaneObservation& p : planes) {
    p.c = R * p.c;
    p.o = x_ms.head<3>() + d.head<3>() + R * (p.o - x_ms.head<3>());
  }
  return planes;
}

TEST(HLine, FitsOnNoisyPlanesMatchCentralDifferencesWithTheWeightsHeld) {
  const Vec6 truth = test_line();
  const Pass pass = camera_pass(truth, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 1.0, 37);
  const std::vector<PlaneObservation> planes = planes_of(pass);
  const Pose6 x_ms = pass.obs.back().view.x_ms;
  const LineGeometry g = line_geometry(truth);

  const std::vector<double> w_dir = direction_weights(planes);
  const DirectionFit dir = fit_direction(planes, w_dir, g.t, x_ms);
  EXPECT_GT(dir.spread, 0.0);
  const Eigen::MatrixXd J_dir = numeric_jacobian(
      [&](const Eigen::VectorXd& d) {
        return Eigen::VectorXd::Constant(1, fit_direction(moved(planes, x_ms, d), w_dir, g.t, x_ms + d).alpha);
      },
      Eigen::VectorXd::Zero(6));
  EXPECT_LT(relative_error(dir.J_pose, J_dir), 1e-6) << dir.J_pose << "\n" << J_dir;

  const Vec2 t = direction(angle_of(g.t) + 0.01), pivot(0.3, -0.2);
  const std::vector<double> w_pos = plane_weights(planes, t, Vec3(pivot.x(), pivot.y(), 2.0));
  const std::optional<PositionFit> pos = fit_position(planes, w_pos, t, pivot, x_ms);
  ASSERT_TRUE(pos);
  EXPECT_GT(pos->chi2, 0.0);
  const Eigen::MatrixXd J_pose = numeric_jacobian(
      [&](const Eigen::VectorXd& d) { return Eigen::VectorXd(fit_position(moved(planes, x_ms, d), w_pos, t, pivot, x_ms + d)->x); },
      Eigen::VectorXd::Zero(6));
  EXPECT_LT(relative_error(pos->J_pose, J_pose), 1e-6) << pos->J_pose << "\n" << J_pose;
  const Eigen::MatrixXd J_alpha = numeric_jacobian(
      [&](const Eigen::VectorXd& a) {
        return Eigen::VectorXd(fit_position(planes, w_pos, direction(angle_of(t) + a[0]), pivot, x_ms)->x);
      },
      Eigen::VectorXd::Zero(1));
  EXPECT_LT(relative_error(pos->J_alpha, J_alpha), 1e-6) << pos->J_alpha.transpose() << "\n" << J_alpha.transpose();
}

// ---------------------------------------------------------------- the life cycle

// A camera at height 0 passes under a 3 m line 2.2 m up, crossing it
// obliquely (1.3 m normal to it over the pass), with 1-px noise on the end
// points. The line must start tentative, get its direction after three
// observations, be triangulated once the cameras spread 0.5 m normal to it,
// and slide its ends out to where the images showed them.
TEST(HLine, CameraPassGrowsTheMspaceAndSlidesTheEnds) {
  const double sigma_px = 1.0;
  const Vec6 truth = test_line();
  const LineGeometry tg = line_geometry(truth);
  const Pass pass = camera_pass(truth, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, sigma_px, 23);
  HLineConfig config;
  config.max_path_distance = 100.0;  // keep everything: the whole pass is the extent
  HLineType type(config);

  std::unique_ptr<Feature> f;
  std::optional<Extension> ext_direction, ext_position;
  double shortest_px = std::numeric_limits<double>::infinity(), length_after_position = 0.0;
  for (const Observation& o : pass.obs) {
    if (!f) {
      f = type.create(o.m, o.view);
      ASSERT_TRUE(f);
    } else {  // what association would ask: the measurement belongs to the line
      Innovation in;
      ASSERT_TRUE(f->innovation(to_sensor_frame(kLayout, f->coords(), o.view.x_ms), o.m, in));
    }
    f->add_dense_information(o.m, o.view);
    EXPECT_EQ(f->coords()[2], f->coords()[5]);
    if (f->mspace_dim() == 0) shortest_px = std::min(shortest_px, (o.m.v.segment<2>(2) - o.m.v.head<2>()).norm());
    if (f->mspace_dim() == 3) {  // the ends only ever grow
      const double L = line_geometry(f->coords()).L;
      EXPECT_GE(L, length_after_position - 1e-12);
      length_after_position = L;
    }
    std::optional<Extension> ext = f->extend(o.view);
    if (!ext) continue;
    (ext->new_dims == 1 ? ext_direction : ext_position) = ext;
    if (ext->new_dims == 2) length_after_position = line_geometry(f->coords()).L;
    if (ext->new_dims == 1) {
      // Direction: each observation's image direction has σ ≈ √2 σ_px/ℓ
      // (two ends, each off by σ_px across the segment of ℓ px); the mean
      // must be within 3 such σ of the shortest segment, and the reported
      // variance must be of that size (between 1/√3 and 3 of it: the mean of
      // three observations, inflated when they scatter).
      const double sigma_single = kSqrt2 * sigma_px / shortest_px;
      const double sigma_reported = std::sqrt(2.0 * ext->C_new(0, 0));  // δx_p = δα/√2
      const LineGeometry g = line_geometry(f->coords());
      const double error = std::asin(g.t.x() * tg.t.y() - g.t.y() * tg.t.x());
      EXPECT_LT(std::abs(error), 3.0 * sigma_single);
      EXPECT_LT(std::abs(error), 3.0 * sigma_reported);
      EXPECT_GT(sigma_reported, sigma_single / std::sqrt(3.0) * 0.99);
      EXPECT_LT(sigma_reported, 3.0 * sigma_single);
      EXPECT_LT(std::abs(f->coords()[2] - (o.view.x_ms[kZ] + config.initial_height)), 1e-12);  // a guess
    }
    if (ext->new_dims == 2) {
      // Offset (at the anchor) and height: the new coordinates are
      // √2 (δo, δz) = J_own δ1 + w, w ~ N(0, C_new) (no estimator runs here,
      // so δ1 is still the first extension's error, known from the truth).
      // Without the direction's part, the error must lie within 3σ of the
      // triangulation covariance C_new; with it, within 3σ of
      // C_new + J_own Var(δ1) J_ownᵀ.
      ASSERT_TRUE(ext_direction);
      const LineGeometry g = line_geometry(f->coords());
      const auto* hf = dynamic_cast<const HLineFeature*>(f.get());
      const Vec2 error = kSqrt2 * Vec2(tg.n.dot(hf->anchor() - tg.p1.head<2>()), g.z - tg.z);
      const double d1 = std::asin(tg.t.x() * g.t.y() - tg.t.y() * g.t.x()) / kSqrt2;  // δα/√2
      const Vec2 noise = error - ext->J_own.col(0) * d1;
      const Eigen::Matrix2d C_total = ext->C_new + ext->J_own * ext_direction->C_new * ext->J_own.transpose();
      for (int i = 0; i < 2; ++i) {
        EXPECT_LT(std::abs(noise[i]), 3.0 * std::sqrt(ext->C_new(i, i))) << "row " << i << ": " << noise.transpose();
        EXPECT_LT(std::abs(error[i]), 3.0 * std::sqrt(C_total(i, i))) << "row " << i << ": " << error.transpose();
        EXPECT_LT(std::sqrt(ext->C_new(i, i) / 2.0), 0.05);  // σ of the offset, the height (m)
      }
      // The height entered only once its σ was small next to the height.
      EXPECT_LE(std::sqrt(ext->C_new(1, 1) / 2.0), config.max_height_sigma * (g.z - o.view.x_ms[kZ]));
      // The cameras had spread at least min_baseline normal to the line.
      double lo = 1e9, hi = -1e9;
      for (const HLineObservation& ob : hf->observations()) {
        lo = std::min(lo, g.n.dot(ob.plane.o.head<2>()));
        hi = std::max(hi, g.n.dot(ob.plane.o.head<2>()));
      }
      EXPECT_GE(hi - lo, config.min_baseline);
    }
  }
  ASSERT_TRUE(ext_direction);
  ASSERT_TRUE(ext_position);
  EXPECT_EQ(f->mspace_dim(), 3);

  // The pass showed the whole line (both true ends appear in some image).
  double seen_lo = 1.0, seen_hi = 0.0;
  for (const auto& [lo, hi] : pass.seen) {
    seen_lo = std::min(seen_lo, lo);
    seen_hi = std::max(seen_hi, hi);
  }
  ASSERT_EQ(seen_lo, 0.0);
  ASSERT_EQ(seen_hi, 1.0);
  // The ends are the extent of the feet of all the stored end-point rays on
  // the line (nothing was pruned and, without an estimator, the line did not
  // move after its position entered).
  const LineGeometry g = line_geometry(f->coords());
  const auto* hf = dynamic_cast<const HLineFeature*>(f.get());
  ASSERT_EQ(hf->num_observations(), static_cast<int>(pass.obs.size()));
  double foot_lo = 1e9, foot_hi = -1e9, slope = 0.0;
  for (const HLineObservation& ob : hf->observations())
    for (const Vec3& u : {ob.ray_s, ob.ray_e}) {
      const double s = *ray_to_line(ob.plane.o, u, g.p1, Vec3(g.t.x(), g.t.y(), 0.0));
      foot_lo = std::min(foot_lo, s);
      foot_hi = std::max(foot_hi, s);
      slope = std::max(slope, std::abs(u.head<2>().dot(g.t)) / std::hypot(u.head<2>().dot(g.n), u.z()));
    }
  EXPECT_NEAR(foot_lo, 0.0, 1e-9);
  EXPECT_NEAR(foot_hi, g.L, 1e-9);
  // And they lie at the true ends: 1 px at ≤ 3 m with f = 500 is ≤ 6 mm
  // along the line, and the farthest of ≤ 61 such errors stays within
  // 3.3σ ≈ 2 cm; an error δ of the line's height or offset moves a ray's
  // foot along the line by at most δ times the ray's slope along the line
  // (|u·t| / √((u·n)² + u_z²)).
  const double position_error = std::abs(g.z - tg.z) + std::abs(tg.n.dot(hf->anchor() - tg.p1.head<2>()));
  const double tolerance = 0.02 + slope * position_error;
  const double s1 = tg.t.dot(g.p1.head<2>() - tg.p1.head<2>()), s2 = tg.t.dot(g.p2.head<2>() - tg.p1.head<2>());
  EXPECT_NEAR(std::min(s1, s2), 0.0, tolerance);
  EXPECT_NEAR(std::max(s1, s2), tg.L, tolerance);
  EXPECT_LT(tolerance, 0.06);
}

// ---------------------------------------------------------------- consistency of the planes

constexpr double kCameraHeight = 0.4;

/// A corridor line along x at lateral position y and height z, 2 m long
/// about x = −5 (the panel edge and the tile line of the rendered ceiling).
Vec6 corridor_line(double y, double z) { return make_line(Vec2(-5.0, y), Vec2::UnitX(), z, -1.0, 1.0); }

/// The plane of `line` seen without noise from a camera looking straight up
/// at (x, y), C_v of 1 px.
PlaneObservation plane_seen_from(const Vec6& line, double x, double y) {
  const Pose6 x_ms = make_pose(x, y, kCameraHeight, 0.0, 0.0, 0.0);
  const Measurement m = ceiling_line(project_line(line, x_ms, kFocal), 1.0);
  return plane_in_map(*measured_line(m.v), m.C_v, x_ms);
}

/// Planes of `line` from cameras along x at y = 0 (a camera path parallel to
/// the line: in the plane normal to it, one viewpoint).
std::vector<PlaneObservation> planes_along_x(const Vec6& line, int count) {
  std::vector<PlaneObservation> planes;
  for (int i = 0; i < count; ++i) planes.push_back(plane_seen_from(line, -5.5 + 0.05 * i, 0.0));
  return planes;
}

const InverseHeightPrior kPrior{0.5, 0.25};

// From one camera path parallel to the line the planes fix the ray's slope
// but not the height: the estimate's inverse height stays the prior's. The
// plane of a neighbour 0.12 m away (3° off from there) is still rejected
// outright, and one of the same line accepted. (In (offset, height) the
// planes of both lines meet on the camera path itself, and pass.)
// Drawing (Feature::drawing): while only the direction is in the M-space
// (dim 1) the end points are a guess at initial_height, so the line asks to
// be drawn as a direction alone — a Direction item parallel to it, shown at
// the newest camera centre — and nothing placed; tentative (dim 0) and
// placed (dim 3) lines keep the generic drawing of their end points.
TEST(HLine, DrawnAsItsDirectionOnlyWhileThePositionIsAGuess) {
  const Vec6 truth = test_line();
  const Pass pass = camera_pass(truth, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 1.0, 23);
  HLineConfig config;
  config.max_path_distance = 100.0;
  HLineType type(config);
  std::unique_ptr<Feature> f;
  int seen_at[4] = {0, 0, 0, 0};
  for (const Observation& o : pass.obs) {
    if (!f) f = type.create(o.m, o.view);
    ASSERT_TRUE(f);
    f->add_dense_information(o.m, o.view);
    f->extend(o.view);
    const int dim = f->mspace_dim();
    ++seen_at[dim];
    const std::optional<FeatureDrawing> drawing = f->drawing();
    if (dim != 1) {
      EXPECT_FALSE(drawing.has_value()) << "dim " << dim;
      continue;
    }
    ASSERT_TRUE(drawing.has_value());
    EXPECT_TRUE(drawing->direction_only());
    ASSERT_EQ(drawing->items.size(), 1u);
    const DrawingItem& item = drawing->items.front();
    ASSERT_EQ(item.kind, DrawingItem::Kind::Direction);
    ASSERT_EQ(item.points.cols(), 2);
    const LineGeometry g = line_geometry(f->coords());
    const Vec2 d = item.points.col(1);
    EXPECT_NEAR(d.norm(), 1.0, 1e-12);
    EXPECT_NEAR(d.x() * g.t.y() - d.y() * g.t.x(), 0.0, 1e-12);  // parallel to the line
    const auto* hf = dynamic_cast<const HLineFeature*>(f.get());
    EXPECT_LT((Vec2(item.points.col(0)) - hf->observations().back().plane.o.head<2>()).norm(), 1e-12);
  }
  EXPECT_GT(seen_at[1], 0) << "the pass never held the line at dim 1";
  EXPECT_GT(seen_at[3], 0);
}

TEST(HLine, APlaneFromTheSameViewpointIsTestedByItsAngleWhateverTheHeight) {
  const Vec6 edge = corridor_line(-0.48, 2.6), tile = corridor_line(-0.6, 2.6);
  const std::vector<PlaneObservation> stored = planes_along_x(edge, 20);
  const Vec2 t = Vec2::UnitX();
  const Vec3 at(-5.0, -0.5, 2.6);
  const PlaneObservation same = plane_seen_from(edge, -4.4, 0.0), other = plane_seen_from(tile, -4.4, 0.0);
  const double rho = 1.0 / (2.6 - kCameraHeight);
  const std::optional<RayEstimate> e = estimate_ray(stored, plane_weights(stored, t, at), t, same.o, rho, kPrior);
  ASSERT_TRUE(e);
  EXPECT_NEAR(e->x[0], 0.48 / 2.2, 1e-9);  // s = n·(P − q)/(P_z − q_z), n = (0, −1)
  EXPECT_NEAR(e->x[1], kPrior.rho, 1e-9);  // the height is the prior's
  EXPECT_NEAR(std::sqrt(e->cov(1, 1)), kPrior.sigma, 1e-9);
  const double threshold = 6.63;  // χ²(1) at 0.99
  EXPECT_LT(plane_chi2(same, plane_weights({same}, t, at)[0], t, same.o, rho, *e), 1e-12);
  EXPECT_GT(plane_chi2(other, plane_weights({other}, t, at)[0], t, other.o, rho, *e), 100.0 * threshold);
  // Where the prior is wrong the ray still holds: the point lies on it.
  const Vec3 P = ray_point(*e, t, same.o);
  EXPECT_NEAR((P.y() - same.o.y()) / (P.z() - same.o.z()), -0.48 / 2.2, 1e-9);
}

// The inverse-height form is the triangulation itself once the cameras
// spread: noise-free planes of a crossing pass give the line's point
// exactly, each with zero deleted residual.
TEST(HLine, InverseHeightFitRecoversTheLineFromACrossingPass) {
  const Vec6 truth = test_line();
  const LineGeometry g = line_geometry(truth);
  const Pass pass = camera_pass(truth, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 0.0, 43);
  const std::vector<PlaneObservation> planes = planes_of(pass);
  const Vec3 q = planes.back().o;
  const std::optional<RayEstimate> e =
      estimate_ray(planes, plane_weights(planes, g.t, Vec3(0.0, 0.4, 2.2)), g.t, q, 1.0 / 2.2);
  ASSERT_TRUE(e);
  EXPECT_NEAR(e->x[1], 1.0 / (g.z - q.z()), 1e-9);
  const Vec3 P = ray_point(*e, g.t, q);
  EXPECT_NEAR(P.z(), g.z, 1e-9);
  EXPECT_NEAR(g.n.dot(P.head<2>() - g.p1.head<2>()), 0.0, 1e-9);
  EXPECT_LT(e->chi2, 1e-12);
  EXPECT_EQ(e->rows, static_cast<int>(planes.size()));
  for (double d : e->deleted_chi2) EXPECT_LT(d, 1e-12);
}

// The rendered corridor's trap: a panel edge (y = −0.48) seen along the whole
// corridor from y = 0, then the tile line 0.12 m beside it (y = −0.6) seen
// while the robot turns off across them (y 0.05 … 0.5). Together they meet
// in a point far below the ceiling; the cameras either side of the cut
// between the two groups disagree, and the smaller side is the turn's
// planes. With the edge seen in both groups they agree.
TEST(HLine, SplitTestSeesARayMeetingANeighboursPlanes) {
  const Vec6 edge = corridor_line(-0.48, 2.6), tile = corridor_line(-0.6, 2.6);
  const Vec2 t = Vec2::UnitX();
  for (const Vec6* turn_line : {&tile, &edge}) {
    std::vector<PlaneObservation> planes = planes_along_x(edge, 30);
    for (int j = 1; j <= 10; ++j) planes.push_back(plane_seen_from(*turn_line, -5.0, 0.05 * j));
    const Vec3 q = planes.back().o;
    const std::vector<double> w = plane_weights(planes, t, Vec3(-5.0, -0.5, 2.6));
    const SplitTest split = split_test(planes, w, t, q, 1.0 / 2.2, kPrior);
    if (turn_line == &edge) {
      // Only the prior differs: it holds the ray-only side at ρ = 0.5, the
      // other side sees ρ = 1/2.2; (0.5 − 1/2.2)²/0.25² = 0.033.
      EXPECT_LT(split.chi2, 0.05);
      continue;
    }
    EXPECT_GT(split.chi2, 9.21 * 10.0);  // χ²(2) at 0.99
    std::vector<std::size_t> smaller = split.smaller;
    std::sort(smaller.begin(), smaller.end());
    ASSERT_EQ(smaller.size(), 10u);
    for (std::size_t k = 0; k < smaller.size(); ++k) EXPECT_EQ(smaller[k], 30 + k);
    // Fitted together, the two groups meet 0.5 m below the ceiling.
    const std::optional<RayEstimate> e = estimate_ray(planes, w, t, q, 1.0 / 2.2, kPrior);
    ASSERT_TRUE(e);
    EXPECT_LT(ray_point(*e, t, q).z(), 2.6 - 0.5);
  }
}

TEST(HLine, RaySpreadShowsViewpointsStandingApart) {
  const Vec2 t = Vec2::UnitX();
  const Vec3 P(0.0, 0.0, 2.6);
  std::vector<PlaneObservation> two_paths, crossing;
  for (int i = 0; i < 10; ++i) {
    PlaneObservation p{Vec3::UnitZ(), Mat3::Zero(), Vec3::Zero()};  // only the camera centres count
    p.o = Vec3(0.1 * i, -0.8, kCameraHeight);
    two_paths.push_back(p);
    p.o.y() = 0.8;
    two_paths.push_back(p);
    p.o = Vec3(0.0, -0.8 + 1.6 * i / 9.0, kCameraHeight);
    crossing.push_back(p);
  }
  const double ray = std::atan2(0.8, 2.2);
  const RaySpread apart = ray_spread(two_paths, t, P), swept = ray_spread(crossing, t, P);
  EXPECT_NEAR(apart.span, 2.0 * ray, 1e-12);
  EXPECT_NEAR(apart.largest_gap, apart.span, 1e-12);
  EXPECT_NEAR(swept.span, 2.0 * ray, 1e-12);
  EXPECT_LT(swept.largest_gap, 0.15 * swept.span);
}

/// The observations of several passes in time order (ties in the order of
/// `passes`): at the same time, or, when `consecutive`, one pass after the
/// other (times and path distances continuing).
std::vector<Observation> merged(const std::vector<Pass>& passes, bool consecutive) {
  std::vector<Observation> out;
  double t0 = 0.0, path0 = 0.0;
  for (const Pass& pass : passes) {
    for (Observation o : pass.obs) {
      o.view.t += t0;
      o.view.path_distance += path0;
      out.push_back(o);
    }
    if (consecutive && !out.empty()) {
      t0 = out.back().view.t + 0.1;
      path0 = out.back().view.path_distance + 1.0;
    }
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const Observation& a, const Observation& b) { return a.view.t < b.view.t; });
  return out;
}

/// A feature fed by feed_all and its extensions.
struct FedFeature {
  std::unique_ptr<Feature> feature;
  std::optional<Extension> direction, position;
  std::size_t position_at = 0;
};

/// Feeds the observations to one feature created from the first, as an
/// association that lets all of them through would, up to the position's
/// extension (from then on, c·r̂ tells lines apart) or to the end.
FedFeature feed_all(const HLineConfig& config, const std::vector<Observation>& obs) {
  HLineType type(config);
  FedFeature fed;
  for (std::size_t i = 0; i < obs.size() && !fed.position; ++i) {
    if (!fed.feature) fed.feature = type.create(obs[i].m, obs[i].view);
    fed.feature->add_dense_information(obs[i].m, obs[i].view);
    std::optional<Extension> ext = fed.feature->extend(obs[i].view);
    if (ext && ext->new_dims == 1) fed.direction = ext;
    if (ext && ext->new_dims == 2) {
      fed.position = ext;
      fed.position_at = i;
    }
  }
  return fed;
}

/// Height error of a triangulated feature and its σ from C_new (δx_p = √2 δz).
std::pair<double, double> height_error(const FedFeature& fed, const Vec6& truth) {
  return {fed.feature->coords()[2] - truth[2], std::sqrt(fed.position->C_new(1, 1) / 2.0)};
}

// A pass under the test line and its parallel neighbour 0.6 m away (the tile
// grid), where every measurement of both reaches the line: at dims 0 and 1
// c·t̂ cannot tell them apart. None of the neighbour's planes may be stored,
// and the triangulation must find the line's own height.
TEST(HLine, ParallelNeighbourPlanesAreNotStored) {
  const Vec6 truth = test_line();
  const LineGeometry g = line_geometry(truth);
  Vec6 neighbour = truth;
  for (int e : {0, 3}) neighbour.segment<2>(e) += 0.6 * g.n;
  const Pass own = camera_pass(truth, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 1.0, 47);
  const Pass other = camera_pass(neighbour, Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 1.0, 53);
  ASSERT_GT(other.obs.size(), 20u);
  HLineConfig config;
  config.max_path_distance = 100.0;
  std::vector<Observation> obs = merged({own, other}, false);
  while (obs.front().view.t < own.obs.front().view.t) obs.erase(obs.begin());  // the line starts with its own
  const FedFeature fed = feed_all(config, obs);
  ASSERT_TRUE(fed.position);
  const auto* f = dynamic_cast<const HLineFeature*>(fed.feature.get());
  // Each stored plane holds the true line (its end points within 3 cm).
  for (const HLineObservation& o : f->observations())
    for (int e : {0, 3}) EXPECT_LT(std::abs(o.plane.c.dot(truth.segment<3>(e) - o.plane.o)), 0.03);
  const double t_entered = obs[fed.position_at].view.t;
  const auto own_fed = std::count_if(own.obs.begin(), own.obs.end(),
                                     [&](const Observation& o) { return o.view.t <= t_entered; });
  EXPECT_GE(f->num_observations(), own_fed - 2);  // hardly any of its own lost (1 % by the test)
  const auto [error, sigma] = height_error(fed, truth);
  EXPECT_LT(std::abs(error), 3.0 * sigma);
  EXPECT_LE(sigma, config.max_height_sigma * g.z);  // test (c); camera_pass's cameras are at z = 0
}

// Two camera paths parallel to the line, 0.8 m either side: baseline enough,
// but two viewpoints always meet in a point. The line waits (test (d)) until
// a pass across it fills the rays in between; without the test it would have
// entered at once.
TEST(HLine, TwoViewpointsAloneDoNotTriangulate) {
  const Vec6 truth = test_line();
  const LineGeometry g = line_geometry(truth);
  const Vec2 c = 0.5 * (g.p1 + g.p2).head<2>();
  const Pass left = camera_pass(truth, c - 0.8 * g.n - 0.6 * g.t, c - 0.8 * g.n + 0.6 * g.t, 12, 1.0, 59);
  const Pass right = camera_pass(truth, c + 0.8 * g.n + 0.6 * g.t, c + 0.8 * g.n - 0.6 * g.t, 12, 1.0, 61);
  const Pass across = camera_pass(truth, c - 0.9 * g.n + 0.3 * g.t, c + 0.9 * g.n + 0.3 * g.t, 24, 1.0, 67);
  ASSERT_GE(left.obs.size(), 10u);
  ASSERT_GE(right.obs.size(), 10u);
  HLineConfig config;
  config.max_path_distance = 100.0;
  const std::vector<Observation> paths = merged({left, right}, true);
  EXPECT_FALSE(feed_all(config, paths).position);
  HLineConfig no_gap_test = config;
  no_gap_test.max_ray_gap = 1.0;
  const FedFeature hasty = feed_all(no_gap_test, paths);
  ASSERT_TRUE(hasty.position);
  EXPECT_EQ(hasty.position_at, left.obs.size());  // at the second path's first ray

  const FedFeature fed = feed_all(config, merged({left, right, across}, true));
  ASSERT_TRUE(fed.position);
  EXPECT_GE(fed.position_at, paths.size());
  const auto [error, sigma] = height_error(fed, truth);
  EXPECT_LT(std::abs(error), 3.0 * sigma);
}

// ---------------------------------------------------------------- bookkeeping

TEST(HLine, CreatesATentativeLineInTheMeasuredPlaneAtTheGuessedHeight) {
  std::mt19937_64 rng(29);
  const Scene s = random_scene(rng);
  HLineType type(HLineConfig{});
  const Measurement m = ceiling_line(project_line(s.line, s.x_ms, kFocal), 1.0);
  SensorView view;
  view.x_ms = s.x_ms;
  view.C_ms = Mat6::Identity() * 1e-4;
  std::unique_ptr<Feature> f = type.create(m, view);
  ASSERT_TRUE(f);
  f->add_dense_information(m, view);
  EXPECT_EQ(f->mspace_dim(), 0);
  const Vec6 x = f->coords();
  EXPECT_NEAR(x[2], s.x_ms[kZ] + HLineConfig{}.initial_height, 1e-12);
  // Both end points lie in the plane through the camera and the segment.
  const Vec3 c = rotation(s.x_ms) * measured_line(m.v)->c;
  for (int e : {0, 3}) EXPECT_NEAR(c.dot(x.segment<3>(e) - s.x_ms.head<3>()), 0.0, 1e-9);
  // Parallel to the true line, and η = 0.
  EXPECT_NEAR(std::abs(line_geometry(x).t.dot(line_geometry(s.line).t)), 1.0, 1e-9);
  Innovation in;
  ASSERT_TRUE(f->innovation(to_sensor_frame(kLayout, x, s.x_ms), m, in));
  EXPECT_LT(std::abs(in.eta[0]), 1e-12);
  // Gating covariance: a turn about the centre, positive.
  const Eigen::MatrixXd G = f->gating_covariance();
  ASSERT_EQ(G.rows(), 6);
  EXPECT_GT(G.trace(), 0.0);
  EXPECT_LT((hline_B(x, 3, 0.5 * (x.head<2>() + x.segment<2>(3))).bottomRows(2) * G).norm(), 1e-15);
}

TEST(HLine, PrunesObservationsByPathDistance) {
  HLineConfig config;
  config.max_path_distance = 1.0;
  config.consistency_probability = 1.0 - 1e-12;  // this test is about pruning: keep every plane of the true line
  const Pass pass = camera_pass(test_line(), Vec2(-1.5, -1.0), Vec2(1.5, 1.5), 60, 1.0, 31);
  HLineFeature f(config, test_line(), 1, Vec2::Zero());
  for (const Observation& o : pass.obs) f.add_dense_information(o.m, o.view);
  const double newest = pass.obs.back().view.path_distance;
  ASSERT_GT(newest, 2.0);
  for (const HLineObservation& o : f.observations()) EXPECT_LE(newest - o.view.path_distance, 1.0);
  int expected = 0;
  for (const Observation& o : pass.obs) expected += newest - o.view.path_distance <= 1.0 ? 1 : 0;
  EXPECT_EQ(f.num_observations(), expected);
}

TEST(HLine, SaveRestoreRoundTripAndRejectsBrokenState) {
  HLineType type(HLineConfig{});
  for (int dim : {0, 1, 3}) {
    const auto s = type.sample(dim, 41);
    ASSERT_TRUE(s);
    const SavedFeature saved = s->feature->save();
    const auto back = type.restore(saved);
    EXPECT_EQ(back->mspace_dim(), dim);
    EXPECT_EQ(back->coords(), s->feature->coords());
    EXPECT_LT((back->B() - s->feature->B()).norm(), 1e-15);
    EXPECT_NEAR(*back->footprint_radius(), 0.5 * line_geometry(saved.coords).L, 1e-15);
  }
  SavedFeature bad = type.sample(3, 41)->feature->save();
  bad.coords[5] += 0.1;  // not horizontal
  EXPECT_THROW(type.restore(bad), std::invalid_argument);
  bad = type.sample(3, 41)->feature->save();
  bad.mspace_dim = 2;
  EXPECT_THROW(type.restore(bad), std::invalid_argument);
  bad = type.sample(3, 41)->feature->save();
  bad.extra.resize(0);
  EXPECT_THROW(type.restore(bad), std::invalid_argument);
  EXPECT_FALSE(type.sample(2, 1));
}

TEST(HLine, ParametersReadFromTheirDefaults) {
  PluginArgs args;
  args.params = Params::defaults(HLineType::param_specs());
  const HLineType type(args);
  const HLineConfig d;
  EXPECT_EQ(type.config().min_observations, d.min_observations);
  EXPECT_NEAR(type.config().max_direction_spread, d.max_direction_spread, 1e-12);
  EXPECT_NEAR(type.config().match_angle, d.match_angle, 1e-12);
  EXPECT_EQ(type.config().min_baseline, d.min_baseline);
  EXPECT_EQ(type.config().consistency_probability, d.consistency_probability);
  EXPECT_EQ(type.config().inverse_height_sigma, d.inverse_height_sigma);
  EXPECT_EQ(type.config().max_height_sigma, d.max_height_sigma);
  EXPECT_EQ(type.config().max_ray_gap, d.max_ray_gap);
  args.params.set("max_observations", std::int64_t{2});
  EXPECT_THROW(HLineType{args}, std::invalid_argument);
}

}  // namespace
}  // namespace mspace::hline
