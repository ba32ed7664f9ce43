// considered_map.cpp — the Schmidt (consider) update of localize mode.
//
// The state is split into the robot r (estimated) and the map m (considered):
//
//   P = [ P_rr  P_rm ]      an observation  η = H_r δx_r + H_m δx_m + v,  v ~ N(0, C_η)
//       [ P_mr  P_mm ]      (H = J_η,state of eq. 30, over the robot's and the features' rows)
//
// Schmidt's consider filter applies the Kalman gain to the robot only and
// keeps the map as it is:
//
//   S   = H P Hᵀ + C_η,   K_r = (P_rr H_rᵀ + P_rm H_mᵀ) S⁻¹,
//   δx_r = K_r η,   P_rr ← P_rr − K_r S K_rᵀ,   P_rm ← P_rm − K_r (H_r P_rm + H_m P_mm),   P_mm unchanged.
//
// The estimator holds P_rr only, and its update is the ordinary one. So the
// step's observations are handed to it as one observation of the robot that
// has exactly that effect: write the map's error as its regression on the
// robot's plus what the robot's error does not explain,
//
//   δx_m = A δx_r + w,   A = P_mr P_rr⁻¹,   w ~ N(0, P_mm − P_mr P_rr⁻¹ P_rm), w independent of δx_r,
//
// so that  η = (H_r + H_m A) δx_r + (H_m w + v):  Jacobian J' = H_r + H_m A and
// noise C' = C_η + H_m (P_mm − P_mr P_rr⁻¹ P_rm) H_mᵀ. The ordinary update with
// (J', C') gives P_rr J'ᵀ = P_rr H_rᵀ + P_rm H_mᵀ and J' P_rr J'ᵀ + C' = S, i.e.
// the gain K_r and P_rr's update above. With P_rm = 0 this is the old
// per-update inflation C_η + H_m P_mm H_mᵀ; stacking the step's observations
// into one keeps the correlation of the map's errors across features.
#include "considered_map.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

namespace mspace::kernel {
namespace {

/// P⁺ for a symmetric positive semi-definite P (the robot's covariance is
/// singular before the first motion when initial_pose.sigma is 0).
Eigen::MatrixXd psd_pseudo_inverse(const Eigen::MatrixXd& P) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(P);
  const Eigen::VectorXd& d = eig.eigenvalues();
  const double tol = 1e-12 * std::max(1.0, d.cwiseAbs().maxCoeff());
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(d.size());
  for (Eigen::Index i = 0; i < d.size(); ++i)
    if (d[i] > tol) inv[i] = 1.0 / d[i];
  return eig.eigenvectors() * inv.asDiagonal() * eig.eigenvectors().transpose();
}

}  // namespace

ConsideredMap::ConsideredMap(int k, int rows, std::shared_ptr<const Eigen::MatrixXd> joint, int capacity)
    : k_(k), rows_in_map_(rows), capacity_(capacity), joint_(std::move(joint)), P_rW_(k, capacity) {
  if (capacity < 1) throw std::invalid_argument("ConsideredMap: capacity must be at least 1 row");
  if (joint_ && (joint_->rows() != rows || joint_->cols() != rows))
    throw std::invalid_argument("ConsideredMap: the joint covariance is not " + std::to_string(rows) + " x " +
                                std::to_string(rows));
  if (joint_ && rows > capacity) joint_.reset();  // see the header: used as the features' own blocks
  // With the joint covariance every update correlates the robot with every
  // map row, observed or not: all of them are in the working set from the
  // start (the robot starts uncorrelated with the map, so P_rm = 0 is exact).
  if (joint_)
    for (int r = 0; r < rows; ++r) enter(k + r, 0, {});
}

