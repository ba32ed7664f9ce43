// smoother.cpp — periodic robust Gauss–Newton over the kernel's problem (see smoother.hpp).
#include "smoother.hpp"
#include "variance_components.hpp"

#include "mspace/state.hpp"

#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

namespace mspace::smoother {

namespace {

using SpMat = Eigen::SparseMatrix<double>;

/// ρ(s) and the weight ρ'(s) of a squared Mahalanobis norm s.
std::pair<double, double> robust(Loss loss, double c, double s) {
  const double c2 = c * c;
  switch (loss) {
    case Loss::Huber:
      if (s <= c2) return {s, 1.0};
      return {2.0 * c * std::sqrt(s) - c2, c / std::sqrt(s)};
    case Loss::Cauchy:
      return {c2 * std::log1p(s / c2), 1.0 / (1.0 + s / c2)};
    case Loss::None:
      break;
  }
  return {s, 1.0};
}

/// The normal equations of all factors at the problem's current values.
struct Normal {
  std::vector<Eigen::Triplet<double>> triplets;
  Eigen::VectorXd g;
  double cost = 0.0;
  double by_kind[kFactorKinds] = {};  ///< ½ Σ ρ by FactorKind
  int down_weighted = 0;
};

Normal build(NonlinearProblem& problem, const SmootherOptions& o, const KindScales& scales) {
  Normal out;
  const int n = problem.tangent_dim();
  out.g = Eigen::VectorXd::Zero(n);
  WhitenedFactor f;
  for (int i = 0; i < problem.num_factors(); ++i) {
    if (!whiten(problem, i, scales, f)) continue;
    const Eigen::VectorXd& r = f.r;
    const Eigen::MatrixXd& J = f.J;
    const double s = r.squaredNorm();
    const auto [rho, w] = f.robust ? robust(o.loss, o.loss_scale, s) : std::pair<double, double>{s, 1.0};
    if (f.robust && w < 1.0) ++out.down_weighted;
    out.cost += 0.5 * rho;
    out.by_kind[static_cast<int>(f.kind)] += 0.5 * rho;
    const Eigen::MatrixXd H = w * J.transpose() * J;
    const Eigen::VectorXd g = w * J.transpose() * r;
    for (std::size_t a = 0; a < f.idx.size(); ++a) {
      out.g[f.idx[a]] += g[static_cast<Eigen::Index>(a)];
      for (std::size_t b = 0; b < f.idx.size(); ++b)
        if (f.idx[b] <= f.idx[a])  // lower triangle
          out.triplets.emplace_back(f.idx[a], f.idx[b],
                                    H(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)));
    }
  }
  return out;
}

/// S⁻¹ for a symmetric positive definite S (read from its lower triangle),
/// through S = L Lᵀ: M = L⁻¹ is lower triangular, so each block of its columns
/// is solved only from its own first row down; then S⁻¹ = Mᵀ M, each block
/// of columns a product over the rows where M is non-zero. About 4n³/3
/// flops, against 7n³/3 for llt.solve(I) (two full triangular solves).
Eigen::MatrixXd inverse_spd(const Eigen::MatrixXd& S) {
  const Eigen::LLT<Eigen::MatrixXd> llt(S);
  if (llt.info() != Eigen::Success)
    throw std::runtime_error("smoother: the Schur complement is not positive definite");
  const Eigen::MatrixXd& L = llt.matrixLLT();  // L in the lower triangle
  const Eigen::Index n = S.rows();
  constexpr Eigen::Index kBlock = 64;
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(n, n);
  for (Eigen::Index c0 = 0; c0 < n; c0 += kBlock) {
    const Eigen::Index b = std::min(kBlock, n - c0);
    auto X = M.block(c0, c0, n - c0, b);
    X.topRows(b).setIdentity();
    L.bottomRightCorner(n - c0, n - c0).triangularView<Eigen::Lower>().solveInPlace(X);
  }
  Eigen::MatrixXd C(n, n);
  for (Eigen::Index c0 = 0; c0 < n; c0 += kBlock) {
    const Eigen::Index b = std::min(kBlock, n - c0);
    // Rows [c0, n) of columns [c0, c0 + b): M's rows above c0 are zero there.
    C.block(c0, c0, n - c0, b).noalias() =
        M.bottomRightCorner(n - c0, n - c0).transpose() * M.block(c0, c0, n - c0, b);
  }
  return C.selfadjointView<Eigen::Lower>();
}

/// A tiny Levenberg term keeps H definite along directions no factor
/// constrains yet (it changes nothing measurable elsewhere).
constexpr double kDamping = 1e-9;

SpMat assemble(const Normal& normal, int n, double damping) {
  SpMat H(n, n);
  H.setFromTriplets(normal.triplets.begin(), normal.triplets.end());
  for (int i = 0; i < n; ++i) H.coeffRef(i, i) += damping;
  H.makeCompressed();
  return H;
}

using Ldlt = Eigen::SimplicialLDLT<SpMat, Eigen::Lower>;

/// Gauss–Newton with step halving from the normal equations (`normal`, `H`)
/// at the current values; leaves them at the final values.
void gauss_newton(NonlinearProblem& problem, const SmootherOptions& o, const KindScales& scales, Normal& normal,
                  SpMat& H, Ldlt& ldlt, OptimisationReport& report) {
  const int n = problem.tangent_dim();
  for (int it = 0; it < o.max_iterations; ++it) {
    ldlt.factorize(H);
    if (ldlt.info() != Eigen::Success)
      throw std::runtime_error("smoother: the information matrix is not positive definite");
    Eigen::VectorXd delta = -ldlt.solve(normal.g);
    const double cost = normal.cost;
    problem.retract(delta);
    ++report.iterations;
    Normal next = build(problem, o, scales);
    // Step halving: Gauss–Newton overshoots far from the optimum; the
    // retraction is not exactly invertible, so halve by moving back.
    for (int halving = 0; halving < 4 && next.cost > cost * (1.0 + 1e-9); ++halving) {
      delta *= 0.5;
      problem.retract(-delta);
      next = build(problem, o, scales);
    }
    normal = std::move(next);
    H = assemble(normal, n, kDamping);
    if (delta.lpNorm<Eigen::Infinity>() < o.tolerance || cost - normal.cost < o.cost_tolerance * cost) break;
  }
}

/// The iterated variance-component estimate (variance_components.hpp): the
/// motion and observation kinds' scales re-estimated at the optimum and the
/// problem re-optimised with them, until every factor is within
/// `noise_tolerance` of 1 or after `noise_iterations` rounds.
void estimate_noise_scales(NonlinearProblem& problem, const SmootherOptions& o, KindScales& scales, Normal& normal,
                           SpMat& H, Ldlt& ldlt, OptimisationReport& report, Logger& log) {
  const int n = problem.tangent_dim();
  // M = Pᵀ L⁻ᵀ D^-½ of P H Pᵀ = L D Lᵀ, so that H⁻¹ = M Mᵀ.
  const auto half_solve = [&](const Eigen::MatrixXd& Z) -> Eigen::MatrixXd {
    Eigen::MatrixXd X = ldlt.vectorD().cwiseSqrt().cwiseInverse().asDiagonal() * Z;
    ldlt.matrixU().solveInPlace(X);
    return ldlt.permutationPinv() * X;
  };
  const auto weight = [&](double s) { return robust(o.loss, o.loss_scale, s).second; };
  for (int round = 0; round < o.noise_iterations; ++round) {
    ldlt.factorize(H);
    if (ldlt.info() != Eigen::Success)
      throw std::runtime_error("smoother: the information matrix is not positive definite");
    const auto components = variance_components(problem, scales, o.noise_probes, half_solve, weight);
    bool moved = false;
    for (int k = 0; k < kFactorKinds; ++k) {
      if (!estimated_kind(static_cast<FactorKind>(k))) continue;
      const double f = components[static_cast<std::size_t>(k)].factor();
      scales[static_cast<std::size_t>(k)] *= f;
      moved = moved || std::abs(f - 1.0) > o.noise_tolerance;
      log.debug("noise round ", round, ": kind ", k, ": ",
                  components[static_cast<std::size_t>(k)].rows, " rows, redundancy ",
                  components[static_cast<std::size_t>(k)].redundancy(), ", variance factor ", f, " -> scale ",
                  scales[static_cast<std::size_t>(k)]);
    }
    ++report.noise_rounds;
    if (!moved) break;
    normal = build(problem, o, scales);
    H = assemble(normal, n, kDamping);
    gauss_newton(problem, o, scales, normal, H, ldlt, report);
  }
}

}  // namespace

