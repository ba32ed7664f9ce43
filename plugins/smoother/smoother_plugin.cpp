// smoother_plugin.cpp — the plugin descriptor of the `smoother` estimator.
#include <memory>

#include "mspace/plugin_export.hpp"
#include "smoother.hpp"

namespace {

using mspace::smoother::Loss;
using mspace::smoother::RunningFilter;
using mspace::smoother::Smoother;
using mspace::smoother::SmootherOptions;

std::unique_ptr<mspace::PluginObject> make_smoother(const mspace::PluginArgs& args) {
  SmootherOptions o;
  o.period = static_cast<int>(args.params.get_int("period"));
  o.growth = args.params.get_double("growth");
  o.loop_spacing = static_cast<int>(args.params.get_int("loop_spacing"));
  o.cost_tolerance = args.params.get_double("cost_tolerance");
  o.loop_gap = static_cast<int>(args.params.get_int("loop_gap"));
  o.loop_correction = args.params.get_double("loop_correction");
  o.max_iterations = static_cast<int>(args.params.get_int("max_iterations"));
  o.tolerance = args.params.get_double("tolerance");
  const std::string& loss = args.params.get_string("loss");
  o.loss = loss == "huber" ? Loss::Huber : loss == "cauchy" ? Loss::Cauchy : Loss::None;
  o.loss_scale = args.params.get_double("loss_scale");
  o.initial_capacity = static_cast<int>(args.params.get_int("initial_capacity"));
  o.running_filter = args.params.get_string("running_filter") == "ekf" ? RunningFilter::Ekf : RunningFilter::Cekf;
  o.max_active = static_cast<int>(args.params.get_int("max_active"));
  o.keep_steps = static_cast<int>(args.params.get_int("keep_steps"));
  o.observability_constrained = args.params.get_bool("observability_constrained");
  o.noise_estimation = args.params.get_string("noise_estimation") == "variance_components";
  o.noise_iterations = static_cast<int>(args.params.get_int("noise_iterations"));
  o.noise_tolerance = args.params.get_double("noise_tolerance");
  o.noise_probes = static_cast<int>(args.params.get_int("noise_probes"));
  return std::make_unique<Smoother>(o, args.logger);
}

mspace::PluginDescriptor describe() {
  mspace::PluginDescriptor d;
  d.name = "smoother";
  d.kind = mspace::PluginKind::Estimator;
  d.description =
      "Re-linearising smoother over the kernel's nonlinear problem (pose nodes, motion, observation "
      "and linear factors; features retracted by eq. 24): the M-space EKF between optimisations, "
      "robust Gauss-Newton over everything every `period` pose nodes and when a feature unseen "
      "for `loop_gap` pose nodes is re-observed; the EKF covariance is then re-set to the marginal "
      "of the optimised information matrix. The EKF runs as the compressed EKF (running_filter: cekf, "
      "as the cekf plugin) or the full one (ekf): the same numbers to round-off, different cost.";
  const SmootherOptions def;
  d.params = {
      mspace::param_int("period", def.period, "pose nodes between two optimisations (0: only on loop closures)", 0,
                        1'000'000),
      mspace::param_double("growth", def.growth,
                           "... and at least this fraction of all pose nodes (total cost about 1/growth "
                           "optimisations of the final problem)",
                           0.0, 100.0),
      mspace::param_int("loop_spacing", def.loop_spacing,
                        "pose nodes since the last optimisation before a loop closure may trigger one", 0, 1'000'000),
      mspace::param_int("loop_gap", def.loop_gap,
                        "a feature re-observed after this many pose nodes unseen may trigger an optimisation ...", 1,
                        1'000'000),
      mspace::param_double("loop_correction", def.loop_correction,
                           "... when that update moves the robot by at least this many standard deviations", 0.0),
      mspace::param_int("max_iterations", def.max_iterations, "Gauss-Newton iterations per optimisation", 1, 1000),
      mspace::param_double("tolerance", def.tolerance, "stop when the largest step component is below this", 0.0),
      mspace::param_double("cost_tolerance", def.cost_tolerance,
                           "... or when the cost falls by less than this fraction in an iteration", 0.0),
      mspace::param_string("loss", "huber", "robust loss on the observation factors", {"huber", "cauchy", "none"}),
      mspace::param_double("loss_scale", def.loss_scale,
                           "where the robust loss departs from least squares, in Mahalanobis units", 1e-6),
      mspace::param_int("initial_capacity", def.initial_capacity,
                        "EKF state rows to allocate room for at reset (running_filter: ekf)", 1, 1'000'000),
      mspace::param_string("running_filter", "cekf",
                           "the EKF between optimisations: cekf (compressed, cost O(active^2) per update) or ekf "
                           "(full, O(N^2)); the same numbers to round-off",
                           {"cekf", "ekf"}),
      mspace::param_int("max_active", def.max_active,
                        "running_filter cekf: active rows that trigger a global update (as the cekf plugin's)", 1,
                        1'000'000),
      mspace::param_int("keep_steps", def.keep_steps,
                        "running_filter cekf: rows touched within this many updates stay active (as the cekf "
                        "plugin's)",
                        0, 1'000'000),
      mspace::param_bool("observability_constrained", def.observability_constrained,
                         "the running filter in observability-constrained mode (Huang, Mourikis & Roumeliotis, "
                         "IJRR 2010; as the ekf plugin's): its updates between optimisations gain no information "
                         "along a global rigid motion of robot and map"),
      mspace::param_string("noise_estimation", "none",
                           "variance_components: estimate the motion and the observation factors' noise scales from "
                           "the residuals at each optimisation (iterated variance-component estimation) and use them "
                           "from then on; none: the configured noise as it is",
                           {"none", "variance_components"}),
      mspace::param_int("noise_iterations", def.noise_iterations,
                        "variance_components: estimate / re-optimise rounds per optimisation, at most", 1, 1000),
      mspace::param_double("noise_tolerance", def.noise_tolerance,
                           "variance_components: stop when every variance factor is within this of 1", 0.0, 1.0),
      mspace::param_int("noise_probes", def.noise_probes,
                        "variance_components: random vectors of the redundancy (trace) estimate", 1, 10'000),
  };
  d.factory = &make_smoother;
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
