// numeric.cpp — see mspace/numeric.hpp.
#include "mspace/numeric.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "mspace/pose.hpp"

namespace mspace {
namespace {

using Clock = std::chrono::steady_clock;

thread_local std::array<NumericUsage, kNumericJacobianCount> g_usage{};

void record(NumericJacobian which, long evaluations, Clock::time_point start) {
  NumericUsage& u = g_usage[static_cast<std::size_t>(which)];
  ++u.calls;
  u.evaluations += evaluations;
  u.seconds += std::chrono::duration<double>(Clock::now() - start).count();
}

/// The Jacobian of f at x, f(x) = f0 known. Returns false (J unspecified)
/// when a coordinate cannot be differenced on either side; `evaluations`
/// counts the calls of f.
bool differences(const NumericFunction& f, const Eigen::VectorXd& x, const Eigen::VectorXd& f0,
                 const NumericOptions& o, Eigen::MatrixXd& J, long& evaluations) {
  if (o.scale.size() != 0 && o.scale.size() != x.size())
    throw std::invalid_argument("numeric_jacobian: NumericOptions::scale has " + std::to_string(o.scale.size()) +
                                " entries for " + std::to_string(x.size()) + " coordinates");
  const auto m = f0.size();
  J.resize(m, x.size());
  Eigen::VectorXd xp = x, fp(m), fm(m);
  auto evaluate = [&](double xj, Eigen::Index j, Eigen::VectorXd& out) {
    xp[j] = xj;
    ++evaluations;
    const bool ok = f(xp, out) && out.size() == m;
    xp[j] = x[j];
    return ok;
  };
  auto delta = [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
    Eigen::VectorXd d = a - b;
    for (int row : o.angle_rows)
      if (row >= 0 && row < m) d[row] = wrap_angle(d[row]);
    return d;
  };
  for (Eigen::Index j = 0; j < x.size(); ++j) {
    const double scale = o.scale.size() == 0 ? 1.0 : std::abs(o.scale[j]);
    const double h = o.relative_step * std::max(std::abs(x[j]), scale);
    const bool plus = evaluate(x[j] + h, j, fp), minus = evaluate(x[j] - h, j, fm);
    if (plus && minus) {
      J.col(j) = delta(fp, fm) / (2.0 * h);
    } else if (plus) {
      J.col(j) = delta(fp, f0) / h;
    } else if (minus) {
      J.col(j) = delta(f0, fm) / h;
    } else {
      return false;
    }
  }
  return true;
}

}  // namespace

const char* numeric_jacobian_name(NumericJacobian which) {
  switch (which) {
    case NumericJacobian::eta_o: return "J_eta_o";
    case NumericJacobian::eta_v: return "J_eta_v";
    case NumericJacobian::sensor: return "J_sensor";
    case NumericJacobian::own: return "J_own";
    case NumericJacobian::measurement: return "J_measurement";
    case NumericJacobian::other: return "other";
  }
  return "?";
}

Eigen::MatrixXd numeric_jacobian(NumericJacobian which, const NumericFunction& f, const Eigen::VectorXd& x,
                                 const NumericOptions& options) {
  const Clock::time_point start = Clock::now();
  long evaluations = 1;
  Eigen::VectorXd f0;
  if (!f(x, f0)) throw std::runtime_error("numeric_jacobian: the function cannot be evaluated at x");
  Eigen::MatrixXd J;
  const bool ok = differences(f, x, f0, options, J, evaluations);
  record(which, evaluations, start);
  if (!ok)
    throw std::runtime_error(std::string("numeric_jacobian (") + numeric_jacobian_name(which) +
                             "): the function cannot be evaluated on either side of a coordinate");
  return J;
}

bool numeric_innovation(const Residual& residual, const Eigen::VectorXd& x_o, const Eigen::VectorXd& v,
                        Innovation& out, unsigned parts, const NumericOptions& options) {
  Clock::time_point start = Clock::now();
  if (!residual(x_o, v, out.eta) || out.eta.size() == 0) return false;
  long evaluations = 1;
  if ((parts & kNumericEtaO) != 0u) {
    const NumericFunction f = [&](const Eigen::VectorXd& x, Eigen::VectorXd& eta) { return residual(x, v, eta); };
    const bool ok = differences(f, x_o, out.eta, options, out.J_eta_o, evaluations);
    record(NumericJacobian::eta_o, evaluations, start);
    if (!ok) return false;
    start = Clock::now();
    evaluations = 0;
  }
  if ((parts & kNumericEtaV) != 0u) {
    NumericOptions ov = options;
    ov.scale.resize(0);
    const NumericFunction f = [&](const Eigen::VectorXd& vv, Eigen::VectorXd& eta) { return residual(x_o, vv, eta); };
    const bool ok = differences(f, v, out.eta, ov, out.J_eta_v, evaluations);
    record(NumericJacobian::eta_v, evaluations, start);
    if (!ok) return false;
  }
  return true;
}

NumericUsage numeric_usage(NumericJacobian which) { return g_usage[static_cast<std::size_t>(which)]; }

void reset_numeric_usage() { g_usage.fill(NumericUsage{}); }

}  // namespace mspace
