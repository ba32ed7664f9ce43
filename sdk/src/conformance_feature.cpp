// conformance_feature.cpp — the checks of a feature type (see conformance.hpp).
//
// Everything is generic: the suite asks the type for samples
// (FeatureType::sample) and only uses the Feature interface, the layout and
// the SDK transform x_o = T(x_f | x_ms) (eqs. 7–9, 18) with J_of and J_os (eq. 19).
#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <string>

#include "conformance_internal.hpp"
#include "mspace/feature.hpp"
#include "mspace/numeric.hpp"
#include "mspace/pose.hpp"
#include "mspace/transform.hpp"

namespace mspace::conformance::detail {
namespace {

constexpr double kJacobianTol = 1e-5;   ///< relative error of analytic vs central differences
constexpr double kDualityTol = 1e-9;    ///< |B·B̃ − I| (eq. 12)
constexpr double kConditionTol = 1e8;   ///< condition number of B̃
constexpr double kRoundTripTol = 1e-12;
constexpr double kSymmetryTol = 1e-6;   ///< |∂η/∂x_f · d| along a declared symmetry
constexpr double kConsistencyTol = 100; ///< NIS of the sample's own measurement
constexpr int kMaxFeeds = 50;           ///< observations fed before an extension counts as missing
/// C_new against Σ_k J_v,k C_v J_v,kᵀ, and the gating covariance against its
/// first-order propagation: largest |λ − 1| of the generalised eigenvalues.
constexpr double kCovarianceTol = 1e-3;
constexpr int kTimedCalls = 20;         ///< innovation() calls per timed batch
constexpr int kTimedBatches = 5;        ///< batches per sample; the fastest counts
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

const Eigen::VectorXd kNoEta;  ///< returned when the innovation is rejected

/// η for the feature coordinates x_f seen from x_ms (NaN-filled of size m when rejected).
Eigen::VectorXd eta_at(const Feature& f, const Eigen::VectorXd& x_f, const Pose6& x_ms, const Measurement& m,
                       Eigen::Index m_size) {
  Innovation inn;
  const Eigen::VectorXd x_o = to_sensor_frame(f.layout(), x_f, x_ms);
  if (!f.innovation(x_o, m, inn) || inn.eta.size() != m_size) return Eigen::VectorXd::Constant(m_size, kNaN);
  return inn.eta;
}

double max_abs(const Eigen::MatrixXd& m) { return m.size() == 0 ? 0.0 : m.cwiseAbs().maxCoeff(); }

/// Largest difference of two matrices, +inf when their sizes differ.
double difference(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) return std::numeric_limits<double>::infinity();
  return max_abs(a - b);
}

/// One sample and everything the checks derive from it.
struct Probe {
  const FeatureType& type;
  FeatureSample sample;
  int dim;
  std::uint64_t seed;
  Eigen::VectorXd x_o;
  Eigen::MatrixXd J_of, J_os;
  Innovation inn;
};

void check_structure(const Probe& p, Recorder& r) {
  const Feature& f = *p.sample.feature;
  const int n = p.type.layout().size();
  int bad = 0;
  std::string why;
  auto expect = [&](bool ok, const std::string& what) {
    if (!ok && bad++ == 0) why = what;
  };
  expect(f.mspace_dim() == p.dim, "mspace_dim() is " + std::to_string(f.mspace_dim()));
  expect(f.layout() == p.type.layout(), "feature layout differs from the type's");
  expect(f.coords().size() == n, "coords() has the wrong size");
  expect(f.B().rows() == p.dim && f.B().cols() == n, "B is not dim × n");
  expect(f.B_dual().rows() == n && f.B_dual().cols() == p.dim, "B̃ is not n × dim");
  r.at_most("feature.sizes", bad, 0, why + " (dim " + std::to_string(p.dim) + ")");
  const bool finite = f.coords().allFinite() && f.B().allFinite() && f.B_dual().allFinite() &&
                      p.sample.x_ms.allFinite() && p.sample.measurement.v.allFinite();
  r.at_most("feature.finite", finite ? 0 : 1, 0, "non-finite x_f, B, B̃ or sample");
}

// eq. 12: B B̃ = I, and B̃ must have full column rank.
void check_duality(const Feature& f, Recorder& r) {
  const Eigen::MatrixXd B = f.B(), Bd = f.B_dual();
  if (B.cols() != Bd.rows()) {
    r.fail("feature.B_Bdual_identity", "B and B̃ do not fit together");
    return;
  }
  const Eigen::MatrixXd I = Eigen::MatrixXd::Identity(B.rows(), Bd.cols());
  r.at_most("feature.B_Bdual_identity", difference(B * Bd, I), kDualityTol,
            "B·B̃ ≠ I at dim " + std::to_string(f.mspace_dim()));
  if (Bd.cols() == 0) return;
  const Eigen::VectorXd sv = Eigen::JacobiSVD<Eigen::MatrixXd>(Bd).singularValues();
  const double cond = sv.minCoeff() > 0 ? sv.maxCoeff() / sv.minCoeff() : std::numeric_limits<double>::infinity();
  r.at_most("feature.Bdual_condition", cond, kConditionTol, "B̃ is (nearly) rank deficient");
}

bool compute_innovation(Probe& p, Recorder& r) {
  const Feature& f = *p.sample.feature;
  p.x_o = to_sensor_frame(f.layout(), f.coords(), p.sample.x_ms, &p.J_of, &p.J_os);
  const bool ok = f.innovation(p.x_o, p.sample.measurement, p.inn);
  r.at_most("feature.innovation_accepts_sample", ok ? 0 : 1, 0,
            "innovation() rejected the sample's own measurement (dim " + std::to_string(p.dim) + ")");
  if (!ok) return false;
  const Eigen::Index m = p.inn.eta.size();
  const bool sizes = m > 0 && p.inn.J_eta_o.rows() == m && p.inn.J_eta_o.cols() == p.x_o.size() &&
                     p.inn.J_eta_v.rows() == m && p.inn.J_eta_v.cols() == p.sample.measurement.v.size();
  r.at_most("feature.innovation_sizes", sizes ? 0 : 1, 0, "η, J_ηo or J_ηv has the wrong size");
  const bool finite = p.inn.eta.allFinite() && p.inn.J_eta_o.allFinite() && p.inn.J_eta_v.allFinite();
  r.at_most("feature.finite", finite ? 0 : 1, 0, "non-finite η or Jacobian");
  return sizes && finite;
}

using Clock = std::chrono::steady_clock;

double micros_since(Clock::time_point start) {
  return std::chrono::duration<double, std::micro>(Clock::now() - start).count();
}

/// Which Jacobians of `parts` the numeric helpers produced since the last reset.
void split_numeric(const std::vector<NumericJacobian>& parts, Cost& c) {
  c.evaluations = 0;
  for (NumericJacobian j : parts) {
    const NumericUsage u = numeric_usage(j);
    (u.calls > 0 ? c.numeric : c.analytic).push_back(numeric_jacobian_name(j));
    c.evaluations += static_cast<double>(u.evaluations);
  }
}

// The cost of innovation() per call, which of J_ηo, J_ηv are numeric, and what
// central differences through innovation() itself cost (all-numeric bound).
void record_innovation_cost(const Probe& p, Recorder& r) {
  const Feature& f = *p.sample.feature;
  const Measurement& m = p.sample.measurement;
  Innovation inn;
  Cost c;
  c.function = "innovation";
  // The fastest of several batches: the time of the call itself, not of
  // whatever else the machine was doing.
  reset_numeric_usage();
  c.micros = std::numeric_limits<double>::infinity();
  for (int batch = 0; batch < kTimedBatches; ++batch) {
    const Clock::time_point start = Clock::now();
    for (int i = 0; i < kTimedCalls; ++i) f.innovation(p.x_o, m, inn);
    c.micros = std::min(c.micros, micros_since(start) / kTimedCalls);
  }
  split_numeric({NumericJacobian::eta_o, NumericJacobian::eta_v}, c);
  c.evaluations /= kTimedCalls * kTimedBatches;
  c.calls = 1;
  const Eigen::Index msize = p.inn.eta.size();
  const auto eta_of_xo = [&](const Eigen::VectorXd& x_o) -> Eigen::VectorXd {
    if (!f.innovation(x_o, m, inn) || inn.eta.size() != msize) return Eigen::VectorXd::Constant(msize, kNaN);
    return inn.eta;
  };
  const auto eta_of_v = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    Measurement mv = m;
    mv.v = v;
    if (!f.innovation(p.x_o, mv, inn) || inn.eta.size() != msize) return Eigen::VectorXd::Constant(msize, kNaN);
    return inn.eta;
  };
  c.micros_by_differences = std::numeric_limits<double>::infinity();
  for (int batch = 0; batch < kTimedBatches; ++batch) {
    const Clock::time_point start = Clock::now();
    f.innovation(p.x_o, m, inn);
    numeric_jacobian(eta_of_xo, p.x_o);
    numeric_jacobian(eta_of_v, m.v);
    c.micros_by_differences = std::min(c.micros_by_differences, micros_since(start));
  }
  reset_numeric_usage();
  r.cost(c);
}

