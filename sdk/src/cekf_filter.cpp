// cekf_filter.cpp — the compressed EKF (Guivant & Nebot 2001) on the M-space
// state of T-RO 2007 §V-B, eqs. 23–32. See cekf_filter.hpp for the partition
// into active rows A and passive rows B and the invariants
//   P_AB = Φ G,   P_BB = P⁰_BB − Gᵀ Ψ G.                                  (I)
#include "mspace/cekf_filter.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

#include "mspace/dense_product.hpp"
#include "mspace/estimator_support.hpp"

namespace mspace::cekf {

namespace {

using Eigen::Index;
namespace support = mspace::estimator_support;

constexpr Index kInitialCapacity = 64;

/// Makes `m` at least rows × cols, doubling each dimension that is too small;
/// keeps the top-left used_rows × used_cols block, new entries are zero.
void grow(Eigen::MatrixXd& m, Index rows, Index cols, Index used_rows, Index used_cols) {
  if (rows <= m.rows() && cols <= m.cols()) return;
  const Index new_rows = rows <= m.rows() ? m.rows() : std::max(rows, 2 * m.rows());
  const Index new_cols = cols <= m.cols() ? m.cols() : std::max(cols, 2 * m.cols());
  Eigen::MatrixXd bigger = Eigen::MatrixXd::Zero(new_rows, new_cols);
  bigger.topLeftCorner(used_rows, used_cols) = m.topLeftCorner(used_rows, used_cols);
  m.swap(bigger);
}

/// Keeps the entries (keep[a], keep[b]) of the lower triangle of `m` at (a, b),
/// keep ascending. Column by column in increasing order: a destination never
/// comes after its source, so every entry is read before it is overwritten.
void compact_lower(Eigen::MatrixXd& m, const std::vector<int>& keep) {
  const auto kept = static_cast<int>(keep.size());
  for (int b = 0; b < kept; ++b) {
    for (int a = b; a < kept; ++a) m(a, b) = m(keep[a], keep[b]);
  }
}

}  // namespace

CekfFilter::CekfFilter(int max_active, int keep_steps, bool observability_constrained, bool churn_fallback)
    : max_active_(max_active),
      keep_steps_(keep_steps),
      constrained_(observability_constrained),
      churn_fallback_(churn_fallback) {
  if (max_active < 1) {
    throw std::invalid_argument("cekf: max_active must be at least 1, got " + std::to_string(max_active));
  }
  if (keep_steps < 0) {
    throw std::invalid_argument("cekf: keep_steps must be at least 0, got " + std::to_string(keep_steps));
  }
}

void CekfFilter::reset(const Eigen::MatrixXd& P_rr) {
  support::validate_reset(P_rr, "cekf reset");
  k_ = static_cast<int>(P_rr.rows());
  n_ = na_ = ns_ = k_;
  n0_ = 0;  // nothing passive yet
  slot_.resize(static_cast<std::size_t>(k_));
  std::iota(slot_.begin(), slot_.end(), 0);
  active_ = slot_;
  touched_.assign(static_cast<std::size_t>(k_), 0);
  seen_in_.assign(static_cast<std::size_t>(k_), 0);
  all_active_ = false;
  interval_ = 0;
  interval_rows_ = 0;
  virtual_basis_ = virtual_active_ = 0;
  fallbacks_ = 0;
  churn_ratio_ = -1.0;
  slot_live_.assign(static_cast<std::size_t>(k_), 1);
  dead_slots_ = 0;
  updates_ = 0;
  global_updates_ = 0;
  memo_.clear();

  const Index cap = std::max<Index>(k_, kInitialCapacity);
  paa_ = Eigen::MatrixXd::Zero(cap, cap);
  phi_ = Eigen::MatrixXd::Zero(cap, kInitialCapacity);
  psi_ = Eigen::MatrixXd::Zero(kInitialCapacity, kInitialCapacity);
  g_ = Eigen::MatrixXd::Zero(kInitialCapacity, cap);
  p0_ = Eigen::MatrixXd::Zero(cap, cap);
  paa_.topLeftCorner(k_, k_).triangularView<Eigen::Lower>() = P_rr;
  if (constrained_) U_.reset(k_);
}

void CekfFilter::set_unobservable(const Eigen::MatrixXd& U_r) {
  if (constrained_) U_.set(U_r, "cekf set_unobservable");
}

void CekfFilter::predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) {
  support::validate_prediction(J_rr, Q, k_, "cekf predict");

  // eq. 26: C_rr ← J_rr C_rr J_rrᵀ + Q.
  const Eigen::MatrixXd C_rr = paa_.topLeftCorner(k_, k_).selfadjointView<Eigen::Lower>();
  paa_.topLeftCorner(k_, k_).triangularView<Eigen::Lower>() = J_rr * C_rr * J_rr.transpose() + Q;

  // eq. 27 inside A: the lower triangle holds C_{A∖r, r}, which becomes C_{A∖r, r} J_rrᵀ.
  // Both products below have k columns or rows and run at every step (73 000
  // times on Victoria Park, over ~100 rows or columns): plain loops on raw
  // pointers with J_rr copied row-major (column c of the result is Σ_l
  // J_rr(c, l) times column l), because Eigen's products of these shapes and
  // its dynamic-size indexing cost several times the arithmetic. The sums
  // are formed in the order l = 0, 1, … as with the column expressions before.
  const Index rows = na_ - k_;
  thread_local std::vector<double> c_ar, J_rows, column;  // C_{A∖r, r} (rows × k, column-major), J_rr row-major
  c_ar.resize(static_cast<std::size_t>(rows * k_));
  J_rows.resize(static_cast<std::size_t>(k_ * k_));
  column.resize(static_cast<std::size_t>(k_));
  double* J = J_rows.data();
  for (Index l = 0; l < k_; ++l) {
    const double* from = paa_.data() + l * paa_.outerStride() + k_;
    std::copy(from, from + rows, c_ar.data() + l * rows);
  }
  for (Index c = 0; c < k_; ++c)
    for (Index l = 0; l < k_; ++l) J[c * k_ + l] = J_rr(c, l);
  for (Index c = 0; c < k_; ++c) {
    double* out = paa_.data() + c * paa_.outerStride() + k_;
    const double* j = J + c * k_;
    const double* first = c_ar.data();
    for (Index i = 0; i < rows; ++i) out[i] = j[0] * first[i];
    for (Index l = 1; l < k_; ++l) {
      const double* col = c_ar.data() + l * rows;
      for (Index i = 0; i < rows; ++i) out[i] += j[l] * col[i];
    }
  }

  // eq. 27 against B: C_rB = Φ_r G becomes J_rr Φ_r G, so Φ_r ← J_rr Φ_r
  // (column by column: the k entries of a column of Φ_r are contiguous).
  double* kept = column.data();
  for (Index b = 0; b < n0_; ++b) {
    double* phi_column = phi_.data() + b * phi_.outerStride();
    for (Index l = 0; l < k_; ++l) kept[l] = phi_column[l];
    for (Index c = 0; c < k_; ++c) {
      double sum = 0.0;
      for (Index l = 0; l < k_; ++l) sum += J[c * k_ + l] * kept[l];
      phi_column[c] = sum;
    }
  }

  // The unobservable directions move with the robot block: U_r ← J_rr U_r.
  if (constrained_) U_.predict(J_rr);
}

