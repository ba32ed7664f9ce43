// conformance_others.cpp — the checks of motion models, estimators,
// extractors and data sources (see conformance.hpp).
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>

#include "conformance_internal.hpp"
#include "mspace/estimator.hpp"
#include "mspace/extractor.hpp"
#include "mspace/motion_model.hpp"
#include "mspace/pose.hpp"
#include "mspace/source.hpp"

namespace mspace::conformance::detail {
namespace {

constexpr double kJacobianTol = 1e-5;
constexpr double kKalmanTol = 1e-9;  ///< relative error against the closed-form filter
constexpr int kSourceSteps = 20;

bool is_angle(int pose_index) { return pose_index >= kTheta; }

/// True when `call` throws a std::exception.
template <class F>
bool throws(F&& call) {
  try {
    call();
    return false;
  } catch (const std::exception&) {
    return true;
  }
}

// ---------------------------------------------------------------- motion model

Pose6 random_pose(Rng& rng) {
  return make_pose(uniform(rng, -10, 10), uniform(rng, -10, 10), uniform(rng, -1, 1), uniform(rng, -3, 3),
                   uniform(rng, -0.3, 0.3), uniform(rng, -0.3, 0.3));
}

/// The estimated coordinates of f(x_r, x_d) (eq. 25), angle differences wrapped.
Eigen::VectorXd estimated_part(const Pose6& pose, const Pose6& reference, const std::vector<int>& dofs) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(dofs.size()));
  for (std::size_t i = 0; i < dofs.size(); ++i) {
    const int d = dofs[i];
    out[static_cast<Eigen::Index>(i)] = is_angle(d) ? reference[d] + wrap_angle(pose[d] - reference[d]) : pose[d];
  }
  return out;
}

void check_motion_sample(const MotionModel& model, const std::vector<int>& dofs, std::uint64_t seed, Recorder& r) {
  Rng rng(seed);
  const int k = static_cast<int>(dofs.size());
  const int d = model.increment_size();
  const Pose6 x_r = random_pose(rng);
  Eigen::VectorXd x_d(d);
  for (int i = 0; i < d; ++i) x_d[i] = uniform(rng, -0.3, 0.3);
  const double dt = 0.1;
  const MotionPrediction p = model.predict(x_r, x_d, dt);
  const bool sizes = p.J_rr.rows() == k && p.J_rr.cols() == k && p.J_rd.rows() == k && p.J_rd.cols() == d &&
                     p.C_d.rows() == d && p.C_d.cols() == d;
  r.at_most("motion.sizes", sizes ? 0 : 1, 0, "J_rr must be k × k, J_rd k × d and C_d d × d");
  const bool finite = p.pose.allFinite() && p.J_rr.allFinite() && p.J_rd.allFinite() && p.C_d.allFinite();
  r.at_most("motion.finite", finite ? 0 : 1, 0, "non-finite prediction");
  if (!sizes || !finite) return;

  // eq. 26: J_rr = ∂f/∂x_r over the estimated coordinates, J_rd = ∂f/∂x_d.
  Eigen::VectorXd xr_est(k);
  for (int i = 0; i < k; ++i) xr_est[i] = x_r[dofs[i]];
  const auto f_of_xr = [&](const Eigen::VectorXd& est) {
    Pose6 x = x_r;
    for (int i = 0; i < k; ++i) x[dofs[i]] = est[i];
    return estimated_part(model.predict(x, x_d, dt).pose, p.pose, dofs);
  };
  const auto f_of_xd = [&](const Eigen::VectorXd& inc) {
    return estimated_part(model.predict(x_r, inc, dt).pose, p.pose, dofs);
  };
  r.at_most("motion.J_rr", relative_error(p.J_rr, numeric_jacobian(f_of_xr, xr_est)), kJacobianTol,
            "J_rr differs from central differences (seed " + std::to_string(seed) + ")");
  r.at_most("motion.J_rd", relative_error(p.J_rd, numeric_jacobian(f_of_xd, x_d)), kJacobianTol,
            "J_rd differs from central differences (seed " + std::to_string(seed) + ")");
  r.at_least("motion.C_d_psd", d == 0 ? 0.0 : spd_ratio(p.C_d), -1e-12, "C_d is not symmetric positive semi-definite");

  const MotionPrediction again = model.predict(x_r, x_d, dt);
  r.at_most("motion.deterministic", (again.pose - p.pose).cwiseAbs().maxCoeff(), 0.0, "predict() is not repeatable");
  const Eigen::VectorXd long_xd = Eigen::VectorXd::Zero(d + 1);
  r.at_most("motion.wrong_size_rejected", throws([&] { model.predict(x_r, long_xd, dt); }) ? 0 : 1, 0,
            "predict() accepted an increment of the wrong size without an exception");
}

