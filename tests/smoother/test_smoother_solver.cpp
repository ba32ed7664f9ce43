// The smoother's Gauss–Newton and marginal recovery (plugins/smoother) on a
// linear-Gaussian problem whose answer is known in closed form: the
// optimum is the dense weighted least-squares solution, and the covariance
// the smoother re-sets its filter to is (H⁻¹)[S, S] of the dense information
// matrix H — the Schur complement over the earlier pose nodes must give the
// same numbers.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <vector>

#include <Eigen/Dense>

#include "mspace/cekf_filter.hpp"
#include "mspace/ekf_filter.hpp"
#include "mspace/problem.hpp"
#include "smoother.hpp"

namespace {

using namespace mspace;

/// Linear factors r = A x − b on a value vector x (the tangent space is x
/// itself): k = 3 rows for the current pose, m map rows, N−1 earlier nodes.
class LinearProblem final : public NonlinearProblem {
 public:
  LinearProblem(int k, int m, int nodes, std::uint64_t seed) : k_(k), m_(m), nodes_(nodes) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> g(0.0, 1.0);
    x_ = Eigen::VectorXd::Zero(tangent_dim());
    const auto add = [&](std::vector<int> idx, bool robust) {
      Factor f;
      f.idx = std::move(idx);
      const int rows = static_cast<int>(f.idx.size()) >= 2 * k ? k : 2;
      f.A = Eigen::MatrixXd(rows, static_cast<Eigen::Index>(f.idx.size()));
      for (Eigen::Index i = 0; i < f.A.size(); ++i) f.A.data()[i] = g(rng);
      f.b = Eigen::VectorXd(rows);
      for (Eigen::Index i = 0; i < rows; ++i) f.b[i] = g(rng);
      Eigen::MatrixXd L = Eigen::MatrixXd::Identity(rows, rows) * 0.5;
      for (Eigen::Index i = 0; i < rows; ++i)
        for (Eigen::Index j = 0; j < i; ++j) L(i, j) = 0.1 * g(rng);
      f.C = L * L.transpose();
      f.robust = robust;
      factors_.push_back(f);
    };
    const auto node = [&](int n) {  // tangent rows of node n (n = nodes−1: the current pose)
      std::vector<int> idx;
      const int first = pose_node_index(n);
      for (int j = 0; j < k_; ++j) idx.push_back(first + j);
      return idx;
    };
    add(node(0), false);  // prior
    for (int n = 0; n + 1 < nodes_; ++n) {  // motion
      std::vector<int> idx = node(n);
      const std::vector<int> next = node(n + 1);
      idx.insert(idx.end(), next.begin(), next.end());
      add(idx, false);
    }
    for (int n = 0; n < nodes_; ++n)  // observations of two map rows
      for (int r = 0; r < 2; ++r) {
        std::vector<int> idx = node(n);
        idx.push_back(k_ + (2 * n + r) % m_);
        idx.push_back(k_ + (3 * n + r + 1) % m_);
        if (idx[k_] == idx[k_ + 1]) idx.pop_back();
        add(idx, true);
      }
    for (int r = 0; r < m_; ++r) add({k_ + r}, false);  // priors on the map rows
  }

  int robot_dim() const override { return k_; }
  int state_dim() const override { return k_ + m_; }
  int tangent_dim() const override { return state_dim() + k_ * (nodes_ - 1); }
  int num_pose_nodes() const override { return nodes_; }
  int pose_node_index(int node) const override { return node == nodes_ - 1 ? 0 : state_dim() + k_ * node; }
  int num_factors() const override { return static_cast<int>(factors_.size()); }
  bool linearize(int i, FactorLinearization& out) override {
    const Factor& f = factors_[static_cast<std::size_t>(i)];
    out.kind = FactorKind::Linear;
    out.idx = f.idx;
    out.J = f.A;
    out.C = f.C;
    out.eta = f.A * x_(f.idx) - f.b;
    out.robust = f.robust;
    return true;
  }
  void retract(const Eigen::VectorXd& delta) override { x_ += delta; }