// The sample's measurement must agree with the feature: NIS ηᵀ S⁻¹ η with S = J_ηv C_v J_ηvᵀ.
void check_consistency(const Probe& p, Recorder& r) {
  const Eigen::MatrixXd& Jv = p.inn.J_eta_v;
  const Eigen::MatrixXd& C_v = p.sample.measurement.C_v;
  if (C_v.rows() != Jv.cols() || C_v.cols() != Jv.cols()) {
    r.fail("feature.sample_consistent", "C_v has the wrong size");
    return;
  }
  const Eigen::MatrixXd S = Jv * C_v * Jv.transpose();
  const Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (S + S.transpose()));
  if (llt.info() != Eigen::Success) {
    r.fail("feature.sample_consistent", "J_ηv C_v J_ηvᵀ is not positive definite");
    return;
  }
  r.at_most("feature.sample_consistent", p.inn.eta.dot(llt.solve(p.inn.eta)), kConsistencyTol,
            "the sample's measurement does not agree with its feature");
}

// eq. 16: J_ηo and J_ηv; eq. 30: J_ηo J_of B̃ and J_ηo J_os.
void check_jacobians(const Probe& p, Recorder& r) {
  const Feature& f = *p.sample.feature;
  const Measurement& m = p.sample.measurement;
  const Eigen::Index msize = p.inn.eta.size();
  const std::string at = " (dim " + std::to_string(p.dim) + ", seed " + std::to_string(p.seed) + ")";

  const auto eta_of_xo = [&](const Eigen::VectorXd& x_o) -> Eigen::VectorXd {
    Innovation inn;
    if (!f.innovation(x_o, m, inn) || inn.eta.size() != msize) return Eigen::VectorXd::Constant(msize, kNaN);
    return inn.eta;
  };
  r.at_most("feature.J_eta_o", relative_error(p.inn.J_eta_o, numeric_jacobian(eta_of_xo, p.x_o)), kJacobianTol,
            "J_ηo differs from central differences" + at);

  const auto eta_of_v = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    Measurement mv = m;
    mv.v = v;
    Innovation inn;
    if (!f.innovation(p.x_o, mv, inn) || inn.eta.size() != msize) return Eigen::VectorXd::Constant(msize, kNaN);
    return inn.eta;
  };
  r.at_most("feature.J_eta_v", relative_error(p.inn.J_eta_v, numeric_jacobian(eta_of_v, m.v)), kJacobianTol,
            "J_ηv differs from central differences" + at);

  const auto eta_of_pose = [&](const Eigen::VectorXd& x) { return eta_at(f, f.coords(), Pose6(x), m, msize); };
  r.at_most("feature.J_eta_sensor", relative_error(p.inn.J_eta_o * p.J_os, numeric_jacobian(eta_of_pose, p.sample.x_ms)),
            kJacobianTol, "J_ηo·J_os differs from central differences" + at);

  if (p.dim == 0) return;
  // Perturb a restored copy through apply_perturbation (eq. 24), so features
  // that keep constraints are differentiated the way the kernel moves them.
  const auto eta_of_dxp = [&](const Eigen::VectorXd& dx_p) -> Eigen::VectorXd {
    std::unique_ptr<Feature> copy = p.type.restore(f.save());
    copy->apply_perturbation(dx_p);
    return eta_at(*copy, copy->coords(), p.sample.x_ms, m, msize);
  };
  const Eigen::MatrixXd chain = p.inn.J_eta_o * p.J_of * f.B_dual();
  guarded(r, "feature.J_eta_xp", [&] {
    r.at_most("feature.J_eta_xp", relative_error(chain, numeric_jacobian(eta_of_dxp, Eigen::VectorXd::Zero(p.dim))),
              kJacobianTol, "J_ηo·J_of·B̃ (eq. 30) differs from differences of apply_perturbation" + at);
  });
}