void ConsideredMap::set_block(const std::vector<int>& rows, const Eigen::MatrixXd& P) {
  for (std::size_t a = 0; a < rows.size(); ++a) {
    std::vector<std::pair<int, double>>& row = neighbours_[rows[a]];
    for (std::size_t b = 0; b < rows.size(); ++b) {
      const double v = P(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
      const auto same = std::find_if(row.begin(), row.end(), [&](const auto& e) { return e.first == rows[b]; });
      if (same == row.end())
        row.emplace_back(rows[b], v);
      else
        same->second = v;  // a row shared by two features: both blocks hold it
    }
  }
}

Eigen::MatrixXd ConsideredMap::map_block(const std::vector<int>& a, const std::vector<int>& b) const {
  Eigen::MatrixXd P = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(a.size()), static_cast<Eigen::Index>(b.size()));
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (joint_) {
      for (std::size_t j = 0; j < b.size(); ++j)
        P(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = (*joint_)(a[i] - k_, b[j] - k_);
      continue;
    }
    const auto it = neighbours_.find(a[i]);
    if (it == neighbours_.end()) continue;
    for (const auto& [row, v] : it->second)
      for (std::size_t j = 0; j < b.size(); ++j)
        if (b[j] == row) P(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = v;
  }
  return P;
}

Eigen::MatrixXd ConsideredMap::covariance(const std::vector<int>& idx, const Eigen::MatrixXd& P_rr) const {
  const auto n = static_cast<Eigen::Index>(idx.size());
  Eigen::MatrixXd P = Eigen::MatrixXd::Zero(n, n);
  std::vector<int> map_rows;
  std::vector<Eigen::Index> map_at;
  for (Eigen::Index i = 0; i < n; ++i) {
    const int r = idx[static_cast<std::size_t>(i)];
    if (r >= k_) {
      map_rows.push_back(r);
      map_at.push_back(i);
    }
  }
  const Eigen::MatrixXd P_mm = map_block(map_rows, map_rows);
  for (Eigen::Index i = 0; i < n; ++i) {
    const int a = idx[static_cast<std::size_t>(i)];
    for (Eigen::Index j = 0; j < n; ++j) {
      const int b = idx[static_cast<std::size_t>(j)];
      if (a < k_ && b < k_) {
        P(i, j) = P_rr(a, b);
      } else if (a < k_ || b < k_) {  // robot × map: from the working set
        const int robot = std::min(a, b), row = std::max(a, b);
        const auto it = column_of_.find(row);
        if (it != column_of_.end()) P(i, j) = P_rW_(robot, it->second);
      }
    }
  }
  for (std::size_t a = 0; a < map_at.size(); ++a)
    for (std::size_t b = 0; b < map_at.size(); ++b)
      P(map_at[a], map_at[b]) = P_mm(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
  return P;
}

void ConsideredMap::predict(const Eigen::MatrixXd& J_rr) {
  const auto used = static_cast<Eigen::Index>(rows_.size());
  if (used > 0) P_rW_.leftCols(used) = (J_rr * P_rW_.leftCols(used)).eval();
}

int ConsideredMap::enter(int row, std::int64_t step, const std::vector<int>& keep) {
  if (const auto it = column_of_.find(row); it != column_of_.end()) {
    last_used_[static_cast<std::size_t>(it->second)] = step;
    return it->second;
  }
  if (static_cast<int>(rows_.size()) >= capacity_) {
    // Full: the least recently observed row that this step does not observe
    // leaves (its column is filled by the last one).
    int victim = -1;
    for (int c = 0; c < static_cast<int>(rows_.size()); ++c) {
      if (std::find(keep.begin(), keep.end(), rows_[static_cast<std::size_t>(c)]) != keep.end()) continue;
      if (victim < 0 || last_used_[static_cast<std::size_t>(c)] < last_used_[static_cast<std::size_t>(victim)])
        victim = c;
    }
    if (victim >= 0) {
      const int last = static_cast<int>(rows_.size()) - 1;
      column_of_.erase(rows_[static_cast<std::size_t>(victim)]);
      if (victim != last) {
        P_rW_.col(victim) = P_rW_.col(last);
        rows_[static_cast<std::size_t>(victim)] = rows_.back();
        last_used_[static_cast<std::size_t>(victim)] = last_used_.back();
        column_of_[rows_[static_cast<std::size_t>(victim)]] = victim;
      }
      rows_.pop_back();
      last_used_.pop_back();
      ++evicted_;
    }
  }
  const auto col = static_cast<Eigen::Index>(rows_.size());
  if (col >= P_rW_.cols()) P_rW_.conservativeResize(Eigen::NoChange, col + 1);  // one step observes more than capacity
  // A row enters with the correlation with the robot that it has through the
  // rows U of W its own blocks correlate it with (another coordinate of the
  // same feature): P_rc = P_rU P_UU⁻¹ P_Uc, i.e. the robot and the row are
  // taken as independent given U. That keeps the whole covariance valid
  // (positive semi-definite); it is exact for a row never observed whose
  // feature's other rows were never observed either (P_rc = 0).
  P_rW_.col(col).setZero();
  if (const auto it = neighbours_.find(row); it != neighbours_.end()) {
    std::vector<int> U;
    for (const auto& [r, v] : it->second)
      if (r != row && column_of_.count(r) != 0) U.push_back(r);
    if (!U.empty()) {
      const Eigen::LDLT<Eigen::MatrixXd> P_UU(map_block(U, U));
      if (P_UU.info() == Eigen::Success && (P_UU.vectorD().array() > 0.0).all()) {
        Eigen::MatrixXd P_rU(k_, static_cast<Eigen::Index>(U.size()));
        for (std::size_t j = 0; j < U.size(); ++j) P_rU.col(static_cast<Eigen::Index>(j)) = P_rW_.col(column_of_.at(U[j]));
        P_rW_.col(col) = P_rU * P_UU.solve(map_block(U, {row}));
      }
    }
  }
  rows_.push_back(row);
  last_used_.push_back(step);
  column_of_[row] = static_cast<int>(col);
  return static_cast<int>(col);
}

LinearizedObservation ConsideredMap::condition(const std::vector<LinearizedObservation>& obs,
                                               const Eigen::MatrixXd& P_rr, std::int64_t step) {
  // The observed map rows O, and the stacked H_r, H_O, C_η.
  std::vector<int> observed;
  Eigen::Index m = 0;
  for (const LinearizedObservation& o : obs) {
    m += o.eta.size();
    for (int r : o.idx)
      if (r >= k_ && std::find(observed.begin(), observed.end(), r) == observed.end()) observed.push_back(r);
  }
  for (int r : observed) enter(r, step, observed);
  const auto nO = static_cast<Eigen::Index>(observed.size());
  const auto nW = static_cast<Eigen::Index>(rows_.size());
  Eigen::MatrixXd H_r = Eigen::MatrixXd::Zero(m, k_), H_O = Eigen::MatrixXd::Zero(m, nO);
  LinearizedObservation out;
  out.eta.resize(m);
  out.C_eta = Eigen::MatrixXd::Zero(m, m);
  Eigen::Index at = 0;
  for (const LinearizedObservation& o : obs) {
    const Eigen::Index mi = o.eta.size();
    out.eta.segment(at, mi) = o.eta;
    out.C_eta.block(at, at, mi, mi) = o.C_eta;
    for (std::size_t c = 0; c < o.idx.size(); ++c) {
      const int r = o.idx[c];
      if (r < k_)
        H_r.block(at, r, mi, 1) += o.J.col(static_cast<Eigen::Index>(c));
      else
        H_O.block(at, std::find(observed.begin(), observed.end(), r) - observed.begin(), mi, 1) +=
            o.J.col(static_cast<Eigen::Index>(c));
    }
    at += mi;
  }
  Eigen::MatrixXd P_rO(k_, nO);
  for (Eigen::Index j = 0; j < nO; ++j) P_rO.col(j) = P_rW_.col(column_of_.at(observed[static_cast<std::size_t>(j)]));
  const Eigen::MatrixXd P_OO = map_block(observed, observed);

  // The equivalent observation of the robot alone (top of this file).
  const Eigen::MatrixXd A = (psd_pseudo_inverse(P_rr) * P_rO).transpose();  // |O| × k: P_Or P_rr⁻¹
  out.J = H_r + H_O * A;
  Eigen::MatrixXd W = P_OO - A * P_rO;  // P_OO − P_Or P_rr⁻¹ P_rO
  W = 0.5 * (W + W.transpose()).eval();
  out.C_eta += H_O * W * H_O.transpose();
  out.C_eta = 0.5 * (out.C_eta + out.C_eta.transpose()).eval();
  out.idx.resize(static_cast<std::size_t>(k_));
  for (int i = 0; i < k_; ++i) out.idx[static_cast<std::size_t>(i)] = i;

  // The gain and (H P)_W for commit().
  const Eigen::MatrixXd PHt = P_rr * H_r.transpose() + P_rO * H_O.transpose();  // k × m
  const Eigen::MatrixXd S = out.J * P_rr * out.J.transpose() + out.C_eta;
  const Eigen::LDLT<Eigen::MatrixXd> S_ldlt(S);
  if (S_ldlt.info() != Eigen::Success)
    throw std::runtime_error("localize: the innovation covariance S (" + std::to_string(m) + " x " +
                             std::to_string(m) + ") of the consider update cannot be factorised");
  K_r_ = S_ldlt.solve(PHt.transpose()).transpose();
  G_ = H_r * P_rW_.leftCols(nW);
  if (joint_) {
    G_ += H_O * map_block(observed, rows_);
  } else {
    // H_O P_OW of the block model: an observed row is correlated only with
    // the rows of its features' own blocks (a few per row, not |W|).
    for (Eigen::Index j = 0; j < nO; ++j) {
      const auto it = neighbours_.find(observed[static_cast<std::size_t>(j)]);
      if (it == neighbours_.end()) continue;
      for (const auto& [row, v] : it->second)
        if (const auto col = column_of_.find(row); col != column_of_.end()) G_.col(col->second) += v * H_O.col(j);
    }
  }
  return out;
}

StateAugmentation ConsideredMap::as_augmentation(const Eigen::MatrixXd& P_rr, const Eigen::MatrixXd& P_mm) const {
  Eigen::MatrixXd P_rm = Eigen::MatrixXd::Zero(k_, rows_in_map_);
  for (std::size_t c = 0; c < rows_.size(); ++c) P_rm.col(rows_[c] - k_) = P_rW_.col(static_cast<Eigen::Index>(c));
  StateAugmentation aug;
  aug.idx.resize(static_cast<std::size_t>(k_));
  for (int i = 0; i < k_; ++i) aug.idx[static_cast<std::size_t>(i)] = i;
  aug.J = (psd_pseudo_inverse(P_rr) * P_rm).transpose();  // P_mr P_rr⁻¹
  const Eigen::MatrixXd C = P_mm - aug.J * P_rm;
  aug.C_new = 0.5 * (C + C.transpose());
  return aug;
}

void ConsideredMap::commit() {
  const Eigen::Index nW = G_.cols();
  if (K_r_.size() == 0 || nW == 0) return;
  P_rW_.leftCols(nW) -= K_r_ * G_;
  K_r_.resize(0, 0);
  G_.resize(0, 0);
}

}  // namespace mspace::kernel
