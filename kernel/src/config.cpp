#include "config.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <numbers>
#include <set>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "logging.hpp"

namespace mspace::kernel {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kDegToRad = std::numbers::pi / 180.0;
constexpr double kRadToDeg = 180.0 / std::numbers::pi;
/// Pose entries 3..5 (θ, φ, ψ) are angles: degrees in YAML, radians inside.
constexpr int kFirstAngle = kTheta;

const std::vector<std::string> kTopKeys = {"run",         "source",       "motion", "estimator", "features", "sensors",
                                           "association", "initial_pose", "output", "evaluation", "map",
                                           "problem"};
const std::vector<std::string> kProblemKeys = {"freeze_in_sensor_frame"};
const std::vector<std::string> kEvaluationKeys = {"relations", "relations_max_dt", "ground_truth_sensor", "reference"};
const std::vector<std::string> kRunKeys = {"name",       "log_level", "max_steps", "checkpoint_every",
                                           "health_check_every", "plugin_path", "seed", "skip_steps"};
const std::vector<std::string> kMapKeys = {"load", "mode", "start", "working_set_rows", "extend_when_unmapped"};
const std::vector<std::string> kMapModes = {"mapping", "localize", "extend"};
const std::vector<std::string> kMapStarts = {"config", "map_end"};
const std::vector<std::string> kSensorKeys = {"channel", "mount", "extractor", "feeds", "max_range", "silent_readings"};
const std::vector<std::string> kAssociationKeys = {"gate_probability", "new_feature_probability", "tentative_max_age",
                                                   "join_distance", "method", "jcbb_max_nodes", "refuse_ambiguous",
                                                   "reentry_joint_test", "reentry_covariance_scale",
                                                   "spatial_index", "index_cell_size", "loop_closing", "loop_local_path",
                                                   "loop_min_gap_path", "loop_drift_per_metre",
                                                   "loop_drift_deg_per_metre", "loop_min_matches",
                                                   "loop_ambiguity_ratio", "loop_scans",
                                                   "loop_revisit_window", "loop_confirm_repeats",
                                                   "loop_wide_drift_per_metre", "relocalize_by_scans"};
const std::vector<std::string> kAssociationMethods = {"nearest_neighbour", "jcbb"};
const std::vector<std::string> kInitialPoseKeys = {"pose", "sigma"};
const std::vector<std::string> kOutputKeys = {"dir",     "trajectory",   "map",         "summary",
                                              "picture", "picture_size", "robot_frame", "grid",
                                              "map_covariance", "frames"};
const std::vector<std::string> kGridKeys = {"enabled", "resolution", "max_range"};

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const std::string& item : items) out += (out.empty() ? "" : ", ") + item;
  return out;
}

bool contains(const std::vector<std::string>& items, const std::string& item) {
  return std::find(items.begin(), items.end(), item) != items.end();
}

/// Shortest text that reads back as the same double (".inf" etc. in YAML spelling).
std::string format_number(double v) {
  if (std::isnan(v)) return ".nan";
  if (std::isinf(v)) return v > 0 ? ".inf" : "-.inf";
  char buf[64];
  const auto result = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, result.ptr);
}

/// Angles converted from radians back to degrees carry rounding noise in the
/// last bits (90° → 90.00000000000001); 12 significant digits hide it.
std::string format_degrees(double radians) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.12g", radians * kRadToDeg);
  return buf;
}

std::string format_range(double min, double max) {
  auto bound = [](double v) { return std::isinf(v) ? std::string(v > 0 ? "inf" : "-inf") : format_number(v); };
  std::string out = "[";  // built by appending: "[" + std::string&& trips GCC 12's -Wrestrict
  out += bound(min);
  out += ", ";
  out += bound(max);
  out += ']';
  return out;
}

/// How a node looks, for "expected X, got Y" messages.
std::string describe(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Scalar: return "'" + node.Scalar() + "'";
    case YAML::NodeType::Sequence: return "a list";
    case YAML::NodeType::Map: return "a map";
    default: return "nothing";
  }
}

/// yaml-cpp's conversion of a scalar, or nothing if it does not convert.
template <class T>
std::optional<T> convert(const YAML::Node& node) {
  if (!node.IsScalar()) return std::nullopt;
  try {
    return node.as<T>();
  } catch (const YAML::BadConversion&) {
    return std::nullopt;
  }
}

bool is_valid_name(const std::string& name) {
  return !name.empty() && std::all_of(name.begin(), name.end(),
                                      [](unsigned char c) { return std::isalnum(c) != 0 || c == '_' || c == '-'; });
}

/// One YAML value being read: the node, its dotted key for messages and
/// where it is. `note` is appended to problems (it names the plugin).
struct Item {
  YAML::Node node;
  std::string key;
  std::string name;  ///< last component of the key
  YAML::Mark mark;   ///< of the value, or of its key when the value is empty
  YAML::Mark key_mark;
  std::string note;
};

/// Reads one document into a RunConfig. Each method reads one kind of value
/// or one section and reports problems through fail().
class Reader {
 public:
  Reader(std::string file, PluginRegistry& registry, std::vector<std::string> overrides = {},
         bool map_from_command_line = false)
      : file_(std::move(file)),
        registry_(registry),
        overrides_(std::move(overrides)),
        map_from_command_line_(map_from_command_line) {}

  RunConfig read_document(const YAML::Node& root);

 private:
  [[noreturn]] void fail(const YAML::Mark& mark, const std::string& key, const std::string& problem) const;
  [[noreturn]] void fail(const Item& item, const std::string& problem) const {
    fail(item.mark, item.key, problem + item.note);
  }
  std::string where(const YAML::Mark& mark) const { return file_ + ":" + std::to_string(std::max(mark.line, 0) + 1); }

  // Maps and lists.
  std::vector<Item> entries(const Item& map, const std::vector<std::string>* allowed) const;
  std::vector<Item> elements(const Item& list) const;
  static const Item* find(const std::vector<Item>& fields, const std::string& name);
  const Item& need(const Item& map, const std::vector<Item>& fields, const std::string& name) const;

