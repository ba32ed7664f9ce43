// variance_components.cpp — see variance_components.hpp.
#include "variance_components.hpp"

#include <Eigen/Cholesky>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

namespace mspace::smoother {

double VarianceComponent::factor() const {
  const double rho = redundancy();
  if (factors == 0 || rho < kMinRedundancy) return 1.0;
  return weighted_sum / rho;
}

bool estimated_kind(FactorKind kind) { return kind == FactorKind::Motion || kind == FactorKind::Observation; }

bool whiten(NonlinearProblem& problem, int i, const KindScales& scales, WhitenedFactor& out) {
  FactorLinearization lin;
  if (!problem.linearize(i, lin) || lin.eta.size() == 0) return false;
  const Eigen::LLT<Eigen::MatrixXd> llt(lin.C);
  if (llt.info() != Eigen::Success)
    throw std::runtime_error("smoother: factor " + std::to_string(i) +
                             " has a covariance that is not positive definite");
  const double inv_sigma = 1.0 / std::sqrt(scales[static_cast<int>(lin.kind)]);
  out.kind = lin.kind;
  out.r = inv_sigma * llt.matrixL().solve(lin.eta);
  out.J = inv_sigma * llt.matrixL().solve(lin.J);
  out.idx = std::move(lin.idx);
  out.robust = lin.robust;
  return true;
}

Eigen::MatrixXd rademacher_probes(int n, int probes) {
  std::mt19937_64 rng(0x5eed);  // fixed: the same probes every run
  std::bernoulli_distribution coin(0.5);
  Eigen::MatrixXd Z(n, probes);
  for (Eigen::Index j = 0; j < Z.cols(); ++j)
    for (Eigen::Index i = 0; i < Z.rows(); ++i) Z(i, j) = coin(rng) ? 1.0 : -1.0;
  return Z;
}

}  // namespace mspace::smoother