KindScales optimise_with_noise_estimation(NonlinearProblem& problem, const SmootherOptions& options,
                                          KindScales scales, Logger& log) {
  OptimisationReport report;
  Normal normal = build(problem, options, scales);
  SpMat H = assemble(normal, problem.tangent_dim(), kDamping);
  Ldlt ldlt;
  ldlt.analyzePattern(H);
  gauss_newton(problem, options, scales, normal, H, ldlt, report);
  estimate_noise_scales(problem, options, scales, normal, H, ldlt, report, log);
  return scales;
}

Smoother::Smoother(SmootherOptions options, Logger* log)
    : o_(options), log_(log != nullptr ? log : &null_logger()), filter_(make_filter()) {
  if (o_.period < 0 || o_.loop_gap < 1 || o_.max_iterations < 1 || !(o_.loss_scale > 0.0) || o_.growth < 0.0 ||
      o_.loop_spacing < 0)
    throw std::invalid_argument(
        "smoother: period ≥ 0, growth ≥ 0, loop_gap ≥ 1, loop_spacing ≥ 0, max_iterations ≥ 1 and loss_scale > 0 "
        "required");
}

Smoother::Filter Smoother::make_filter() const {
  if (o_.running_filter == RunningFilter::Ekf)
    return Filter(std::in_place_type<ekf::EkfFilter>, o_.initial_capacity, o_.observability_constrained);
  return Filter(std::in_place_type<cekf::CekfFilter>, o_.max_active, o_.keep_steps, o_.observability_constrained);
}