// All observations of the step as one measurement η ≈ H δx[I] (eqs. 28–32),
// I ⊂ A after activation. With S = H P_AA Hᵀ + C_η = L Lᵀ,
//   W = P_AA Hᵀ L⁻ᵀ (n_A × m),   V = (H Φ)ᵀ L⁻ᵀ (n0 × m),   w = L⁻¹ η:
//   K_A = W L⁻¹ and K_B = P_BA Hᵀ S⁻¹ = Gᵀ Φᵀ Hᵀ S⁻¹ = Gᵀ V L⁻¹, so (eq. 31)
//     δx_A = −W w,   δx_B = −Gᵀ (V w)
//   and (eq. 32, δP = −K S Kᵀ)
//     P_AA ← P_AA − W Wᵀ
//     P_AB ← P_AB − K_A H P_AB = (Φ − W Vᵀ) G             ⇒ Φ ← Φ − W Vᵀ
//     P_BB ← P_BB − Gᵀ Φᵀ Hᵀ S⁻¹ H Φ G = P⁰_BB − Gᵀ (Ψ + V Vᵀ) G  ⇒ Ψ ← Ψ + V Vᵀ.
// In constrained mode every H is first made to annihilate U (see ekf_filter.hpp).
Eigen::VectorXd CekfFilter::update(const std::vector<LinearizedObservation>& obs) {
  if (constrained_ && U_.directions() > 0) return apply_update(U_.constrain(obs, "cekf update"));
  return apply_update(obs);
}

Eigen::VectorXd CekfFilter::apply_update(const std::vector<LinearizedObservation>& obs) {
  const support::StackedObservation s = support::stack_observations(obs, n_, "cekf update");
  Eigen::VectorXd dx = Eigen::VectorXd::Zero(n_);
  if (s.eta.size() == 0) return dx;

  activate(s.union_idx);
  const std::vector<int> pos = positions(s.union_idx);
  Eigen::MatrixXd W = Eigen::MatrixXd::Zero(na_, s.J.rows());  // P_AA Hᵀ
  add_product(W, 1.0, active_columns(pos), s.J);

  // eq. 29: S = H P_II Hᵀ + C_η.
  const Eigen::MatrixXd S = s.J * W(pos, Eigen::all) + s.C_eta;
  const Eigen::LLT<Eigen::MatrixXd> llt(S);
  if (llt.info() != Eigen::Success) {
    throw std::runtime_error("cekf update: S (" + support::size_text(S.rows(), S.cols()) +
                             ") is not positive definite");
  }
  Eigen::MatrixXd V = Eigen::MatrixXd::Zero(n0_, s.J.rows());  // (H Φ)ᵀ = Φ_Iᵀ Jᵀ
  add_product(V, 1.0, phi_rows_transposed(pos), s.J);
  // W ← W L⁻ᵀ and V ← V L⁻ᵀ (L⁻ᵀ = U⁻¹ with U = Lᵀ, the factor's upper
  // triangle). Before the first global update there is no passive basis
  // (n0 = 0) and V is empty: solve_upper_on_right then does nothing.
  const Eigen::MatrixXd U = llt.matrixU();
  solve_upper_on_right(W, U);
  solve_upper_on_right(V, U);
  const Eigen::VectorXd whitened = llt.matrixL().solve(s.eta);

  // eq. 31 (before Φ changes: δx_B uses the Φ of the prior).
  const Eigen::VectorXd dx_active = -W * whitened;
  const Eigen::VectorXd basis_step = V * whitened;
  Eigen::VectorXd dx_slots(ns_);  // −Gᵀ (V w): one dot product of n0 numbers per slot, at every update
  transposed_product(dx_slots, -1.0, g_.topLeftCorner(n0_, ns_), basis_step);
  for (int i = 0; i < n_; ++i) {
    const auto u = static_cast<std::size_t>(i);
    dx[i] = active_[u] >= 0 ? dx_active[active_[u]] : dx_slots[slot_[u]];
  }

  // eq. 32 on the compressed representation.
  add_product(paa_.topLeftCorner(na_, na_), -1.0, W, W, ProductPart::lower);
  add_product(phi_.topLeftCorner(na_, n0_), -1.0, W, V);
  add_product(psi_.topLeftCorner(n0_, n0_), 1.0, V, V, ProductPart::lower);
  mirror_psi();
  refresh_memo(V);

  ++updates_;
  interval_rows_ += s.eta.size();
  touch(s.union_idx);
  flush_if_needed();
  return dx;
}

// δx_new = J δx[idx] + w with idx ⊂ A after activation:
//   C_new,A = J P_idx,A,  C_new,new = J P_idx,idx Jᵀ + C_new,
//   C_new,B = J P_idx,B = (J Φ_idx) G  ⇒ the new rows of Φ are J Φ_idx.
int CekfFilter::augment(const StateAugmentation& aug) {
  support::validate_augmentation(aug, n_, "cekf augment");
  const auto added = static_cast<int>(aug.C_new.rows());
  const int first = n_;
  if (added == 0) return first;

  activate(aug.idx);
  const std::vector<int> pos = positions(aug.idx);
  const Eigen::MatrixXd C_new_A = aug.J * active_columns(pos).transpose();
  const Eigen::MatrixXd C_new_new = C_new_A(Eigen::all, pos) * aug.J.transpose() + aug.C_new;
  const Eigen::MatrixXd phi_new = aug.J * phi_(pos, Eigen::seqN(0, n0_));

  reserve_active(na_ + added);
  reserve_slots(ns_ + added);
  paa_.block(na_, 0, added, na_) = C_new_A;
  paa_.block(na_, na_, added, added).triangularView<Eigen::Lower>() = C_new_new;
  phi_.block(na_, 0, added, n0_) = phi_new;
  if (constrained_) U_.augment(aug);
  for (int r = 0; r < added; ++r) {
    slot_.push_back(ns_ + r);
    active_.push_back(na_ + r);
    touched_.push_back(updates_);
    seen_in_.push_back(interval_);  // active from birth: never in the basis
    slot_live_.push_back(1);
  }
  if (all_active_) virtual_active_ += added;
  n_ += added;
  na_ += added;
  ns_ += added;
  touch(aug.idx);
  flush_if_needed();
  return first;
}

