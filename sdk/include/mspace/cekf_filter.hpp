// mspace/cekf_filter.hpp — the compressed extended Kalman filter (Guivant &
// Nebot 2001) over the M-space state of T-RO 2007 §V-B, in the SDK library
// because two estimator plugins use it: `cekf` and the `smoother` (its running
// covariance between re-optimisations, re-set by assign()).
//
// Same interface, same numbers (to round-off) as the full EKF of plugins/ekf,
// but an update costs O(n_A² m + n_B n0) instead of O(N² m): observations of
// one step touch the robot and a few features, so the work is confined to a
// small "active" part of the state, and the rest of the covariance is brought
// up to date only now and then, in a "global update".
//
// Partition and invariants. The state rows are split into an active set A
// (the robot and recently touched rows) and a passive set B. The filter keeps
//   P_AA                 dense and exact (n_A × n_A),
//   P⁰_BB                the passive block as it was at the last global update,
//   G = P⁰_{a0,B}        the basis: rows a0 of that covariance (the rows that
//                        were active then or have been activated since) against
//                        the passive columns (n0 × n_B),
//   Φ (n_A × n0), Ψ (n0 × n0, symmetric)
// such that at all times
//   P_AB = Φ G,          P_BB = P⁰_BB − Gᵀ Ψ G.                          (I)
// An update touching only A changes P_AA as the EKF does (eqs. 28–32) and
// folds its effect on B into Φ and Ψ; the passive part of δx_state is
// −Gᵀ Φᵀ Hᵀ S⁻¹ η, O(n_B n0). A row of B that an update or an augmentation
// needs is first "activated": moved to A with the basis growing by one row.
// When the basis or A grow beyond `max_active`, the global update writes
// P_AB and P_BB from (I) and re-partitions: A = robot + the rows touched within
// the last `keep_steps` updates (at most max_active/2 rows, the most recent),
// Φ = I, Ψ = 0; it costs O(n_B² n0). marginal() and cross() evaluate (I) for
// passive rows without changing the representation (marginal() remembers the
// P_BB corrections it computed, see memo_, so the kernel's gating, which asks
// about the same features at every reading, stays cheap).
//
// Churn (issue 13). A global update costs O(n_B² n0) however few updates
// came before it; the EKF pays O(N² m) per update. When the robot moves fast
// every update brings new rows, the basis fills after a few updates and the
// global updates cost more than the EKF's updates of the same interval would
// have. With `churn_fallback` (the default) the filter compares the two at
// every global update (leading terms, see global_update_cost()) and keeps a
// running mean r̄ of their ratio; when r̄ > 1 it makes every row active:
// A = all, no basis, and each update is the EKF's own (eqs. 28–32 on the
// whole covariance). Meanwhile it counts the basis and A that a compressed
// partition would have had (the rows touched since a virtual global update)
// and compresses again as soon as the mean with that virtual global update's
// ratio falls below kReturnShare (see flush_if_needed()). Both switches are
// global updates, exact as every other: the numbers stay the EKF's.
// docs/performance.md has the measurements.
//
// Defaults: max_active = 96 and keep_steps = 8 gave the shortest Victoria Park
// run (config/victoria_park.yaml) and are near the best of BM_CekfMaxActive in
// tests/bench/bench_cekf.cpp.
//
// Storage. Every state row owns a "slot" in the square P⁰ store (its row and
// column there) from the moment it is created; slots of removed rows are
// dropped at the next global update. Entries of P⁰ involving a row that is
// currently active are stale and never read. G is stored basis × slots: the
// basis coordinates of one slot are contiguous, because the gating queries,
// activations and the memo read G one slot at a time (thousands of times
// per global update), while a row is appended only when a row is activated.
//
// Observability-constrained mode (optional; Huang, Mourikis & Roumeliotis,
// IJRR 2010), as in plugins/ekf (see mspace/ekf_filter.hpp): the unobservable
// directions U (dim() × u) are a plain per-row matrix, independent of the
// partition into A and B, so they are carried beside it (predict() maps the
// robot rows, augment() appends J U[idx], remove() drops rows) and every
// observation's Jacobian is projected (J ← J − J U_i (U_iᵀ U_i)⁺ U_iᵀ) before
// the update sees it. Off by default; off, or before set_unobservable(), the
// filter is the plain CEKF bit for bit.
//
// Errors: as plugins/ekf (see mspace/ekf_filter.hpp), with "cekf" in place of "ekf",
// e.g. "cekf update: observation 2: J row 1 is not finite"; all thrown before
// the covariance changes. An update whose S is not positive definite may
// have activated rows before it throws: that changes the representation, not
// the covariance.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <vector>

#include "mspace/estimator.hpp"
#include "mspace/estimator_support.hpp"

namespace mspace::cekf {

class CekfFilter final : public Estimator {
 public:
  static constexpr int kDefaultMaxActive = 96;
  static constexpr int kDefaultKeepSteps = 8;
  /// Back to the compressed form when a virtual global update would have cost
  /// less than this share of the EKF's updates (below 1: hysteresis).
  static constexpr double kReturnShare = 0.8;
  /// Cost ratios (global update / EKF updates) are capped at this, so that an
  /// interval of augmentations alone (the EKF pays almost nothing) weighs no
  /// more than one where compression clearly lost.
  static constexpr double kMaxCostRatio = 2.0;

