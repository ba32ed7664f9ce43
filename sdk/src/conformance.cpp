// conformance.cpp — the suite's driver: descriptor sanity, construction with
// the defaults, dispatch by kind, and the text and JUnit reports.
#include "mspace/conformance.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <memory>
#include <ostream>
#include <set>
#include <sstream>
#include <variant>

#include "conformance_internal.hpp"
#include "mspace/abi.hpp"

namespace mspace::conformance {

int Report::failures() const {
  return static_cast<int>(std::count_if(checks.begin(), checks.end(), [](const CheckResult& c) { return !c.passed; }));
}

const CheckResult* Report::find(const std::string& name) const {
  for (const CheckResult& c : checks)
    if (c.name == name) return &c;
  return nullptr;
}

namespace detail {

// ---------------------------------------------------------------- Recorder

CheckResult* Recorder::find(const std::string& name) {
  for (CheckResult& c : checks_)
    if (c.name == name) return &c;
  return nullptr;
}

void Recorder::add(const std::string& name, double value, double tolerance, bool lower_is_better,
                   const std::string& note) {
  CheckResult* c = find(name);
  if (c == nullptr || c->skipped) {
    if (c == nullptr) c = &checks_.emplace_back();
    *c = CheckResult{};
    c->name = name;
    c->worst = value;
    c->tolerance = tolerance;
    c->lower_is_better = lower_is_better;
  } else if (!std::isnan(c->worst)) {
    const bool worse = std::isnan(value) || (lower_is_better ? value > c->worst : value < c->worst);
    if (worse) c->worst = value;
  }
  const bool ok = !std::isnan(value) && (lower_is_better ? value <= tolerance : value >= tolerance);
  if (!ok && c->passed) {
    c->passed = false;
    c->note = note;
  }
}

void Recorder::at_most(const std::string& name, double value, double tolerance, const std::string& note,
                       bool always_show_note) {
  add(name, value, tolerance, true, note);
  if (always_show_note) {
    CheckResult* c = find(name);
    c->note = note;
    c->show_note = true;
  }
}

void Recorder::at_least(const std::string& name, double value, double tolerance, const std::string& note) {
  add(name, value, tolerance, false, note);
}

void Recorder::fail(const std::string& name, const std::string& note) {
  add(name, std::numeric_limits<double>::quiet_NaN(), 0.0, true, note);
}

void Recorder::cost(const Cost& c) {
  auto merge = [](std::vector<std::string>& into, const std::vector<std::string>& names) {
    for (const std::string& n : names)
      if (std::find(into.begin(), into.end(), n) == into.end()) into.push_back(n);
  };
  auto it = std::find_if(costs_.begin(), costs_.end(), [&](const Cost& x) { return x.function == c.function; });
  if (it == costs_.end()) {
    costs_.push_back(c);
    return;
  }
  const double n0 = it->calls, n1 = c.calls, n = std::max(1.0, n0 + n1);
  it->micros = (it->micros * n0 + c.micros * n1) / n;
  it->evaluations = (it->evaluations * n0 + c.evaluations * n1) / n;
  if (std::isnan(it->micros_by_differences)) {
    it->micros_by_differences = c.micros_by_differences;
  } else if (!std::isnan(c.micros_by_differences)) {
    it->micros_by_differences = (it->micros_by_differences * n0 + c.micros_by_differences * n1) / n;
  }
  it->calls += c.calls;
  merge(it->numeric, c.numeric);
  merge(it->analytic, c.analytic);
  // A Jacobian numeric in one call and analytic in another is listed as numeric.
  std::erase_if(it->analytic, [&](const std::string& a) {
    return std::find(it->numeric.begin(), it->numeric.end(), a) != it->numeric.end();
  });
}

void Recorder::skip(const std::string& name, const std::string& note) {
  if (find(name) != nullptr) return;
  CheckResult& c = checks_.emplace_back();
  c.name = name;
  c.skipped = true;
  c.note = note;
}

// ---------------------------------------------------------------- numbers

double uniform(Rng& rng, double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); }

Eigen::MatrixXd random_spd(Rng& rng, int n, double lo, double hi) {
  Eigen::MatrixXd a(n, n);
  for (int i = 0; i < a.size(); ++i) a.data()[i] = uniform(rng, -1.0, 1.0);
  const Eigen::MatrixXd q = a.householderQr().householderQ();
  Eigen::VectorXd eig(n);
  for (int i = 0; i < n; ++i) eig[i] = uniform(rng, lo, hi);
  const Eigen::MatrixXd m = q * eig.asDiagonal() * q.transpose();
  return 0.5 * (m + m.transpose());
}

Eigen::MatrixXd numeric_jacobian(const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& f,
                                 const Eigen::VectorXd& x, double h) {
  Eigen::MatrixXd J;
  for (Eigen::Index j = 0; j < x.size(); ++j) {
    Eigen::VectorXd xp = x, xm = x;
    xp[j] += h;
    xm[j] -= h;
    const Eigen::VectorXd d = (f(xp) - f(xm)) / (2.0 * h);
    if (j == 0) J.resize(d.size(), x.size());
    J.col(j) = d;
  }
  return J;
}

double relative_error(const Eigen::MatrixXd& analytic, const Eigen::MatrixXd& numeric) {
  if (analytic.rows() != numeric.rows() || analytic.cols() != numeric.cols())
    return std::numeric_limits<double>::infinity();
  if (analytic.size() == 0) return 0.0;
  if (!analytic.allFinite() || !numeric.allFinite()) return std::numeric_limits<double>::quiet_NaN();
  double worst = 0.0;
  for (Eigen::Index i = 0; i < analytic.rows(); ++i) {
    const double size = std::max({analytic.row(i).cwiseAbs().maxCoeff(), numeric.row(i).cwiseAbs().maxCoeff(), kRowFloor});
    worst = std::max(worst, (analytic.row(i) - numeric.row(i)).cwiseAbs().maxCoeff() / size);
  }
  return worst;
}

double covariance_mismatch(const Eigen::MatrixXd& C, const Eigen::MatrixXd& E) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  if (C.rows() != E.rows() || C.cols() != E.cols() || C.rows() != C.cols()) return kInf;
  if (C.size() == 0) return 0.0;
  if (!C.allFinite() || !E.allFinite()) return kInf;
  const Eigen::MatrixXd Es = 0.5 * (E + E.transpose()), Cs = 0.5 * (C + C.transpose());
  const Eigen::VectorXd eig_E = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(Es, Eigen::EigenvaluesOnly).eigenvalues();
  const double e_max = eig_E.cwiseAbs().maxCoeff();
  if (e_max > 0 && eig_E.minCoeff() > 1e-12 * e_max) {
    const Eigen::LLT<Eigen::MatrixXd> llt(Es);
    const Eigen::MatrixXd L_inv = llt.matrixL().solve(Eigen::MatrixXd::Identity(E.rows(), E.cols()));
    const Eigen::MatrixXd M = L_inv * Cs * L_inv.transpose();
    const Eigen::VectorXd lambda =
        Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(0.5 * (M + M.transpose()), Eigen::EigenvaluesOnly).eigenvalues();
    if (lambda.minCoeff() <= 0) return kInf;
    return std::max({lambda.maxCoeff() - 1.0, 1.0 / lambda.minCoeff() - 1.0, 1.0 - lambda.minCoeff(),
                     1.0 - 1.0 / lambda.maxCoeff()});
  }
  return (Cs - Es).cwiseAbs().maxCoeff() / std::max(e_max, 1e-300);
}

