// ekf_filter.cpp — the M-space EKF, T-RO 2007 §V-B, eqs. 23–32.
#include "mspace/ekf_filter.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "mspace/dense_product.hpp"
#include "mspace/estimator_support.hpp"

namespace mspace::ekf {

using Eigen::Index;
using estimator_support::require_indices;
using estimator_support::size_text;

EkfFilter::EkfFilter(int initial_capacity, bool observability_constrained)
    : initial_capacity_(initial_capacity), constrained_(observability_constrained) {
  if (initial_capacity < 1) {
    throw std::invalid_argument("ekf: initial_capacity must be at least 1, got " +
                                std::to_string(initial_capacity));
  }
}

void EkfFilter::reset(const Eigen::MatrixXd& P_rr) {
  estimator_support::validate_reset(P_rr, "ekf reset");
  k_ = static_cast<int>(P_rr.rows());
  n_ = k_;
  store_.resize(std::max(k_, initial_capacity_), std::max(k_, initial_capacity_));
  store_.topLeftCorner(k_, k_).triangularView<Eigen::Lower>() = P_rr;
  if (constrained_) U_.reset(k_);
}

void EkfFilter::set_unobservable(const Eigen::MatrixXd& U_r) {
  if (constrained_) U_.set(U_r, "ekf set_unobservable");
}

void EkfFilter::predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) {
  estimator_support::validate_prediction(J_rr, Q, k_, "ekf predict");

  // eq. 26: C_rr ← J_rr C_rr J_rrᵀ + Q  (Q = J_rd C_d J_rdᵀ).
  const Eigen::MatrixXd C_rr = store_.topLeftCorner(k_, k_).selfadjointView<Eigen::Lower>();
  store_.topLeftCorner(k_, k_).triangularView<Eigen::Lower>() = J_rr * C_rr * J_rr.transpose() + Q;

  // eq. 27: C_rp ← J_rr C_rp. The lower triangle holds C_pr = C_rpᵀ (rows k.., columns
  // 0..k−1), so C_pr ← C_pr J_rrᵀ: O(N·k), through an N×k temporary.
  auto C_pr = store_.block(k_, 0, n_ - k_, k_);
  C_pr = C_pr * J_rr.transpose();

  // The unobservable directions move with the robot block: U_r ← J_rr U_r.
  if (constrained_) U_.predict(J_rr);
}

Eigen::VectorXd EkfFilter::update(const std::vector<LinearizedObservation>& obs) {
  if (constrained_ && U_.directions() > 0) return apply_update(U_.constrain(obs, "ekf update"));
  return apply_update(obs);
}

Eigen::VectorXd EkfFilter::apply_update(const std::vector<LinearizedObservation>& obs) {
  const estimator_support::StackedObservation s =
      estimator_support::stack_observations(obs, n_, "ekf update");
  Eigen::VectorXd dx = Eigen::VectorXd::Zero(n_);
  if (s.eta.size() == 0) return dx;

  // J_η,state is zero outside the columns I, so C Jᵀ = C[:, I] J_Iᵀ (N × m).
  Eigen::MatrixXd CJt = gather_columns(s.union_idx) * s.J.transpose();

  // eq. 29: S = J C Jᵀ + C_η, where J C Jᵀ = J_I (C Jᵀ)[I, :].
  const Eigen::MatrixXd S = s.J * CJt(s.union_idx, Eigen::all) + s.C_eta;
  const Eigen::LLT<Eigen::MatrixXd> llt(S);
  if (llt.info() != Eigen::Success) {
    throw std::runtime_error("ekf update: S (" + size_text(S.rows(), S.cols()) +
                             ") is not positive definite");
  }

  // eq. 28 with S = L Lᵀ: K = C Jᵀ S⁻¹ = W L⁻¹, where W = C Jᵀ L⁻ᵀ (computed in place).
  llt.matrixU().solveInPlace<Eigen::OnTheRight>(CJt);
  const Eigen::MatrixXd& W = CJt;

  // eq. 31: δx_state = −K η = −W (L⁻¹ η).
  const Eigen::VectorXd whitened = llt.matrixL().solve(s.eta);
  dx.noalias() = -W * whitened;

  // eq. 32: δC_state = −K J C = −W Wᵀ, one symmetric rank-m update of the stored lower
  // triangle (no N×N temporary).
  add_product(store_.topLeftCorner(n_, n_), -1.0, W, W, ProductPart::lower);
  return dx;
}

int EkfFilter::augment(const StateAugmentation& aug) {
  estimator_support::validate_augmentation(aug, n_, "ekf augment");
  const auto added = static_cast<int>(aug.C_new.rows());

  const int first = n_;
  if (added == 0) return first;
  if (n_ + added > capacity()) reserve(std::max(n_ + added, 2 * capacity()));

  // δx_new = J δx[idx] + w, so C_new,all = J C[idx, :] and
  // C_new,new = J C[idx, idx] Jᵀ + C_new.
  const Eigen::MatrixXd C_new_all = aug.J * gather_columns(aug.idx).transpose();
  const Eigen::MatrixXd C_new_new = C_new_all(Eigen::all, aug.idx) * aug.J.transpose() + aug.C_new;
  store_.block(n_, 0, added, n_) = C_new_all;
  store_.block(n_, n_, added, added).triangularView<Eigen::Lower>() = C_new_new;
  if (constrained_) U_.augment(aug);
  n_ += added;
  return first;
}