  // Scalars and lists of scalars. Every scalar may name environment
  // variables, ${VAR} or ${VAR:-default} (expand_env_vars): a number, an
  // integer or a bool is read from the expanded text.
  std::string text(const Item& item) const;
  /// The item's node, or a scalar node of its expanded text when it names a variable.
  YAML::Node scalar(const Item& item) const;
  /// 'expanded' (from '${VAR}') when the text was expanded, else 'text'.
  static std::string describe_scalar(const Item& item, const YAML::Node& value);
  double number(const Item& item, double min = -kInf, double max = kInf) const;
  std::int64_t integer(const Item& item, double min = -kInf, double max = kInf) const;
  bool boolean(const Item& item) const;
  double probability(const Item& item) const;
  /// The position of the item's text in `choices`; an error naming them otherwise.
  std::size_t choice(const Item& item, const std::vector<std::string>& choices) const;
  std::vector<double> numbers(const Item& item, int size, double min = -kInf, double max = kInf) const;
  std::vector<std::string> texts(const Item& item) const;
  Pose6 pose(const Item& item, double min = -kInf) const;
  std::string name(const Item& key_item) const;

  // Plugin instances.
  InstanceConfig instance(const Item& item, const std::string& instance_name, PluginKind kind) const;
  const PluginDescriptor& descriptor(const Item& plugin_item, const std::string& plugin, PluginKind kind) const;
  Params params(const Item& item, const std::vector<Item>& fields, const PluginDescriptor& d) const;
  ParamValue param_value(const Item& item, const ParamSpec& spec) const;

  // Sections.
  void read_run(const Item* item, RunConfig& config) const;
  std::vector<InstanceConfig> read_features(const Item& item) const;
  SensorConfig read_sensor(const Item& item, const std::vector<std::string>& feature_names) const;
  std::vector<std::string> read_feeds(const Item& item, const std::vector<std::string>& feature_names) const;
  AssociationConfig read_association(const Item* item) const;
  /// True for `initial_pose: search`.
  bool read_initial_pose(const Item* item, RunConfig& config) const;
  OutputConfig read_output(const Item* item, const std::string& run_name) const;
  MapConfig read_map(const Item* item) const;
  EvaluationConfig read_evaluation(const Item* item, const std::vector<SensorConfig>& sensors) const;

  /// The --set assignment that gave `key` (or a map above it), or nullptr.
  const std::string* override_of(const std::string& key) const;

  std::string file_;
  PluginRegistry& registry_;
  std::vector<std::string> overrides_;  ///< "dotted.key=value", as given on the command line
  bool map_from_command_line_ = false;  ///< --map / --mode follow: the map section is checked then
};

const std::string* Reader::override_of(const std::string& key) const {
  for (const std::string& o : overrides_) {
    const std::string k = o.substr(0, o.find('='));
    if (key == k || key.starts_with(k + ".") || key.starts_with(k + "[")) return &o;
  }
  return nullptr;
}

void Reader::fail(const YAML::Mark& mark, const std::string& key, const std::string& problem) const {
  std::ostringstream os;
  // A value from the command line is named by its --set, not by a place in the file.
  if (const std::string* o = key.empty() ? nullptr : override_of(key))
    os << "--set " << *o << ": ";
  else
    os << file_ << ':' << std::max(mark.line, 0) + 1 << ':' << std::max(mark.column, 0) + 1 << ": ";
  if (!key.empty()) os << key << ": ";
  os << problem;
  throw ConfigError(os.str());
}

std::vector<Item> Reader::entries(const Item& map, const std::vector<std::string>* allowed) const {
  if (!map.node.IsMap()) fail(map, "expected a map of 'key: value' entries, got " + describe(map.node));
  std::vector<Item> fields;
  std::set<std::string> seen;
  for (const auto& entry : map.node) {
    const YAML::Mark key_mark = entry.first.Mark();
    const std::string key_name = entry.first.IsScalar() ? entry.first.Scalar() : std::string();
    const std::string key = map.key.empty() ? key_name : map.key + "." + key_name;
    if (key_name.empty()) fail(key_mark, map.key, "keys must be plain names");
    if (!seen.insert(key_name).second) fail(key_mark, key, "duplicate key");
    if (allowed != nullptr && !contains(*allowed, key_name))
      fail(key_mark, key, "unknown key (allowed: " + join(*allowed) + ")");
    const YAML::Mark value_mark = entry.second.IsNull() ? key_mark : entry.second.Mark();
    fields.push_back(Item{entry.second, key, key_name, value_mark, key_mark, map.note});
  }
  return fields;
}

std::vector<Item> Reader::elements(const Item& list) const {
  if (!list.node.IsSequence()) fail(list, "expected a list [a, b, ...], got " + describe(list.node));
  std::vector<Item> items;
  for (std::size_t i = 0; i < list.node.size(); ++i) {
    const YAML::Node element = list.node[i];
    const YAML::Mark mark = element.IsNull() ? list.mark : element.Mark();
    items.push_back(Item{element, list.key + "[" + std::to_string(i) + "]", list.name, mark, mark, list.note});
  }
  return items;
}

const Item* Reader::find(const std::vector<Item>& fields, const std::string& name) {
  for (const Item& field : fields)
    if (field.name == name) return &field;
  return nullptr;
}

const Item& Reader::need(const Item& map, const std::vector<Item>& fields, const std::string& name) const {
  if (const Item* field = find(fields, name)) return *field;
  fail(map.key_mark, map.key.empty() ? name : map.key + "." + name, "missing required key");
}

std::string Reader::text(const Item& item) const {
  if (!item.node.IsScalar()) fail(item, "expected a string, got " + describe(item.node));
  try {
    return expand_env_vars(item.node.Scalar());
  } catch (const std::invalid_argument& e) {
    fail(item, e.what());
  }
}

YAML::Node Reader::scalar(const Item& item) const {
  if (!item.node.IsScalar() || item.node.Scalar().find("${") == std::string::npos) return item.node;
  try {
    return YAML::Node(expand_env_vars(item.node.Scalar()));
  } catch (const std::invalid_argument& e) {
    fail(item, e.what());
  }
}

std::string Reader::describe_scalar(const Item& item, const YAML::Node& value) {
  if (value.IsScalar() && item.node.IsScalar() && value.Scalar() != item.node.Scalar())
    return describe(value) + " (from " + describe(item.node) + ")";
  return describe(value);
}

double Reader::number(const Item& item, double min, double max) const {
  const YAML::Node value = scalar(item);
  const std::optional<double> v = convert<double>(value);
  if (!v) fail(item, "expected a number, got " + describe_scalar(item, value));
  if (!(*v >= min && *v <= max)) fail(item, format_number(*v) + " is out of range " + format_range(min, max));
  return *v;
}

std::int64_t Reader::integer(const Item& item, double min, double max) const {
  const YAML::Node value = scalar(item);
  const std::optional<std::int64_t> v = convert<std::int64_t>(value);
  if (!v) fail(item, "expected an integer, got " + describe_scalar(item, value));
  const auto as_double = static_cast<double>(*v);
  if (!(as_double >= min && as_double <= max))
    fail(item, std::to_string(*v) + " is out of range " + format_range(min, max));
  return *v;
}

