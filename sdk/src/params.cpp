#include "mspace/params.hpp"

#include <algorithm>
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

namespace {

double parse_number(const std::string& name, const std::string& text) {
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || text.find_first_not_of(" \t", used) != std::string::npos)
    throw std::invalid_argument("parameter '" + name + "': '" + text + "' is not a number");
  return value;
}

void check_range(const ParamSpec& spec, double value) {
  if (value < spec.min || value > spec.max)
    throw std::invalid_argument("parameter '" + spec.name + "': " + format_param(value) + " is out of range [" +
                                format_param(spec.min) + ", " + format_param(spec.max) + "]");
}

}  // namespace

ParamValue parse_param(const ParamSpec& spec, const std::string& text) {
  switch (spec.type) {
    case ParamType::Bool:
      if (text == "true") return true;
      if (text == "false") return false;
      throw std::invalid_argument("parameter '" + spec.name + "': '" + text + "' is not true or false");
    case ParamType::Int: {
      const double v = parse_number(spec.name, text);
      if (v != static_cast<double>(static_cast<std::int64_t>(v)))
        throw std::invalid_argument("parameter '" + spec.name + "': '" + text + "' is not an integer");
      check_range(spec, v);
      return static_cast<std::int64_t>(v);
    }
    case ParamType::Double: {
      const double v = parse_number(spec.name, text);
      check_range(spec, v);
      return v;
    }
    case ParamType::DoubleList: {
      std::string body = text;
      if (!body.empty() && body.front() == '[' && body.back() == ']') body = body.substr(1, body.size() - 2);
      std::vector<double> values;
      std::stringstream items(body);
      for (std::string item; std::getline(items, item, ',');) {
        values.push_back(parse_number(spec.name, item));
        check_range(spec, values.back());
      }
      if (spec.list_size >= 0 && static_cast<int>(values.size()) != spec.list_size)
        throw std::invalid_argument("parameter '" + spec.name + "': needs " + std::to_string(spec.list_size) +
                                    " numbers, got " + std::to_string(values.size()));
      return values;
    }
    case ParamType::String:
      if (!spec.choices.empty() && std::find(spec.choices.begin(), spec.choices.end(), text) == spec.choices.end())
        throw std::invalid_argument("parameter '" + spec.name + "': '" + text + "' is not an allowed value");
      return text;
  }
  throw std::invalid_argument("parameter '" + spec.name + "' has an unknown type");
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