// The gating covariance G of a new (dim 0) feature stands for the
// uncertainty of x_f that the creating observation leaves (the kernel adds
// J_of G J_ofᵀ to the gate, kernel/src/slam.cpp). Seen through the innovation
// of the same measurement, J_ηf G J_ηfᵀ (J_ηf = J_ηo J_of) must equal the
// first-order propagation J_ηf (J_fv C_v J_fvᵀ + J_fs C_ms J_fsᵀ) J_ηfᵀ, with
// J_fv, J_fs differences of x_f after create() + add_dense_information() in
// v and in x_ms. Directions η does not see (a wall's end points along the
// wall, a camera point's depth) are not compared.
void check_gating_covariance(const Probe& p, Recorder& r) {
  guarded(r, "feature.gating_covariance", [&] {
    auto& type = const_cast<FeatureType&>(p.type);  // create() is non-const; the object is the suite's own
    const Measurement& m = p.sample.measurement;
    Rng rng(p.seed ^ 0x9e3779b97f4a7c15ULL);
    SensorView view;
    view.t = 0.1;
    view.C_ms = random_spd(rng, 6, 1e-5, 1e-3);
    const std::string at = " (seed " + std::to_string(p.seed) + ")";
    auto created = [&](const Eigen::VectorXd& v, const Pose6& x_ms) -> std::unique_ptr<Feature> {
      Measurement mv = m;
      mv.v = v;
      view.x_ms = x_ms;
      std::unique_ptr<Feature> f = type.create(mv, view);
      if (f) f->add_dense_information(mv, view);
      return f;
    };
    const std::unique_ptr<Feature> f0 = created(m.v, p.sample.x_ms);
    if (!f0) {
      r.fail("feature.gating_covariance", "create() refused the sample's own measurement" + at);
      return;
    }
    const int n = p.type.layout().size();
    const Eigen::MatrixXd C_ms = view.C_ms;
    auto coords_of_v = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
      const std::unique_ptr<Feature> f = created(v, p.sample.x_ms);
      return f ? Eigen::VectorXd(f->coords()) : Eigen::VectorXd::Constant(n, kNaN);
    };
    auto coords_of_pose = [&](const Eigen::VectorXd& x) -> Eigen::VectorXd {
      const std::unique_ptr<Feature> f = created(m.v, Pose6(x));
      return f ? Eigen::VectorXd(f->coords()) : Eigen::VectorXd::Constant(n, kNaN);
    };
    const Eigen::MatrixXd J_fv = numeric_jacobian(coords_of_v, m.v);
    const Eigen::MatrixXd J_fs = numeric_jacobian(coords_of_pose, p.sample.x_ms);
    Eigen::MatrixXd J_of;
    const Eigen::VectorXd x_o = to_sensor_frame(f0->layout(), f0->coords(), p.sample.x_ms, &J_of);
    Innovation inn;
    if (!f0->innovation(x_o, m, inn)) {
      r.fail("feature.gating_covariance", "a feature created from the sample's measurement rejects it" + at);
      return;
    }
    const Eigen::MatrixXd J_eta_f = inn.J_eta_o * J_of;
    Eigen::MatrixXd G = f0->gating_covariance();
    if (G.size() == 0) G = Eigen::MatrixXd::Zero(n, n);
    if (G.rows() != n || G.cols() != n) {
      r.fail("feature.gating_covariance", "gating_covariance() is not n × n" + at);
      return;
    }
    const Eigen::MatrixXd expected =
        J_eta_f * (J_fv * m.C_v * J_fv.transpose() + J_fs * C_ms * J_fs.transpose()) * J_eta_f.transpose();
    r.at_most("feature.gating_covariance", covariance_mismatch(J_eta_f * G * J_eta_f.transpose(), expected),
              kCovarianceTol,
              "J_ηf G J_ηfᵀ of a new feature differs from J_ηf (J_fv C_v J_fvᵀ + J_fs C_ms J_fsᵀ) J_ηfᵀ "
              "(largest |λ − 1| shown)" + at);
  });
}