bool Reader::boolean(const Item& item) const {
  const YAML::Node value = scalar(item);
  const std::optional<bool> v = convert<bool>(value);
  if (!v) fail(item, "expected true or false, got " + describe_scalar(item, value));
  return *v;
}

std::size_t Reader::choice(const Item& item, const std::vector<std::string>& choices) const {
  const std::string value = text(item);
  const auto it = std::find(choices.begin(), choices.end(), value);
  if (it == choices.end()) fail(item, "'" + value + "' is not one of: " + join(choices));
  return static_cast<std::size_t>(it - choices.begin());
}

double Reader::probability(const Item& item) const {
  const double p = number(item);
  if (!(p > 0.0 && p < 1.0)) fail(item, format_number(p) + " is out of range (0, 1)");
  return p;
}

std::vector<double> Reader::numbers(const Item& item, int size, double min, double max) const {
  const std::vector<Item> items = elements(item);
  if (size >= 0 && items.size() != static_cast<std::size_t>(size))
    fail(item, "expected a list of " + std::to_string(size) + " numbers, got " + std::to_string(items.size()));
  std::vector<double> values;
  for (const Item& element : items) values.push_back(number(element, min, max));
  return values;
}

std::vector<std::string> Reader::texts(const Item& item) const {
  std::vector<std::string> values;
  for (const Item& element : elements(item)) values.push_back(text(element));
  return values;
}

Pose6 Reader::pose(const Item& item, double min) const {
  const std::vector<double> v = numbers(item, 6, min);
  Pose6 p;
  for (int i = 0; i < 6; ++i) p[i] = i >= kFirstAngle ? v[i] * kDegToRad : v[i];
  return p;
}

std::string Reader::name(const Item& key_item) const {
  if (!is_valid_name(key_item.name))
    fail(key_item.key_mark, key_item.key, "names may only use letters, digits, '_' and '-'");
  return key_item.name;
}

const PluginDescriptor& Reader::descriptor(const Item& plugin_item, const std::string& plugin, PluginKind kind) const {
  std::shared_ptr<const LoadedPlugin> loaded;
  try {
    loaded = registry_.load(plugin);
  } catch (const PluginError& e) {
    fail(plugin_item, e.what());
  }
  // The registry keeps the library loaded, so the descriptor stays valid.
  if (loaded->descriptor->kind != kind)
    fail(plugin_item, kind_mismatch_message(plugin, loaded->descriptor->kind, kind));
  return *loaded->descriptor;
}

InstanceConfig Reader::instance(const Item& item, const std::string& instance_name, PluginKind kind) const {
  const std::vector<Item> fields = entries(item, nullptr);  // parameters are checked in params()
  const Item& plugin_item = need(item, fields, "plugin");
  InstanceConfig config;
  config.instance = instance_name;
  config.plugin = text(plugin_item);
  config.where = where(item.key_mark);
  config.params = params(item, fields, descriptor(plugin_item, config.plugin, kind));
  return config;
}

Params Reader::params(const Item& item, const std::vector<Item>& fields, const PluginDescriptor& d) const {
  const std::string note = " (plugin '" + d.name + "')";
  auto spec_of = [&d](const std::string& name) -> const ParamSpec* {
    for (const ParamSpec& spec : d.params)
      if (spec.name == name) return &spec;
    return nullptr;
  };
  Params values = Params::defaults(d.params);
  // A plugin's default may name environment variables too, e.g. a data path
  // "${MSPACE_DATA:-../shared/datasets}/…": expand them like YAML values.
  for (const ParamSpec& spec : d.params) {
    if (spec.type != ParamType::String || spec.required) continue;
    try {
      values.set(spec.name, expand_env_vars(std::get<std::string>(spec.default_value)));
    } catch (const std::invalid_argument& e) {
      fail(item.key_mark, item.key + "." + spec.name, std::string("default of plugin '") + d.name + "': " + e.what());
    }
  }
  for (Item field : fields) {
    if (field.name == "plugin") continue;
    const ParamSpec* spec = spec_of(field.name);
    if (spec == nullptr) {
      std::vector<std::string> names;
      for (const ParamSpec& s : d.params) names.push_back(s.name);
      fail(field.key_mark, field.key,
           "unknown parameter of plugin '" + d.name + "' (" +
               (names.empty() ? std::string("it has no parameters") : "its parameters: " + join(names)) + ")");
    }
    field.note = note;
    values.set(spec->name, param_value(field, *spec));
  }
  for (const ParamSpec& spec : d.params) {
    if (spec.required && !values.has(spec.name))
      fail(item.key_mark, item.key + "." + spec.name,
           "missing required parameter of plugin '" + d.name + "'" +
               (spec.description.empty() ? std::string() : " (" + spec.description + ")"));
  }
  return values;
}

ParamValue Reader::param_value(const Item& item, const ParamSpec& spec) const {
  switch (spec.type) {
    case ParamType::Bool: return boolean(item);
    case ParamType::Int: return integer(item, spec.min, spec.max);
    case ParamType::Double: return number(item, spec.min, spec.max);
    case ParamType::DoubleList: return numbers(item, spec.list_size, spec.min, spec.max);
    case ParamType::String: {
      std::string value = text(item);
      if (!spec.choices.empty() && !contains(spec.choices, value))
        fail(item, "'" + value + "' is not one of: " + join(spec.choices));
      return value;
    }
  }
  fail(item, "parameter has an unknown type");
}

void Reader::read_run(const Item* item, RunConfig& config) const {
  const std::string stem = std::filesystem::path(file_).stem().string();
  config.name = stem.empty() ? "run" : stem;
  if (item == nullptr) return;
  const std::vector<Item> fields = entries(*item, &kRunKeys);
  if (const Item* f = find(fields, "name")) {
    config.name = text(*f);
    if (config.name.empty() || config.name.find_first_of("/ \t") != std::string::npos)
      fail(*f, "a run name must be non-empty, without '/' or spaces");
  }
  if (const Item* f = find(fields, "log_level")) {
    config.log_level = text(*f);
    try {
      parse_log_level(config.log_level);
    } catch (const std::invalid_argument& e) {
      fail(*f, e.what());
    }
  }
  if (const Item* f = find(fields, "max_steps")) config.max_steps = integer(*f, 0);
  if (const Item* f = find(fields, "checkpoint_every")) config.checkpoint_every = integer(*f, 0);
  if (const Item* f = find(fields, "health_check_every")) config.health_check_every = integer(*f, 0);
  if (const Item* f = find(fields, "plugin_path")) config.plugin_path = texts(*f);
  if (const Item* f = find(fields, "seed")) config.seed = integer(*f);
  if (const Item* f = find(fields, "skip_steps")) config.skip_steps = integer(*f, 0);
}