Eigen::MatrixXd CekfFilter::marginal(const std::vector<int>& idx) const { return cross(idx, idx); }

Eigen::MatrixXd CekfFilter::cross(const std::vector<int>& rows, const std::vector<int>& cols) const {
  support::require_indices(rows, n_, "cekf cross: rows", false);
  if (&rows != &cols) support::require_indices(cols, n_, "cekf cross: cols", false);
  const auto is_active = [this](int i) { return active_[static_cast<std::size_t>(i)] >= 0; };
  if (std::all_of(rows.begin(), rows.end(), is_active) && std::all_of(cols.begin(), cols.end(), is_active)) {
    return active_block(rows, cols);  // the common case
  }
  return mixed_block(rows, cols, &rows == &cols);
}

Eigen::MatrixXd CekfFilter::active_block(const std::vector<int>& rows, const std::vector<int>& cols) const {
  Eigen::MatrixXd out(static_cast<Index>(rows.size()), static_cast<Index>(cols.size()));
  for (std::size_t j = 0; j < cols.size(); ++j) {
    const int b = active_[static_cast<std::size_t>(cols[j])];
    for (std::size_t i = 0; i < rows.size(); ++i)
      out(static_cast<Index>(i), static_cast<Index>(j)) = paa(active_[static_cast<std::size_t>(rows[i])], b);
  }
  return out;
}

// Entries from (I): A×A from P_AA; with the basis coordinates Φ_a of an active
// row a and G_j of a passive row j, P_aj = Φ_a G_j and P_ij = P⁰_ij − G_iᵀ Ψ G_j.
Eigen::MatrixXd CekfFilter::mixed_block(const std::vector<int>& rows, const std::vector<int>& cols,
                                        bool symmetric) const {
  if (symmetric) {
    // The kernel's gating calls this (the robot and one passive feature) for
    // every feature in range at every reading, so it allocates nothing but its
    // result: the per-row bookkeeping lives in buffers kept between calls, the
    // active rows' Φ is copied once (its rows are a column of the storage apart),
    // and the P_aj = Φ_a G_j are dot products with G's column of slot j read
    // in place; P⁰_JJ and G_Jᵀ Ψ G_J come from the memo.
    const std::vector<int>& idx = rows;
    const auto n = static_cast<Index>(idx.size());
    thread_local std::vector<int> position, passive_slots;  // per output row: active position (−1: passive)
    thread_local std::vector<Index> passive_index;         // … its place among the passive rows
    thread_local std::vector<double> phi_active;           // Φ_a of the active rows, n0 numbers each
    position.resize(static_cast<std::size_t>(n));
    passive_index.resize(static_cast<std::size_t>(n));
    passive_slots.clear();
    Index active_rows = 0;
    for (Index i = 0; i < n; ++i) {
      const auto row = static_cast<std::size_t>(idx[static_cast<std::size_t>(i)]);
      position[static_cast<std::size_t>(i)] = active_[row];
      if (active_[row] >= 0) {
        passive_index[static_cast<std::size_t>(i)] = active_rows++;  // here: its place among the active rows
      } else {
        passive_index[static_cast<std::size_t>(i)] = static_cast<Index>(passive_slots.size());
        passive_slots.push_back(slot_[row]);
      }
    }
    Eigen::MatrixXd out(n, n);
    phi_active.resize(static_cast<std::size_t>(active_rows * n0_));
    for (Index i = 0; i < n; ++i) {
      const int a = position[static_cast<std::size_t>(i)];
      if (a < 0) continue;
      double* to = phi_active.data() + passive_index[static_cast<std::size_t>(i)] * n0_;
      for (Index b = 0; b < n0_; ++b) to[b] = phi_(a, b);
    }
    // P_aj = Φ_a G_j for every active row a and passive slot j: per slot, the
    // dot products of its column of G (read in place) with the copied Φ_a
    // (an n0 × active_rows matrix): one transposed_product per passive row.
    thread_local std::vector<double> phi_g;  // [passive place * active_rows + active place]
    const auto passive_rows = static_cast<Index>(passive_slots.size());
    phi_g.resize(static_cast<std::size_t>(passive_rows * active_rows));
    if (active_rows > 0) {
      const Eigen::Map<const Eigen::MatrixXd> phi_a(phi_active.data(), n0_, active_rows);
      for (Index p = 0; p < passive_rows; ++p) {
        transposed_product(Eigen::Map<Eigen::VectorXd>(phi_g.data() + p * active_rows, active_rows), 1.0, phi_a,
                           g_.col(passive_slots[static_cast<std::size_t>(p)]).head(n0_));
      }
    }
    const MemoEntry* memo = nullptr;
    if (const auto found = memo_.find(passive_slots); found != memo_.end()) {
      found->second.asked = true;
      memo = &found->second;
    } else {
      memo = &passive_memo(passive_slots, g_(Eigen::seqN(0, n0_), passive_slots));
    }
    for (Index j = 0; j < n; ++j) {
      const int b = position[static_cast<std::size_t>(j)];
      const Index pj = passive_index[static_cast<std::size_t>(j)];
      for (Index i = j; i < n; ++i) {
        const int a = position[static_cast<std::size_t>(i)];
        const Index pi = passive_index[static_cast<std::size_t>(i)];
        double value = 0.0;
        if (a >= 0 && b >= 0) {
          value = paa(a, b);
        } else if (a < 0 && b < 0) {
          value = memo->p0_block(pi, pj) - memo->quadratic(pi, pj);
        } else {  // one active row, one passive: Φ_a G_j from above
          const Index active_place = a >= 0 ? pi : pj;
          const Index passive_place = a >= 0 ? pj : pi;
          value = phi_g[static_cast<std::size_t>(passive_place * active_rows + active_place)];
        }
        out(i, j) = value;
        out(j, i) = value;
      }
    }
    return out;
  }
  // The general case (cross(): rows and columns differ).
  Eigen::MatrixXd out(static_cast<Index>(rows.size()), static_cast<Index>(cols.size()));
  const Split r = split(rows);
  const Split c = split(cols);
  const auto basis = Eigen::seqN(0, n0_);
  const Eigen::MatrixXd g_rows = g_(basis, r.passive_slot);  // G_i, n0 × |rows in B|
  const Eigen::MatrixXd g_cols = g_(basis, c.passive_slot);
  // A handful of rows and columns: coefficient-wise products of copied rows
  // beat blocked products.
  const Eigen::MatrixXd ab = Eigen::MatrixXd(phi_(r.active_pos, basis)).lazyProduct(g_cols);
  const Eigen::MatrixXd ba = Eigen::MatrixXd(phi_(c.active_pos, basis)).lazyProduct(g_rows);
  const Eigen::MatrixXd bb = g_rows.transpose() * psi_times(g_cols);
  for (std::size_t i = 0; i < r.active_at.size(); ++i) {
    for (std::size_t j = 0; j < c.active_at.size(); ++j)
      out(r.active_at[i], c.active_at[j]) = paa(r.active_pos[i], c.active_pos[j]);
    for (std::size_t j = 0; j < c.passive_at.size(); ++j)
      out(r.active_at[i], c.passive_at[j]) = ab(static_cast<Index>(i), static_cast<Index>(j));
  }
  for (std::size_t i = 0; i < r.passive_at.size(); ++i) {
    for (std::size_t j = 0; j < c.active_at.size(); ++j)
      out(r.passive_at[i], c.active_at[j]) = ba(static_cast<Index>(j), static_cast<Index>(i));
    for (std::size_t j = 0; j < c.passive_at.size(); ++j)
      out(r.passive_at[i], c.passive_at[j]) =
          p0(r.passive_slot[i], c.passive_slot[j]) - bb(static_cast<Index>(i), static_cast<Index>(j));
  }
  return out;
}

