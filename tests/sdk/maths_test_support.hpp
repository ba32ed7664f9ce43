// Shared helpers for the SDK maths tests: a seeded sampler of poses and
// feature coordinates, central-difference Jacobians and a tracker of the
// worst relative error over many random states.
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <functional>
#include <numbers>
#include <random>
#include <sstream>
#include <string>

#include "mspace/coords.hpp"
#include "mspace/pose.hpp"

namespace mspace::test {

/// Random states for the Jacobian checks: each test uses its own fixed seed.
constexpr int kRandomStates = 1000;
/// Step of the central differences.
constexpr double kStep = 1e-6;
/// Allowed worst relative error analytic vs. central differences. The
/// difference error is O(h²) + O(ε·|x|/h), a few 1e-9 here at worst; a wrong
/// term gives an error of order 1.
constexpr double kJacobianTol = 1e-7;

class Sampler {
 public:
  explicit Sampler(unsigned seed) : rng_(seed) {}

  double uniform(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng_); }

  /// Pose with positions in ±10 m (z in ±2 m), any yaw, and pitch and roll
  /// within ±max_tilt (a tilted sensor or robot on uneven ground).
  Pose6 pose(double max_tilt = 0.5) {
    const double pi = std::numbers::pi;
    return make_pose(uniform(-10, 10), uniform(-10, 10), uniform(-2, 2), uniform(-pi, pi),
                     uniform(-max_tilt, max_tilt), uniform(-max_tilt, max_tilt));
  }

  Eigen::VectorXd vector(int n, double half_range = 10.0) {
    Eigen::VectorXd v(n);
    for (int i = 0; i < n; ++i) v[i] = uniform(-half_range, half_range);
    return v;
  }

  /// 1–5 blocks of random kinds.
  CoordLayout layout() {
    std::vector<BlockKind> blocks(std::uniform_int_distribution<int>(1, 5)(rng_));
    for (BlockKind& kind : blocks) kind = static_cast<BlockKind>(std::uniform_int_distribution<int>(0, 2)(rng_));
    return CoordLayout(std::move(blocks));
  }

 private:
  std::mt19937 rng_;
};

using VectorFn = std::function<Eigen::VectorXd(const Eigen::VectorXd&)>;
using DifferenceFn = std::function<Eigen::VectorXd(const Eigen::VectorXd&, const Eigen::VectorXd&)>;

inline Eigen::VectorXd plain_difference(const Eigen::VectorXd& a, const Eigen::VectorXd& b) { return a - b; }

/// Pose outputs: the angle difference is wrapped, so a step across ±π is fine.
inline Eigen::VectorXd wrapped_pose_difference(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return pose_difference(Pose6(a), Pose6(b));
}

/// ∂f/∂x by central differences.
inline Eigen::MatrixXd numeric_jacobian(const VectorFn& f, const Eigen::VectorXd& x,
                                        const DifferenceFn& difference = plain_difference) {
  const Eigen::VectorXd f0 = f(x);
  Eigen::MatrixXd J(f0.size(), x.size());
  for (int i = 0; i < x.size(); ++i) {
    Eigen::VectorXd plus = x, minus = x;
    plus[i] += kStep;
    minus[i] -= kStep;
    J.col(i) = difference(f(plus), f(minus)) / (2.0 * kStep);
  }
  return J;
}

/// Pose → pose function differentiated with wrapped angle outputs.
inline Eigen::MatrixXd numeric_pose_jacobian(const std::function<Pose6(const Pose6&)>& f, const Pose6& x) {
  return numeric_jacobian([&](const Eigen::VectorXd& v) -> Eigen::VectorXd { return f(Pose6(v)); }, x,
                          wrapped_pose_difference);
}

/// max |analytic − numeric| / max(1, max |numeric|).
inline double relative_error(const Eigen::MatrixXd& analytic, const Eigen::MatrixXd& numeric) {
  const double scale = std::max(1.0, numeric.cwiseAbs().maxCoeff());
  return (analytic - numeric).cwiseAbs().maxCoeff() / scale;
}

/// Keeps the worst relative error seen and the state it was seen at.
class WorstError {
 public:
  void update(const Eigen::MatrixXd& analytic, const Eigen::MatrixXd& numeric, const std::string& state) {
    const double error = relative_error(analytic, numeric);
    ++count_;
    if (error > worst_) {
      worst_ = error;
      state_ = state;
    }
  }
  double worst() const { return worst_; }
  int count() const { return count_; }
  std::string report() const {
    std::ostringstream s;
    s << "worst relative error " << worst_ << " over " << count_ << " random states, at " << state_;
    return s.str();
  }

 private:
  double worst_ = 0.0;
  int count_ = 0;
  std::string state_ = "(none)";
};

inline std::string describe(const Eigen::MatrixXd& m) {
  std::ostringstream s;
  s << m.transpose();
  return "[" + s.str() + "]";
}

}  // namespace mspace::test