MapConfig Reader::read_map(const Item* item) const {
  MapConfig map;
  if (item == nullptr) return map;
  const std::vector<Item> fields = entries(*item, &kMapKeys);
  if (const Item* f = find(fields, "load")) {
    map.load = text(*f);
    if (map.load.empty()) fail(*f, "the map folder is empty");
  }
  constexpr MapConfig::Mode kModes[] = {MapConfig::Mode::Mapping, MapConfig::Mode::Localize, MapConfig::Mode::Extend};
  if (const Item* f = find(fields, "mode")) map.mode = kModes[choice(*f, kMapModes)];
  if (const Item* f = find(fields, "start")) map.start_at_map_end = choice(*f, kMapStarts) == 1;
  if (const Item* f = find(fields, "working_set_rows"))
    map.working_set_rows = static_cast<int>(integer(*f, 1, 1 << 20));
  if (const Item* f = find(fields, "extend_when_unmapped")) {
    map.extend_when_unmapped = number(*f, 0.0);
    if (map.extend_when_unmapped > 0.0 && map.mode != MapConfig::Mode::Localize && !map_from_command_line_)
      fail(*f, "extend_when_unmapped switches a localize run to mapping; this run's map.mode is " +
                   std::string(map_mode_name(map.mode)));
  }
  std::string problem = map_config_problem(map);
  if (!problem.empty() && !map_from_command_line_) fail(*item, problem);
  return map;
}

std::vector<InstanceConfig> Reader::read_features(const Item& item) const {
  std::vector<InstanceConfig> features;
  for (const Item& field : entries(item, nullptr))
    features.push_back(instance(field, name(field), PluginKind::Feature));
  if (features.empty()) fail(item, "at least one feature instance is needed");
  return features;
}

std::vector<std::string> Reader::read_feeds(const Item& item, const std::vector<std::string>& feature_names) const {
  std::vector<std::string> feeds;
  for (const Item& element : elements(item)) {
    std::string feed = text(element);
    if (!contains(feature_names, feed))
      fail(element, "unknown feature instance '" + feed + "' (instances under features: " + join(feature_names) + ")");
    if (contains(feeds, feed)) fail(element, "'" + feed + "' is listed twice");
    feeds.push_back(std::move(feed));
  }
  if (feeds.empty()) fail(item, "a sensor must feed at least one feature instance");
  return feeds;
}

SensorConfig Reader::read_sensor(const Item& item, const std::vector<std::string>& feature_names) const {
  const std::vector<Item> fields = entries(item, &kSensorKeys);
  SensorConfig sensor;
  sensor.name = name(item);
  sensor.channel = sensor.name;
  if (const Item* f = find(fields, "channel")) {
    sensor.channel = text(*f);
    if (sensor.channel.empty()) fail(*f, "the channel name is empty");
  }
  sensor.mount = pose(need(item, fields, "mount"));
  sensor.extractor = instance(need(item, fields, "extractor"), sensor.name, PluginKind::Extractor);
  sensor.feeds = read_feeds(need(item, fields, "feeds"), feature_names);
  if (const Item* f = find(fields, "max_range")) sensor.max_range = number(*f, 0.0);
  if (const Item* f = find(fields, "silent_readings")) sensor.silent_readings = integer(*f, 0);
  return sensor;
}

AssociationConfig Reader::read_association(const Item* item) const {
  AssociationConfig association;
  if (item == nullptr) return association;
  const std::vector<Item> fields = entries(*item, &kAssociationKeys);
  if (const Item* f = find(fields, "gate_probability")) association.gate_probability = probability(*f);
  if (const Item* f = find(fields, "new_feature_probability")) association.new_feature_probability = probability(*f);
  if (const Item* f = find(fields, "tentative_max_age"))
    association.tentative_max_age = static_cast<int>(integer(*f, 1, std::numeric_limits<int>::max()));
  if (const Item* f = find(fields, "join_distance")) association.join_distance = number(*f, 0.0);
  if (const Item* f = find(fields, "method"))
    association.method = choice(*f, kAssociationMethods) == 1 ? AssociationConfig::Method::Jcbb
                                                              : AssociationConfig::Method::NearestNeighbour;
  if (const Item* f = find(fields, "jcbb_max_nodes")) association.jcbb_max_nodes = integer(*f, 1);
  if (const Item* f = find(fields, "refuse_ambiguous")) association.refuse_ambiguous = boolean(*f);
  if (const Item* f = find(fields, "reentry_joint_test")) association.reentry_joint_test = boolean(*f);
  if (const Item* f = find(fields, "reentry_covariance_scale"))
    association.reentry_covariance_scale = number(*f, 1.0, 100.0);
  if (const Item* f = find(fields, "spatial_index")) association.spatial_index = boolean(*f);
  if (const Item* f = find(fields, "index_cell_size")) association.index_cell_size = number(*f, 0.0);
  if (const Item* f = find(fields, "loop_closing")) association.loop_closing = boolean(*f);
  if (const Item* f = find(fields, "loop_local_path")) association.loop_local_path = number(*f, 0.1);
  if (const Item* f = find(fields, "loop_min_gap_path")) association.loop_min_gap_path = number(*f, 0.0);
  if (const Item* f = find(fields, "loop_drift_per_metre")) association.loop_drift_per_metre = number(*f, 0.0, 1.0);
  if (const Item* f = find(fields, "loop_drift_deg_per_metre"))
    association.loop_drift_deg_per_metre = number(*f, 0.0, 10.0);
  if (const Item* f = find(fields, "loop_min_matches")) association.loop_min_matches = static_cast<int>(integer(*f, 3, 1000));
  if (const Item* f = find(fields, "loop_ambiguity_ratio"))
    association.loop_ambiguity_ratio = number(*f, 0.1, 1.0);
  if (const Item* f = find(fields, "loop_scans")) association.loop_scans = boolean(*f);
  if (const Item* f = find(fields, "loop_revisit_window")) association.loop_revisit_window = boolean(*f);
  if (const Item* f = find(fields, "relocalize_by_scans")) association.relocalize_by_scans = boolean(*f);
  if (const Item* f = find(fields, "loop_confirm_repeats"))
    association.loop_confirm_repeats = static_cast<int>(integer(*f, 0, 100));
  if (const Item* f = find(fields, "loop_wide_drift_per_metre")) {
    association.loop_wide_drift_per_metre = number(*f, 0.0, 1.0);
    if (association.loop_wide_drift_per_metre > 0.0 && !association.loop_revisit_window)
      fail(*f, "needs loop_revisit_window: true (the wider window is reckoned from the travel since each old "
               "feature was last seen)");
  }
  if (const Item* f = find(fields, "reentry_joint_test");
      f != nullptr && association.reentry_joint_test && association.method != AssociationConfig::Method::Jcbb)
    fail(*f, "needs method: jcbb (the test is a joint compatibility search)");
  return association;
}