// Declared symmetries: η must not change along them, and they must lie outside the M-space.
void check_symmetries(const Probe& p, Recorder& r) {
  const Feature& f = *p.sample.feature;
  const Eigen::MatrixXd S = f.symmetry_directions();
  if (S.cols() == 0) {
    r.skip("feature.symmetry_invariance", "the type declares no symmetry directions");
    return;
  }
  if (S.rows() != f.coords().size()) {
    r.fail("feature.symmetry_invariance", "symmetry_directions() has the wrong number of rows");
    return;
  }
  const Eigen::Index msize = p.inn.eta.size();
  for (Eigen::Index j = 0; j < S.cols(); ++j) {
    const Eigen::VectorXd d = S.col(j).normalized();
    const auto eta_along = [&](const Eigen::VectorXd& t) {
      return eta_at(f, f.coords() + t[0] * d, p.sample.x_ms, p.sample.measurement, msize);
    };
    const Eigen::MatrixXd slope = numeric_jacobian(eta_along, Eigen::VectorXd::Zero(1));
    r.at_most("feature.symmetry_invariance", max_abs(slope), kSymmetryTol,
              "η changes along declared symmetry direction " + std::to_string(j));
    r.at_most("feature.symmetry_outside_mspace", max_abs(f.B() * d), kDualityTol,
              "symmetry direction " + std::to_string(j) + " has a component in the M-space (B·d ≠ 0)");
  }
}

/// Largest difference between two features' state, B, B̃ and innovation.
double feature_difference(const Feature& a, const Feature& b, const Probe& p) {
  double d = difference(a.coords(), b.coords());
  d = std::max(d, a.mspace_dim() == b.mspace_dim() ? 0.0 : std::numeric_limits<double>::infinity());
  d = std::max(d, difference(a.B(), b.B()));
  d = std::max(d, difference(a.B_dual(), b.B_dual()));
  const Eigen::Index msize = p.inn.eta.size();
  const Eigen::VectorXd ea = eta_at(a, a.coords(), p.sample.x_ms, p.sample.measurement, msize);
  const Eigen::VectorXd eb = eta_at(b, b.coords(), p.sample.x_ms, p.sample.measurement, msize);
  return std::max(d, ea.allFinite() && eb.allFinite() ? difference(ea, eb) : kNaN);
}

/// Largest difference between two saved states; +inf when their layout
/// (dimension, version, array names or sizes) differs.
double saved_difference(const SavedFeature& a, const SavedFeature& b) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  if (a.mspace_dim != b.mspace_dim || a.version != b.version || a.arrays.size() != b.arrays.size()) return kInf;
  double d = std::max(difference(a.coords, b.coords), difference(a.extra, b.extra));
  for (std::size_t i = 0; i < a.arrays.size(); ++i) {
    if (a.arrays[i].name != b.arrays[i].name) return kInf;
    d = std::max(d, difference(a.arrays[i].value, b.arrays[i].value));
  }
  return d;
}

/// Largest difference between two extensions (+inf when only one extended).
double extension_difference(const std::optional<Extension>& a, const std::optional<Extension>& b) {
  if (a.has_value() != b.has_value()) return std::numeric_limits<double>::infinity();
  if (!a) return 0.0;
  if (a->new_dims != b->new_dims || a->sensor != b->sensor) return std::numeric_limits<double>::infinity();
  return std::max(
      {difference(a->J_sensor, b->J_sensor), difference(a->J_own, b->J_own), difference(a->C_new, b->C_new)});
}

/// Phases 3 and 4 on one feature: add_dense_information then extend, with
/// an exception counted as an outcome (a restored copy must throw too).
struct FeedOutcome {
  bool threw = false;
  std::optional<Extension> extension;
};

FeedOutcome feed(Feature& f, const Measurement& m, const SensorView& view) {
  FeedOutcome out;
  try {
    f.add_dense_information(m, view);
    out.extension = f.extend(view);
  } catch (const std::exception&) {
    out.threw = true;
  }
  return out;
}

void check_round_trip(const Probe& p, Recorder& r) {
  guarded(r, "feature.save_restore", [&] {
    const SavedFeature saved = p.sample.feature->save();
    std::unique_ptr<Feature> copy = p.type.restore(saved);
    if (copy == nullptr) {
      r.fail("feature.save_restore", "restore() returned nullptr");
      return;
    }
    r.at_most("feature.save_restore", feature_difference(*p.sample.feature, *copy, p), kRoundTripTol,
              "restore(save()) differs from the original");
    r.at_most("feature.save_restore_state", saved_difference(saved, copy->save()), kRoundTripTol,
              "restore(save()).save() differs from save(): state is lost or changed on the way");
  });
}