  /// The dense weighted least-squares problem: H and the optimum.
  void dense(Eigen::MatrixXd& H, Eigen::VectorXd& x) const {
    const int n = tangent_dim();
    H = Eigen::MatrixXd::Zero(n, n);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
    for (const Factor& f : factors_) {
      const Eigen::MatrixXd W = f.C.inverse();
      H(f.idx, f.idx) += f.A.transpose() * W * f.A;
      g(f.idx) += f.A.transpose() * W * f.b;
    }
    x = H.ldlt().solve(g);
  }
  const Eigen::VectorXd& values() const { return x_; }
  /// Moves factor i's right-hand side by `sigmas` of its first row's σ.
  void corrupt(int i, double sigmas) {
    Factor& f = factors_[static_cast<std::size_t>(i)];
    f.b[0] += sigmas * std::sqrt(f.C(0, 0));
  }

 private:
  struct Factor {
    std::vector<int> idx;
    Eigen::MatrixXd A, C;
    Eigen::VectorXd b;
    bool robust = false;
  };
  int k_, m_, nodes_;
  Eigen::VectorXd x_;
  std::vector<Factor> factors_;
};

TEST(SmootherSolver, LinearProblemGivesTheLeastSquaresSolutionAndTheExactMarginal) {
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    LinearProblem p(3, 8, 40, seed);
    smoother::SmootherOptions o;
    o.loss = smoother::Loss::None;  // least squares exactly
    o.tolerance = 1e-12;
    o.cost_tolerance = 0.0;
    smoother::Smoother s(o);
    s.reset(Eigen::Matrix3d::Identity());
    StateAugmentation aug;
    aug.J = Eigen::MatrixXd::Zero(8, 0);
    aug.C_new = Eigen::MatrixXd::Identity(8, 8);
    s.augment(aug);
    ASSERT_EQ(s.dim(), p.state_dim());
    s.optimise(p);

    Eigen::MatrixXd H;
    Eigen::VectorXd x;
    p.dense(H, x);
    EXPECT_LT((p.values() - x).lpNorm<Eigen::Infinity>(), 1e-8) << "seed " << seed;
    const Eigen::MatrixXd C = H.inverse().topLeftCorner(p.state_dim(), p.state_dim());
    EXPECT_LT((s.covariance() - C).lpNorm<Eigen::Infinity>(), 1e-8 * (1.0 + C.lpNorm<Eigen::Infinity>()))
        << "seed " << seed;
    // One Gauss–Newton step solves a linear problem; the 1e-9 Levenberg term
    // leaves remainders of that order, which take at most two more, tiny steps.
    EXPECT_LE(s.last_report().iterations, 3) << "seed " << seed;
  }
}

// A robust loss leaves the factors that agree alone and down-weights a gross
// outlier: with one observation's right-hand side moved by 100 σ, the Huber
// solution stays far closer to the clean optimum than least squares.
TEST(SmootherSolver, HuberLossResistsAGrossOutlier) {
  LinearProblem clean(3, 8, 40, 7);
  Eigen::MatrixXd H;
  Eigen::VectorXd x_clean;
  clean.dense(H, x_clean);
  double err[2] = {0, 0};
  const smoother::Loss losses[2] = {smoother::Loss::None, smoother::Loss::Huber};
  for (int l = 0; l < 2; ++l) {
    LinearProblem p(3, 8, 40, 7);
    p.corrupt(45, 100.0);
    smoother::SmootherOptions o;
    o.loss = losses[l];
    o.max_iterations = 30;
    o.tolerance = 1e-10;
    o.cost_tolerance = 0.0;
    smoother::Smoother s(o);
    s.reset(Eigen::Matrix3d::Identity());
    StateAugmentation aug;
    aug.J = Eigen::MatrixXd::Zero(8, 0);
    aug.C_new = Eigen::MatrixXd::Identity(8, 8);
    s.augment(aug);
    s.optimise(p);
    err[l] = (p.values() - x_clean).norm();
  }
  std::cout << "outlier: error least squares " << err[0] << ", Huber " << err[1] << "\n";
  EXPECT_LT(err[1], 0.2 * err[0]);
}


