// variance_components.hpp — estimating each factor kind's noise scale from the
// smoother's own residuals (variance-component estimation, Helmert/Förstner).
//
// A least-squares problem whose factors come in groups k (here: the factor
// kinds of mspace/problem.hpp) with covariances C_i = σ²_k × (the configured C_i) has,
// at its optimum, E[Σ_{i∈k} r_iᵀ C_i⁻¹ r_i] = σ²_k ρ_k, where the redundancy
//   ρ_k = m_k − tr(H⁻¹ H_k)
// is the group's residual rows m_k less the share of the unknowns it
// determines (H = Σ_k H_k the information matrix, H_k = Σ_{i∈k} J_iᵀ C_i⁻¹ J_i;
// Σ_k tr(H⁻¹ H_k) = number of unknowns). So
//   σ̂²_k = Σ_{i∈k} w_i r_iᵀ C_i⁻¹ r_i / ρ_k
// (w_i the robust loss's weight at the optimum) estimates by how much the
// configured noise of group k is too small (σ̂² > 1) or too large (σ̂² < 1),
// from the data's internal consistency only: no ground truth. Re-scaling the
// groups and re-optimising until σ̂²_k ≈ 1 is the classical iteration (Förstner
// 1979; Koch, "Parameter Estimation and Hypothesis Testing in Linear Models",
// §3.6: "iterated estimates of variance components").
//
// tr(H⁻¹ H_k) is estimated without forming H⁻¹ (Hutchinson's estimator) in
// its symmetric form: with H⁻¹ = M Mᵀ (M from the sparse LDLᵀ factor,
// M = Pᵀ L⁻ᵀ D^-½), tr(H⁻¹ H_k) = tr(Mᵀ H_k M) = E[zᵀ Mᵀ H_k M z] for random ±1
// vectors z. y = M z is one triangular solve, and yᵀ H_k y = Σ_{i∈k} w_i |J_i y|²
// (never negative). Mᵀ H_k M is symmetric with eigenvalues in [0, 1], so the
// estimate's standard deviation is at most √(2 tr / probes): with 32 probes
// and 10 000 unknowns determined by the group, 0.25 % of the trace. (The
// unsymmetric form zᵀ H⁻¹ H_k z has no such bound and is useless when H is
// ill-conditioned.) The probes come from a fixed seed: runs stay deterministic.
#pragma once

#include <array>
#include <vector>

#include <Eigen/Core>

#include "mspace/problem.hpp"

namespace mspace::smoother {

/// Multipliers of each factor kind's configured covariance (C ← scale · C).
using KindScales = std::array<double, kFactorKinds>;

/// One group's statistics at an optimum.
struct VarianceComponent {
  int factors = 0;
  int rows = 0;               ///< m_k
  double weighted_sum = 0.0;  ///< Σ w_i r_iᵀ C_i⁻¹ r_i (C_i already scaled)
  double trace = 0.0;         ///< tr(H⁻¹ H_k), estimated
  /// ρ_k = m_k − tr(H⁻¹ H_k).
  double redundancy() const { return rows - trace; }
  /// σ̂²_k relative to the scale in use; 1 when the group has too little
  /// redundancy to say anything (below kMinRedundancy).
  double factor() const;
};

/// Below this redundancy a group's scale is not estimated.
inline constexpr double kMinRedundancy = 10.0;

/// The kinds whose scale is estimated: motion and observation factors (the
/// prior, extension priors, frozen linearisations and coincidences keep theirs).
bool estimated_kind(FactorKind kind);

/// A whitened, weighted factor: r = L⁻¹ η / √scale, J likewise (C = L Lᵀ), and
/// the robust weight w. Returns false when the factor has no rows.
struct WhitenedFactor {
  FactorKind kind = FactorKind::Linear;
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  std::vector<int> idx;
  bool robust = false;
};
bool whiten(NonlinearProblem& problem, int i, const KindScales& scales, WhitenedFactor& out);

/// Per-kind statistics at the problem's current values. `half_solve` applies M
/// (H⁻¹ = M Mᵀ, H the information matrix of the same values, scales and robust
/// weights) to a block of columns; `weight` gives a whitened factor's robust weight from its
/// squared norm. `probes` random ±1 vectors (seeded) estimate the traces.
template <class HalfSolve, class Weight>
std::array<VarianceComponent, kFactorKinds> variance_components(NonlinearProblem& problem, const KindScales& scales,
                                                                int probes, const HalfSolve& half_solve, const Weight& weight);

/// The random ±1 probe matrix (n × probes) for a fixed seed.
Eigen::MatrixXd rademacher_probes(int n, int probes);

template <class HalfSolve, class Weight>
std::array<VarianceComponent, kFactorKinds> variance_components(NonlinearProblem& problem, const KindScales& scales,
                                                                int probes, const HalfSolve& half_solve, const Weight& weight) {
  std::array<VarianceComponent, kFactorKinds> out{};
  const Eigen::MatrixXd Z = rademacher_probes(problem.tangent_dim(), probes);
  const Eigen::MatrixXd Y = half_solve(Z);
  WhitenedFactor f;
  for (int i = 0; i < problem.num_factors(); ++i) {
    if (!whiten(problem, i, scales, f)) continue;
    VarianceComponent& c = out[static_cast<int>(f.kind)];
    const double s = f.r.squaredNorm();
    const double w = f.robust ? weight(s) : 1.0;
    ++c.factors;
    c.rows += static_cast<int>(f.r.size());
    c.weighted_sum += w * s;
    Eigen::MatrixXd Jy = Eigen::MatrixXd::Zero(f.J.rows(), probes);
    for (std::size_t a = 0; a < f.idx.size(); ++a)
      Jy.noalias() += f.J.col(static_cast<Eigen::Index>(a)) * Y.row(f.idx[a]);
    c.trace += w * Jy.squaredNorm() / probes;
  }
  return out;
}

}  // namespace mspace::smoother
