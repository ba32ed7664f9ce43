// mspace_module.cpp — the Python module `mspace` (its compiled part,
// mspace._mspace; mspace/__init__.py is the package).
//
// A thin layer over the kernel: a Run is the Slam of `mspace run` built from
// the same RunRequest (run_request.hpp), so a configuration, its overrides and
// their errors are exactly the command line's. Poses and matrices come back
// as NumPy arrays (pybind11/eigen.h copies them). The module is linked against
// the SDK library, and plugins are checked by the registry as always; at
// import, the SDK library's ABI tag is compared with the one this module was
// compiled with, so an upgrade of one without the other fails at once with a
// message instead of corrupting memory.
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <boost/dll/runtime_symbol_info.hpp>
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include "config.hpp"
#include "mspace/abi.hpp"
#include "outputs.hpp"
#include "persistence.hpp"
#include "plugin_registry.hpp"
#include "run_request.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace py = pybind11;
namespace fs = std::filesystem;
using namespace mspace;
using namespace mspace::kernel;

namespace {

/// The plugin folder of an installed or built tree, found from this module's
/// own file: <prefix>/<python dir>/mspace/_mspace*.so, plugins in
/// <prefix>/<plugin dir> (MSPACE_PYTHON_TO_PREFIX and MSPACE_PLUGIN_RELDIR
/// are set by kernel/python/CMakeLists.txt for both trees).
fs::path module_plugin_dir() {
  const fs::path module = boost::dll::this_line_location().string();
  return (module.parent_path() / MSPACE_PYTHON_TO_PREFIX / MSPACE_PLUGIN_RELDIR).lexically_normal();
}

void setup_registry(PluginRegistry& registry, const std::vector<std::string>& plugin_dirs,
                    const std::vector<std::string>& plugin_files) {
  for (const auto& dir : plugin_dirs) registry.add_search_dir(dir);
  for (const auto& dir : PluginRegistry::default_search_dirs()) registry.add_search_dir(dir);
  registry.add_search_dir(module_plugin_dir());
  for (const auto& file : plugin_files) registry.add_plugin_file(file);
}

/// "KEY=VALUE" overrides from a dict {key: value} (values as YAML text:
/// str() of numbers and booleans in YAML spelling) or a list of strings.
std::vector<std::string> overrides_from(const py::object& set) {
  std::vector<std::string> out;
  if (set.is_none()) return out;
  if (py::isinstance<py::dict>(set)) {
    for (const auto& [key, value] : set.cast<py::dict>()) {
      std::string text;
      if (py::isinstance<py::bool_>(value))
        text = value.cast<bool>() ? "true" : "false";
      else if (py::isinstance<py::list>(value) || py::isinstance<py::tuple>(value)) {
        text = "[";
        bool first = true;
        for (const auto& item : value) {
          text += (first ? "" : ", ") + py::str(item).cast<std::string>();
          first = false;
        }
        text += "]";
      } else
        text = py::str(value).cast<std::string>();
      out.push_back(py::str(key).cast<std::string>() + "=" + text);
    }
    return out;
  }
  for (const auto& item : set) out.push_back(item.cast<std::string>());
  return out;
}

/// (t: (N,), poses: (N, 6)) — x y z θ φ ψ per row (m, rad).
py::tuple pose_arrays(const std::vector<StampedPose>& poses) {
  py::array_t<double> t(static_cast<py::ssize_t>(poses.size()));
  py::array_t<double> p({static_cast<py::ssize_t>(poses.size()), static_cast<py::ssize_t>(6)});
  auto tv = t.mutable_unchecked<1>();
  auto pv = p.mutable_unchecked<2>();
  for (std::size_t i = 0; i < poses.size(); ++i) {
    tv(static_cast<py::ssize_t>(i)) = poses[i].t;
    for (int k = 0; k < 6; ++k) pv(static_cast<py::ssize_t>(i), k) = poses[i].pose[k];
  }
  return py::make_tuple(t, p);
}

/// One map feature as Python sees it (from a run or from a map file).
struct PyFeature {
  std::int64_t id = 0;
  std::string type;    ///< the feature-type instance of the configuration
  std::string plugin;  ///< the plugin that implements it
  Eigen::VectorXd coords;
  int mspace_dim = 0;
  std::optional<Eigen::MatrixXd> covariance;  ///< of its M-space perturbations; None while tentative
  std::int64_t observations = 0;