// Dense information must survive save/restore: a copy restored after the
// first observation, fed the same observations as the original, must give
// the same innovations, gating covariances, coordinates and extensions.
void check_round_trip_future(const Probe& p, Recorder& r) {
  guarded(r, "feature.save_restore_future", [&] {
    std::optional<FeatureSample> s = p.type.sample(p.dim, p.seed);
    if (!s || !s->feature) {
      r.fail("feature.save_restore_future", "sample() returned nothing");
      return;
    }
    Feature& original = *s->feature;
    SensorView view;
    view.x_ms = s->x_ms;
    view.C_ms = Mat6::Identity() * 1e-6;
    auto view_at = [&](int k) {
      view.t = 0.1 * k;
      view.path_distance = 0.1 * k;
      return view;
    };
    feed(original, s->measurement, view_at(1));
    std::unique_ptr<Feature> copy = p.type.restore(original.save());
    if (copy == nullptr) {
      r.fail("feature.save_restore_future", "restore() returned nullptr");
      return;
    }
    constexpr double kInf = std::numeric_limits<double>::infinity();
    // The innovations of both for the sample's measurement (sizes may change with the dimension).
    auto innovation_difference = [&](const Feature& a, const Feature& b) {
      Innovation ia, ib;
      const bool oka = a.innovation(to_sensor_frame(a.layout(), a.coords(), s->x_ms), s->measurement, ia);
      const bool okb = b.innovation(to_sensor_frame(b.layout(), b.coords(), s->x_ms), s->measurement, ib);
      if (oka != okb) return kInf;
      if (!oka) return 0.0;
      return std::max(
          {difference(ia.eta, ib.eta), difference(ia.J_eta_o, ib.J_eta_o), difference(ia.J_eta_v, ib.J_eta_v)});
    };
    double worst = 0.0;
    int extensions = 0;
    for (int k = 2; k <= kMaxFeeds && extensions < 2; ++k) {
      const SensorView v = view_at(k);
      const FeedOutcome a = feed(original, s->measurement, v), b = feed(*copy, s->measurement, v);
      if (a.threw != b.threw) worst = kInf;
      worst = std::max(worst, extension_difference(a.extension, b.extension));
      worst = std::max(worst, difference(original.coords(), copy->coords()));
      worst = std::max(worst, original.mspace_dim() == copy->mspace_dim() ? 0.0 : kInf);
      worst = std::max(worst, difference(original.gating_covariance(), copy->gating_covariance()));
      worst = std::max(worst, difference(original.B_dual(), copy->B_dual()));
      worst = std::max(worst, innovation_difference(original, *copy));
      if (a.extension) ++extensions;
      if (a.threw) break;
    }
    r.at_most("feature.save_restore_future", worst, kRoundTripTol,
              "a copy restored after one observation, fed the same observations, behaves differently (dim " +
                  std::to_string(p.dim) + ", seed " + std::to_string(p.seed) + ")");
  });
}

// Feature::absorb: the kernel merges a feature mapped twice into its older
// copy. Absorbing an exact copy of itself adds no evidence about anything
// new, so it may change no innovation, no M-space coordinate and no
// dimension (the estimator is not told about absorb()).
void check_absorb_copy(const Probe& p, Recorder& r) {
  guarded(r, "feature.absorb_copy", [&] {
    const SavedFeature saved = p.sample.feature->save();
    std::unique_ptr<Feature> merged = p.type.restore(saved), copy = p.type.restore(saved);
    if (merged == nullptr || copy == nullptr) {
      r.fail("feature.absorb_copy", "restore() returned nullptr");
      return;
    }
    merged->absorb(*copy);
    const Feature& original = *p.sample.feature;
    if (merged->mspace_dim() != original.mspace_dim() || merged->coords().size() != original.coords().size()) {
      r.fail("feature.absorb_copy", "absorbing an identical copy changed the M-space dimension or the layout");
      return;
    }
    // Coordinates outside the M-space (e.g. a wall's free ends) may move.
    const Eigen::VectorXd moved_in_mspace = original.B() * (merged->coords() - original.coords());
    const Eigen::Index msize = p.inn.eta.size();
    const Eigen::VectorXd before = eta_at(original, original.coords(), p.sample.x_ms, p.sample.measurement, msize);
    const Eigen::VectorXd after = eta_at(*merged, merged->coords(), p.sample.x_ms, p.sample.measurement, msize);
    r.at_most("feature.absorb_copy", std::max(max_abs(moved_in_mspace), after.allFinite() ? difference(before, after) : kNaN),
              kSymmetryTol, "absorbing an identical copy moved the feature in its M-space or changed its innovation");
  });
}

void check_determinism(const Probe& p, Recorder& r) {
  guarded(r, "feature.sample_deterministic", [&] {
    std::optional<FeatureSample> again = p.type.sample(p.dim, p.seed);
    if (!again || !again->feature) {
      r.fail("feature.sample_deterministic", "a second sample() with the same seed returned nothing");
      return;
    }
    double d = std::max(difference(again->feature->coords(), p.sample.feature->coords()),
                        difference(again->x_ms, p.sample.x_ms));
    d = std::max(d, difference(again->measurement.v, p.sample.measurement.v));
    d = std::max(d, difference(again->measurement.C_v, p.sample.measurement.C_v));
    r.at_most("feature.sample_deterministic", d, 0.0, "sample() differs for the same seed");
  });
}

/// True when `call` throws a std::exception or returns false.
template <class F>
bool rejected(F&& call) {
  try {
    return !call();
  } catch (const std::exception&) {
    return true;
  }
}