// ---------------------------------------------------------------- estimator

/// The closed-form linear-Gaussian filter on a dense covariance, for reference.
struct DenseFilter {
  Eigen::MatrixXd P;

  void predict(const Eigen::MatrixXd& F, const Eigen::MatrixXd& Q) {  // eqs. 26–27
    const Eigen::Index k = F.rows();
    Eigen::MatrixXd G = Eigen::MatrixXd::Identity(P.rows(), P.cols());
    G.topLeftCorner(k, k) = F;
    P = G * P * G.transpose();
    P.topLeftCorner(k, k) += Q;
  }
  void augment(const StateAugmentation& a) {
    const Eigen::Index n = P.rows(), m = a.C_new.rows();
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(m, n);
    for (std::size_t i = 0; i < a.idx.size(); ++i) J.col(a.idx[i]) = a.J.col(static_cast<Eigen::Index>(i));
    Eigen::MatrixXd out(n + m, n + m);
    out << P, P * J.transpose(), J * P, J * P * J.transpose() + a.C_new;
    P = out;
  }
  Eigen::VectorXd update(const std::vector<LinearizedObservation>& obs) {  // eqs. 28–32
    Eigen::Index m = 0;
    for (const auto& o : obs) m += o.eta.size();
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, P.rows()), R = Eigen::MatrixXd::Zero(m, m);
    Eigen::VectorXd eta(m);
    Eigen::Index row = 0;
    for (const auto& o : obs) {
      const Eigen::Index mi = o.eta.size();
      for (std::size_t i = 0; i < o.idx.size(); ++i) H.block(row, o.idx[i], mi, 1) = o.J.col(static_cast<Eigen::Index>(i));
      R.block(row, row, mi, mi) = o.C_eta;
      eta.segment(row, mi) = o.eta;
      row += mi;
    }
    const Eigen::MatrixXd S = H * P * H.transpose() + R;
    const Eigen::MatrixXd K = P * H.transpose() * S.inverse();
    P = P - K * S * K.transpose();
    return -K * eta;  // eq. 31: δx = −K η
  }
  void remove(int i) {
    std::vector<int> keep;
    for (int j = 0; j < P.rows(); ++j)
      if (j != i) keep.push_back(j);
    P = P(keep, keep).eval();
  }
};

std::vector<int> all_indices(int n) {
  std::vector<int> idx(static_cast<std::size_t>(n));
  std::iota(idx.begin(), idx.end(), 0);
  return idx;
}

Eigen::MatrixXd random_matrix(Rng& rng, int rows, int cols) {
  Eigen::MatrixXd m(rows, cols);
  for (int i = 0; i < m.size(); ++i) m.data()[i] = uniform(rng, -1, 1);
  return m;
}

LinearizedObservation random_observation(Rng& rng, std::vector<int> idx, int m) {
  LinearizedObservation o;
  o.idx = std::move(idx);
  o.eta = random_matrix(rng, m, 1);
  o.J = random_matrix(rng, m, static_cast<int>(o.idx.size()));
  o.C_eta = random_spd(rng, m, 0.05, 0.5);
  return o;
}

double covariance_error(const Estimator& est, const DenseFilter& ref) {
  if (est.dim() != ref.P.rows()) return std::numeric_limits<double>::infinity();
  return relative_error(est.marginal(all_indices(est.dim())), ref.P);
}

