#include "mspace/params.hpp"

#include <sstream>
#include <stdexcept>

namespace mspace {

const char* param_type_name(ParamType type) {
  switch (type) {
    case ParamType::Bool: return "bool";
    case ParamType::Int: return "int";
    case ParamType::Double: return "double";
    case ParamType::String: return "string";
    case ParamType::DoubleList: return "list of doubles";
  }
  return "?";
}

std::string format_param(const ParamValue& value) {
  std::ostringstream os;
  os.precision(10);
  std::visit(
      [&os](const auto& v) {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, bool>) {
          os << (v ? "true" : "false");
        } else if constexpr (std::is_same_v<T, std::string>) {
          os << '"' << v << '"';
        } else if constexpr (std::is_same_v<T, std::vector<double>>) {
          os << '[';
          for (std::size_t i = 0; i < v.size(); ++i) os << (i ? ", " : "") << v[i];
          os << ']';
        } else {
          os << v;
        }
      },
      value);
  return os.str();
}

ParamSpec param_double(std::string name, double def, std::string description, double min, double max) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::Double;
  s.default_value = def;
  s.description = std::move(description);
  s.min = min;
  s.max = max;
  return s;
}

ParamSpec param_int(std::string name, std::int64_t def, std::string description, double min, double max) {
  ParamSpec s = param_double(std::move(name), 0.0, std::move(description), min, max);
  s.type = ParamType::Int;
  s.default_value = def;
  return s;
}

ParamSpec param_bool(std::string name, bool def, std::string description) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::Bool;
  s.default_value = def;
  s.description = std::move(description);
  return s;
}

ParamSpec param_string(std::string name, std::string def, std::string description,
                       std::vector<std::string> choices) {
  ParamSpec s;
  s.name = std::move(name);
  s.type = ParamType::String;
  s.default_value = std::move(def);
  s.description = std::move(description);
  s.choices = std::move(choices);
  return s;
}

ParamSpec param_list(std::string name, std::vector<double> def, std::string description, int list_size,
                     double min, double max) {
  ParamSpec s = param_double(std::move(name), 0.0, std::move(description), min, max);
  s.type = ParamType::DoubleList;
  s.default_value = std::move(def);
  s.list_size = list_size;
  return s;
}

ParamSpec required(ParamSpec spec) {
  spec.required = true;
  return spec;
}

const ParamValue& Params::at(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) throw std::invalid_argument("parameter '" + name + "' is not set");
  return it->second;
}

namespace {
template <class T>
const T& get_as(const ParamValue& v, const std::string& name, const char* type) {
  if (const T* p = std::get_if<T>(&v)) return *p;
  throw std::invalid_argument("parameter '" + name + "' is not a " + type + " (it is " + format_param(v) + ")");
}
}  // namespace

bool Params::get_bool(const std::string& name) const { return get_as<bool>(at(name), name, "bool"); }
std::int64_t Params::get_int(const std::string& name) const {
  return get_as<std::int64_t>(at(name), name, "int");
}
double Params::get_double(const std::string& name) const {
  const ParamValue& v = at(name);
  if (const auto* i = std::get_if<std::int64_t>(&v)) return static_cast<double>(*i);
  return get_as<double>(v, name, "double");
}
const std::string& Params::get_string(const std::string& name) const {
  return get_as<std::string>(at(name), name, "string");
}
const std::vector<double>& Params::get_list(const std::string& name) const {
  return get_as<std::vector<double>>(at(name), name, "list of doubles");
}

Params Params::defaults(const std::vector<ParamSpec>& specs) {
  Params p;
  for (const ParamSpec& s : specs)
    if (!s.required) p.set(s.name, s.default_value);
  return p;
}

}  // namespace mspace