  /// `max_active` (≥ 1): active rows or basis rows that trigger a global update.
  /// `keep_steps` (≥ 0): a row touched within this many updates stays active
  /// across a global update. `observability_constrained`: the mode described above.
  /// `churn_fallback`: EKF updates while the active set churns (see "Churn" above).
  explicit CekfFilter(int max_active = kDefaultMaxActive, int keep_steps = kDefaultKeepSteps,
                      bool observability_constrained = false, bool churn_fallback = true);

  void reset(const Eigen::MatrixXd& P_rr) override;
  int dim() const override { return n_; }
  void predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) override;
  Eigen::VectorXd update(const std::vector<LinearizedObservation>& obs) override;
  int augment(const StateAugmentation& aug) override;
  Eigen::MatrixXd marginal(const std::vector<int>& idx) const override;
  Eigen::MatrixXd cross(const std::vector<int>& rows, const std::vector<int>& cols) const override;
  void remove(std::vector<int> idx) override;
  /// Observability-constrained mode only (ignored otherwise): replaces the
  /// robot's rows of U by U_r (robot_dim() × u). Feature rows keep their
  /// propagated values when u is unchanged and start at zero otherwise.
  void set_unobservable(const Eigen::MatrixXd& U_r) override;

  /// Checkpoints: the partition (slots, active positions, touch times), the
  /// used blocks of P_AA, Φ, Ψ, Gᵀ and P⁰ with their storage capacities, the
  /// memo of passive quadratics and U: a restored filter computes bit for bit
  /// as the saved one would have.
  bool has_state() const override { return true; }
  void save_state(StateWriter& out) const override;
  void restore_state(const StateReader& in, int version) override;

  /// The global update: brings P_AB and P_BB up to date and re-partitions.
  void flush();
  /// Replaces the whole covariance by C (dim() × dim(), symmetric, read from
  /// its lower triangle), e.g. the marginal of an optimised information
  /// matrix (the smoother): C is written into P⁰ and the filter re-partitions
  /// as a global update does (A = robot and recent rows, Φ = I, Ψ = 0).
  /// O(dim()²). The state dimension, the touch times and U stay as they are.
  void assign(const Eigen::MatrixXd& C);
  /// The whole covariance C_state (dim() × dim()), for tests and diagnostics.
  Eigen::MatrixXd covariance() const;

  int robot_dim() const { return k_; }
  /// Rows in the active set A.
  int active_dim() const { return na_; }
  /// Rows of the basis G.
  int basis_dim() const { return n0_; }
  /// Whether state row i is in A.
  bool is_active(int i) const { return active_.at(static_cast<std::size_t>(i)) >= 0; }
  /// Global updates done since reset() (flush() calls included).
  std::int64_t global_updates() const { return global_updates_; }
  /// Whether every row is active because the active set churned (see "Churn").
  bool all_active() const { return all_active_; }
  /// Times since reset() the filter made every row active because of churn.
  std::int64_t fallbacks() const { return fallbacks_; }
  bool observability_constrained() const { return constrained_; }
  /// The unobservable directions U (dim() × u) in observability-constrained
  /// mode; 0 × 0 otherwise.
  const Eigen::MatrixXd& unobservable() const { return U_.matrix(); }

 private:
  /// eqs. 28–32 for the given (possibly constrained) observations.
  Eigen::VectorXd apply_update(const std::vector<LinearizedObservation>& obs);
  /// P_AA(a, b) from the lower triangle (active positions).
  double paa(int a, int b) const { return a >= b ? paa_(a, b) : paa_(b, a); }
  /// P⁰(s, t) from the lower triangle (slots).
  double p0(int s, int t) const { return s >= t ? p0_(s, t) : p0_(t, s); }
  /// P_AA[:, pos] (n_A × pos.size()).
  Eigen::MatrixXd active_columns(const std::vector<int>& pos) const;
  /// Φ_Iᵀ for the active positions pos (n0 × pos.size()).
  Eigen::MatrixXd phi_rows_transposed(const std::vector<int>& pos) const;
  /// Writes column s of the P⁰ store (all ns_ slots) into `out`.
  void p0_column(int s, Eigen::Ref<Eigen::VectorXd, 0, Eigen::InnerStride<>> out) const;
  /// The rows or columns of a marginal or cross request, split by set:
  /// output positions with their active position (A) or slot (B).
  struct Split {
    std::vector<Eigen::Index> active_at, passive_at;
    std::vector<int> active_pos, passive_slot;
  };
  Split split(const std::vector<int>& idx) const;
  struct MemoEntry;
  /// The memo entry of the passive slots J with g = G_{:,J}, made if not there.
  const MemoEntry& passive_memo(const std::vector<int>& slots, const Eigen::MatrixXd& g) const;
  /// P⁰_JJ for the slots J.
  Eigen::MatrixXd p0_block(const std::vector<int>& slots) const;
  /// Brings the memo up to date with Ψ ← Ψ + V Vᵀ and drops the blocks not asked about.
  void refresh_memo(const Eigen::MatrixXd& V);
  /// Ψ g (n0 × g.cols()).
  Eigen::MatrixXd psi_times(const Eigen::MatrixXd& g) const;
  /// Copies the lower triangle of Ψ into the upper one.
  void mirror_psi();
  /// C[rows, cols] when all of them are active: entries of P_AA.
  Eigen::MatrixXd active_block(const std::vector<int>& rows, const std::vector<int>& cols) const;
  /// C[rows, cols] with passive rows among them, from (I); `symmetric` (rows
  /// and cols the same, as from marginal()) lets the memo serve the P_BB part.
  Eigen::MatrixXd mixed_block(const std::vector<int>& rows, const std::vector<int>& cols, bool symmetric) const;
  /// Active positions of the state rows idx (all of them active).
  std::vector<int> positions(const std::vector<int>& idx) const;