double spd_ratio(const Eigen::MatrixXd& m) {
  constexpr double kBad = -std::numeric_limits<double>::infinity();
  if (m.rows() != m.cols() || m.size() == 0 || !m.allFinite()) return kBad;
  const double scale = std::max(1e-300, m.cwiseAbs().maxCoeff());
  if ((m - m.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) return kBad;
  const Eigen::VectorXd eig = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(m, Eigen::EigenvaluesOnly).eigenvalues();
  return eig.minCoeff() / std::max(1e-300, eig.maxCoeff());
}

}  // namespace detail

namespace {

using detail::Recorder;

bool valid_name(const std::string& name) {
  return !name.empty() && std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
  });
}

bool holds_declared_type(const ParamSpec& s) {
  switch (s.type) {
    case ParamType::Bool: return std::holds_alternative<bool>(s.default_value);
    case ParamType::Int: return std::holds_alternative<std::int64_t>(s.default_value);
    case ParamType::Double: return std::holds_alternative<double>(s.default_value);
    case ParamType::String: return std::holds_alternative<std::string>(s.default_value);
    case ParamType::DoubleList: return std::holds_alternative<std::vector<double>>(s.default_value);
  }
  return false;
}

bool in_range(const ParamSpec& s, double v) { return std::isfinite(v) && v >= s.min && v <= s.max; }