const Estimator& Smoother::running() const {
  return std::visit([](const auto& f) -> const Estimator& { return f; }, filter_);
}

Estimator& Smoother::running() {
  return std::visit([](auto& f) -> Estimator& { return f; }, filter_);
}

Eigen::MatrixXd Smoother::covariance() const {
  return std::visit([](const auto& f) { return f.covariance(); }, filter_);
}

void Smoother::reset(const Eigen::MatrixXd& P_rr) {
  running().reset(P_rr);
  k_ = static_cast<int>(P_rr.rows());
  key_ = 0;
  last_optimised_ = 0;
  last_seen_.assign(static_cast<std::size_t>(k_), 0);
  loop_ = false;
  scales_.fill(1.0);
}

// The running filter sees the noise scaled as the optimisation does.
void Smoother::predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) {
  const double scale = scales_[static_cast<int>(FactorKind::Motion)];
  if (scale == 1.0) {
    running().predict(J_rr, Q);
  } else {
    running().predict(J_rr, scale * Q);
  }
}

Eigen::VectorXd Smoother::update(const std::vector<LinearizedObservation>& obs) {
  std::vector<int> robot(static_cast<std::size_t>(k_));
  for (int i = 0; i < k_; ++i) robot[static_cast<std::size_t>(i)] = i;
  const Eigen::MatrixXd C_rr = running().marginal(robot);
  const double scale = scales_[static_cast<int>(FactorKind::Observation)];
  Eigen::VectorXd dx;
  if (scale == 1.0) {
    dx = running().update(obs);
  } else {
    std::vector<LinearizedObservation> scaled = obs;
    for (LinearizedObservation& o : scaled) o.C_eta *= scale;
    dx = running().update(scaled);
  }
  // Loop trigger: a feature row no update touched for loop_gap pose nodes,
  // re-observed with a large robot correction.
  bool stale = false;
  for (const LinearizedObservation& o : obs)
    for (int i : o.idx) {
      if (i < k_) continue;
      auto& seen = last_seen_[static_cast<std::size_t>(i)];
      if (key_ - seen >= o_.loop_gap) stale = true;
      seen = key_;
    }
  if (stale) {
    const Eigen::VectorXd dr = dx.head(k_);
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(C_rr);
    if (ldlt.info() == Eigen::Success && dr.dot(ldlt.solve(dr)) >= o_.loop_correction * o_.loop_correction)
      loop_ = true;
  }
  return dx;
}