  std::string repr() const {
    return "<mspace.Feature " + std::to_string(id) + " " + type + " (" + plugin + "), M-space dimension " +
           std::to_string(mspace_dim) + ">";
  }
};

py::dict errors_dict(const TrajectoryErrors& e) {
  py::dict d;
  d["matched"] = e.matched;
  d["ate_rmse"] = e.ate_rmse;
  d["ate_median"] = e.ate_median;
  d["ate_max"] = e.ate_max;
  d["final_translation"] = e.final_translation;
  d["final_heading"] = e.final_heading ? py::cast(*e.final_heading) : py::none();
  return d;
}

py::dict relations_dict(const RelationErrors& r) {
  py::dict d;
  d["total"] = r.total;
  d["matched"] = r.matched;
  d["translation_mean"] = r.translation.mean;
  d["translation_std"] = r.translation.std;
  d["rotation_deg_mean"] = r.rotation_deg.mean;
  d["rotation_deg_std"] = r.rotation_deg.std;
  return d;
}

py::dict summary_dict(const RunSummary& s) {
  py::dict d;
  d["run"] = s.run_name;
  d["config_file"] = s.config_file;
  d["steps"] = s.steps;
  d["data_seconds"] = s.data_seconds;
  d["wall_seconds"] = s.wall_seconds;
  d["source_load_seconds"] = s.source_load_seconds;
  d["state_dimension"] = s.state_dimension;
  py::dict features;
  for (const auto& [type, by_dim] : s.features_by_dim) {
    py::dict counts;
    for (const auto& [dim, count] : by_dim) counts[py::int_(dim)] = count;
    features[py::str(type)] = counts;
  }
  d["features_by_dim"] = features;
  d["errors"] = s.errors ? py::object(errors_dict(*s.errors)) : py::none();
  d["mean_nees"] = s.nees_dof > 0 ? py::cast(s.mean_nees) : py::none();
  d["nees_dof"] = s.nees_dof;
  d["relations"] = s.relations ? py::object(relations_dict(*s.relations)) : py::none();
  d["skipped_records"] = s.skipped_records;
  d["interrupted"] = s.interrupted.empty() ? py::none() : py::cast(s.interrupted);
  d["stopped_by_error"] = s.stopped_by_error.empty() ? py::none() : py::cast(s.stopped_by_error);
  return d;
}

/// A run: the configuration resolved like `mspace run`'s, stepped or run to
/// its end from Python.
class PyRun {
 public:
  PyRun(const std::string& config, const py::object& set, const std::string& out, const std::string& estimator,
        std::optional<long long> seed, long long max_steps, const std::string& map, const std::string& mode,
        const std::string& log_level, const std::vector<std::string>& plugin_dirs,
        const std::vector<std::string>& plugins) {
    setup_registry(registry_, plugin_dirs, plugins);
    RunRequest request;
    request.config_file = config;
    request.sets = overrides_from(set);
    request.output_dir = out;
    request.estimator = estimator;
    request.seed = seed;
    request.max_steps = max_steps;
    request.map = map;
    request.mode = mode;
    request.log_level = log_level;
    slam_ = std::make_unique<Slam>(resolve_run_request(request, registry_), registry_);
    started_ = std::chrono::steady_clock::now();
  }

  bool step() { return slam_->step(); }

  /// To the end of the data (or max_steps), with the progress bar and the
  /// outputs of `mspace run`. Ctrl-C stops it after the current step, writes
  /// the outputs of the steps done (the summary's stopped_by_error says
  /// KeyboardInterrupt) and raises KeyboardInterrupt.
  py::dict run(bool progress, bool write_outputs) {
    RunOptions options;
    options.progress = progress;
    options.write_outputs = write_outputs;
    options.write_checkpoints = write_outputs;
    // The run does not touch Python objects: other Python threads go on
    // while it runs, and every step looks for a pending signal (Ctrl-C).
    options.after_step = [](std::size_t) {
      py::gil_scoped_acquire python;
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    };
    RunResult result;
    {
      py::gil_scoped_release others_may_run;
      result = run_to_end(*slam_, options);
    }
    files_ = result.files;
    return summary_dict(result.summary);
  }