/// Empty when the default of `s` is consistent with its declaration, else why not.
std::string param_problem(const ParamSpec& s) {
  if (s.required) return {};
  if (!holds_declared_type(s)) return "default is not a " + std::string(param_type_name(s.type));
  if (const auto* i = std::get_if<std::int64_t>(&s.default_value); i && !in_range(s, static_cast<double>(*i)))
    return "default outside its range";
  if (const auto* d = std::get_if<double>(&s.default_value); d && !in_range(s, *d)) return "default outside its range";
  if (const auto* l = std::get_if<std::vector<double>>(&s.default_value)) {
    if (s.list_size >= 0 && static_cast<int>(l->size()) != s.list_size) return "default list has the wrong length";
    for (double v : *l)
      if (!in_range(s, v)) return "default list element outside the range";
  }
  if (const auto* str = std::get_if<std::string>(&s.default_value);
      str && !s.choices.empty() && std::find(s.choices.begin(), s.choices.end(), *str) == s.choices.end())
    return "default is not one of the choices";
  return {};
}

void check_descriptor(const PluginDescriptor& d, Recorder& r) {
  r.at_most("descriptor.name", valid_name(d.name) ? 0 : 1, 0, "name must be non-empty [a-z0-9_]");
  r.at_most("descriptor.abi_tag", d.abi_tag == sdk_abi_tag() ? 0 : 1, 0,
            "ABI tag '" + d.abi_tag + "' differs from the checker's '" + sdk_abi_tag() + "'");
  r.at_most("descriptor.description", d.description.empty() ? 1 : 0, 0, "empty description");
  r.at_most("descriptor.factory", d.factory == nullptr ? 1 : 0, 0, "no factory");
  int problems = 0;
  std::string first;
  std::set<std::string> names;
  for (const ParamSpec& s : d.params) {
    std::string why = param_problem(s);
    if (!valid_name(s.name)) why = "invalid parameter name";
    if (!names.insert(s.name).second) why = "declared twice";
    if (s.description.empty() && why.empty()) why = "no description";
    if (!why.empty()) {
      if (problems++ == 0) first = "parameter '" + s.name + "': " + why;
    }
  }
  r.at_most("descriptor.params", problems, 0, first);
}

}  // namespace

namespace detail {

Params instance_params(const PluginDescriptor& descriptor, const Options& options) {
  Params params = Params::defaults(descriptor.params);
  for (const auto& [name, text] : options.params) {
    const auto spec = std::find_if(descriptor.params.begin(), descriptor.params.end(),
                                   [&name = name](const ParamSpec& s) { return s.name == name; });
    if (spec == descriptor.params.end())
      throw std::invalid_argument("plugin '" + descriptor.name + "' has no parameter '" + name + "'");
    params.set(name, parse_param(*spec, text));
  }
  for (const ParamSpec& spec : descriptor.params)
    if (spec.required && !params.has(spec.name))
      throw std::invalid_argument("parameter '" + spec.name + "' has no default: give it with --param " + spec.name +
                                  "=VALUE");
  return params;
}

}  // namespace detail

Report check_plugin(const PluginDescriptor& descriptor, const Options& options) {
  Report report;
  report.plugin = descriptor.name;
  report.kind = plugin_kind_name(descriptor.kind);
  Recorder r;
  check_descriptor(descriptor, r);
  std::unique_ptr<PluginObject> object;
  if (descriptor.factory != nullptr) {
    PluginArgs args;
    args.instance_name = "mspace_check";
    detail::guarded(r, "construct.defaults", [&] {
      args.params = detail::instance_params(descriptor, options);
      object = descriptor.factory(args);
    });
    r.at_most("construct.defaults", object == nullptr ? 1 : 0, 0, "no instance could be created");
  }
  if (object != nullptr) {
    // Anything a check did not catch itself fails "checks.completed".
    detail::guarded(r, "checks.completed", [&] {
      switch (descriptor.kind) {
        case PluginKind::Feature: detail::check_feature_type(*object, options, r); break;
        case PluginKind::MotionModel: detail::check_motion_model(*object, options, r); break;
        case PluginKind::Estimator: detail::check_estimator(*object, options, r); break;
        case PluginKind::Extractor: detail::check_extractor(*object, options, r); break;
        case PluginKind::Source: detail::check_source(descriptor, *object, options, r); break;
      }
    });
  }
  report.checks = r.take();
  report.costs = r.take_costs();
  return report;
}

