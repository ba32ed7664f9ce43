// conformance_pair.cpp — the extractor ↔ feature contract check behind
// `mspace check EXTRACTOR.so FEATURE.so` (see conformance.hpp, mspace/scene.hpp).
//
// For every sample scene of the extractor (a noise-free reading and the true
// shapes it shows):
//   1. the feature type builds the true feature of each shape
//      (FeatureType::from_true_shape);
//   2. the extractor extracts the reading;
//   3. every measurement of a kind the type accepts is compared with the true
//      features: its innovation η (eq. 16) against the nearest one, in units
//      of the measurement's own standard deviation, σ_i = √(J_ηv C_v J_ηvᵀ)_ii,
//      must be within kTruthTol (3σ) — on a noise-free reading what remains
//      is the extractor's discretisation, which its C_v must cover. A convention the
//      two plugins disagree on (an angle's sign, a frame, which end is which,
//      what a flag means) shows here and in nothing that checks one plugin;
//   4. every true shape must be explained by some measurement (so a reading
//      whose objects are all missed does not pass vacuously);
//   5. each measurement also starts a feature the way a run does: create →
//      add_dense_information → extend, the same view fed again until the
//      feature enters the estimator (or kMaxFeeds), then its innovation for
//      the same measurement must be ≈ 0 as well.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <string>

#include "conformance_internal.hpp"
#include "mspace/extractor.hpp"
#include "mspace/feature.hpp"
#include "mspace/transform.hpp"