bool Reader::read_initial_pose(const Item* item, RunConfig& config) const {
  if (item == nullptr) return false;
  if (item->node.IsScalar()) {  // `initial_pose: search`: the kidnapped robot
    if (item->node.Scalar() != "search")
      fail(*item, "expected {pose: [...], sigma: [...]} or 'search' (find the robot in the loaded map), not '" +
                      item->node.Scalar() + "'");
    return true;
  }
  const std::vector<Item> fields = entries(*item, &kInitialPoseKeys);
  if (const Item* f = find(fields, "pose")) config.initial_pose = pose(*f);
  if (const Item* f = find(fields, "sigma")) config.initial_sigma = pose(*f, 0.0);
  return false;
}

OutputConfig Reader::read_output(const Item* item, const std::string& run_name) const {
  OutputConfig output;
  output.dir = "out/" + run_name;
  if (item == nullptr) return output;
  const std::vector<Item> fields = entries(*item, &kOutputKeys);
  if (const Item* f = find(fields, "dir")) output.dir = text(*f);
  if (const Item* f = find(fields, "trajectory")) output.trajectory = boolean(*f);
  if (const Item* f = find(fields, "map")) output.map = boolean(*f);
  if (const Item* f = find(fields, "summary")) output.summary = boolean(*f);
  if (const Item* f = find(fields, "picture")) output.picture = boolean(*f);
  if (const Item* f = find(fields, "picture_size")) output.picture_size = static_cast<int>(integer(*f, 64, 20000));
  if (const Item* f = find(fields, "frames")) output.frames = integer(*f, 0, 1e12);
  if (const Item* f = find(fields, "robot_frame")) output.robot_frame = text(*f);
  if (const Item* f = find(fields, "map_covariance")) output.map_joint_covariance = choice(*f, {"joint", "marginal"}) == 0;
  if (const Item* g = find(fields, "grid")) {
    const std::vector<Item> grid = entries(*g, &kGridKeys);
    if (const Item* f = find(grid, "enabled")) output.grid.enabled = boolean(*f);
    if (const Item* f = find(grid, "resolution")) output.grid.resolution = number(*f, 0.005, 10.0);
    if (const Item* f = find(grid, "max_range")) output.grid.max_range = number(*f, 0.1, 1000.0);
  }
  return output;
}

EvaluationConfig Reader::read_evaluation(const Item* item, const std::vector<SensorConfig>& sensors) const {
  EvaluationConfig evaluation;
  if (item == nullptr) return evaluation;
  const std::vector<Item> fields = entries(*item, &kEvaluationKeys);
  if (const Item* f = find(fields, "relations")) {
    evaluation.relations = text(*f);
    if (!std::filesystem::is_regular_file(evaluation.relations)) fail(*f, "no such file '" + evaluation.relations + "'");
  }
  if (const Item* f = find(fields, "relations_max_dt")) evaluation.relations_max_dt = number(*f, 0.0);
  if (const Item* f = find(fields, "ground_truth_sensor")) {
    evaluation.ground_truth_sensor = text(*f);
    std::vector<std::string> names;
    for (const SensorConfig& sensor : sensors) names.push_back(sensor.name);
    if (std::find(names.begin(), names.end(), evaluation.ground_truth_sensor) == names.end())
      fail(*f, "no sensor named '" + evaluation.ground_truth_sensor + "' (sensors: " + join(names) + ")");
  }
  if (const Item* f = find(fields, "reference")) evaluation.reference = text(*f);
  return evaluation;
}

RunConfig Reader::read_document(const YAML::Node& root) {
  const YAML::Mark start = root.Mark();
  if (!root.IsMap())
    fail(start, "",
         root.IsNull() ? "the configuration is empty"
                       : "the configuration must be a map of sections (" + join(kTopKeys) + ")");
  const Item top{root, "", "", start, start, ""};
  const std::vector<Item> sections = entries(top, &kTopKeys);
  RunConfig config;
  config.file = file_;
  read_run(find(sections, "run"), config);
  // The sections below look plugins up, so the run's plugin directories must be known first.
  for (const std::string& dir : config.plugin_path) registry_.add_search_dir(dir);
  config.source = instance(need(top, sections, "source"), "source", PluginKind::Source);
  config.motion = instance(need(top, sections, "motion"), "motion", PluginKind::MotionModel);
  config.estimator = instance(need(top, sections, "estimator"), "estimator", PluginKind::Estimator);
  config.features = read_features(need(top, sections, "features"));
  std::vector<std::string> feature_names;
  for (const InstanceConfig& feature : config.features) feature_names.push_back(feature.instance);
  const Item& sensors = need(top, sections, "sensors");
  for (const Item& field : entries(sensors, nullptr)) config.sensors.push_back(read_sensor(field, feature_names));
  if (config.sensors.empty()) fail(sensors, "at least one sensor is needed");
  config.association = read_association(find(sections, "association"));
  const Item* initial_pose = find(sections, "initial_pose");
  const bool search_pose = read_initial_pose(initial_pose, config);
  config.output = read_output(find(sections, "output"), config.name);
  config.evaluation = read_evaluation(find(sections, "evaluation"), config.sensors);
  config.map = read_map(find(sections, "map"));
  if (const Item* problem = find(sections, "problem")) {
    const std::vector<Item> fields = entries(*problem, &kProblemKeys);
    if (const Item* f = find(fields, "freeze_in_sensor_frame")) config.problem.freeze_in_sensor_frame = boolean(*f);
  }
  if (search_pose) {
    config.map.search_pose = true;
    // Without a map section the map may come from the command line (--map);
    // resolve_run_request checks then. A map section that says otherwise is wrong now.
    const std::string problem = map_config_problem(config.map);
    if (!problem.empty() && find(sections, "map") != nullptr && !map_from_command_line_) fail(*initial_pose, problem);
  }
  return config;
}

// ---- Writing the effective configuration -------------------------------

/// A plugin parameter as the effective configuration prints it: 15
/// significant digits, so that a default a plugin converts from radians
/// (30° → 29.999999999999996) prints as what it is; any value a user writes
/// has fewer digits and prints unchanged.
std::string format_param_number(double v) {
  if (!std::isfinite(v)) return format_number(v);
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.15g", v);
  return buf;
}

