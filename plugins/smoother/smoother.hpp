// smoother.hpp — a re-linearising estimator over the kernel's nonlinear
// problem (mspace/problem.hpp): periodic Gauss–Newton over every pose node and
// M-space row, with a robust loss on the observations.
//
// Between optimisations it is the M-space EKF (T-RO 2007 §V-B, eqs. 23–32),
// run as the compressed EKF (mspace/cekf_filter.hpp, shared with the `cekf`
// plugin; `running_filter: cekf`, the default) or the full one
// (mspace/ekf_filter.hpp, shared with `ekf`; `running_filter: ekf`) — the same
// numbers to round-off: every ordinary step costs what that filter's step
// costs, and its covariance is what the kernel gates with. The kernel calls relinearize() at the end of every step that
// added a pose node; the smoother optimises when
//   - max(`period`, `growth` × all pose nodes) pose nodes have passed since
//     the last optimisation (so the optimisations' total cost stays about
//     1/growth full optimisations of the final problem), or
//   - an update re-observed a feature whose rows no update had touched for
//     `loop_gap` pose nodes and moved the robot by at least `loop_correction`
//     of its standard deviations (δx_rᵀ C_rr⁻¹ δx_r, C_rr before the update):
//     a loop closes, the correction is large and the EKF's linearisation of
//     everything since is the worst (at most every `loop_spacing` nodes), or
//   - the data ended (end_of_data) and anything happened since the last one,
//   - or the run asks for it (optimise_now(), tests).
// Each optimisation (optimise()):
//   1. Gauss–Newton with step halving: linearise every factor at the current
//      values, whiten with C⁻½, weight observations by the robust loss
//      (iteratively re-weighted least squares: Huber or Cauchy on the
//      Mahalanobis norm), solve H δ = −g with a sparse LDLᵀ (Eigen
//      SimplicialLDLT, AMD ordering, symbolic analysis once per optimisation),
//      retract everything through the problem (eq. 24 for features);
//   1b. with `noise_estimation`, re-estimate the motion and observation
//      kinds' noise scales from the residuals (variance_components.hpp) and
//      re-optimise, a few rounds; the scales stay for the next optimisation
//      and scale Q and C_η in the running filter;
//   2. the running covariance is re-set to the marginal of the final
//      information matrix H over the estimator's rows S = [0, dim()) (current
//      pose and every M-space row), the earlier pose nodes P marginalised:
//      the inverse of the Schur complement H_SS − H_PSᵀ H_PP⁻¹ H_PS. H_PP is
//      block tridiagonal (every factor touches at most one earlier node, a
//      motion factor two consecutive ones), so its sparse LDLᵀ has no fill.
//      Cost for n = dim() and N pose nodes of k rows: O(N k³) to factor
//      H_PP, O(n (N k² + nnz(H_PS))) for the n solves and products, O(n³)
//      for the dense inverse; memory O(n² + 64 N k).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include <variant>

#include "mspace/cekf_filter.hpp"
#include "mspace/ekf_filter.hpp"
#include "mspace/estimator.hpp"
#include "variance_components.hpp"