// Wrong-sized inputs must be rejected (false or an exception), never used.
void check_wrong_sizes(const Probe& p, Recorder& r) {
  const Feature& f = *p.sample.feature;
  const Measurement& m = p.sample.measurement;
  int accepted = 0;
  std::string first;
  auto expect_rejected = [&](bool ok, const char* what) {
    if (!ok && accepted++ == 0) first = what;
  };
  Innovation inn;
  const Eigen::VectorXd long_xo = Eigen::VectorXd::Ones(p.x_o.size() + 1);
  expect_rejected(rejected([&] { return f.innovation(long_xo, m, inn); }), "innovation() accepted an x_o of the wrong size");
  Measurement long_m = m;
  long_m.v = Eigen::VectorXd::Ones(m.v.size() + 1);
  long_m.C_v = Eigen::MatrixXd::Identity(m.v.size() + 1, m.v.size() + 1);
  expect_rejected(rejected([&] { return f.innovation(p.x_o, long_m, inn); }), "innovation() accepted a v of the wrong size");
  Measurement other = m;
  other.kind = "mspace_check_unknown_kind";
  expect_rejected(rejected([&] { return f.innovation(p.x_o, other, inn); }), "innovation() accepted an unknown kind");
  expect_rejected(rejected([&] {
                    SavedFeature bad = f.save();
                    bad.coords = Eigen::VectorXd::Ones(bad.coords.size() + 1);
                    return p.type.restore(bad) != nullptr;
                  }),
                  "restore() accepted coordinates of the wrong size");
  expect_rejected(rejected([&] {
                    std::unique_ptr<Feature> copy = p.type.restore(f.save());
                    copy->add_dense_information(long_m, SensorView{});
                    return true;
                  }),
                  "add_dense_information() accepted a v of the wrong size without an exception");
  r.at_most("feature.wrong_size_rejected", accepted, 0, first);
}

// ---------------------------------------------------------------- extension

/// The outcome of feeding one sample's measurement repeatedly until the feature extends.
struct Fed {
  std::unique_ptr<Feature> feature;
  std::optional<Extension> extension;
  int feeds = 0;            ///< observations fed, the extending one included
  Measurement measurement;  ///< the sample's measurement (unperturbed)
  std::vector<Eigen::MatrixXd> C_v;  ///< of each fed measurement
  double extend_micros = 0; ///< time of the extend() call that extended
  Cost cost;                ///< of that call: which Jacobians were numeric
};

/// A perturbation of one component of the measurement of one feed.
struct FeedPerturbation {
  int feed = 0;  ///< 1-based; 0: none
  int component = 0;
  double h = 0.0;
};

/// Samples (dim, seed), perturbs its M-space by dx_old (eq. 24) and feeds
/// observations k = 1, 2, … (FeatureType::sample_observation, else the
/// sample's own measurement from its own pose) at increasing times, calling
/// extend() after each until it extends (phase 3 then phase 4 of the loop).
/// `dpose` moves the sensor pose of feed `anchor` by dpose and every other
/// view rigidly with it (x_k' = (x_a + dpose) ⊕ (⊖x_a ⊕ x_k)).
Fed feed_until_extension(const FeatureType& type, int dim, std::uint64_t seed, const Pose6& dpose,
                         const Eigen::VectorXd& dx_old, const FeedPerturbation& dv = {}, int anchor = 1) {
  FeatureSample s = *type.sample(dim, seed);
  Fed fed;
  fed.feature = std::move(s.feature);
  fed.measurement = s.measurement;
  if (dx_old.size() > 0) fed.feature->apply_perturbation(dx_old);
  auto observation = [&](int k) {
    std::optional<SampleObservation> o = type.sample_observation(dim, seed, k);
    if (!o) o = SampleObservation{s.x_ms, 0.0, s.measurement};
    return *o;
  };
  const bool moving = type.sample_observation(dim, seed, 1).has_value();
  const Pose6 x_anchor = moving ? observation(anchor).x_ms : s.x_ms;
  SensorView view;
  view.C_ms = Mat6::Identity() * 1e-6;
  for (int k = 1; k <= kMaxFeeds && !fed.extension; ++k) {
    fed.feeds = k;
    SampleObservation o = observation(k);
    view.t = 0.1 * k;
    view.path_distance = o.path_distance;
    view.x_ms = moving ? compound(x_anchor + dpose, relative(x_anchor, o.x_ms)) : Pose6(o.x_ms + dpose);
    if (dv.feed == k && dv.component < o.measurement.v.size()) o.measurement.v[dv.component] += dv.h;
    fed.C_v.push_back(o.measurement.C_v);
    fed.feature->add_dense_information(o.measurement, view);
    reset_numeric_usage();
    const Clock::time_point start = Clock::now();
    fed.extension = fed.feature->extend(view);
    fed.extend_micros = micros_since(start);
  }
  if (fed.extension) {
    fed.cost.function = "extend from dim " + std::to_string(dim);
    fed.cost.micros = fed.extend_micros;
    fed.cost.calls = 1;
    std::vector<NumericJacobian> parts{NumericJacobian::sensor};
    if (dim > 0) parts.push_back(NumericJacobian::own);
    split_numeric(parts, fed.cost);
    const NumericUsage v = numeric_usage(NumericJacobian::measurement);
    if (v.calls > 0) fed.cost.numeric.push_back("J_measurement");
    fed.cost.evaluations += static_cast<double>(v.evaluations);
  }
  reset_numeric_usage();
  return fed;
}

