// ekf_plugin.cpp — the plugin descriptor of the `ekf` estimator.
#include <memory>

#include "mspace/ekf_filter.hpp"
#include "mspace/plugin_export.hpp"

namespace {

std::unique_ptr<mspace::PluginObject> make_ekf(const mspace::PluginArgs& args) {
  const auto capacity = static_cast<int>(args.params.get_int("initial_capacity"));
  return std::make_unique<mspace::ekf::EkfFilter>(capacity, args.params.get_bool("observability_constrained"));
}

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "ekf";
  d.kind = mspace::PluginKind::Estimator;
  d.description =
      "Extended Kalman filter over the robot pose and the features' M-space perturbations "
      "(T-RO 2007 eqs. 23-32): full covariance, all observations of a step applied as one "
      "update, O(N*k) prediction, O(N^2*m) update.";
  d.params = {
      mspace::param_int("initial_capacity", 64,
                        "state rows to allocate room for at reset; the storage doubles "
                        "when the state outgrows it",
                        1, 1'000'000),
      mspace::param_bool("observability_constrained", false,
                         "observability-constrained EKF (Huang, Mourikis & Roumeliotis, IJRR 2010): "
                         "carry the unobservable global motion of robot and map through every step "
                         "and project it out of each observation's Jacobian, so no update "
                         "informs it"),
  };
  d.factory = &make_ekf;
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