namespace mspace::conformance {
namespace {

using detail::Recorder;

/// Largest |η_i| / σ_i allowed on a noise-free reading, σ from the
/// measurement's own covariance: the error must lie within three standard
/// deviations of what the extractor itself claims, the usual bound of a
/// consistent estimate. What remains on noise-free data is discretisation
/// (measured with --samples 60: laser_lines + wall up to 1.5σ, where a point
/// of the neighbouring wall at a corner stays inside the fit's 3σ inlier
/// band; the other in-tree pairs below 1e-11σ). A flipped convention gives
/// tens to hundreds of σ (the broken_bearing fixture: 156σ).
constexpr double kTruthTol = 3.0;
/// Feeds of the same measurement before a created feature counts as not
/// extending from one view.
constexpr int kMaxFeeds = 50;

constexpr double kInf = std::numeric_limits<double>::infinity();

/// max_i |η_i| / σ_i with σ_i² = (J_ηv C_v J_ηvᵀ)_ii, or +inf when
/// `feature` refuses the measurement or returns malformed sizes.
double normalized_innovation(const Feature& feature, const Pose6& x_ms, const Measurement& m) {
  const Eigen::VectorXd x_o = to_sensor_frame(feature.layout(), feature.coords(), x_ms);
  Innovation inn;
  if (!feature.innovation(x_o, m, inn)) return kInf;
  if (inn.eta.size() == 0 || inn.J_eta_v.rows() != inn.eta.size() || inn.J_eta_v.cols() != m.C_v.rows())
    return kInf;
  const Eigen::MatrixXd S = inn.J_eta_v * m.C_v * inn.J_eta_v.transpose();
  double worst = 0.0;
  for (Eigen::Index i = 0; i < inn.eta.size(); ++i) {
    const double sigma = std::sqrt(std::max(S(i, i), 1e-300));
    worst = std::max(worst, std::abs(inn.eta[i]) / sigma);
  }
  return std::isnan(worst) ? kInf : worst;
}

std::string describe(const Measurement& m) {
  std::ostringstream os;
  os << "'" << m.kind << "' v = (" << m.v.transpose().format(Eigen::IOFormat(4, Eigen::DontAlignCols, ", ")) << ")";
  if (m.flags != 0) os << " flags " << m.flags;
  return os.str();
}

std::string join(const std::vector<std::string>& names) {
  std::string out;
  for (const std::string& n : names) out += (out.empty() ? "" : ", ") + n;
  return out.empty() ? "none" : out;
}

/// The instance of `descriptor` with its defaults and those of Options::params
/// that it declares (the pair shares one --param list).
std::unique_ptr<PluginObject> make_instance(const PluginDescriptor& descriptor, const Options& options) {
  Options own = options;
  std::erase_if(own.params, [&](const auto& entry) {
    return std::none_of(descriptor.params.begin(), descriptor.params.end(),
                        [&](const ParamSpec& s) { return s.name == entry.first; });
  });
  PluginArgs args;
  args.instance_name = "mspace_check";
  args.params = detail::instance_params(descriptor, own);
  return descriptor.factory(args);
}

void check_scene(Extractor& extractor, FeatureType& type, const SampleScene& scene, std::uint64_t seed,
                 Recorder& r) {
  const std::string where = " (scene seed " + std::to_string(seed) + ")";
  std::vector<std::unique_ptr<Feature>> truth;
  std::vector<std::string> refused;
  for (const TrueShape& shape : scene.truth) {
    truth.push_back(type.from_true_shape(shape, scene.x_ms));
    if (!truth.back()) refused.emplace_back(shape_kind_name(shape.kind));
  }
  if (!refused.empty()) {
    r.skip("pair.truth_innovation", "the feature type builds no feature from the scene's true shapes (" +
                                        join(refused) + "): it has no FeatureType::from_true_shape for them");
    return;
  }

  std::vector<Measurement> measurements;
  extractor.extract(scene.reading, measurements);
  const std::vector<std::string> accepted = type.measurement_kinds();
  std::vector<std::string> produced;
  std::vector<const Measurement*> ours;
  for (const Measurement& m : measurements) {
    if (std::find(produced.begin(), produced.end(), m.kind) == produced.end()) produced.push_back(m.kind);
    if (std::find(accepted.begin(), accepted.end(), m.kind) != accepted.end()) ours.push_back(&m);
  }
  r.at_most("pair.kinds", ours.empty() ? 1 : 0, 0,
            "the extractor's sample reading gave no measurement of a kind the feature type accepts (produced: " +
                join(produced) + "; accepted: " + join(accepted) + ")" + where);

  // 3 and 4: every measurement against the nearest true feature.
  std::vector<bool> explained(truth.size(), false);
  for (const Measurement* m : ours) {
    double best = kInf;
    std::size_t nearest = 0;
    for (std::size_t k = 0; k < truth.size(); ++k) {
      const double z = normalized_innovation(*truth[k], scene.x_ms, *m);
      if (z < best) best = z, nearest = k;
    }
    if (best <= kTruthTol) explained[nearest] = true;
    std::ostringstream note;
    note << "measurement " << describe(*m) << ": ";
    if (std::isinf(best))
      note << "no true shape accepts it (innovation() refused it for every one)";
    else
      note << "|η_i|/σ_i = " << best << " against the nearest true " << shape_kind_name(scene.truth[nearest].kind)
           << " — the two plugins read v differently";
    r.at_most("pair.truth_innovation", best, kTruthTol, note.str() + where);
  }
  const auto missed = std::count(explained.begin(), explained.end(), false);
  std::ostringstream found;
  found << missed << " of " << truth.size() << " true shapes explained by no measurement within " << kTruthTol
        << " σ" << where;
  r.at_most("pair.truth_found", static_cast<double>(missed), 0, found.str());

  // 5: the run's path, create → dense information → extension → innovation.
  SensorView view;
  view.t = scene.reading.t;
  view.x_ms = scene.x_ms;
  view.C_ms = Mat6::Identity() * 1e-6;
  int extended = 0;
  for (const Measurement* m : ours) {
    std::unique_ptr<Feature> f = type.create(*m, view);
    if (!f) continue;
    f->add_dense_information(*m, view);
    for (int k = 1; k <= kMaxFeeds && f->mspace_dim() == 0; ++k) {
      f->extend(view);
      if (f->mspace_dim() == 0) f->add_dense_information(*m, view);
    }
    if (f->mspace_dim() == 0) continue;
    ++extended;
    r.at_most("pair.created_innovation", normalized_innovation(*f, scene.x_ms, *m), kTruthTol,
              "the feature created from measurement " + describe(*m) +
                  " and extended does not predict it: create()/extend() and innovation() read v differently" +
                  where);
  }
  if (extended == 0)
    r.skip("pair.created_innovation",
           "no feature created from the extractor's measurements entered the estimator from one sensor pose "
           "within " + std::to_string(kMaxFeeds) + " feeds (the type needs a moving sensor)");
}

}  // namespace

Report check_pair(const PluginDescriptor& extractor, const PluginDescriptor& feature, const Options& options) {
  Report report;
  report.plugin = extractor.name + " + " + feature.name;
  report.kind = "extractor + feature";
  Recorder r;
  if (extractor.kind != PluginKind::Extractor || feature.kind != PluginKind::Feature) {
    r.fail("pair.kinds", "a pair check takes an extractor and a feature type ('" + extractor.name + "' is a " +
                             plugin_kind_name(extractor.kind) + ", '" + feature.name + "' a " +
                             plugin_kind_name(feature.kind) + ")");
    report.checks = r.take();
    return report;
  }
  detail::guarded(r, "pair.completed", [&] {
    const std::unique_ptr<PluginObject> ex_object = make_instance(extractor, options);
    const std::unique_ptr<PluginObject> type_object = make_instance(feature, options);
    auto& ex = static_cast<Extractor&>(*ex_object);
    auto& type = static_cast<FeatureType&>(*type_object);
    for (int s = 0; s < options.samples; ++s) {
      const std::uint64_t seed = options.seed * 7919 + static_cast<std::uint64_t>(s);
      const std::optional<SampleScene> scene = ex.sample_scene(seed);
      if (!scene) {
        r.skip("pair.truth_innovation", "the extractor '" + extractor.name +
                                            "' provides no sample_scene(), so there is no true geometry to compare "
                                            "with");
        break;
      }
      detail::guarded(r, "pair.truth_innovation", [&] { check_scene(ex, type, *scene, seed, r); });
    }
  });
  report.checks = r.take();
  return report;
}

}  // namespace mspace::conformance