void emit_param(YAML::Emitter& out, const ParamValue& value) {
  std::visit(
      [&out](const auto& v) {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, bool>) {
          out << (v ? "true" : "false");
        } else if constexpr (std::is_same_v<T, std::int64_t>) {
          out << std::to_string(v);
        } else if constexpr (std::is_same_v<T, double>) {
          out << format_param_number(v);
        } else if constexpr (std::is_same_v<T, std::string>) {
          out << v;
        } else {
          out << YAML::Flow << YAML::BeginSeq;
          for (double x : v) out << format_param_number(x);
          out << YAML::EndSeq;
        }
      },
      value);
}

void emit_instance_body(YAML::Emitter& out, const InstanceConfig& instance) {
  out << YAML::BeginMap << YAML::Key << "plugin" << YAML::Value << instance.plugin;
  for (const auto& [name, value] : instance.params.values()) {
    out << YAML::Key << name << YAML::Value;
    emit_param(out, value);
  }
  out << YAML::EndMap;
}

void emit_pose(YAML::Emitter& out, const Pose6& pose) {
  out << YAML::Flow << YAML::BeginSeq;
  for (int i = 0; i < 6; ++i) out << (i >= kFirstAngle ? format_degrees(pose[i]) : format_number(pose[i]));
  out << YAML::EndSeq;
}

void emit_string_list(YAML::Emitter& out, const std::vector<std::string>& items) {
  out << YAML::Flow << YAML::BeginSeq;
  for (const std::string& item : items) out << item;
  out << YAML::EndSeq;
}

const char* yes_no(bool v) { return v ? "true" : "false"; }

void emit_run(YAML::Emitter& out, const RunConfig& c) {
  out << YAML::Key << "run" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << c.name;
  out << YAML::Key << "log_level" << YAML::Value << c.log_level;
  out << YAML::Key << "max_steps" << YAML::Value << std::to_string(c.max_steps);
  out << YAML::Key << "checkpoint_every" << YAML::Value << std::to_string(c.checkpoint_every);
  out << YAML::Key << "health_check_every" << YAML::Value << std::to_string(c.health_check_every);
  out << YAML::Key << "plugin_path" << YAML::Value;
  emit_string_list(out, c.plugin_path);
  if (c.seed) out << YAML::Key << "seed" << YAML::Value << std::to_string(*c.seed);
  if (c.skip_steps > 0) out << YAML::Key << "skip_steps" << YAML::Value << std::to_string(c.skip_steps);
  out << YAML::EndMap;
  if (!c.map.load.empty() || c.map.mode != MapConfig::Mode::Mapping) {
    out << YAML::Key << "map" << YAML::Value << YAML::BeginMap;
    if (!c.map.load.empty()) out << YAML::Key << "load" << YAML::Value << c.map.load;
    out << YAML::Key << "mode" << YAML::Value << map_mode_name(c.map.mode);
    out << YAML::Key << "start" << YAML::Value << (c.map.start_at_map_end ? "map_end" : "config");
    out << YAML::Key << "working_set_rows" << YAML::Value << c.map.working_set_rows;
    out << YAML::Key << "extend_when_unmapped" << YAML::Value << c.map.extend_when_unmapped;
    out << YAML::EndMap;
  }
  if (c.problem.freeze_in_sensor_frame) {
    out << YAML::Key << "problem" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "freeze_in_sensor_frame" << YAML::Value << "true";
    out << YAML::EndMap;
  }
}

void emit_sensors(YAML::Emitter& out, const std::vector<SensorConfig>& sensors) {
  out << YAML::Key << "sensors" << YAML::Value << YAML::BeginMap;
  for (const SensorConfig& s : sensors) {
    out << YAML::Key << s.name << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "channel" << YAML::Value << s.channel;
    out << YAML::Key << "mount" << YAML::Value;
    emit_pose(out, s.mount);
    out << YAML::Key << "extractor" << YAML::Value;
    emit_instance_body(out, s.extractor);
    out << YAML::Key << "feeds" << YAML::Value;
    emit_string_list(out, s.feeds);
    out << YAML::Key << "max_range" << YAML::Value << format_number(s.max_range);
    out << YAML::Key << "silent_readings" << YAML::Value << s.silent_readings;
    out << YAML::EndMap;
  }
  out << YAML::EndMap;
}