// Dropping rows keeps (I) on the rest: an active row takes its rows of P_AA
// and Φ along, a passive one its column of G and its row and column of P⁰
// (its slot, left unused until the next global update). The basis stays.
void CekfFilter::remove(std::vector<int> idx) {
  support::validate_removal(idx, n_, k_, "cekf remove");
  std::vector<char> gone(static_cast<std::size_t>(n_), 0);
  std::vector<char> position_gone(static_cast<std::size_t>(na_), 0);
  for (int i : idx) {
    const auto u = static_cast<std::size_t>(i);
    gone[u] = 1;
    if (active_[u] >= 0) position_gone[static_cast<std::size_t>(active_[u])] = 1;
    slot_live_[static_cast<std::size_t>(slot_[u])] = 0;
    ++dead_slots_;
  }
  std::vector<int> keep, new_position(static_cast<std::size_t>(na_), -1);
  for (int a = 0; a < na_; ++a) {
    if (position_gone[static_cast<std::size_t>(a)]) continue;
    new_position[static_cast<std::size_t>(a)] = static_cast<int>(keep.size());
    keep.push_back(a);
  }
  compact_active(keep);
  memo_.clear();

  std::size_t w = 0;
  std::vector<int> kept_rows;
  for (std::size_t i = 0; i < gone.size(); ++i) {
    if (gone[i]) continue;
    kept_rows.push_back(static_cast<int>(i));
    slot_[w] = slot_[i];
    active_[w] = active_[i] >= 0 ? new_position[static_cast<std::size_t>(active_[i])] : -1;
    touched_[w] = touched_[i];
    seen_in_[w] = seen_in_[i];
    ++w;
  }
  slot_.resize(w);
  active_.resize(w);
  touched_.resize(w);
  seen_in_.resize(w);
  n_ = static_cast<int>(w);
  if (constrained_) U_.keep_rows(kept_rows);
}

void CekfFilter::flush() { global_update(false); }

// The global update: (I) written out, then a new partition with Φ = I, Ψ = 0:
// A = the robot and the recent rows, or (all_rows) every row.
void CekfFilter::global_update(bool all_rows) {
  reserve_store();
  memo_.clear();  // Ψ becomes 0
  if (n0_ > 0) refresh_passive_block();
  write_active_rows_into_store();
  if (dead_slots_ > 0) drop_dead_slots();
  finish_global_update(all_rows);
}

void CekfFilter::finish_global_update(bool all_rows) {
  if (all_rows) {
    std::vector<int> all(static_cast<std::size_t>(n_));
    std::iota(all.begin(), all.end(), 0);
    repartition(all);
  } else {
    repartition(choose_active());
  }
  all_active_ = all_rows;
  start_interval();
  ++global_updates_;
}

// C is the covariance of every row: all of it goes into P⁰ (the slots of
// active rows included), after which the store holds what a global update
// would have written there, and the same re-partition follows.
void CekfFilter::assign(const Eigen::MatrixXd& C) {
  estimator_support::require_size(C, n_, n_, "cekf assign", "C");
  estimator_support::require_finite(C, "cekf assign", "C");
  reserve_store();
  memo_.clear();  // Ψ becomes 0
  if (dead_slots_ > 0) drop_dead_slots();
  for (int j = 0; j < n_; ++j) {
    const int t = slot_[static_cast<std::size_t>(j)];
    for (int i = j; i < n_; ++i) {
      const int s = slot_[static_cast<std::size_t>(i)];
      p0_(std::max(s, t), std::min(s, t)) = C(i, j);
    }
  }
  finish_global_update(all_active_);
}

Eigen::MatrixXd CekfFilter::covariance() const {
  std::vector<int> all(static_cast<std::size_t>(n_));
  std::iota(all.begin(), all.end(), 0);
  return marginal(all);
}

// ---------------------------------------------------------------- activation