void check_extension_shape(const FeatureType& type, int dim, const Fed& fed, Recorder& r) {
  const Extension& e = *fed.extension;
  const Feature& f = *fed.feature;
  const int n = type.layout().size();
  const std::vector<int> dims = type.reachable_dims();
  int bad = 0;
  std::string why;
  auto expect = [&](bool ok, const std::string& what) {
    if (!ok && bad++ == 0) why = what;
  };
  expect(e.new_dims > 0, "new_dims ≤ 0");
  expect(f.mspace_dim() == dim + e.new_dims, "mspace_dim() is not old dim + new_dims");
  expect(std::find(dims.begin(), dims.end(), f.mspace_dim()) != dims.end(), "the new dimension is not in reachable_dims()");
  expect(e.sensor == 0, "Extension::sensor is not the view's sensor");
  expect(e.J_sensor.size() == 0 || (e.J_sensor.rows() == e.new_dims && e.J_sensor.cols() == 6), "J_sensor is not new × 6");
  expect(e.J_own.size() == 0 || (e.J_own.rows() == e.new_dims && e.J_own.cols() == dim), "J_own is not new × old dim");
  expect(e.C_new.rows() == e.new_dims && e.C_new.cols() == e.new_dims, "C_new is not new × new");
  expect(f.B().rows() == f.mspace_dim() && f.B().cols() == n, "B has the wrong size after extension");
  expect(f.coords().allFinite() && e.J_sensor.allFinite() && e.J_own.allFinite() && e.C_new.allFinite(),
         "non-finite values after extension");
  r.at_most("feature.extension_sizes", bad, 0, why + " (from dim " + std::to_string(dim) + ")");
  r.at_least("feature.extension_C_new_spd", spd_ratio(e.C_new), 1e-12,
             "C_new is not symmetric positive definite (λ_min/λ_max shown)");
  check_duality(f, r);
}

/// Whether a perturbed run extended at the same feed to the same dimension.
bool same_extension(const Fed& nominal, const Fed& run, int dim) {
  return run.extension && run.feeds == nominal.feeds && run.extension->new_dims == nominal.extension->new_dims &&
         run.feature->mspace_dim() == dim + nominal.extension->new_dims;
}

/// Numeric ∂(new M-space coordinates)/∂(input) where `perturbed(j, ±h)` feeds a
/// perturbed run: the new coordinates are the last rows of B applied to Δx_f.
Eigen::MatrixXd extension_jacobian(const Fed& nominal, int dim, int inputs,
                                   const std::function<Fed(int, double)>& perturbed) {
  const Extension& e = *nominal.extension;
  const Eigen::MatrixXd B_new = nominal.feature->B().bottomRows(e.new_dims);
  Eigen::MatrixXd J(e.new_dims, inputs);
  for (int j = 0; j < inputs; ++j) {
    const Fed plus = perturbed(j, kStep), minus = perturbed(j, -kStep);
    if (!same_extension(nominal, plus, dim) || !same_extension(nominal, minus, dim))
      return Eigen::MatrixXd::Constant(e.new_dims, inputs, kNaN);
    J.col(j) = B_new * (plus.feature->coords() - minus.feature->coords()) / (2.0 * kStep);
  }
  return J;
}

void check_extension_jacobians(const FeatureType& type, int dim, std::uint64_t seed, const Fed& nominal, Recorder& r) {
  const Extension& e = *nominal.extension;
  const std::string at = " (from dim " + std::to_string(dim) + ", seed " + std::to_string(seed) + ")";
  const Eigen::VectorXd no_dx = Eigen::VectorXd::Zero(dim);
  const Eigen::MatrixXd J_sensor = e.J_sensor.size() == 0 ? Eigen::MatrixXd::Zero(e.new_dims, 6) : e.J_sensor;
  const Eigen::MatrixXd numeric_sensor = extension_jacobian(nominal, dim, 6, [&](int j, double h) {
    Pose6 d = Pose6::Zero();
    d[j] = h;
    return feed_until_extension(type, dim, seed, d, no_dx, {}, nominal.feeds);
  });
  r.at_most("feature.extension_J_sensor", relative_error(J_sensor, numeric_sensor), kJacobianTol,
            "J_sensor differs from B_new·(x_f(x_ms + h e_j) − x_f(x_ms − h e_j))/2h, x_f after the extending "
            "feed, B_new the new rows of B" + at);
  if (dim == 0) return;
  const Eigen::MatrixXd J_own = e.J_own.size() == 0 ? Eigen::MatrixXd::Zero(e.new_dims, dim) : e.J_own;
  const Eigen::MatrixXd numeric_own = extension_jacobian(nominal, dim, dim, [&](int j, double h) {
    Eigen::VectorXd dx = no_dx;
    dx[j] = h;
    return feed_until_extension(type, dim, seed, Pose6::Zero(), dx);
  });
  r.at_most("feature.extension_J_own", relative_error(J_own, numeric_own), kJacobianTol,
            "J_own differs from B_new·(x_f(+h) − x_f(−h))/2h with δx_p,old = ±h e_j applied before the feeds" + at);
}