/// One scripted run: reset, predict, two augmentations, predict, update, remove.
void check_estimator_run(Estimator& est, std::uint64_t seed, Recorder& r) {
  Rng rng(seed);
  const int k = 3;
  DenseFilter ref{random_spd(rng, k, 0.1, 1.0)};
  est.reset(ref.P);
  r.at_most("estimator.reset", covariance_error(est, ref), kKalmanTol, "marginal() after reset() is not P_rr");

  const Eigen::MatrixXd F = Eigen::MatrixXd::Identity(k, k) + 0.2 * random_matrix(rng, k, k);
  const Eigen::MatrixXd Q = random_spd(rng, k, 0.01, 0.1);
  est.predict(F, Q);
  ref.predict(F, Q);
  r.at_most("estimator.predict", covariance_error(est, ref), kKalmanTol, "prediction differs from F P Fᵀ + Q (eq. 26)");

  const StateAugmentation a1{{0, 1}, random_matrix(rng, 2, 2), random_spd(rng, 2, 0.1, 1.0)};
  const StateAugmentation a2{{}, Eigen::MatrixXd(1, 0), random_spd(rng, 1, 0.1, 1.0)};
  const int first1 = est.augment(a1);
  ref.augment(a1);
  const int first2 = est.augment(a2);
  ref.augment(a2);
  r.at_most("estimator.augment", std::max(covariance_error(est, ref), first1 == k && first2 == k + 2 ? 0.0 : 1.0),
            kKalmanTol, "augmented covariance or returned index differs from the closed form");

  est.predict(F, Q);  // now with robot–feature cross-covariances (eq. 27)
  ref.predict(F, Q);
  r.at_most("estimator.predict", covariance_error(est, ref), kKalmanTol, "prediction with features differs (eq. 27)");

  const std::vector<LinearizedObservation> obs = {random_observation(rng, {0, 3, 4}, 2),
                                                   random_observation(rng, {5, 1}, 1)};
  const Eigen::VectorXd dx = est.update(obs);
  const Eigen::VectorXd dx_ref = ref.update(obs);
  r.at_most("estimator.kalman_update", std::max(relative_error(dx, dx_ref), covariance_error(est, ref)), kKalmanTol,
            "δx or covariance after update() differs from the closed-form Kalman filter (eqs. 28–32)");
  r.at_most("estimator.cross", relative_error(est.cross({0, 1}, {3, 5}), ref.P({0, 1}, {3, 5})), kKalmanTol,
            "cross() differs from the covariance");

  est.remove({3});
  ref.remove(3);
  r.at_most("estimator.remove", covariance_error(est, ref), kKalmanTol, "remove() left the wrong covariance");

  const int dim_before = est.dim();
  LinearizedObservation bad = random_observation(rng, {0, 1}, 2);
  bad.J = Eigen::MatrixXd::Ones(2, 3);
  const bool rejected = throws([&] { est.update({bad}); }) && throws([&] { est.predict(Eigen::MatrixXd::Identity(k + 1, k + 1), Q); });
  r.at_most("estimator.wrong_size_rejected",
            rejected && est.dim() == dim_before && covariance_error(est, ref) <= kKalmanTol ? 0 : 1, 0,
            "wrong-sized update()/predict() must throw and leave the state unchanged");
}

// ---------------------------------------------------------------- extractor, source

/// spd_ratio of C_v — except for a direction given as a unit vector (|v| = 1,
/// e.g. the lamps' 'bearing3d'): such a v has no variance along itself, so its
/// C_v is singular by construction (C_v v = 0) and must be positive definite
/// on the plane normal to v instead (v vᵀ, scaled, fills the null direction).
double covariance_ratio(const Measurement& m) {
  if (m.C_v.rows() != m.v.size() || m.C_v.cols() != m.v.size()) return -1.0;
  if (m.v.size() >= 2 && std::abs(m.v.norm() - 1.0) <= 1e-9) {
    const double scale = m.C_v.cwiseAbs().maxCoeff();
    if (scale > 0.0 && (m.C_v * m.v).norm() <= 1e-9 * scale)
      return spd_ratio(m.C_v + scale * m.v * m.v.transpose());
  }
  return spd_ratio(m.C_v);
}

bool measurement_ok(const Measurement& m) {
  return !m.kind.empty() && m.v.size() > 0 && m.v.allFinite() && covariance_ratio(m) > 0 &&
         m.dense.allFinite();
}

bool same_measurements(const std::vector<Measurement>& a, const std::vector<Measurement>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].kind != b[i].kind || a[i].v != b[i].v || a[i].C_v != b[i].C_v || a[i].flags != b[i].flags) return false;
  }
  return true;
}

bool same_steps(const DataStep& a, const DataStep& b) {
  if (a.t != b.t || a.odometry != b.odometry || a.odometry_covariance != b.odometry_covariance ||
      a.readings.size() != b.readings.size())
    return false;
  for (std::size_t i = 0; i < a.readings.size(); ++i) {
    const SensorReading& x = a.readings[i];
    const SensorReading& y = b.readings[i];
    if (x.channel != y.channel || x.t != y.t || x.values != y.values || x.file != y.file) return false;
  }
  return true;
}

}  // namespace

void check_motion_model(PluginObject& object, const Options& options, Recorder& r) {
  const auto& model = static_cast<const MotionModel&>(object);
  const std::vector<int> dofs = model.estimated_dofs();
  const bool ok = !dofs.empty() && std::is_sorted(dofs.begin(), dofs.end()) &&
                  std::adjacent_find(dofs.begin(), dofs.end()) == dofs.end() && dofs.front() >= 0 && dofs.back() < 6 &&
                  model.increment_size() >= 0;
  r.at_most("motion.declaration", ok ? 0 : 1, 0, "estimated_dofs() must be distinct ascending pose indices 0..5");
  if (!ok) return;
  for (int s = 0; s < options.samples; ++s) {
    guarded(r, "motion.predict", [&] { check_motion_sample(model, dofs, options.seed * 7919 + s, r); });
  }
}