// Rows J ⊂ B move to A, exactly: with g = G_{:,J},
//   P_JA = (Φ g)ᵀ,   P_JJ = P⁰_JJ − gᵀ Ψ g                                 from (I),
// and the basis grows by the rows P⁰_{J,B'} (B' = B ∖ J):
//   G' = [G_{:,B'}; P⁰_{J,B'}],   Ψ' = diag(Ψ, 0),   Φ' = [[Φ, 0], [−gᵀΨ, I]].
// Check of (I) for the new partition:
//   P_{A,B'}  = Φ G_{:,B'}                    = [Φ, 0] G'             (unchanged rows)
//   P_{J,B'}  = P⁰_{J,B'} − gᵀ Ψ G_{:,B'}      = [−gᵀΨ, I] G'          (from (I) for P_BB)
//   P_{B'B'}  = P⁰_{B'B'} − G_{:,B'}ᵀ Ψ G_{:,B'} = P⁰_{B'B'} − G'ᵀ Ψ' G'  (the zero block of Ψ'
//                                                                   hides the new rows of G').
void CekfFilter::activate(const std::vector<int>& rows) {
  std::vector<int> passive;
  for (int i : rows) {
    if (active_[static_cast<std::size_t>(i)] < 0) passive.push_back(i);
  }
  std::sort(passive.begin(), passive.end());
  passive.erase(std::unique(passive.begin(), passive.end()), passive.end());
  if (passive.empty()) return;
  reserve_store();
  const auto t = static_cast<int>(passive.size());
  std::vector<int> slots;
  for (int i : passive) slots.push_back(slot_[static_cast<std::size_t>(i)]);

  const Eigen::MatrixXd g = g_(Eigen::seqN(0, n0_), slots);
  const Eigen::MatrixXd psi_g = psi_times(g);
  const Eigen::MatrixXd P_JA = (phi_.topLeftCorner(na_, n0_) * g).transpose();
  Eigen::MatrixXd P_JJ = -g.transpose() * psi_g;
  for (int b = 0; b < t; ++b) {
    for (int a = b; a < t; ++a)
      P_JJ(a, b) += p0(slots[static_cast<std::size_t>(a)], slots[static_cast<std::size_t>(b)]);
  }

  reserve_active(na_ + t);
  reserve_basis(n0_ + t);
  paa_.block(na_, 0, t, na_) = P_JA;
  paa_.block(na_, na_, t, t).triangularView<Eigen::Lower>() = P_JJ;
  phi_.block(0, n0_, na_, t).setZero();
  phi_.block(na_, 0, t, n0_) = -psi_g.transpose();
  phi_.block(na_, n0_, t, t).setIdentity();
  psi_.block(n0_, 0, t, n0_ + t).setZero();
  psi_.block(0, n0_, n0_, t).setZero();
  for (int c = 0; c < t; ++c) p0_column(slots[static_cast<std::size_t>(c)], g_.row(n0_ + c).head(ns_).transpose());
  for (int c = 0; c < t; ++c) active_[static_cast<std::size_t>(passive[static_cast<std::size_t>(c)])] = na_ + c;
  na_ += t;
  n0_ += t;
}

// ---------------------------------------------------------------- memo

const CekfFilter::MemoEntry& CekfFilter::passive_memo(const std::vector<int>& slots, const Eigen::MatrixXd& g) const {
  auto [entry, added] = memo_.try_emplace(slots);
  if (added) {
    entry->second.quadratic = g.transpose() * psi_times(g);
    entry->second.p0_block = p0_block(slots);
  }
  entry->second.asked = true;
  return entry->second;
}

Eigen::MatrixXd CekfFilter::p0_block(const std::vector<int>& slots) const {
  const auto t = static_cast<Index>(slots.size());
  Eigen::MatrixXd out(t, t);
  for (Index j = 0; j < t; ++j)
    for (Index i = 0; i < t; ++i) out(i, j) = p0(slots[static_cast<std::size_t>(i)], slots[static_cast<std::size_t>(j)]);
  return out;
}

// Ψ ← Ψ + V Vᵀ adds (Vᵀ G_J)ᵀ (Vᵀ G_J) to G_Jᵀ Ψ G_J: O(m n0) per column
// instead of O(n0²) afresh. (Activation pads Ψ and G with blocks that cancel,
// so it leaves G_Jᵀ Ψ G_J as it is.) Blocks not asked about since the last
// update are dropped.
void CekfFilter::refresh_memo(const Eigen::MatrixXd& V) {
  std::erase_if(memo_, [](const auto& entry) { return !entry.second.asked; });
  std::vector<int> all_slots;
  for (const auto& [slots, entry] : memo_) all_slots.insert(all_slots.end(), slots.begin(), slots.end());
  // Vᵀ G_J for all of them, column by column: Vᵀ g for each slot's column g
  // of G read in place (m dot products of n0 numbers against V's columns,
  // which stay in the cache), with no copy of the columns and no packing.
  const auto cols = static_cast<Index>(all_slots.size());
  Eigen::MatrixXd VtG(V.cols(), cols);
  for (Index c = 0; c < cols; ++c)
    transposed_product(VtG.col(c), 1.0, V, g_.col(all_slots[static_cast<std::size_t>(c)]).head(n0_));
  Index column = 0;
  for (auto& [slots, entry] : memo_) {
    const auto size = static_cast<Index>(slots.size());
    const auto block = VtG.middleCols(column, size);
    entry.quadratic.noalias() += block.transpose().lazyProduct(block);  // a few entries: no blocked product
    entry.asked = false;
    column += size;
  }
}

void CekfFilter::touch(const std::vector<int>& rows) {
  for (int i : rows) {
    const auto u = static_cast<std::size_t>(i);
    touched_[u] = updates_;
    if (seen_in_[u] == interval_) continue;
    seen_in_[u] = interval_;  // first touch in this interval: activated in the compressed form
    if (all_active_) {
      ++virtual_basis_;
      ++virtual_active_;
    }
  }
}

// ---------------------------------------------------------------- churn

// Costs in multiply–adds, leading terms only. A global update after an
// interval with basis n0 and active part n_A: P⁰_BB − Gᵀ Ψ G over the lower
// triangle (ns² n0 / 2) with Ψ Gᵀ (ns n0²), and P_AB = Φ G (n_A n0 ns).
// The plain EKF pays ns² m / 2 for each update of m rows (eq. 32 on the whole
// covariance), so ns² r / 2 for the interval's r rows.
double CekfFilter::global_update_cost(int basis, int active) const {
  const auto ns = static_cast<double>(ns_), n0 = static_cast<double>(basis);
  return ns * ns * n0 / 2.0 + ns * n0 * (n0 + static_cast<double>(active));
}

double CekfFilter::ekf_interval_cost() const {
  const auto ns = static_cast<double>(ns_);
  return ns * ns * static_cast<double>(interval_rows_) / 2.0;
}

void CekfFilter::start_interval() {
  ++interval_;
  interval_rows_ = 0;
  if (!all_active_) return;
  // The partition a global update would choose now (robot and recent rows) is
  // the virtual interval's starting basis.
  const std::vector<int> kept = choose_active();
  for (int i : kept) seen_in_[static_cast<std::size_t>(i)] = interval_;
  virtual_basis_ = virtual_active_ = static_cast<int>(kept.size());
}

// Global update cost over the EKF's cost of the interval's updates, capped at
// kMaxCostRatio (an interval of augmentations only costs the EKF almost nothing).
double CekfFilter::cost_ratio(int basis, int active) const {
  const double global = global_update_cost(basis, active), ekf = ekf_interval_cost();
  if (global <= 0.0) return 0.0;
  return global >= kMaxCostRatio * ekf ? kMaxCostRatio : global / ekf;
}

