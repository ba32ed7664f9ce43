// mspace/params.hpp — declared plugin parameters and the values a run gives them.
//
// A plugin declares each parameter (name, type, default, range, description)
// in its descriptor. The kernel validates the YAML against these declarations
// — unknown keys, wrong types, out-of-range values and missing required
// parameters are errors naming file, line and key — and hands the plugin a
// complete Params with every declared parameter set.
#pragma once

#include <cstdint>
#include <limits>
#include <map>
#include <string>
#include <variant>
#include <vector>

namespace mspace {

enum class ParamType : std::uint8_t { Bool, Int, Double, String, DoubleList };

const char* param_type_name(ParamType type);

using ParamValue = std::variant<bool, std::int64_t, double, std::string, std::vector<double>>;

/// Reads a value of spec's type from text ("0.5", "3", "true", "abc",
/// "[1, 2, 3]" or "1,2,3") and checks its range, list size and choices;
/// throws std::invalid_argument naming the parameter otherwise.
struct ParamSpec;
ParamValue parse_param(const ParamSpec& spec, const std::string& text);

/// Human-readable rendering of a value ("0.5", "true", "[1, 2, 3]", "\"abc\"").
std::string format_param(const ParamValue& value);

struct ParamSpec {
  std::string name;
  ParamType type = ParamType::Double;
  ParamValue default_value = 0.0;
  /// Inclusive range for Int/Double (each element of a DoubleList).
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool required = false;  ///< no default: the YAML must set it
  std::string description;
  /// For DoubleList: required length, or -1 for any.
  int list_size = -1;
  /// For String: allowed values (empty = any string).
  std::vector<std::string> choices;
};

// Builders that keep descriptors readable:
//   param_double("range_sigma", 0.05, "range noise std (m)", 0.0)
ParamSpec param_double(std::string name, double def, std::string description,
                       double min = -std::numeric_limits<double>::infinity(),
                       double max = std::numeric_limits<double>::infinity());
ParamSpec param_int(std::string name, std::int64_t def, std::string description,
                    double min = -std::numeric_limits<double>::infinity(),
                    double max = std::numeric_limits<double>::infinity());
ParamSpec param_bool(std::string name, bool def, std::string description);
ParamSpec param_string(std::string name, std::string def, std::string description,
                       std::vector<std::string> choices = {});
ParamSpec param_list(std::string name, std::vector<double> def, std::string description,
                     int list_size = -1,
                     double min = -std::numeric_limits<double>::infinity(),
                     double max = std::numeric_limits<double>::infinity());
/// A parameter the configuration must provide (no default).
ParamSpec required(ParamSpec spec);

/// Validated parameter values of one plugin instance. Getters throw
/// std::invalid_argument naming the parameter when it is absent or of
/// another type.
class Params {
 public:
  Params() = default;
  void set(const std::string& name, ParamValue value) { values_[name] = std::move(value); }
  bool has(const std::string& name) const { return values_.count(name) != 0; }

  bool get_bool(const std::string& name) const;
  std::int64_t get_int(const std::string& name) const;
  double get_double(const std::string& name) const;  ///< also accepts an Int value
  const std::string& get_string(const std::string& name) const;
  const std::vector<double>& get_list(const std::string& name) const;

  const std::map<std::string, ParamValue>& values() const { return values_; }

  /// Params holding the defaults of `specs` (required ones left unset).
  static Params defaults(const std::vector<ParamSpec>& specs);

 private:
  const ParamValue& at(const std::string& name) const;
  std::map<std::string, ParamValue> values_;
};

}  // namespace mspace