void check_estimator(PluginObject& object, const Options& options, Recorder& r) {
  auto& est = static_cast<Estimator&>(object);
  for (int s = 0; s < options.samples; ++s) {
    guarded(r, "estimator.run", [&] { check_estimator_run(est, options.seed * 7919 + s, r); });
  }
}

void check_extractor(PluginObject& object, const Options& options, Recorder& r) {
  auto& ex = static_cast<Extractor&>(object);
  // An empty reading gives no measurements — or, for an extractor that needs
  // a particular reading layout, a clear error (an exception with a message).
  {
    std::vector<Measurement> out;
    try {
      ex.extract(SensorReading{"mspace_check", 0.0, Eigen::MatrixXd(0, 0), {}}, out);
      r.at_most("extractor.empty_reading", static_cast<double>(out.size()), 0, "an empty reading gave measurements");
    } catch (const std::exception& e) {
      const std::string message = e.what();
      r.at_most("extractor.empty_reading", message.empty() ? 1 : 0, 0,
                message.empty() ? "rejected without a message" : "rejected: " + message);
    }
  }
  for (int s = 0; s < options.samples; ++s) {
    const std::uint64_t seed = options.seed * 7919 + s;
    std::optional<SensorReading> reading = ex.sample_reading(seed);
    if (!reading) {  // a sample scene's reading serves as well
      if (std::optional<SampleScene> scene = ex.sample_scene(seed)) reading = std::move(scene->reading);
    }
    if (!reading) {
      r.skip("extractor.measurements", "the extractor provides neither sample_reading() nor sample_scene()");
      return;
    }
    guarded(r, "extractor.measurements", [&] {
      std::vector<Measurement> first, second;
      ex.extract(*reading, first);
      ex.extract(*reading, second);
      const auto bad = std::count_if(first.begin(), first.end(), [](const Measurement& m) { return !measurement_ok(m); });
      r.at_most("extractor.measurements", first.empty() ? 1.0 : static_cast<double>(bad), 0,
                "no measurements, or non-finite v / C_v not symmetric positive definite (for a unit vector v: "
                "on the plane normal to v)");
      r.at_most("extractor.deterministic", same_measurements(first, second) ? 0 : 1, 0,
                "the same reading gave different measurements");
    });
  }
}

void check_source(const PluginDescriptor& descriptor, PluginObject& object, const Options& options, Recorder& r) {
  auto& source = static_cast<DataSource&>(object);
  PluginArgs args;
  args.instance_name = "mspace_check_twin";
  args.params = instance_params(descriptor, options);
  std::unique_ptr<PluginObject> twin_object = descriptor.factory(args);
  auto& twin = static_cast<DataSource&>(*twin_object);
  r.at_most("source.initial_pose", source.initial_pose().allFinite() ? 0 : 1, 0, "non-finite initial pose");
  int bad = 0, different = 0, steps = 0;
  double last_t = -std::numeric_limits<double>::infinity();
  for (; steps < kSourceSteps; ++steps) {
    DataStep a, b;
    const bool more = source.next(a);
    if (more != twin.next(b)) ++different;
    if (!more) break;
    bool ok = std::isfinite(a.t) && a.t >= last_t && a.odometry.allFinite();
    for (const SensorReading& reading : a.readings) ok = ok && reading.values.allFinite() && std::isfinite(reading.t);
    if (a.ground_truth) ok = ok && a.ground_truth->allFinite();
    if (a.odometry_covariance.size() > 0)  // d × d for the d-vector x_d, finite and symmetric
      ok = ok && a.odometry_covariance.rows() == a.odometry.size() && a.odometry_covariance.cols() == a.odometry.size() &&
           a.odometry_covariance.allFinite() &&
           (a.odometry_covariance - a.odometry_covariance.transpose()).cwiseAbs().maxCoeff() <=
               1e-9 * (1.0 + a.odometry_covariance.cwiseAbs().maxCoeff());
    bad += ok ? 0 : 1;
    different += same_steps(a, b) ? 0 : 1;
    last_t = a.t;
  }
  r.at_most("source.steps_well_formed", steps == 0 ? 1 : bad, 0,
            "no steps, or non-finite / decreasing times, odometry or readings, or an odometry covariance "
            "that is not a finite symmetric d × d matrix");
  r.at_most("source.deterministic", different, 0, "two instances with the same parameters gave different steps");
}

}  // namespace mspace::conformance::detail