// Compressed: a global update when the basis or A outgrow max_active. The
// ratio of its cost to the EKF's updates of the interval is averaged over
// intervals (r̄ ← (r̄ + r) / 2, so one unlucky interval does not decide); when
// r̄ > 1 the next partition is A = everything (updates are the EKF's, no global
// updates). All active: after every call, the ratio r of the global update of
// a virtual compressed filter (its basis and A counted by touch() and
// augment()) to the EKF's updates since its interval began enters the same
// mean; when (r̄ + r) / 2 < kReturnShare the filter compresses again (at once:
// a slow robot repeats rows and r falls fast). The virtual interval ends as a
// real one would, and then (r̄ + r) / 2 becomes r̄.
void CekfFilter::flush_if_needed() {
  if (!all_active_) {
    if (n0_ <= max_active_ && na_ <= max_active_) return;
    const double ratio = cost_ratio(n0_, na_);
    churn_ratio_ = churn_ratio_ < 0.0 ? ratio : 0.5 * (churn_ratio_ + ratio);
    const bool churn = churn_fallback_ && churn_ratio_ > 1.0;
    if (churn) ++fallbacks_;
    global_update(churn);
    return;
  }
  const double mean = 0.5 * (churn_ratio_ + cost_ratio(virtual_basis_, virtual_active_));
  if (mean < kReturnShare) {
    churn_ratio_ = mean;
    global_update(false);
  } else if (virtual_basis_ > max_active_ || virtual_active_ > max_active_) {
    churn_ratio_ = mean;
    start_interval();
  }
}

// ---------------------------------------------------------------- global update

// P⁰_BB ← P⁰_BB − Gᵀ Ψ G, the lower triangle only (one triangular product).
// Entries of active or dead slots come out meaningless; the next steps
// overwrite or drop them.
void CekfFilter::refresh_passive_block() {
  const Eigen::MatrixXd gt = g_.topLeftCorner(n0_, ns_).transpose();
  Eigen::MatrixXd gt_psi = Eigen::MatrixXd::Zero(ns_, n0_);  // Gᵀ Ψ = (Ψ G)ᵀ, Ψ symmetric
  add_product(gt_psi, 1.0, gt, psi_.topLeftCorner(n0_, n0_));
  add_product(p0_.topLeftCorner(ns_, ns_), -1.0, gt, gt_psi, ProductPart::lower);
}

// The rows of A into the store: P_AB = Φ G against every slot, then P_AA.
// (No basis: every row is active, P_AA is all of it.)
void CekfFilter::write_active_rows_into_store() {
  std::vector<int> slot_of(static_cast<std::size_t>(na_));
  for (int i = 0; i < n_; ++i) {
    const auto u = static_cast<std::size_t>(i);
    if (active_[u] >= 0) slot_of[static_cast<std::size_t>(active_[u])] = slot_[u];
  }
  if (n0_ > 0) {
    Eigen::MatrixXd pab = Eigen::MatrixXd::Zero(na_, ns_);
    add_product(pab, 1.0, phi_.topLeftCorner(na_, n0_), g_.topLeftCorner(n0_, ns_).transpose());
    // Row a of P_AB goes to column s = slot(a) of the lower triangle from
    // the diagonal down (contiguous), and left of it to row s, whose entries
    // are a column of the store apart. Those are written column by column
    // with the active rows in slot order: active rows are mostly recent
    // features with nearby slots, so the entries of one column that go out
    // together share cache lines (row by row, each entry was a cache line of
    // its own, evicted before the next active row came back to it).
    std::vector<int> by_slot(static_cast<std::size_t>(na_));
    std::iota(by_slot.begin(), by_slot.end(), 0);
    std::sort(by_slot.begin(), by_slot.end(), [&](int a, int b) {
      return slot_of[static_cast<std::size_t>(a)] < slot_of[static_cast<std::size_t>(b)];
    });
    for (int a = 0; a < na_; ++a) {
      const int s = slot_of[static_cast<std::size_t>(a)];
      p0_.col(s).segment(s, ns_ - s) = pab.row(a).segment(s, ns_ - s).transpose();
    }
    std::size_t first = 0;  // by_slot[first..]: the active rows with slot > t
    for (int t = 0; t < ns_; ++t) {
      while (first < by_slot.size() && slot_of[static_cast<std::size_t>(by_slot[first])] <= t) ++first;
      for (std::size_t i = first; i < by_slot.size(); ++i) {
        const int a = by_slot[i];
        p0_(slot_of[static_cast<std::size_t>(a)], t) = pab(a, t);
      }
    }
  }
  for (int b = 0; b < na_; ++b) {
    for (int a = b; a < na_; ++a) {
      const int s = slot_of[static_cast<std::size_t>(a)], t = slot_of[static_cast<std::size_t>(b)];
      p0_(std::max(s, t), std::min(s, t)) = paa_(a, b);
    }
  }
}

// Slots of removed rows leave the store (it holds the full covariance now).
void CekfFilter::drop_dead_slots() {
  std::vector<int> keep, new_slot(static_cast<std::size_t>(ns_), -1);
  for (int s = 0; s < ns_; ++s) {
    if (!slot_live_[static_cast<std::size_t>(s)]) continue;
    new_slot[static_cast<std::size_t>(s)] = static_cast<int>(keep.size());
    keep.push_back(s);
  }
  compact_lower(p0_, keep);
  for (int& s : slot_) s = new_slot[static_cast<std::size_t>(s)];
  ns_ = static_cast<int>(keep.size());
  slot_live_.assign(static_cast<std::size_t>(ns_), 1);
  dead_slots_ = 0;
}

// The robot and the rows touched within the last keep_steps updates, at most
// max_active/2 rows in all (the most recently touched win), ascending.
std::vector<int> CekfFilter::choose_active() const {
  std::vector<int> recent;
  for (int i = k_; i < n_; ++i) {
    if (touched_[static_cast<std::size_t>(i)] > updates_ - keep_steps_) recent.push_back(i);
  }
  const auto room = static_cast<std::size_t>(std::max(0, max_active_ / 2 - k_));
  if (recent.size() > room) {
    std::stable_sort(recent.begin(), recent.end(), [this](int a, int b) {
      return touched_[static_cast<std::size_t>(a)] > touched_[static_cast<std::size_t>(b)];
    });
    recent.resize(room);
    std::sort(recent.begin(), recent.end());
  }
  std::vector<int> chosen(static_cast<std::size_t>(k_));
  std::iota(chosen.begin(), chosen.end(), 0);
  chosen.insert(chosen.end(), recent.begin(), recent.end());
  return chosen;
}