  void activate(const std::vector<int>& rows);
  void touch(const std::vector<int>& rows);
  void flush_if_needed();
  /// The global update; the new A is every row (all_rows) or choose_active().
  void global_update(bool all_rows);
  /// Its end, once P⁰ holds every row's covariance: the new partition (every
  /// row, or choose_active()) and a new interval.
  void finish_global_update(bool all_rows);
  /// Multiply–adds of a global update with the given basis and active sizes.
  double global_update_cost(int basis, int active) const;
  /// Multiply–adds the plain EKF spent on this interval's updates.
  double ekf_interval_cost() const;
  /// global_update_cost(basis, active) / ekf_interval_cost(), in [0, kMaxCostRatio].
  double cost_ratio(int basis, int active) const;
  /// A new (real or, all active, virtual) interval between global updates.
  void start_interval();
  void refresh_passive_block();
  void write_active_rows_into_store();
  void drop_dead_slots();
  std::vector<int> choose_active() const;
  void repartition(const std::vector<int>& active_rows);
  void compact_active(const std::vector<int>& keep);

  void reserve_active(int rows);
  void reserve_basis(int cols);
  void reserve_slots(int slots);
  void reserve_store();

  int max_active_;
  int keep_steps_;
  bool constrained_;                             ///< observability-constrained mode
  bool churn_fallback_;                          ///< see "Churn"
  estimator_support::UnobservableDirections U_;  ///< dim() × u (constrained mode only)

  int k_ = 0;   ///< robot pose dimension (rows 0..k−1, always active at positions 0..k−1)
  int n_ = 0;   ///< state dimension
  int na_ = 0;  ///< |A|
  int n0_ = 0;  ///< basis rows
  int ns_ = 0;  ///< slots in use (live or dead)

  // Per state row.
  std::vector<int> slot_;              ///< its slot in the P⁰ store
  std::vector<int> active_;            ///< its position in A, −1 when passive
  std::vector<std::int64_t> touched_;  ///< value of updates_ when last touched
  std::vector<std::int64_t> seen_in_;  ///< interval_ when last touched or created

  // Churn (see above).
  bool all_active_ = false;         ///< A = every row, no basis
  std::int64_t interval_ = 0;       ///< number of the interval since the last (virtual) global update
  std::int64_t interval_rows_ = 0;  ///< measurement rows of the updates in it
  int virtual_basis_ = 0;           ///< all active: the basis a compressed partition would have
  int virtual_active_ = 0;          ///< all active: the A it would have
  std::int64_t fallbacks_ = 0;
  double churn_ratio_ = -1.0;       ///< running mean of cost_ratio() at global updates (< 0: none yet)

  std::vector<char> slot_live_;  ///< per slot: still owned by a state row
  int dead_slots_ = 0;

  Eigen::MatrixXd paa_;  ///< capacity²; lower triangle of [0,na_)² is P_AA
  Eigen::MatrixXd phi_;  ///< capacity; [0,na_) × [0,n0_) is Φ
  Eigen::MatrixXd psi_;  ///< capacity²; [0,n0_)² is Ψ (both triangles)
  Eigen::MatrixXd g_;    ///< capacity; [0,n0_) × [0,ns_) is G (columns of active slots stale)
  Eigen::MatrixXd p0_;   ///< capacity²; lower triangle of [0,ns_)² is P⁰ (passive pairs valid)

  /// Memo of P⁰_JJ and G_Jᵀ Ψ G_J for the passive blocks J (slot lists) that marginal()
  /// was asked about: the kernel's gating asks for the same features' marginals
  /// at every reading, and update() keeps the memo exact at O(m n0) per column.
  /// It makes the const marginal() modify the object: not thread-safe.
  struct MemoEntry {
    Eigen::MatrixXd quadratic;  ///< G_Jᵀ Ψ G_J
    Eigen::MatrixXd p0_block;   ///< P⁰_JJ (fixed until the next global update, which empties the memo)
    bool asked = false;  ///< asked about since the last update
  };
  mutable std::map<std::vector<int>, MemoEntry> memo_;

  std::int64_t updates_ = 0;
  std::int64_t global_updates_ = 0;
};

}  // namespace mspace::cekf