  py::dict summary() const {
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
    return summary_dict(summarize(*slam_, elapsed));
  }

  std::vector<PyFeature> features() const {
    std::vector<PyFeature> out;
    out.reserve(slam_->features().size());
    for (const MapFeature& f : slam_->features()) {
      const FeatureTypeSlot& type = slam_->feature_types()[static_cast<std::size_t>(f.type)];
      PyFeature p;
      p.id = f.id;
      p.type = type.instance;
      p.plugin = type.plugin;
      p.coords = f.feature->coords();
      p.mspace_dim = f.feature->mspace_dim();
      if (!f.state_idx.empty()) p.covariance = slam_->feature_covariance(f);
      p.observations = f.times_matched + 1;
      out.push_back(std::move(p));
    }
    return out;
  }

  void save_map(const fs::path& file) const { write_map_bin(file, *slam_); }

  const Slam& slam() const { return *slam_; }
  const std::vector<std::string>& files() const { return files_; }

 private:
  PluginRegistry registry_;  // before slam_: the plugins' libraries outlive their objects
  std::unique_ptr<Slam> slam_;
  std::chrono::steady_clock::time_point started_;
  std::vector<std::string> files_;
};

/// A saved map (map.bin, docs/maps.md) read without running anything.
struct PyMap {
  fs::path file;
  std::string run;
  std::string abi_tag;
  std::uint32_t format_version = 0;
  Pose6 robot_pose = Pose6::Zero();
  std::vector<PyFeature> features;
};

PyMap load_map(const fs::path& given) {
  PyMap map;
  map.file = find_map_file(given);
  const StoredMap stored = read_map_file(map.file, "map");
  map.run = stored.run;
  map.abi_tag = stored.abi_tag;
  map.format_version = stored.format_version;
  map.robot_pose = stored.robot_pose;
  for (const StoredFeature& f : stored.features) {
    const StoredType& type = stored.types.at(static_cast<std::size_t>(f.type));
    PyFeature p;
    p.id = f.id;
    p.type = type.instance;
    p.plugin = type.plugin;
    p.coords = f.saved.coords;
    p.mspace_dim = f.saved.mspace_dim;
    if (f.covariance.size() > 0) p.covariance = f.covariance;
    p.observations = f.times_matched + 1;
    map.features.push_back(std::move(p));
  }
  return map;
}

}  // namespace