Eigen::MatrixXd EkfFilter::marginal(const std::vector<int>& idx) const { return cross(idx, idx); }

Eigen::MatrixXd EkfFilter::cross(const std::vector<int>& rows, const std::vector<int>& cols) const {
  require_indices(rows, n_, "ekf cross: rows", false);
  require_indices(cols, n_, "ekf cross: cols", false);
  Eigen::MatrixXd out(rows.size(), cols.size());
  for (std::size_t c = 0; c < cols.size(); ++c) {
    for (std::size_t r = 0; r < rows.size(); ++r) {
      out(static_cast<Index>(r), static_cast<Index>(c)) = at(rows[r], cols[c]);
    }
  }
  return out;
}

void EkfFilter::remove(std::vector<int> idx) {
  estimator_support::validate_removal(idx, n_, k_, "ekf remove");
  std::sort(idx.begin(), idx.end());
  std::vector<int> keep;
  keep.reserve(static_cast<std::size_t>(n_) - idx.size());
  for (int i = 0, next = 0; i < n_; ++i) {
    if (next < static_cast<int>(idx.size()) && idx[static_cast<std::size_t>(next)] == i) {
      ++next;
    } else {
      keep.push_back(i);
    }
  }
  // Compact in place, column by column in increasing order: the destination
  // (a, b) never comes after its source (keep[a], keep[b]), so every entry is
  // read before anything overwrites it.
  const auto kept = static_cast<int>(keep.size());
  for (int b = 0; b < kept; ++b) {
    for (int a = b; a < kept; ++a) store_(a, b) = store_(keep[a], keep[b]);
  }
  if (constrained_) U_.keep_rows(keep);
  n_ = kept;
}

void EkfFilter::reserve(int rows) {
  if (rows <= capacity()) return;
  Eigen::MatrixXd bigger(rows, rows);
  bigger.topLeftCorner(n_, n_).triangularView<Eigen::Lower>() = store_.topLeftCorner(n_, n_);
  store_.swap(bigger);
}

void EkfFilter::save_state(StateWriter& out) const {
  Eigen::MatrixXd dims(1, 3);
  dims << k_, n_, constrained_ ? 1.0 : 0.0;
  out.put("dims", dims);
  estimator_support::save_capacity(out, "store", store_);
  out.put("covariance", estimator_support::pack_lower(store_, n_));
  if (constrained_) U_.save(out, "unobservable_");
}

void EkfFilter::restore_state(const StateReader& in, int version) {
  const std::string context = "ekf restore_state";
  if (version != 1) throw std::invalid_argument(context + ": state version " + std::to_string(version) + " (reads 1)");
  const Eigen::MatrixXd& dims = get_state(in, "dims", 1, 3, context);
  if (!(dims(0, 0) >= 1 && dims(0, 1) >= dims(0, 0) && dims(0, 1) <= 1e8) || dims(0, 0) != std::floor(dims(0, 0)) ||
      dims(0, 1) != std::floor(dims(0, 1)))
    throw std::invalid_argument(context + ": saved dimensions are not integers 1 <= k <= n");
  const int k = static_cast<int>(dims(0, 0)), n = static_cast<int>(dims(0, 1));
  if ((dims(0, 2) != 0.0) != constrained_)
    throw std::invalid_argument(context + ": saved with observability_constrained " +
                                (dims(0, 2) != 0.0 ? "true" : "false") + ", this instance has the other setting");
  Eigen::MatrixXd store = estimator_support::restore_capacity(in, "store", n, n, context);
  if (store.rows() != store.cols()) throw std::invalid_argument(context + ": saved store is not square");
  estimator_support::unpack_lower(in.get("covariance"), n, store, context);
  estimator_support::UnobservableDirections U;
  if (constrained_) U.restore(in, "unobservable_", n, context);
  // Nothing above changed the filter: now take it all.
  store_.swap(store);
  k_ = k;
  n_ = n;
  U_ = std::move(U);
}

Eigen::MatrixXd EkfFilter::covariance() const {
  return store_.topLeftCorner(n_, n_).selfadjointView<Eigen::Lower>();
}

void EkfFilter::assign(const Eigen::MatrixXd& C) {
  estimator_support::require_size(C, n_, n_, "ekf assign", "C");
  estimator_support::require_finite(C, "ekf assign", "C");
  store_.topLeftCorner(n_, n_).triangularView<Eigen::Lower>() = C;
}

Eigen::MatrixXd EkfFilter::gather_columns(const std::vector<int>& cols) const {
  // Column j of C_state is row j of the lower triangle left of the diagonal,
  // then column j of the lower triangle from the diagonal down.
  Eigen::MatrixXd out(n_, static_cast<Index>(cols.size()));
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const int j = cols[c];
    auto column = out.col(static_cast<Index>(c));
    column.head(j) = store_.row(j).head(j).transpose();
    column.tail(n_ - j) = store_.col(j).segment(j, n_ - j);
  }
  return out;
}

}  // namespace mspace::ekf