int Smoother::augment(const StateAugmentation& aug) {
  const int first = running().augment(aug);
  last_seen_.resize(static_cast<std::size_t>(running().dim()), key_);
  return first;
}

void Smoother::remove(std::vector<int> idx) {
  running().remove(idx);
  std::sort(idx.begin(), idx.end());
  std::vector<std::int64_t> kept;
  for (std::size_t i = 0; i < last_seen_.size(); ++i)
    if (!std::binary_search(idx.begin(), idx.end(), static_cast<int>(i))) kept.push_back(last_seen_[i]);
  last_seen_ = std::move(kept);
}

void Smoother::save_state(StateWriter& out) const {
  running().save_state(out);  // the filter's own names (dims, store, …)
  Eigen::MatrixXd s(1, 8);
  s << k_, static_cast<double>(key_), static_cast<double>(last_optimised_), loop_ ? 1 : 0, forced_ ? 1 : 0,
      loop_closures_seen_, optimisations_, loop_triggers_;
  out.put("smoother", s);
  put_ints(out, "smoother_last_seen", last_seen_);
  out.put("smoother_noise_scales", Eigen::Map<const Eigen::MatrixXd>(scales_.data(), 1, kFactorKinds));
}

void Smoother::restore_state(const StateReader& in, int version) {
  const std::string context = "smoother restore_state";
  if (version != 1 && version != 2)
    throw std::invalid_argument(context + ": state version " + std::to_string(version) + " (reads 1 and 2)");
  const Eigen::MatrixXd& s = get_state(in, "smoother", 1, 8, context);
  const std::vector<double> v(s.data(), s.data() + s.size());
  for (double x : v)
    if (!(x >= 0 && x <= 1e15) || x != std::floor(x))
      throw std::invalid_argument(context + ": saved counters are not non-negative integers");
  std::vector<std::int64_t> last_seen = get_ints<std::int64_t>(in, "smoother_last_seen", 0, 1e15, context);
  KindScales scales = {1.0, 1.0, 1.0, 1.0, 1.0};  // version 1: before noise estimation
  if (version >= 2) {
    const Eigen::MatrixXd& saved = get_state(in, "smoother_noise_scales", 1, kFactorKinds, context);
    for (int k = 0; k < kFactorKinds; ++k) {
      if (!(saved(0, k) > 0.0) || !std::isfinite(saved(0, k)))
        throw std::invalid_argument(context + ": saved noise scales must be positive");
      scales[static_cast<std::size_t>(k)] = saved(0, k);
    }
  }
  // A fresh filter of the configured kind (each refuses the other's state).
  Filter filter = make_filter();
  Estimator& f = std::visit([](auto& x) -> Estimator& { return x; }, filter);
  f.restore_state(in, 1);  // throws before anything here changed
  if (static_cast<int>(last_seen.size()) != f.dim() || v[2] > v[1] || v[3] > 1 || v[4] > 1)
    throw std::invalid_argument(context + ": the saved bookkeeping does not match the saved filter");
  filter_ = std::move(filter);
  k_ = static_cast<int>(v[0]);
  key_ = static_cast<std::int64_t>(v[1]);
  last_optimised_ = static_cast<std::int64_t>(v[2]);
  loop_ = v[3] != 0;
  forced_ = v[4] != 0;
  loop_closures_seen_ = static_cast<int>(v[5]);
  optimisations_ = static_cast<int>(v[6]);
  loop_triggers_ = static_cast<int>(v[7]);
  last_seen_ = std::move(last_seen);
  scales_ = scales;
}

