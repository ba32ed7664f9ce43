// estimator_support.cpp — input checks and observation stacking of the estimators.
#include "mspace/estimator_support.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <stdexcept>

namespace mspace::estimator_support {

using Eigen::Index;

std::string size_text(Index rows, Index cols) { return std::to_string(rows) + " x " + std::to_string(cols); }

void require_finite(const Eigen::Ref<const Eigen::MatrixXd>& m, const std::string& context, const char* name) {
  for (Index r = 0; r < m.rows(); ++r) {
    if (!m.row(r).allFinite()) {
      throw std::invalid_argument(context + ": " + name + " row " + std::to_string(r) + " is not finite");
    }
  }
}

void require_size(const Eigen::MatrixXd& m, Index rows, Index cols, const std::string& context, const char* name) {
  if (m.rows() != rows || m.cols() != cols) {
    throw std::invalid_argument(context + ": " + name + " is " + size_text(m.rows(), m.cols()) + ", expected " +
                                size_text(rows, cols));
  }
}

void require_indices(const std::vector<int>& idx, int n, const std::string& context, bool distinct) {
  for (int i : idx) {
    if (i < 0 || i >= n) {
      throw std::invalid_argument(context + ": index " + std::to_string(i) + " is out of range [0, " +
                                  std::to_string(n) + ")");
    }
  }
  if (!distinct) return;
  std::vector<int> sorted = idx;
  std::sort(sorted.begin(), sorted.end());
  const auto twice = std::adjacent_find(sorted.begin(), sorted.end());
  if (twice != sorted.end()) {
    throw std::invalid_argument(context + ": index " + std::to_string(*twice) + " appears more than once");
  }
}

void validate_reset(const Eigen::MatrixXd& P_rr, const std::string& context) {
  require_size(P_rr, P_rr.rows(), P_rr.rows(), context, "P_rr");
  require_finite(P_rr, context, "P_rr");
}

void validate_observation(const LinearizedObservation& o, int n, const std::string& context) {
  const Index m = o.J.rows();
  if (o.J.cols() != static_cast<Index>(o.idx.size())) {
    throw std::invalid_argument(context + ": J has " + std::to_string(o.J.cols()) + " columns but idx has " +
                                std::to_string(o.idx.size()) + " indices");
  }
  if (o.eta.size() != m) {
    throw std::invalid_argument(context + ": eta has " + std::to_string(o.eta.size()) + " rows but J has " +
                                std::to_string(m));
  }
  require_size(o.C_eta, m, m, context, "C_eta");
  require_indices(o.idx, n, context, true);
  require_finite(o.eta, context, "eta");
  require_finite(o.J, context, "J");
  require_finite(o.C_eta, context, "C_eta");
}

void validate_augmentation(const StateAugmentation& aug, int n, const std::string& context) {
  const Index added = aug.C_new.rows();
  require_size(aug.C_new, added, added, context, "C_new");
  require_size(aug.J, added, static_cast<Index>(aug.idx.size()), context, "J");
  require_indices(aug.idx, n, context, false);
  require_finite(aug.J, context, "J");
  require_finite(aug.C_new, context, "C_new");
}

void validate_prediction(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q, int k, const std::string& context) {
  require_size(J_rr, k, k, context, "J_rr");
  require_size(Q, k, k, context, "Q");
  require_finite(J_rr, context, "J_rr");
  require_finite(Q, context, "Q");
}

void validate_removal(const std::vector<int>& idx, int n, int k, const std::string& context) {
  require_indices(idx, n, context, true);
  for (int i : idx) {
    if (i < k) {
      throw std::invalid_argument(context + ": index " + std::to_string(i) +
                                  " is a robot pose coordinate (robot dimension " + std::to_string(k) + ")");
    }
  }
}

// ---------------------------------------------------------------- observability constraint

void UnobservableDirections::reset(int k) {
  k_ = k;
  U_ = Eigen::MatrixXd::Zero(k, 0);
}

void UnobservableDirections::set_robot_rows(const Eigen::MatrixXd& U_r, const std::string& context) {
  require_size(U_r, k_, U_r.cols(), context, "U_r");
  require_finite(U_r, context, "U_r");
  if (U_.cols() != U_r.cols()) U_ = Eigen::MatrixXd::Zero(U_.rows(), U_r.cols());
  U_.topRows(k_) = U_r;
}

void UnobservableDirections::set(const Eigen::MatrixXd& U, const std::string& context) {
  if (U.rows() != k_ && U.rows() == U_.rows()) {
    require_finite(U, context, "U");
    U_ = U;
    return;
  }
  set_robot_rows(U, context);
}

void UnobservableDirections::predict(const Eigen::MatrixXd& J_rr) {
  U_.topRows(k_) = (J_rr * U_.topRows(k_)).eval();
}

void UnobservableDirections::augment(const StateAugmentation& aug) {
  const Eigen::MatrixXd rows = aug.J * U_(aug.idx, Eigen::all);
  const Index old = U_.rows();
  U_.conservativeResize(old + rows.rows(), Eigen::NoChange);
  U_.bottomRows(rows.rows()) = rows;
}

void UnobservableDirections::save(StateWriter& out, const std::string& prefix) const {
  out.put(prefix + "k", Eigen::MatrixXd::Constant(1, 1, k_));
  out.put(prefix + "U", U_);
}

void UnobservableDirections::restore(const StateReader& in, const std::string& prefix, Index rows,
                                     const std::string& context) {
  const Eigen::MatrixXd& k = get_state(in, prefix + "k", 1, 1, context);
  const Eigen::MatrixXd& U = get_state(in, prefix + "U", rows, -1, context);
  require_finite(U, context, "U");
  if (!(k(0, 0) >= 0 && k(0, 0) <= static_cast<double>(rows)))
    throw std::invalid_argument(context + ": saved robot dimension " + std::to_string(k(0, 0)) + " is out of range");
  k_ = static_cast<int>(k(0, 0));
  U_ = U;
}

Eigen::MatrixXd pack_lower(const Eigen::MatrixXd& store, Index n) {
  Eigen::MatrixXd packed(n * (n + 1) / 2, 1);
  Index at = 0;
  for (Index c = 0; c < n; ++c) {
    packed.col(0).segment(at, n - c) = store.col(c).segment(c, n - c);
    at += n - c;
  }
  return packed;
}

void unpack_lower(const Eigen::MatrixXd& packed, Index n, Eigen::MatrixXd& store, const std::string& context) {
  require_size(packed, n * (n + 1) / 2, 1, context, "packed lower triangle");
  require_finite(packed, context, "packed lower triangle");
  Index at = 0;
  for (Index c = 0; c < n; ++c) {
    store.col(c).segment(c, n - c) = packed.col(0).segment(at, n - c);
    at += n - c;
  }
}

void save_capacity(StateWriter& out, const std::string& name, const Eigen::MatrixXd& store) {
  Eigen::MatrixXd shape(1, 2);
  shape << static_cast<double>(store.rows()), static_cast<double>(store.cols());
  out.put(name + "_capacity", shape);
}

Eigen::MatrixXd restore_capacity(const StateReader& in, const std::string& name, Index rows, Index cols,
                                 const std::string& context) {
  const Eigen::MatrixXd& shape = get_state(in, name + "_capacity", 1, 2, context);
  constexpr double kMaxSide = 1e8;
  if (!(shape(0, 0) >= static_cast<double>(rows) && shape(0, 1) >= static_cast<double>(cols) &&
        shape(0, 0) <= kMaxSide && shape(0, 1) <= kMaxSide))
    throw std::invalid_argument(context + ": saved capacity of '" + name + "' (" + std::to_string(shape(0, 0)) +
                                " x " + std::to_string(shape(0, 1)) + ") does not hold " + size_text(rows, cols));
  return Eigen::MatrixXd::Zero(static_cast<Index>(shape(0, 0)), static_cast<Index>(shape(0, 1)));
}

void UnobservableDirections::keep_rows(const std::vector<int>& keep) { U_ = U_(keep, Eigen::all).eval(); }

std::vector<LinearizedObservation> UnobservableDirections::constrain(const std::vector<LinearizedObservation>& obs,
                                                                     const std::string& context) const {
  std::vector<LinearizedObservation> out = obs;
  if (U_.cols() == 0) return out;
  for (std::size_t i = 0; i < out.size(); ++i) {
    // Checked here already because U[idx] needs valid indices.
    validate_observation(out[i], static_cast<int>(U_.rows()), context + ": observation " + std::to_string(i));
    out[i].J = annihilating(out[i].J, U_(out[i].idx, Eigen::all));
  }
  return out;
}

Eigen::MatrixXd annihilating(const Eigen::MatrixXd& J, const Eigen::MatrixXd& U) {
  const Eigen::MatrixXd G = (U.transpose() * U).completeOrthogonalDecomposition().pseudoInverse();
  return J - J * U * G * U.transpose();
}

// ---------------------------------------------------------------- stacking

namespace {

std::vector<int> union_of_indices(const std::vector<LinearizedObservation>& obs) {
  std::vector<int> all;
  for (const auto& o : obs) all.insert(all.end(), o.idx.begin(), o.idx.end());
  std::sort(all.begin(), all.end());
  all.erase(std::unique(all.begin(), all.end()), all.end());
  return all;
}

}  // namespace

StackedObservation stack_observations(const std::vector<LinearizedObservation>& obs, int n,
                                      const std::string& context) {
  Index m = 0;
  for (std::size_t i = 0; i < obs.size(); ++i) {
    validate_observation(obs[i], n, context + ": observation " + std::to_string(i));
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
      const auto pos = std::lower_bound(s.union_idx.begin(), s.union_idx.end(), o.idx[c]) - s.union_idx.begin();
      s.J.block(row, pos, rows, 1) = o.J.col(static_cast<Index>(c));
    }
    row += rows;
  }
  return s;
}

}  // namespace mspace::estimator_support