namespace {

std::string format_number(double v) {
  std::ostringstream s;
  s << std::setprecision(3) << v;
  return s.str();
}

std::string status(const CheckResult& c) { return c.skipped ? "SKIP" : c.passed ? "PASS" : "FAIL"; }

std::string xml_escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string join(const std::vector<std::string>& names) {
  std::string out;
  for (const std::string& n : names) out += (out.empty() ? "" : " ") + n;
  return out;
}

/// "0.21 us/call, analytic J_eta_o J_eta_v; by differences through innovation(): 3.4 us/call (16x)".
std::string describe_cost(const Cost& c) {
  std::string text = format_number(c.micros) + " us/call";
  if (!c.numeric.empty())
    text += ", numeric " + join(c.numeric) + " (" + format_number(c.evaluations) + " evaluations/call)";
  if (!c.analytic.empty()) text += ", analytic " + join(c.analytic);
  if (!std::isnan(c.micros_by_differences) && c.micros > 0)
    text += "; by differences through " + c.function + "(): " + format_number(c.micros_by_differences) +
            " us/call (" + format_number(c.micros_by_differences / c.micros) + "x)";
  return text;
}

}  // namespace

void print_report(const Report& report, std::ostream& out) {
  out << report.plugin << " [" << report.kind << "]\n";
  for (const CheckResult& c : report.checks) {
    out << "  " << status(c) << "  " << std::left << std::setw(36) << c.name;
    if (!c.skipped) {
      out << " worst " << std::setw(10) << format_number(c.worst) << " tol " << (c.lower_is_better ? "<= " : ">= ")
          << std::setw(8) << format_number(c.tolerance);
    }
    if (!c.note.empty() && (c.skipped || !c.passed || c.show_note)) out << "  " << c.note;
    out << '\n';
  }
  for (const Cost& c : report.costs)
    out << "  COST  " << std::left << std::setw(36) << c.function << " " << describe_cost(c) << '\n';
  out << "  " << (report.passed() ? "passed" : "FAILED") << ": " << report.checks.size() << " checks, "
      << report.failures() << " failed\n";
}

void write_junit(const std::vector<Report>& reports, std::ostream& out) {
  out << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<testsuites>\n";
  for (const Report& rep : reports) {
    const auto skipped = std::count_if(rep.checks.begin(), rep.checks.end(), [](const CheckResult& c) { return c.skipped; });
    out << "  <testsuite name=\"" << xml_escape(rep.plugin) << "\" tests=\"" << rep.checks.size() << "\" failures=\""
        << rep.failures() << "\" skipped=\"" << skipped << "\">\n";
    if (!rep.costs.empty()) {
      out << "    <properties>\n";
      for (const Cost& c : rep.costs)
        out << "      <property name=\"cost." << xml_escape(c.function) << "\" value=\"" << xml_escape(describe_cost(c))
            << "\"/>\n";
      out << "    </properties>\n";
    }
    for (const CheckResult& c : rep.checks) {
      out << "    <testcase classname=\"mspace.check." << xml_escape(rep.plugin) << "\" name=\"" << xml_escape(c.name)
          << "\">";
      const std::string numbers = "worst " + format_number(c.worst) + ", tolerance " +
                                  (c.lower_is_better ? "<= " : ">= ") + format_number(c.tolerance);
      if (c.skipped) {
        out << "<skipped message=\"" << xml_escape(c.note) << "\"/>";
      } else if (!c.passed) {
        out << "<failure message=\"" << xml_escape(numbers + (c.note.empty() ? "" : ": " + c.note)) << "\"/>";
      } else {
        out << "<system-out>" << xml_escape(numbers) << "</system-out>";
      }
      out << "</testcase>\n";
    }
    out << "  </testsuite>\n";
  }
  out << "</testsuites>\n";
}

}  // namespace mspace::conformance