// With the store holding the full covariance P⁰: A = active_rows, B = the
// rest, P_AA = P⁰_AA, G = P⁰_{A,B} (so a0 = A), Φ = I, Ψ = 0, and (I) holds.
// With every row in A there is no B and no basis (n0 = 0).
void CekfFilter::repartition(const std::vector<int>& active_rows) {
  const auto na = static_cast<int>(active_rows.size());
  const int n0 = na < n_ ? na : 0;
  na_ = 0;  // nothing of the old Φ, Ψ, G, P_AA is kept
  n0_ = 0;
  reserve_active(na);
  reserve_basis(n0);
  std::fill(active_.begin(), active_.end(), -1);
  std::vector<int> slots;
  for (int c = 0; c < na; ++c) {
    const auto i = static_cast<std::size_t>(active_rows[static_cast<std::size_t>(c)]);
    active_[i] = c;
    slots.push_back(slot_[i]);
  }
  for (int b = 0; b < na; ++b) {
    for (int a = b; a < na; ++a)
      paa_(a, b) = p0(slots[static_cast<std::size_t>(a)], slots[static_cast<std::size_t>(b)]);
    if (n0 > 0) p0_column(slots[static_cast<std::size_t>(b)], g_.row(b).head(ns_).transpose());
  }
  phi_.topLeftCorner(na, n0).setIdentity();
  psi_.topLeftCorner(n0, n0).setZero();
  na_ = na;
  n0_ = n0;
}

// ---------------------------------------------------------------- checkpoints

void CekfFilter::save_state(StateWriter& out) const {
  Eigen::MatrixXd dims(1, 9);
  dims << k_, n_, na_, n0_, ns_, dead_slots_, static_cast<double>(updates_), static_cast<double>(global_updates_),
      constrained_ ? 1.0 : 0.0;
  out.put("dims", dims);
  put_ints(out, "slot", slot_);
  put_ints(out, "active", active_);
  put_ints(out, "touched", touched_);
  put_ints(out, "slot_live", slot_live_);
  support::save_capacity(out, "paa", paa_);
  support::save_capacity(out, "phi", phi_);
  support::save_capacity(out, "psi", psi_);
  // G is saved as Gᵀ (slots × basis), the layout of checkpoint version 1.
  support::save_capacity(out, "gt", g_.transpose());
  support::save_capacity(out, "p0", p0_);
  out.put("paa", support::pack_lower(paa_, na_));
  out.put("phi", phi_.topLeftCorner(na_, n0_));
  out.put("psi", psi_.topLeftCorner(n0_, n0_));
  out.put("gt", g_.topLeftCorner(n0_, ns_).transpose());
  // The P⁰ store grows only when a global update needs it: slots past its
  // size have never been written.
  const Index p0_used = std::min<Index>(ns_, p0_.rows());
  out.put("p0_used", Eigen::MatrixXd::Constant(1, 1, static_cast<double>(p0_used)));
  out.put("p0", support::pack_lower(p0_, p0_used));
  Eigen::MatrixXd churn(1, 7);
  churn << (all_active_ ? 1.0 : 0.0), static_cast<double>(interval_), static_cast<double>(interval_rows_),
      virtual_basis_, virtual_active_, static_cast<double>(fallbacks_), churn_ratio_;
  out.put("churn", churn);
  put_ints(out, "seen_in", seen_in_);
  out.put("memo_entries", Eigen::MatrixXd::Constant(1, 1, static_cast<double>(memo_.size())));
  int i = 0;
  for (const auto& [slots, entry] : memo_) {
    const std::string name = "memo_" + std::to_string(i++);
    put_ints(out, name + "_slots", slots);
    out.put(name + "_quadratic", entry.quadratic);
    out.put(name + "_asked", Eigen::MatrixXd::Constant(1, 1, entry.asked ? 1.0 : 0.0));
  }
  if (constrained_) U_.save(out, "unobservable_");
}

void CekfFilter::restore_state(const StateReader& in, int version) {
  const std::string context = "cekf restore_state";
  if (version != 1) throw std::invalid_argument(context + ": state version " + std::to_string(version) + " (reads 1)");
  const Eigen::MatrixXd& dims = get_state(in, "dims", 1, 9, context);
  for (Index j = 0; j < 8; ++j)
    if (!(dims(0, j) >= 0 && dims(0, j) <= (j < 6 ? 1e8 : 1e15)) || dims(0, j) != std::floor(dims(0, j)))
      throw std::invalid_argument(context + ": saved dimension " + std::to_string(j) + " is not a count");
  const int k = static_cast<int>(dims(0, 0)), n = static_cast<int>(dims(0, 1)), na = static_cast<int>(dims(0, 2));
  const int n0 = static_cast<int>(dims(0, 3)), ns = static_cast<int>(dims(0, 4));
  if (k < 1 || n < k || na < k || na > n || ns < n - na)
    throw std::invalid_argument(context + ": saved dimensions are inconsistent");
  if ((dims(0, 8) != 0.0) != constrained_)
    throw std::invalid_argument(context + ": saved with observability_constrained " +
                                (dims(0, 8) != 0.0 ? "true" : "false") + ", this instance has the other setting");
  CekfFilter f(max_active_, keep_steps_, constrained_, churn_fallback_);
  f.k_ = k;
  f.n_ = n;
  f.na_ = na;
  f.n0_ = n0;
  f.ns_ = ns;
  f.dead_slots_ = static_cast<int>(dims(0, 5));
  f.updates_ = static_cast<std::int64_t>(dims(0, 6));
  f.global_updates_ = static_cast<std::int64_t>(dims(0, 7));
  f.slot_ = get_ints<int>(in, "slot", 0, ns - 1, context);
  f.active_ = get_ints<int>(in, "active", -1, na - 1, context);
  f.touched_ = get_ints<std::int64_t>(in, "touched", -1e15, 1e15, context);
  f.slot_live_ = get_ints<char>(in, "slot_live", 0, 1, context);
  if (f.slot_.size() != static_cast<std::size_t>(n) || f.active_.size() != static_cast<std::size_t>(n) ||
      f.touched_.size() != static_cast<std::size_t>(n) || f.slot_live_.size() < static_cast<std::size_t>(ns))
    throw std::invalid_argument(context + ": saved per-row lists do not match the state dimension");
  const auto take = [&](const char* name, Eigen::MatrixXd& store, Index rows, Index cols) {
    const Eigen::MatrixXd& m = get_state(in, name, rows, cols, context);
    support::require_finite(m, context, name);
    store = support::restore_capacity(in, name, rows, cols, context);
    store.topLeftCorner(rows, cols) = m;
  };
  const auto take_lower = [&](const char* name, Eigen::MatrixXd& store, Index n) {
    store = support::restore_capacity(in, name, n, n, context);
    support::unpack_lower(in.get(name), n, store, context + ": " + name);
  };
  take_lower("paa", f.paa_, na);
  take("phi", f.phi_, na, n0);
  take("psi", f.psi_, n0, n0);
  Eigen::MatrixXd gt;
  take("gt", gt, ns, n0);
  f.g_ = gt.transpose();
  const Eigen::MatrixXd& p0_used = get_state(in, "p0_used", 1, 1, context);
  if (!(p0_used(0, 0) >= 0 && p0_used(0, 0) <= ns) || p0_used(0, 0) != std::floor(p0_used(0, 0)))
    throw std::invalid_argument(context + ": bad p0_used");
  take_lower("p0", f.p0_, static_cast<Index>(p0_used(0, 0)));
  const Eigen::MatrixXd& churn = get_state(in, "churn", 1, 7, context);
  support::require_finite(churn, context, "churn");
  f.all_active_ = churn(0, 0) != 0.0;
  f.interval_ = static_cast<std::int64_t>(churn(0, 1));
  f.interval_rows_ = static_cast<std::int64_t>(churn(0, 2));
  f.virtual_basis_ = static_cast<int>(churn(0, 3));
  f.virtual_active_ = static_cast<int>(churn(0, 4));
  f.fallbacks_ = static_cast<std::int64_t>(churn(0, 5));
  f.churn_ratio_ = churn(0, 6);
  f.seen_in_ = get_ints<std::int64_t>(in, "seen_in", -1e15, 1e15, context);
  if (f.seen_in_.size() != static_cast<std::size_t>(n))
    throw std::invalid_argument(context + ": saved 'seen_in' does not match the state dimension");
  const Eigen::MatrixXd& entries = get_state(in, "memo_entries", 1, 1, context);
  if (!(entries(0, 0) >= 0 && entries(0, 0) <= 1e9)) throw std::invalid_argument(context + ": bad memo size");
  for (int i = 0; i < static_cast<int>(entries(0, 0)); ++i) {
    const std::string name = "memo_" + std::to_string(i);
    std::vector<int> slots = get_ints<int>(in, name + "_slots", 0, ns - 1, context);
    MemoEntry entry;
    entry.p0_block = f.p0_block(slots);
    entry.quadratic = get_state(in, name + "_quadratic", static_cast<Index>(slots.size()),
                                static_cast<Index>(slots.size()), context);
    entry.asked = get_state(in, name + "_asked", 1, 1, context)(0, 0) != 0.0;
    f.memo_.emplace(std::move(slots), std::move(entry));
  }
  if (constrained_) f.U_.restore(in, "unobservable_", n, context);
  // Everything was read and checked into f: take it.
  *this = std::move(f);
}