void emit_tail(YAML::Emitter& out, const RunConfig& c) {
  out << YAML::Key << "association" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "gate_probability" << YAML::Value << format_number(c.association.gate_probability);
  out << YAML::Key << "new_feature_probability" << YAML::Value << format_number(c.association.new_feature_probability);
  out << YAML::Key << "tentative_max_age" << YAML::Value << std::to_string(c.association.tentative_max_age);
  out << YAML::Key << "join_distance" << YAML::Value << format_number(c.association.join_distance);
  out << YAML::Key << "method" << YAML::Value << association_method_name(c.association.method);
  out << YAML::Key << "jcbb_max_nodes" << YAML::Value << std::to_string(c.association.jcbb_max_nodes);
  out << YAML::Key << "refuse_ambiguous" << YAML::Value << yes_no(c.association.refuse_ambiguous);
  out << YAML::Key << "reentry_joint_test" << YAML::Value << yes_no(c.association.reentry_joint_test);
  out << YAML::Key << "reentry_covariance_scale" << YAML::Value
      << format_number(c.association.reentry_covariance_scale);
  out << YAML::Key << "spatial_index" << YAML::Value << yes_no(c.association.spatial_index);
  out << YAML::Key << "index_cell_size" << YAML::Value << format_number(c.association.index_cell_size);
  out << YAML::Key << "loop_closing" << YAML::Value << yes_no(c.association.loop_closing);
  out << YAML::Key << "loop_local_path" << YAML::Value << format_number(c.association.loop_local_path);
  out << YAML::Key << "loop_min_gap_path" << YAML::Value << format_number(c.association.loop_min_gap_path);
  out << YAML::Key << "loop_drift_per_metre" << YAML::Value << format_number(c.association.loop_drift_per_metre);
  out << YAML::Key << "loop_drift_deg_per_metre" << YAML::Value
      << format_number(c.association.loop_drift_deg_per_metre);
  out << YAML::Key << "loop_min_matches" << YAML::Value << std::to_string(c.association.loop_min_matches);
  out << YAML::Key << "loop_ambiguity_ratio" << YAML::Value << format_number(c.association.loop_ambiguity_ratio);
  out << YAML::Key << "loop_scans" << YAML::Value << yes_no(c.association.loop_scans);
  out << YAML::Key << "loop_revisit_window" << YAML::Value << yes_no(c.association.loop_revisit_window);
  out << YAML::Key << "loop_confirm_repeats" << YAML::Value << std::to_string(c.association.loop_confirm_repeats);
  out << YAML::Key << "loop_wide_drift_per_metre" << YAML::Value
      << format_number(c.association.loop_wide_drift_per_metre);
  out << YAML::Key << "relocalize_by_scans" << YAML::Value << yes_no(c.association.relocalize_by_scans);
  out << YAML::EndMap;

  if (c.map.search_pose) {
    out << YAML::Key << "initial_pose" << YAML::Value << "search";
  } else {
    out << YAML::Key << "initial_pose" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "pose" << YAML::Value;
    emit_pose(out, c.initial_pose);
    out << YAML::Key << "sigma" << YAML::Value;
    emit_pose(out, c.initial_sigma);
    out << YAML::EndMap;
  }

  out << YAML::Key << "output" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "dir" << YAML::Value << c.output.dir;
  out << YAML::Key << "trajectory" << YAML::Value << yes_no(c.output.trajectory);
  out << YAML::Key << "map" << YAML::Value << yes_no(c.output.map);
  out << YAML::Key << "summary" << YAML::Value << yes_no(c.output.summary);
  out << YAML::Key << "picture" << YAML::Value << yes_no(c.output.picture);
  out << YAML::Key << "picture_size" << YAML::Value << std::to_string(c.output.picture_size);
  out << YAML::Key << "frames" << YAML::Value << std::to_string(c.output.frames);
  out << YAML::Key << "map_covariance" << YAML::Value << (c.output.map_joint_covariance ? "joint" : "marginal");
  if (!c.output.robot_frame.empty()) out << YAML::Key << "robot_frame" << YAML::Value << c.output.robot_frame;
  out << YAML::Key << "grid" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "enabled" << YAML::Value << yes_no(c.output.grid.enabled);
  out << YAML::Key << "resolution" << YAML::Value << format_number(c.output.grid.resolution);
  out << YAML::Key << "max_range" << YAML::Value << format_number(c.output.grid.max_range);
  out << YAML::EndMap;
  out << YAML::EndMap;

  if (!c.evaluation.relations.empty() || !c.evaluation.ground_truth_sensor.empty() || !c.evaluation.reference.empty()) {
    out << YAML::Key << "evaluation" << YAML::Value << YAML::BeginMap;
    if (!c.evaluation.relations.empty()) {
      out << YAML::Key << "relations" << YAML::Value << c.evaluation.relations;
      out << YAML::Key << "relations_max_dt" << YAML::Value << format_number(c.evaluation.relations_max_dt);
    }
    if (!c.evaluation.ground_truth_sensor.empty())
      out << YAML::Key << "ground_truth_sensor" << YAML::Value << c.evaluation.ground_truth_sensor;
    if (!c.evaluation.reference.empty()) out << YAML::Key << "reference" << YAML::Value << c.evaluation.reference;
    out << YAML::EndMap;
  }
}

}  // namespace

std::vector<std::string> accepted_keys() {
  std::vector<std::string> keys;
  auto add = [&](const std::string& prefix, const std::vector<std::string>& names) {
    for (const std::string& n : names) keys.push_back(prefix + n);
  };
  add("", kTopKeys);
  add("run.", kRunKeys);
  add("", {"source.plugin", "motion.plugin", "estimator.plugin", "features.<instance>.plugin"});
  add("sensors.<sensor>.", kSensorKeys);
  add("sensors.<sensor>.extractor.", {"plugin"});
  add("association.", kAssociationKeys);
  add("initial_pose.", kInitialPoseKeys);
  add("output.", kOutputKeys);
  add("output.grid.", kGridKeys);
  add("evaluation.", kEvaluationKeys);
  add("map.", kMapKeys);
  return keys;
}

const char* map_mode_name(MapConfig::Mode mode) {
  switch (mode) {
    case MapConfig::Mode::Localize:
      return "localize";
    case MapConfig::Mode::Extend:
      return "extend";
    case MapConfig::Mode::Mapping:
      break;
  }
  return "mapping";
}

std::string map_config_problem(const MapConfig& map) {
  if (map.mode != MapConfig::Mode::Mapping && map.load.empty())
    return std::string("mode '") + map_mode_name(map.mode) + "' needs the map to load (map.load / --map DIR)";
  if (map.mode == MapConfig::Mode::Mapping && !map.load.empty())
    return "a mapping run starts from an empty map; to map on from '" + map.load +
           "' give mode: extend (or --mode extend), to localize in it mode: localize";
  if (map.start_at_map_end && map.load.empty()) return "start: map_end needs a map to load";
  if (map.extend_when_unmapped > 0.0 && map.mode != MapConfig::Mode::Localize)
    return std::string("extend_when_unmapped switches a localize run to mapping; this run's map.mode is ") +
           map_mode_name(map.mode);
  if (map.search_pose && map.mode != MapConfig::Mode::Localize)
    return std::string("initial_pose: search finds the robot in a map it localizes in; this run's map.mode is ") +
           map_mode_name(map.mode) + " (give --map DIR, or map: {load: DIR, mode: localize})";
  if (map.search_pose && map.start_at_map_end)
    return "initial_pose: search and map.start: map_end contradict each other (the one searches the pose, the other "
           "takes the map's last)";
  return {};
}

const char* association_method_name(AssociationConfig::Method method) {
  return method == AssociationConfig::Method::Jcbb ? "jcbb" : "nearest_neighbour";
}

std::string expand_env_vars(const std::string& text) {
  std::string out;
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t start = text.find("${", pos);
    if (start == std::string::npos) break;
    const std::size_t end = text.find('}', start);
    if (end == std::string::npos) throw std::invalid_argument("unterminated '${' in '" + text + "'");
    out.append(text, pos, start - pos);
    const std::string body = text.substr(start + 2, end - start - 2);
    const std::size_t sep = body.find(":-");
    const std::string var = body.substr(0, sep);
    const char* value = std::getenv(var.c_str());
    const bool has_default = sep != std::string::npos;
    if (value != nullptr && (*value != '\0' || !has_default)) {
      out += value;
    } else if (has_default) {
      out += body.substr(sep + 2);
    } else {
      throw std::invalid_argument("environment variable '" + var + "' is not set (write ${" + var +
                                  ":-default} to give a default)");
    }
    pos = end + 1;
  }
  out.append(text, pos, std::string::npos);
  return out;
}