// C_new is the covariance of w in δx_p,new = J_sensor δx_ms + J_own δx_p,old + w:
// what the measurements' noise puts into the new coordinates. Every fed
// observation k moves them by J_v,k δv_k, so C_new ≈ Σ_k J_v,k C_v J_v,kᵀ.
void check_extension_C_new(const FeatureType& type, int dim, std::uint64_t seed, const Fed& nominal, Recorder& r) {
  const Extension& e = *nominal.extension;
  const std::string at = " (from dim " + std::to_string(dim) + ", seed " + std::to_string(seed) + ")";
  const auto m = static_cast<int>(nominal.measurement.v.size());  // every observation's v has this size
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(e.new_dims, e.new_dims);
  const Eigen::VectorXd no_dx = Eigen::VectorXd::Zero(dim);
  for (int k = 1; k <= nominal.feeds; ++k) {
    const Eigen::MatrixXd J_v = extension_jacobian(nominal, dim, m, [&](int j, double h) {
      return feed_until_extension(type, dim, seed, Pose6::Zero(), no_dx, FeedPerturbation{k, j, h});
    });
    if (!J_v.allFinite()) {
      r.fail("feature.extension_C_new", "a perturbed measurement changed when or how the feature extends" + at);
      return;
    }
    const Eigen::MatrixXd& C_v = nominal.C_v[static_cast<std::size_t>(k - 1)];
    if (C_v.rows() != m || C_v.cols() != m) {
      r.fail("feature.extension_C_new", "an observation's C_v does not fit its v" + at);
      return;
    }
    expected += J_v * C_v * J_v.transpose();
  }
  r.at_most("feature.extension_C_new", covariance_mismatch(e.C_new, expected), kCovarianceTol,
            "C_new differs from Σ_k J_v,k C_v J_v,kᵀ (J_v,k: differences of the new coordinates in the k-th "
            "observation's v; largest |λ − 1| shown)" + at);
}

/// Returns whether the sample extended.
bool check_extension(const FeatureType& type, int dim, std::uint64_t seed, Recorder& r) {
  bool extended = false;
  guarded(r, "feature.extension", [&] {
    Fed nominal = feed_until_extension(type, dim, seed, Pose6::Zero(), Eigen::VectorXd::Zero(dim));
    extended = nominal.extension.has_value();
    if (!nominal.extension) return;
    r.cost(nominal.cost);
    check_extension_shape(type, dim, nominal, r);
    check_extension_jacobians(type, dim, seed, nominal, r);
    check_extension_C_new(type, dim, seed, nominal, r);
  });
  return extended;
}

void check_reachable_dims(const FeatureType& type, Recorder& r) {
  const std::vector<int> dims = type.reachable_dims();
  const bool ok = !dims.empty() && dims.front() == 0 && dims.back() == type.max_mspace_dim() &&
                  std::is_sorted(dims.begin(), dims.end()) &&
                  std::adjacent_find(dims.begin(), dims.end()) == dims.end() &&
                  type.max_mspace_dim() <= type.layout().size() && !type.measurement_kinds().empty();
  r.at_most("feature.declaration", ok ? 0 : 1, 0,
            "reachable_dims() must ascend from 0 to max_mspace_dim() ≤ layout size, with measurement kinds");
}

void check_sample(const FeatureType& type, int dim, std::uint64_t seed, Recorder& r) {
  std::optional<FeatureSample> s = type.sample(dim, seed);
  if (!s || !s->feature) {
    r.fail("feature.sample", "sample(" + std::to_string(dim) + ") returned nothing for a reachable dimension");
    return;
  }
  Probe p{type, std::move(*s), dim, seed, {}, {}, {}, {}};
  check_structure(p, r);
  if (p.sample.feature->mspace_dim() != dim || p.sample.feature->coords().size() != type.layout().size()) return;
  check_duality(*p.sample.feature, r);
  if (!compute_innovation(p, r)) return;
  check_consistency(p, r);
  record_innovation_cost(p, r);
  check_jacobians(p, r);
  if (dim == 0) check_gating_covariance(p, r);
  check_symmetries(p, r);
  check_round_trip(p, r);
  check_round_trip_future(p, r);
  check_absorb_copy(p, r);
  check_determinism(p, r);
  check_wrong_sizes(p, r);
}

}  // namespace

void check_feature_type(PluginObject& object, const Options& options, Recorder& r) {
  const auto& type = static_cast<const FeatureType&>(object);
  check_reachable_dims(type, r);
  try {
    type.sample(0, options.seed);
  } catch (const std::logic_error& e) {
    r.fail("feature.sample", e.what());
    return;
  }
  const std::vector<int> dims = type.reachable_dims();
  // A dimension below the largest from which no sample extends would leave
  // every extension check vacuous for it: that is a failure, not a skip.
  int never = 0;
  std::string counts;
  for (int dim : dims) {
    int extended = 0;
    for (int s = 0; s < options.samples; ++s) {
      const std::uint64_t seed = options.seed * 7919 + static_cast<std::uint64_t>(dim) * 1000 + s;
      guarded(r, "feature.sample", [&] { check_sample(type, dim, seed, r); });
      if (dim != dims.back() && check_extension(type, dim, seed, r)) ++extended;
    }
    if (dim == dims.back()) continue;
    never += extended == 0 ? 1 : 0;
    counts += (counts.empty() ? "" : ", ") + std::string("from dim ") + std::to_string(dim) + ": " +
              std::to_string(extended) + "/" + std::to_string(options.samples);
  }
  if (dims.size() > 1)
    r.at_most("feature.extension_reached", never, 0,
              "samples that extended within " + std::to_string(kMaxFeeds) + " observations " + counts +
                  " (every dimension below the largest must extend for some sample)",
              /*always_show_note=*/true);
}

}  // namespace mspace::conformance::detail