bool Smoother::relinearize(NonlinearProblem& problem, bool end_of_data) {
  if (end_of_data) {
    if (key_ == last_optimised_ || problem.num_pose_nodes() == 0) return false;
    optimise(problem);
    return true;
  }
  ++key_;
  const std::int64_t since = key_ - last_optimised_;
  const double due = std::max(static_cast<double>(o_.period), o_.growth * problem.num_pose_nodes());
  const bool periodic = o_.period > 0 && static_cast<double>(since) >= due;
  const bool loop = loop_ && since >= o_.loop_spacing;
  // The kernel closed a loop by map matching: it moved the variables to a
  // first guess and added coincidence factors; optimise at once.
  const bool closed = problem.loop_closures() != loop_closures_seen_;
  loop_closures_seen_ = problem.loop_closures();
  if (!(periodic || loop || forced_ || closed)) return false;
  if (loop && !periodic) ++loop_triggers_;
  optimise(problem);
  return true;
}

void Smoother::optimise(NonlinearProblem& problem) {
  const auto t0 = std::chrono::steady_clock::now();
  loop_ = false;
  forced_ = false;
  last_optimised_ = key_;
  ++optimisations_;
  const int n = problem.tangent_dim();
  const int state = problem.state_dim();
  if (state != running().dim())
    throw std::logic_error("smoother: the problem has " + std::to_string(state) + " state rows, the filter " +
                           std::to_string(running().dim()));
  report_ = {};
  report_.factors = problem.num_factors();
  report_.variables = n;
  Normal normal = build(problem, o_, scales_);
  report_.initial_cost = normal.cost;
  log_->debug("optimisation ", optimisations_ + 0, ": cost before by kind: prior ", normal.by_kind[0], ", motion ",
              normal.by_kind[1], ", observation ", normal.by_kind[2], ", linear ", normal.by_kind[3], ", coincidence ", normal.by_kind[4]);
  SpMat H = assemble(normal, n, kDamping);
  Eigen::SimplicialLDLT<SpMat, Eigen::Lower> ldlt;
  ldlt.analyzePattern(H);
  gauss_newton(problem, o_, scales_, normal, H, ldlt, report_);
  if (o_.noise_estimation) estimate_noise_scales(problem, o_, scales_, normal, H, ldlt, report_, *log_);
  report_.final_cost = normal.cost;
  report_.down_weighted = normal.down_weighted;

  // The running covariance: the marginal (H⁻¹)[S, S] of the state rows S =
  // [0, state) with the earlier pose nodes P marginalised, as the inverse of
  // the Schur complement H_SS − H_PSᵀ H_PP⁻¹ H_PS. H_PP is block tridiagonal
  // (each factor touches at most one earlier node, a motion factor two
  // consecutive ones), so its sparse LDLᵀ has no fill: O(N k²) per column.
  const auto t1 = std::chrono::steady_clock::now();
  const int np = n - state;
  Eigen::MatrixXd C = Eigen::MatrixXd(H.topLeftCorner(state, state)).selfadjointView<Eigen::Lower>();
  if (np > 0) {
    const SpMat H_PP = H.bottomRightCorner(np, np);
    const SpMat H_PS = H.bottomLeftCorner(np, state);
    Eigen::SimplicialLDLT<SpMat, Eigen::Lower> pp(H_PP);
    if (pp.info() != Eigen::Success) throw std::runtime_error("smoother: H_PP is not positive definite");
    constexpr int kBlock = 64;
    for (int c0 = 0; c0 < state; c0 += kBlock) {
      const int cols = std::min(kBlock, state - c0);
      const Eigen::MatrixXd X = pp.solve(Eigen::MatrixXd(H_PS.middleCols(c0, cols)));
      C.middleCols(c0, cols).noalias() -= H_PS.transpose() * X;
    }
  }
  C = inverse_spd(C);
  std::visit([&](auto& f) { f.assign(0.5 * (C + C.transpose())); }, filter_);
  const auto t2 = std::chrono::steady_clock::now();
  report_.seconds = std::chrono::duration<double>(t2 - t0).count();
  report_.seconds_marginal = std::chrono::duration<double>(t2 - t1).count();
  log_->debug("optimisation ", optimisations_, ": ", report_.iterations, " iterations, cost ", report_.initial_cost,
              " -> ", report_.final_cost, ", ", report_.factors, " factors, ", n, " variables, ",
              report_.down_weighted, " down-weighted, ", report_.seconds, " s (marginal ", report_.seconds_marginal,
              " s)");
}

}  // namespace mspace::smoother