// The running filter in observability-constrained mode (SmootherOptions::
// observability_constrained): between optimisations the smoother is the
// constrained filter of the ekf and cekf plugins — the same δx and covariance
// for the same calls — its updates add no information along the unobservable
// directions U, and it stays so after an optimisation re-set its covariance.
TEST(SmootherObservabilityConstrained, TheRunningFilterIsTheConstrainedFilter) {
  // Global planar motion of a robot at (x, y): translation along x, along y,
  // rotation about the origin.
  const auto global_motion = [](double x, double y) { return Eigen::MatrixXd{{1, 0, -y}, {0, 1, x}, {0, 0, 1}}; };
  const Eigen::MatrixXd P0{{0.3, 0.02, 0.0}, {0.02, 0.2, 0.01}, {0.0, 0.01, 0.1}};
  const Eigen::MatrixXd J_rr{{1, 0, 0.1}, {0, 1, 0.4}, {0, 0, 1}};  // a step that moves the robot by (0.4, −0.1)
  // A point seen from the robot (rows of x, y, θ), then 6 more map rows.
  const StateAugmentation point{{0, 1, 2}, Eigen::MatrixXd{{1, 0, -0.8}, {0, 1, 1.5}}, 0.05 * Eigen::MatrixXd::Identity(2, 2)};
  StateAugmentation rest;
  rest.J = Eigen::MatrixXd::Zero(6, 0);
  rest.C_new = Eigen::MatrixXd::Identity(6, 6);
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::MatrixXd J_obs(2, 5);
  for (Eigen::Index i = 0; i < J_obs.size(); ++i) J_obs.data()[i] = g(rng);
  const LinearizedObservation obs{Eigen::VectorXd{{0.3, -0.2}}, Eigen::MatrixXd{{0.05, 0.01}, {0.01, 0.04}},
                                  {0, 1, 2, 3, 4}, J_obs};
  const auto exercise = [&](Estimator& f) {
    f.reset(P0);
    f.set_unobservable(global_motion(1.0, 2.0));
    f.predict(J_rr, 0.01 * Eigen::MatrixXd::Identity(3, 3));
    f.augment(point);
    f.augment(rest);
    return Eigen::VectorXd(f.update({obs}));
  };
  for (const smoother::RunningFilter kind : {smoother::RunningFilter::Ekf, smoother::RunningFilter::Cekf}) {
    SCOPED_TRACE(kind == smoother::RunningFilter::Ekf ? "running_filter ekf" : "running_filter cekf");
    smoother::SmootherOptions o;
    o.running_filter = kind;
    o.observability_constrained = true;
    smoother::Smoother constrained(o);
    o.observability_constrained = false;
    smoother::Smoother plain(o);
    ekf::EkfFilter ekf_constrained(4, true);
    cekf::CekfFilter cekf_constrained(cekf::CekfFilter::kDefaultMaxActive, cekf::CekfFilter::kDefaultKeepSteps, true);
    Estimator& reference = kind == smoother::RunningFilter::Ekf ? static_cast<Estimator&>(ekf_constrained)
                                                                : static_cast<Estimator&>(cekf_constrained);
    const Eigen::VectorXd dx = exercise(constrained);
    const Eigen::VectorXd dx_reference = exercise(reference);
    const Eigen::VectorXd dx_plain = exercise(plain);
    std::vector<int> all(static_cast<std::size_t>(constrained.dim()));
    for (int i = 0; i < constrained.dim(); ++i) all[static_cast<std::size_t>(i)] = i;
    EXPECT_LT((dx - dx_reference).lpNorm<Eigen::Infinity>(), 1e-12);
    EXPECT_LT((constrained.marginal(all) - reference.marginal(all)).lpNorm<Eigen::Infinity>(), 1e-12);
    EXPECT_GT((dx - dx_plain).lpNorm<Eigen::Infinity>(), 1e-3);  // the constraint does something

    // Robot rows: the global motion at (1.4, 1.9) after the step; the point's:
    // J of its augmentation times the robot's.
    const Eigen::MatrixXd U_r = global_motion(1.4, 1.9);
    Eigen::MatrixXd U = Eigen::MatrixXd::Zero(constrained.dim(), 3);
    U.topRows(3) = U_r;
    U.middleRows(3, 2) = point.J * U_r;

    // The next update (another Jacobian) adds no information along U, and
    // neither does one after an optimisation has re-set the covariance.
    const auto information_along_U = [&](Estimator& f) {
      const Eigen::MatrixXd before = f.marginal(all).inverse();
      f.update({LinearizedObservation{obs.eta, obs.C_eta, obs.idx, J_obs.rowwise().reverse()}});
      return Eigen::MatrixXd(U.transpose() * (f.marginal(all).inverse() - before) * U);
    };
    EXPECT_LT(information_along_U(constrained).cwiseAbs().maxCoeff(), 1e-8);
    EXPECT_GT(information_along_U(plain).cwiseAbs().maxCoeff(), 1e-2);
    LinearProblem problem(3, constrained.dim() - 3, 20, 9);
    constrained.optimise(problem);
    EXPECT_LT(information_along_U(constrained).cwiseAbs().maxCoeff(), 1e-8);
  }
}

}  // namespace
