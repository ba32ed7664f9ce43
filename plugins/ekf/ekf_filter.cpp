// ekf_filter.cpp — the M-space EKF, T-RO 2007 §V-B, eqs. 23–32.
#include "ekf_filter.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Dense>
#include <algorithm>
#include <stdexcept>
#include <string>

namespace mspace::ekf {

namespace {

using Eigen::Index;

std::string size_text(Index rows, Index cols) {
  return std::to_string(rows) + " x " + std::to_string(cols);
}

/// Throws std::invalid_argument naming the first row of `m` holding a NaN or inf.
template <class Derived>
void require_finite(const Eigen::MatrixBase<Derived>& m, const std::string& context,
                    const char* name) {
  for (Index r = 0; r < m.rows(); ++r) {
    if (!m.row(r).allFinite()) {
      throw std::invalid_argument(context + ": " + name + " row " + std::to_string(r) +
                                  " is not finite");
    }
  }
}

void require_size(const Eigen::MatrixXd& m, Index rows, Index cols, const std::string& context,
                  const char* name) {
  if (m.rows() != rows || m.cols() != cols) {
    throw std::invalid_argument(context + ": " + name + " is " + size_text(m.rows(), m.cols()) +
                                ", expected " + size_text(rows, cols));
  }
}

/// Every index in [0, n); with `distinct`, no index twice.
void require_indices(const std::vector<int>& idx, int n, const std::string& context,
                     bool distinct) {
  for (int i : idx) {
    if (i < 0 || i >= n) {
      throw std::invalid_argument(context + ": index " + std::to_string(i) +
                                  " is out of range [0, " + std::to_string(n) + ")");
    }
  }
  if (!distinct) return;
  std::vector<int> sorted = idx;
  std::sort(sorted.begin(), sorted.end());
  const auto twice = std::adjacent_find(sorted.begin(), sorted.end());
  if (twice != sorted.end()) {
    throw std::invalid_argument(context + ": index " + std::to_string(*twice) +
                                " appears more than once");
  }
}

/// Sizes, indices and finiteness of one observation η ≈ J δx[idx] + noise.
void validate(const LinearizedObservation& o, int n, const std::string& context) {
  const Index m = o.J.rows();
  if (o.J.cols() != static_cast<Index>(o.idx.size())) {
    throw std::invalid_argument(context + ": J has " + std::to_string(o.J.cols()) +
                                " columns but idx has " + std::to_string(o.idx.size()) +
                                " indices");
  }
  if (o.eta.size() != m) {
    throw std::invalid_argument(context + ": eta has " + std::to_string(o.eta.size()) +
                                " rows but J has " + std::to_string(m));
  }
  require_size(o.C_eta, m, m, context, "C_eta");
  require_indices(o.idx, n, context, true);
  require_finite(o.eta, context, "eta");
  require_finite(o.J, context, "J");
  require_finite(o.C_eta, context, "C_eta");
}

/// All observations of one step as one measurement over the union I of their
/// state indices: η = J_I δx[I] + noise with block-diagonal C_eta.
struct StackedObservation {
  std::vector<int> union_idx;  ///< I, sorted ascending
  Eigen::VectorXd eta;         ///< m
  Eigen::MatrixXd J;           ///< m × |I|
  Eigen::MatrixXd C_eta;       ///< m × m
};

std::vector<int> union_of_indices(const std::vector<LinearizedObservation>& obs) {
  std::vector<int> all;
  for (const auto& o : obs) all.insert(all.end(), o.idx.begin(), o.idx.end());
  std::sort(all.begin(), all.end());
  all.erase(std::unique(all.begin(), all.end()), all.end());
  return all;
}

StackedObservation stack(const std::vector<LinearizedObservation>& obs, int n) {
  Index m = 0;
  for (std::size_t i = 0; i < obs.size(); ++i) {
    validate(obs[i], n, "ekf update: observation " + std::to_string(i));
    m += obs[i].eta.size();
  }
  StackedObservation s;
  s.union_idx = union_of_indices(obs);
  s.eta.resize(m);
  s.J = Eigen::MatrixXd::Zero(m, static_cast<Index>(s.union_idx.size()));
  s.C_eta = Eigen::MatrixXd::Zero(m, m);
  Index row = 0;
  for (const auto& o : obs) {
    const Index rows = o.eta.size();
    s.eta.segment(row, rows) = o.eta;
    s.C_eta.block(row, row, rows, rows) = o.C_eta;
    for (std::size_t c = 0; c < o.idx.size(); ++c) {
      const auto pos =
          std::lower_bound(s.union_idx.begin(), s.union_idx.end(), o.idx[c]) - s.union_idx.begin();
      s.J.block(row, pos, rows, 1) = o.J.col(static_cast<Index>(c));
    }
    row += rows;
  }
  return s;
}

}  // namespace

EkfFilter::EkfFilter(int initial_capacity) : initial_capacity_(initial_capacity) {
  if (initial_capacity < 1) {
    throw std::invalid_argument("ekf: initial_capacity must be at least 1, got " +
                                std::to_string(initial_capacity));
  }
}

void EkfFilter::reset(const Eigen::MatrixXd& P_rr) {
  const std::string context = "ekf reset";
  require_size(P_rr, P_rr.rows(), P_rr.rows(), context, "P_rr");
  require_finite(P_rr, context, "P_rr");
  k_ = static_cast<int>(P_rr.rows());
  n_ = k_;
  store_.resize(std::max(k_, initial_capacity_), std::max(k_, initial_capacity_));
  store_.topLeftCorner(k_, k_).triangularView<Eigen::Lower>() = P_rr;
}

void EkfFilter::predict(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q) {
  const std::string context = "ekf predict";
  require_size(J_rr, k_, k_, context, "J_rr");
  require_size(Q, k_, k_, context, "Q");
  require_finite(J_rr, context, "J_rr");
  require_finite(Q, context, "Q");

  // eq. 26: C_rr ← J_rr C_rr J_rrᵀ + Q  (Q = J_rd C_d J_rdᵀ).
  const Eigen::MatrixXd C_rr = store_.topLeftCorner(k_, k_).selfadjointView<Eigen::Lower>();
  store_.topLeftCorner(k_, k_).triangularView<Eigen::Lower>() = J_rr * C_rr * J_rr.transpose() + Q;

  // eq. 27: C_rp ← J_rr C_rp. The lower triangle holds C_pr = C_rpᵀ (rows k.., columns
  // 0..k−1), so C_pr ← C_pr J_rrᵀ: O(N·k), through an N×k temporary.
  auto C_pr = store_.block(k_, 0, n_ - k_, k_);
  C_pr = C_pr * J_rr.transpose();
}

Eigen::VectorXd EkfFilter::update(const std::vector<LinearizedObservation>& obs) {
  const StackedObservation s = stack(obs, n_);
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
  store_.topLeftCorner(n_, n_).selfadjointView<Eigen::Lower>().rankUpdate(W, -1.0);
  return dx;
}

int EkfFilter::augment(const StateAugmentation& aug) {
  const std::string context = "ekf augment";
  const auto added = static_cast<int>(aug.C_new.rows());
  require_size(aug.C_new, added, added, context, "C_new");
  require_size(aug.J, added, static_cast<Index>(aug.idx.size()), context, "J");
  require_indices(aug.idx, n_, context, false);
  require_finite(aug.J, context, "J");
  require_finite(aug.C_new, context, "C_new");

  const int first = n_;
  if (added == 0) return first;
  if (n_ + added > capacity()) reserve(std::max(n_ + added, 2 * capacity()));

  // δx_new = J δx[idx] + w, so C_new,all = J C[idx, :] and
  // C_new,new = J C[idx, idx] Jᵀ + C_new.
  const Eigen::MatrixXd C_new_all = aug.J * gather_columns(aug.idx).transpose();
  const Eigen::MatrixXd C_new_new = C_new_all(Eigen::all, aug.idx) * aug.J.transpose() + aug.C_new;
  store_.block(n_, 0, added, n_) = C_new_all;
  store_.block(n_, n_, added, added).triangularView<Eigen::Lower>() = C_new_new;
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
  require_indices(idx, n_, "ekf remove", true);
  for (int i : idx) {
    if (i < k_) {
      throw std::invalid_argument("ekf remove: index " + std::to_string(i) +
                                  " is a robot pose coordinate (robot dimension " +
                                  std::to_string(k_) + ")");
    }
  }
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
  n_ = kept;
}

void EkfFilter::reserve(int rows) {
  if (rows <= capacity()) return;
  Eigen::MatrixXd bigger(rows, rows);
  bigger.topLeftCorner(n_, n_).triangularView<Eigen::Lower>() = store_.topLeftCorner(n_, n_);
  store_.swap(bigger);
}

Eigen::MatrixXd EkfFilter::covariance() const {
  return store_.topLeftCorner(n_, n_).selfadjointView<Eigen::Lower>();
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
