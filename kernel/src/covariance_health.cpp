// covariance_health.cpp — see covariance_health.hpp.
#include "covariance_health.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

namespace mspace::kernel {
namespace {

/// Up to this size the whole-covariance check computes every eigenvalue
/// (O(n³) with a large constant); beyond it, a Cholesky factor and iterations.
constexpr Eigen::Index kExactEigenvaluesUpTo = 300;
/// Power and inverse iteration steps of a large whole-covariance check.
constexpr int kIterations = 60;

double asymmetry_of(const Eigen::MatrixXd& C) {
  const double scale = C.cwiseAbs().maxCoeff();
  return scale > 0.0 ? (C - C.transpose()).cwiseAbs().maxCoeff() / scale : 0.0;
}

}  // namespace

CovarianceFigures covariance_figures(const Eigen::MatrixXd& C) {
  CovarianceFigures f;
  if (C.size() == 0) return f;
  f.asymmetry = asymmetry_of(C);
  const Eigen::MatrixXd symmetric = 0.5 * (C + C.transpose());
  const Eigen::LLT<Eigen::MatrixXd> llt(symmetric);
  if (C.rows() <= kExactEigenvaluesUpTo || llt.info() != Eigen::Success) {
    // Small, or not positive definite (then the figures must be exact).
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(symmetric, Eigen::EigenvaluesOnly);
    f.min_eigenvalue = eig.eigenvalues().minCoeff();
    f.max_eigenvalue = eig.eigenvalues().maxCoeff();
    return f;
  }
  // Positive definite (the Cholesky factor exists): the extreme eigenvalues
  // by power iteration on C and inverse iteration on C⁻¹ through the factor,
  // O(n²) a step against O(n³) for all eigenvalues. Rayleigh quotients, so
  // the largest is a lower bound and the smallest an upper bound on the true
  // value, both exact once converged.
  const Eigen::Index n = C.rows();
  Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(n, 1.0, 2.0).normalized();  // not an eigenvector of a typical C
  Eigen::VectorXd y = x;
  for (int i = 0; i < kIterations; ++i) {
    x = (symmetric * x).normalized();
    y = llt.solve(y).normalized();
  }
  f.max_eigenvalue = x.dot(symmetric * x);
  f.min_eigenvalue = y.dot(symmetric * y);
  return f;
}

std::string CovarianceHealth::check_block(const Eigen::MatrixXd& block, std::int64_t step) {
  ++r_.block_checks;
  r_.max_asymmetry = std::max(r_.max_asymmetry, asymmetry_of(block));
  // The Cholesky factor of the lower triangle exists iff the block is
  // positive definite (for a symmetric block; the asymmetry is reported).
  const Eigen::LLT<Eigen::MatrixXd> llt(block);
  if (llt.info() == Eigen::Success) return {};
  if (r_.blocks_not_pd++ > 0) return {};
  r_.first_not_pd_step = step;
  std::ostringstream s;
  s << "step " << step << ": the estimator's covariance of the " << block.rows()
    << " state rows this update touched is not positive definite (no Cholesky factor; smallest eigenvalue "
    << covariance_figures(block).min_eigenvalue << "); further such steps are counted in the summary";
  return s.str();
}

void CovarianceHealth::record_full(const CovarianceFigures& f, std::int64_t step) {
  ++r_.full_checks;
  r_.max_asymmetry = std::max(r_.max_asymmetry, f.asymmetry);
  if (std::isnan(r_.min_eigenvalue) || f.min_eigenvalue < r_.min_eigenvalue) {
    r_.min_eigenvalue = f.min_eigenvalue;
    r_.min_relative_eigenvalue = f.max_eigenvalue > 0.0 ? f.min_eigenvalue / f.max_eigenvalue : f.min_eigenvalue;
    r_.min_eigenvalue_step = step;
  }
}

void CovarianceHealth::save(StateWriter& out, const std::string& prefix) const {
  Eigen::MatrixXd v(1, 8);
  v << static_cast<double>(r_.block_checks), static_cast<double>(r_.blocks_not_pd),
      static_cast<double>(r_.first_not_pd_step), static_cast<double>(r_.full_checks),
      r_.full_checks > 0 ? r_.min_eigenvalue : 0.0, r_.full_checks > 0 ? r_.min_relative_eigenvalue : 0.0,
      static_cast<double>(r_.min_eigenvalue_step), r_.max_asymmetry;
  out.put(prefix + "figures", v);
}

void CovarianceHealth::restore(const StateReader& in, const std::string& prefix) {
  r_ = {};
  if (!in.has(prefix + "figures")) return;  // a checkpoint written before these checks existed
  const Eigen::MatrixXd& v = get_state(in, prefix + "figures", 1, 8, "covariance health");
  CovarianceHealthReport r;
  r.block_checks = static_cast<std::int64_t>(v(0, 0));
  r.blocks_not_pd = static_cast<std::int64_t>(v(0, 1));
  r.first_not_pd_step = static_cast<std::int64_t>(v(0, 2));
  r.full_checks = static_cast<std::int64_t>(v(0, 3));
  if (r.full_checks > 0) {
    r.min_eigenvalue = v(0, 4);
    r.min_relative_eigenvalue = v(0, 5);
  }
  r.min_eigenvalue_step = static_cast<std::int64_t>(v(0, 6));
  r.max_asymmetry = v(0, 7);
  r_ = r;
}

}  // namespace mspace::kernel