namespace {

/// Sets root's `dotted.key` to `value` (YAML text) for one --set assignment,
/// creating the maps on the way. The value is then read and checked with the
/// rest of the document.
void apply_override(YAML::Node& root, const std::string& assignment) {
  const std::size_t eq = assignment.find('=');
  const auto bad = [&](const std::string& why) { throw ConfigError("--set " + assignment + ": " + why); };
  if (eq == std::string::npos || eq == 0) bad("expected KEY=VALUE, e.g. features.points.min_observations=5");
  const std::string key = assignment.substr(0, eq);
  std::vector<std::string> parts;
  for (std::size_t start = 0;;) {
    const std::size_t dot = key.find('.', start);
    parts.push_back(key.substr(start, dot == std::string::npos ? std::string::npos : dot - start));
    if (dot == std::string::npos) break;
    start = dot + 1;
  }
  YAML::Node value;
  try {
    value = YAML::Load(assignment.substr(eq + 1));
  } catch (const YAML::ParserException& e) {
    bad("the value is not valid YAML: " + e.msg);
  }
  if (!root.IsMap() && !root.IsNull()) bad("the configuration is not a map of sections");
  // YAML::Node is a handle and its operator= writes through it: walk by
  // copy-constructing a fresh handle per level, never by reassigning one.
  std::vector<YAML::Node> path{root};
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    if (parts[i].empty()) bad("empty key component in '" + key + "'");
    YAML::Node parent = path.back();
    const YAML::Node child = parent[parts[i]];
    if (!child.IsDefined() || child.IsNull())
      parent[parts[i]] = YAML::Node(YAML::NodeType::Map);
    else if (!child.IsMap())
      bad("'" + parts[i] + "' is " + describe(child) + ", not a map of keys");
    path.push_back(parent[parts[i]]);
  }
  if (parts.back().empty()) bad("empty key component in '" + key + "'");
  path.back()[parts.back()] = value;
}

/// --estimator: the estimator section becomes `plugin` with its defaults
/// unless it already names that plugin (load_config).
void replace_estimator_section(YAML::Node& root, const std::string& plugin) {
  if (!root.IsMap()) return;  // the reader reports what is wrong with it
  const YAML::Node section = root["estimator"];
  if (section.IsMap() && section["plugin"].IsScalar() && section["plugin"].Scalar() == plugin) return;
  YAML::Node replacement(YAML::NodeType::Map);
  replacement["plugin"] = plugin;
  root["estimator"] = replacement;
}

}  // namespace

RunConfig parse_config(const std::string& text, const std::string& file_name_for_messages, PluginRegistry& registry,
                       const std::vector<std::string>& overrides, bool map_from_command_line,
                       const std::string& estimator_plugin) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    throw ConfigError(file_name_for_messages + ":" + std::to_string(e.mark.line + 1) + ":" +
                      std::to_string(e.mark.column + 1) + ": YAML syntax error: " + e.msg);
  }
  if (!estimator_plugin.empty()) replace_estimator_section(root, estimator_plugin);
  for (const std::string& o : overrides) apply_override(root, o);
  return Reader(file_name_for_messages, registry, overrides, map_from_command_line).read_document(root);
}

RunConfig load_config(const std::filesystem::path& file, PluginRegistry& registry,
                      const std::vector<std::string>& overrides, bool map_from_command_line,
                      const std::string& estimator_plugin) {
  std::error_code ec;
  const auto status = std::filesystem::status(file, ec);
  if (!std::filesystem::exists(status)) throw ConfigError(file.string() + ": no such file");
  if (std::filesystem::is_directory(status))
    throw ConfigError(file.string() + ": is a directory, not a configuration file (e.g. config/sim_points.yaml)");
  std::ifstream in(file);
  if (!in) throw ConfigError(file.string() + ": cannot read the configuration file (permissions?)");
  std::ostringstream text;
  text << in.rdbuf();
  return parse_config(text.str(), file.string(), registry, overrides, map_from_command_line, estimator_plugin);
}

namespace {

std::shared_ptr<const LoadedPlugin> load_estimator_plugin(const std::string& plugin, PluginRegistry& registry) {
  std::shared_ptr<const LoadedPlugin> loaded;
  try {
    loaded = registry.load(plugin);
  } catch (const PluginError& e) {
    throw ConfigError(std::string("--estimator ") + plugin + ": " + e.what());
  }
  if (loaded->descriptor->kind != PluginKind::Estimator)
    throw ConfigError(std::string("--estimator ") + plugin + ": " +
                      kind_mismatch_message(plugin, loaded->descriptor->kind, PluginKind::Estimator));
  return loaded;
}

}  // namespace

void check_estimator_plugin(const std::string& plugin, PluginRegistry& registry) {
  load_estimator_plugin(plugin, registry);
}

void override_estimator(RunConfig& config, const std::string& plugin, PluginRegistry& registry) {
  if (config.estimator.plugin == plugin) return;
  const std::shared_ptr<const LoadedPlugin> loaded = load_estimator_plugin(plugin, registry);
  config.estimator.plugin = plugin;
  config.estimator.params = Params::defaults(loaded->descriptor->params);
  config.estimator.where = "--estimator";
}

std::string effective_config_yaml(const RunConfig& c) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  emit_run(out, c);
  const std::pair<const char*, const InstanceConfig*> singletons[] = {
      {"source", &c.source}, {"motion", &c.motion}, {"estimator", &c.estimator}};
  for (const auto& [key, section] : singletons) {
    out << YAML::Key << key << YAML::Value;
    emit_instance_body(out, *section);
  }
  out << YAML::Key << "features" << YAML::Value << YAML::BeginMap;
  for (const InstanceConfig& feature : c.features) {
    out << YAML::Key << feature.instance << YAML::Value;
    emit_instance_body(out, feature);
  }
  out << YAML::EndMap;
  emit_sensors(out, c.sensors);
  emit_tail(out, c);
  out << YAML::EndMap;
  return "# Effective configuration of " + c.file.string() + " (defaults filled in; angles in degrees)\n" +
         out.c_str() + "\n";
}

}  // namespace mspace::kernel

namespace mspace::kernel {

void apply_run_seed(RunConfig& config) {
  if (!config.seed) return;
  auto reseed = [&](InstanceConfig& inst) {
    if (inst.params.has("seed")) inst.params.set("seed", *config.seed);
  };
  reseed(config.source);
  reseed(config.motion);
  reseed(config.estimator);
  for (InstanceConfig& f : config.features) reseed(f);
  for (SensorConfig& s : config.sensors) reseed(s.extractor);
}

}  // namespace mspace::kernel