// ---------------------------------------------------------------- storage

void CekfFilter::compact_active(const std::vector<int>& keep) {
  compact_lower(paa_, keep);
  for (std::size_t a = 0; a < keep.size(); ++a) {
    phi_.row(static_cast<Index>(a)).head(n0_) = phi_.row(keep[a]).head(n0_);
  }
  na_ = static_cast<int>(keep.size());
}

Eigen::MatrixXd CekfFilter::active_columns(const std::vector<int>& pos) const {
  // Column a of P_AA is row a of the lower triangle left of the diagonal, then
  // column a of the lower triangle from the diagonal down.
  Eigen::MatrixXd out(na_, static_cast<Index>(pos.size()));
  for (std::size_t c = 0; c < pos.size(); ++c) {
    const int a = pos[c];
    auto column = out.col(static_cast<Index>(c));
    column.head(a) = paa_.row(a).head(a).transpose();
    column.tail(na_ - a) = paa_.col(a).segment(a, na_ - a);
  }
  return out;
}

Eigen::MatrixXd CekfFilter::phi_rows_transposed(const std::vector<int>& pos) const {
  Eigen::MatrixXd out(n0_, static_cast<Index>(pos.size()));
  for (std::size_t c = 0; c < pos.size(); ++c) out.col(static_cast<Index>(c)) = phi_.row(pos[c]).head(n0_).transpose();
  return out;
}

void CekfFilter::p0_column(int s, Eigen::Ref<Eigen::VectorXd, 0, Eigen::InnerStride<>> out) const {
  out.head(s) = p0_.row(s).head(s).transpose();
  out.tail(ns_ - s) = p0_.col(s).segment(s, ns_ - s);
}

CekfFilter::Split CekfFilter::split(const std::vector<int>& idx) const {
  Split p;
  for (std::size_t c = 0; c < idx.size(); ++c) {
    const auto i = static_cast<std::size_t>(idx[c]);
    if (active_[i] >= 0) {
      p.active_at.push_back(static_cast<Index>(c));
      p.active_pos.push_back(active_[i]);
    } else {
      p.passive_at.push_back(static_cast<Index>(c));
      p.passive_slot.push_back(slot_[i]);
    }
  }
  return p;
}

Eigen::MatrixXd CekfFilter::psi_times(const Eigen::MatrixXd& g) const {
  // One matrix–vector product per column: with few columns this beats a
  // matrix product, which would first copy Ψ into its blocked layout.
  Eigen::MatrixXd out(n0_, g.cols());
  for (Index c = 0; c < g.cols(); ++c) out.col(c).noalias() = psi_.topLeftCorner(n0_, n0_) * g.col(c);
  return out;
}

void CekfFilter::mirror_psi() {
  for (int c = 0; c + 1 < n0_; ++c) {
    psi_.row(c).segment(c + 1, n0_ - c - 1) = psi_.col(c).segment(c + 1, n0_ - c - 1).transpose();
  }
}

std::vector<int> CekfFilter::positions(const std::vector<int>& idx) const {
  std::vector<int> pos;
  pos.reserve(idx.size());
  for (int i : idx) pos.push_back(active_[static_cast<std::size_t>(i)]);
  return pos;
}

void CekfFilter::reserve_active(int rows) {
  grow(paa_, rows, rows, na_, na_);
  grow(phi_, rows, phi_.cols(), na_, n0_);
}

void CekfFilter::reserve_basis(int cols) {
  grow(phi_, phi_.rows(), cols, na_, n0_);
  grow(psi_, cols, cols, n0_, n0_);
  grow(g_, cols, g_.cols(), n0_, ns_);
}

void CekfFilter::reserve_slots(int slots) { grow(g_, g_.rows(), slots, n0_, ns_); }

// The P⁰ store grows only when it is read or written (activation, global
// update), not with every augmentation: with every row active (churn) it is
// not touched until the next global update. Slots beyond its old size belong
// to rows created since, all active: their entries are stale anyway.
void CekfFilter::reserve_store() {
  const Index used = std::min<Index>(ns_, p0_.rows());
  grow(p0_, ns_, ns_, used, used);
}

}  // namespace mspace::cekf