PYBIND11_MODULE(_mspace, m) {
  m.doc() = "mspace: feature-based SLAM on the M-space feature representation (compiled part)";
  if (std::string(sdk_library_abi_tag()) != MSPACE_ABI_TAG)
    throw py::import_error(std::string("mspace: this Python module was built for SDK ABI '") + MSPACE_ABI_TAG +
                           "' but the SDK library loaded is '" + sdk_library_abi_tag() +
                           "': rebuild and reinstall the module with the same mspace build as the library");
  m.attr("ABI_TAG") = MSPACE_ABI_TAG;
  m.attr("PLUGIN_DIR") = module_plugin_dir().string();

  // Configuration and plugin errors become ValueError / RuntimeError with the
  // kernel's message (file:line:col: key: problem, or the plugin named).
  py::register_exception<ConfigError>(m, "ConfigError", PyExc_ValueError);
  py::register_exception<PersistenceError>(m, "MapFileError", PyExc_RuntimeError);

  py::class_<PyFeature>(m, "Feature", "One feature of a map")
      .def_readonly("id", &PyFeature::id)
      .def_readonly("type", &PyFeature::type, "the feature-type instance of the configuration")
      .def_readonly("plugin", &PyFeature::plugin, "the plugin implementing the type")
      .def_readonly("coords", &PyFeature::coords, "x_f, the feature's coordinates in the map frame")
      .def_readonly("mspace_dim", &PyFeature::mspace_dim, "its M-space dimension")
      .def_readonly("covariance", &PyFeature::covariance,
                    "covariance of its M-space perturbations (mspace_dim²), None while tentative")
      .def_readonly("observations", &PyFeature::observations)
      .def("__repr__", &PyFeature::repr);

  py::class_<PyMap>(m, "Map", "A saved map (map.bin) read with mspace.load_map")
      .def_readonly("file", &PyMap::file)
      .def_readonly("run", &PyMap::run)
      .def_readonly("abi_tag", &PyMap::abi_tag)
      .def_readonly("format_version", &PyMap::format_version)
      .def_readonly("robot_pose", &PyMap::robot_pose)
      .def_readonly("features", &PyMap::features)
      .def("__len__", [](const PyMap& map) { return map.features.size(); })
      .def("__repr__", [](const PyMap& map) {
        return "<mspace.Map " + map.file.string() + ": " + std::to_string(map.features.size()) + " features>";
      });

  m.def("load_map", &load_map, py::arg("path"),
        "Reads a saved map (a run's output folder or its map.bin) with every check of `mspace run --map`.");

  py::class_<PyRun>(m, "Run", R"(A SLAM run as `mspace run` makes it.

Run(config=None, *, set=None, out="", estimator="", seed=None, max_steps=0,
    map="", mode="", log_level="", plugin_dirs=[], plugins=[])

config: a YAML run configuration (None: the built-in simulated world);
set: {key: value} or ["key=value", ...], any configuration key (like --set);
the others as the command line's options of the same names.)")
      .def(py::init<const std::string&, const py::object&, const std::string&, const std::string&,
                    std::optional<long long>, long long, const std::string&, const std::string&, const std::string&,
                    const std::vector<std::string>&, const std::vector<std::string>&>(),
           py::arg("config") = "", py::kw_only(), py::arg("set") = py::none(), py::arg("out") = "",
           py::arg("estimator") = "", py::arg("seed") = py::none(), py::arg("max_steps") = 0, py::arg("map") = "",
           py::arg("mode") = "", py::arg("log_level") = "", py::arg("plugin_dirs") = std::vector<std::string>{},
           py::arg("plugins") = std::vector<std::string>{})
      .def("step", &PyRun::step, "One step of the data; False at its end (or at max_steps).")
      .def("run", &PyRun::run, py::arg("progress") = true, py::arg("write_outputs") = true,
           "Runs to the end (progress on stderr) and writes the outputs; returns the summary.")
      .def("summary", &PyRun::summary, "The summary of the steps done so far (as summary.yaml has it).")
      .def("features", &PyRun::features, "The map's features now.")
      .def("save_map", &PyRun::save_map, py::arg("file"), "Writes the map as a map.bin file (docs/maps.md).")
      .def("trajectory", [](const PyRun& r) { return pose_arrays(r.slam().trajectory()); },
           "(t, poses): time stamps (N,) and poses (N, 6) as estimated online")
      .def("evaluated_trajectory", [](const PyRun& r) { return pose_arrays(r.slam().evaluated_trajectory()); },
           "(t, poses): the trajectory that is scored (a re-linearising estimator's final one, in the reference's frame)")
      .def("ground_truth", [](const PyRun& r) { return pose_arrays(r.slam().ground_truth()); },
           "(t, poses) of the source's ground truth (empty when it has none)")
      .def_property_readonly("steps_done", [](const PyRun& r) { return r.slam().steps_done(); })
      .def_property_readonly("pose", [](const PyRun& r) -> Eigen::VectorXd { return r.slam().pose(); },
                             "x y z θ φ ψ (m, rad)")
      .def_property_readonly("robot_covariance", [](const PyRun& r) { return r.slam().robot_covariance(); },
                             "covariance of the robot's estimated pose coordinates")
      .def_property_readonly("name", [](const PyRun& r) { return r.slam().config().name; })
      .def_property_readonly("estimator", [](const PyRun& r) { return r.slam().config().estimator.plugin; })
      .def_property_readonly("output_dir", [](const PyRun& r) { return r.slam().config().output.dir; })
      .def_property_readonly("output_files", &PyRun::files, "the files the last run() wrote")
      .def_property_readonly("config_yaml", [](const PyRun& r) { return effective_config_yaml(r.slam().config()); },
                             "the fully resolved configuration (as `mspace config` prints it)");
}