namespace mspace::smoother {

enum class Loss : std::uint8_t { None, Huber, Cauchy };
/// The filter between optimisations (same numbers, different cost).
enum class RunningFilter : std::uint8_t { Ekf, Cekf };

struct SmootherOptions {
  int period = 100;           ///< pose nodes between optimisations, at least (0: only on loops)
  double growth = 0.5;        ///< … and at least this fraction of all pose nodes (amortised O(N))
  int loop_spacing = 50;      ///< pose nodes since the last optimisation before a loop may trigger
  int loop_gap = 300;         ///< pose nodes unseen after which a re-observation may trigger
  /// … if that update moves the robot by ≥ this many σ (δx_rᵀ C_rr⁻¹ δx_r ≥ its square)
  double loop_correction = 2.0;
  int max_iterations = 5;     ///< Gauss–Newton iterations per optimisation
  double tolerance = 1e-4;    ///< stop when max |δ| (m, rad, M-space units) falls below
  double cost_tolerance = 1e-3;  ///< … or the cost falls by less than this fraction
  Loss loss = Loss::Huber;
  double loss_scale = 3.0;    ///< in Mahalanobis units (√χ²)
  int initial_capacity = 64;  ///< of the EKF storage (running_filter ekf)
  RunningFilter running_filter = RunningFilter::Cekf;
  int max_active = cekf::CekfFilter::kDefaultMaxActive;  ///< running_filter cekf
  int keep_steps = cekf::CekfFilter::kDefaultKeepSteps;  ///< running_filter cekf
  /// The running filter in observability-constrained mode (Huang, Mourikis &
  /// Roumeliotis, IJRR 2010; mspace/ekf_filter.hpp): its updates between
  /// optimisations gain no information along the unobservable directions U
  /// (a global rigid motion). The optimisation is unchanged: its marginal
  /// re-sets the covariance as before, and the kernel then gives U at the
  /// optimised values (Estimator::set_unobservable with every row). With
  /// problem.freeze_in_sensor_frame the covariance is then consistent
  /// (README, "The smoother's consistency on walls").
  bool observability_constrained = false;
  /// Estimate the motion and observation factors' noise scales from the
  /// residuals at each optimisation (variance components,
  /// variance_components.hpp) and use them from then on, in the optimisation
  /// and in the running filter.
  bool noise_estimation = false;
  int noise_iterations = 10;      ///< re-estimate / re-optimise rounds per optimisation, at most
  double noise_tolerance = 0.02;  ///< … until every variance factor is within this of 1
  int noise_probes = 32;          ///< random vectors of the trace estimate
};

/// What the last optimisation did (tests, logs).
struct OptimisationReport {
  int iterations = 0;
  double initial_cost = 0.0;  ///< ½ Σ ρ(rᵀC⁻¹r) before
  double final_cost = 0.0;    ///< after
  int factors = 0;
  int variables = 0;          ///< tangent dimension
  int down_weighted = 0;      ///< observations beyond the loss scale at the end
  int noise_rounds = 0;       ///< variance-component rounds (noise_estimation)
  double seconds = 0.0;
  double seconds_marginal = 0.0;  ///< of which the covariance recovery
};

/// Gauss–Newton over `problem` followed by the iterated variance-component
/// estimate of the motion and observation kinds (what optimise() does with
/// noise_estimation, without the running filter), starting from `scales`;
/// returns the estimated scales (the problem is left at the optimum).
KindScales optimise_with_noise_estimation(NonlinearProblem& problem, const SmootherOptions& options,
                                          KindScales scales, Logger& log);

class Smoother final : public Estimator {
 public:
  explicit Smoother(SmootherOptions options = {}, Logger* log = nullptr);

  void reset(const Eigen::MatrixXd& P_rr) override;
  int dim() const override { return running().dim(); }
  void predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) override;
  Eigen::VectorXd update(const std::vector<LinearizedObservation>& obs) override;
  int augment(const StateAugmentation& aug) override;
  Eigen::MatrixXd marginal(const std::vector<int>& idx) const override { return running().marginal(idx); }
  Eigen::MatrixXd cross(const std::vector<int>& rows, const std::vector<int>& cols) const override {
    return running().cross(rows, cols);
  }
  void remove(std::vector<int> idx) override;
  /// Passed to the running filter (used in observability-constrained mode).
  void set_unobservable(const Eigen::MatrixXd& U_r) override { running().set_unobservable(U_r); }

  /// Checkpoints: the running EKF (as `ekf` saves it) and the triggers'
  /// bookkeeping; the kernel saves the nonlinear problem beside it.
  bool has_state() const override { return true; }
  int state_version() const override { return 2; }  // 2: + noise scales
  void save_state(StateWriter& out) const override;
  void restore_state(const StateReader& in, int version) override;

  bool wants_problem() const override { return true; }
  bool relinearize(NonlinearProblem& problem, bool end_of_data) override;

  /// Runs one optimisation now (whatever the triggers say).
  void optimise(NonlinearProblem& problem);
  /// The next relinearize() optimises.
  void optimise_now() { forced_ = true; }

  int optimisations() const { return optimisations_; }
  int loop_triggers() const { return loop_triggers_; }
  const OptimisationReport& last_report() const { return report_; }
  /// The multipliers of each factor kind's configured covariance in use
  /// (by FactorKind; all 1 unless noise_estimation).
  const KindScales& noise_scales() const { return scales_; }
  /// The running filter's whole covariance (tests, diagnostics).
  Eigen::MatrixXd covariance() const;

 private:
  SmootherOptions o_;
  Logger* log_;
  using Filter = std::variant<ekf::EkfFilter, cekf::CekfFilter>;
  /// A fresh running filter of the configured kind.
  Filter make_filter() const;
  const Estimator& running() const;
  Estimator& running();

  Filter filter_;
  int k_ = 0;
  std::int64_t key_ = 0;             ///< pose nodes seen by relinearize()
  std::int64_t last_optimised_ = 0;  ///< key_ at the last optimisation
  std::vector<std::int64_t> last_seen_;  ///< by state row: key_ of its last update
  bool loop_ = false;
  bool forced_ = false;
  int loop_closures_seen_ = 0;  ///< NonlinearProblem::loop_closures() at the last relinearize()
  int optimisations_ = 0;
  int loop_triggers_ = 0;
  OptimisationReport report_;
  KindScales scales_ = {1.0, 1.0, 1.0, 1.0, 1.0};
};

}  // namespace mspace::smoother
