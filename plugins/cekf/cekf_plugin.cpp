// cekf_plugin.cpp — the plugin descriptor of the `cekf` estimator.
#include <memory>

#include "mspace/cekf_filter.hpp"
#include "mspace/plugin_export.hpp"

namespace {

using mspace::cekf::CekfFilter;

std::unique_ptr<mspace::PluginObject> make_cekf(const mspace::PluginArgs& args) {
  const auto max_active = static_cast<int>(args.params.get_int("max_active"));
  const auto keep_steps = static_cast<int>(args.params.get_int("keep_steps"));
  return std::make_unique<CekfFilter>(max_active, keep_steps, args.params.get_bool("observability_constrained"),
                                      args.params.get_bool("churn_fallback"));
}

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "cekf";
  d.kind = mspace::PluginKind::Estimator;
  d.description =
      "Compressed extended Kalman filter (Guivant & Nebot 2001) over the robot pose and the "
      "features' M-space perturbations (T-RO 2007 eqs. 23-32): the same estimates as ekf, but an "
      "update works on the robot and the recently touched rows only; the rest of the covariance "
      "is brought up to date by a global update when that active part outgrows max_active.";
  d.params = {
      mspace::param_int("max_active", CekfFilter::kDefaultMaxActive,
                        "active state rows (or basis rows) that trigger a global update, "
                        "O(N^2 * max_active)",
                        1, 1'000'000),
      mspace::param_int("keep_steps", CekfFilter::kDefaultKeepSteps,
                        "rows touched within this many updates stay active across a global "
                        "update (at most max_active/2 rows)",
                        0, 1'000'000),
      mspace::param_bool("observability_constrained", false,
                         "observability-constrained EKF (Huang, Mourikis & Roumeliotis, IJRR 2010), as "
                         "in ekf: carry the unobservable global motion of robot and map through every "
                         "step and project it out of each observation's Jacobian, so no update "
                         "informs it"),
      mspace::param_bool("churn_fallback", true,
                         "when a global update costs more than the full EKF's updates since the last one "
                         "(the active set churns, e.g. a fast robot), make every row active and update as "
                         "the EKF does, until compressing would pay again; results are the same either way"),
  };
  d.factory = &make_cekf;
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
