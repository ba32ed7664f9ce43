// problem.cpp — pose nodes and factors of the nonlinear problem (problem.hpp).
#include "problem.hpp"
#include "problem_factor.hpp"

#include <algorithm>
#include <map>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include <Eigen/LU>

#include "mspace/transform.hpp"
#include "slam.hpp"

namespace mspace::kernel {

namespace {

Eigen::MatrixXd select_columns(const Mat6& J, const std::vector<int>& dofs) {
  Eigen::MatrixXd out(6, static_cast<Eigen::Index>(dofs.size()));
  for (std::size_t j = 0; j < dofs.size(); ++j) out.col(static_cast<Eigen::Index>(j)) = J.col(dofs[j]);
  return out;
}

void add_to_pose(Pose6& x, const std::vector<int>& dofs, const Eigen::Ref<const Eigen::VectorXd>& d) {
  for (std::size_t i = 0; i < dofs.size(); ++i) x[dofs[i]] += d[static_cast<Eigen::Index>(i)];
  for (int a = kTheta; a <= kPsi; ++a) x[a] = wrap_angle(x[a]);
}

}  // namespace

Problem::Problem(Context context) : c_(std::move(context)), k_(static_cast<int>(c_.dofs.size())) {}

Problem::~Problem() = default;

int Problem::state_dim() const { return c_.estimator->dim(); }

int Problem::tangent_dim() const {
  const int past = static_cast<int>(nodes_.size()) - (current_ ? 1 : 0);
  return state_dim() + k_ * past;
}

int Problem::pose_node_index(int node) const {
  if (current_ && node == static_cast<int>(nodes_.size()) - 1) return 0;
  return state_dim() + k_ * node;
}

Pose6 Problem::node_value(int node) const {
  if (current_ && node == static_cast<int>(nodes_.size()) - 1) return *c_.x_r;
  return nodes_[static_cast<std::size_t>(node)];
}

int Problem::live_observation_factors() const {
  return static_cast<int>(std::count_if(factors_.begin(), factors_.end(), [](const auto& f) { return f->live; }));
}

bool Problem::live_factors_match_features() const {
  std::unordered_map<int, const MapFeature*> by_id;
  for (const MapFeature& mf : *c_.features) by_id[mf.id] = &mf;
  for (const auto& f : factors_) {
    if (!f->live) continue;
    const auto it = by_id.find(f->feature_id);
    if (it == by_id.end() || it->second->feature->mspace_dim() != f->dim || it->second->state_idx != f->rows)
      return false;
  }
  return true;
}

void Problem::sync_rows() {
  const int n = state_dim();
  const auto old = acc_.size();
  if (old == n) return;
  acc_.conservativeResize(n);
  if (n > old) acc_.tail(n - old).setZero();
}

// ---- recording ----------------------------------------------------------------

void Problem::start(const Eigen::MatrixXd& P0) {
  factors_.clear();  // (a restart before the first step: a loaded map moves the start)
  pending_.clear();
  pending_records_.clear();
  frozen_ = 0;
  acc_.resize(0);
  sync_rows();
  nodes_ = {*c_.x_r};
  records_ = {0};
  current_ = true;
  auto f = std::make_unique<Factor>();
  f->kind = FactorKind::Prior;
  f->eta = Eigen::VectorXd::Zero(k_);
  f->J = Eigen::MatrixXd::Identity(k_, k_);
  // A zero initial σ (the map frame defined by the first pose) is kept as a
  // very stiff prior (σ = 1 µm / 1 µrad) so that C stays invertible.
  f->C = P0 + 1e-12 * Eigen::MatrixXd::Identity(k_, k_);
  f->lin_nodes = {0};
  f->node_base = {*c_.x_r};
  factors_.push_back(std::move(f));
}

void Problem::motion(const Eigen::VectorXd& x_d, double dt, std::size_t record, const Eigen::MatrixXd& C_d) {
  if (x_d.size() == 0 || nodes_.empty()) return;
  if (current_) {  // the newest node keeps the value it has before the robot moves
    nodes_.back() = *c_.x_r;
    current_ = false;
  }
  pending_.push_back({x_d, dt, C_d});
  pending_records_.push_back(record);
}

void Problem::key_pose(std::size_t record) {
  if (nodes_.empty()) return;
  if (current_) {  // no motion since the newest node: it stands for this step too
    records_.back() = record;
    return;
  }
  nodes_.push_back(*c_.x_r);
  records_.push_back(record);
  current_ = true;
  node_this_step_ = true;
  auto f = std::make_unique<Factor>();
  f->kind = FactorKind::Motion;
  f->from = static_cast<int>(nodes_.size()) - 2;
  f->to = static_cast<int>(nodes_.size()) - 1;
  f->odometry = std::move(pending_);
  f->odometry_records = std::move(pending_records_);
  pending_.clear();
  pending_records_.clear();
  factors_.push_back(std::move(f));
}

void Problem::observed(const MapFeature& mf, const Measurement& m, int sensor, const Innovation& in,
                       const Eigen::MatrixXd& C_eta, const Eigen::MatrixXd& J_state) {
  sync_rows();
  if (!current_) throw std::logic_error("problem: an observation without a pose node");
  auto f = std::make_unique<Factor>();
  f->kind = FactorKind::Observation;
  f->live = true;
  f->robust = true;
  f->feature_id = mf.id;
  f->feature = mf.feature;
  f->type = mf.type;
  // The innovation reads v, C_v, kind and flags; the dense evidence belongs
  // to phase 3 and is not kept.
  f->m.kind = m.kind;
  f->m.v = m.v;
  f->m.C_v = m.C_v;
  f->m.flags = m.flags;
  f->sensor = sensor;
  f->node = static_cast<int>(nodes_.size()) - 1;
  f->rows = mf.state_idx;
  f->dim = mf.feature->mspace_dim();
  f->eta = in.eta;
  f->J = J_state;
  f->C = C_eta;
  f->lin_nodes = {f->node};
  f->node_base = {*c_.x_r};
  f->lin_rows = f->rows;
  f->row_base = acc_(f->rows);
  factors_.push_back(std::move(f));
}

void Problem::moved(const Eigen::VectorXd& dx) {
  sync_rows();
  acc_ += dx;
}

void Problem::freeze(Factor& f) {
  if (!f.live) return;
  f.live = false;
  ++frozen_;
}

void Problem::freeze_feature(int feature_id) {
  const auto snapshot = snapshots_.find(feature_id);
  for (auto& f : factors_) {
    if (!f->live || f->feature_id != feature_id) continue;
    if (snapshot != snapshots_.end()) freeze_in_frame(*f, snapshot->second);
    freeze(*f);
  }
  if (snapshot != snapshots_.end()) snapshots_.erase(snapshot);
}

void Problem::before_extend(const MapFeature& mf) {
  if (!c_.freeze_in_sensor_frame) return;
  const FeatureTypeSlot& type = (*c_.types)[static_cast<std::size_t>(mf.type)];
  snapshot(mf, guarded(type.instance, *type.library, "B", [&] { return mf.feature->B(); }));
}

void Problem::snapshot(const MapFeature& mf, const Eigen::MatrixXd& B) {
  sync_rows();
  snapshots_[mf.id] = {B, mf.feature->coords()};
  // A live factor whose pose node moved since its last linearisation (a
  // loop closure's warp) is linearised again, for freezing: that turn would
  // otherwise be frozen into G.
  constexpr double kMovedM = 0.01, kMovedRad = 1e-3;
  FactorLinearization lin;
  for (auto& f : factors_) {
    if (!f->live || f->feature_id != mf.id || f->feature->mspace_dim() != f->dim || f->node_base.size() != 1) continue;
    const Pose6 d = pose_difference(node_value(f->node), f->node_base.front());
    if (d.head<3>().norm() > kMovedM || d.tail<3>().cwiseAbs().maxCoeff() > kMovedRad) evaluate_observation(*f, lin);
  }
}

bool Problem::in_frame(int i) const { return factors_.at(static_cast<std::size_t>(i))->in_frame; }

const MapFeature* Problem::map_feature(int id) const {
  // Slam appends features with rising ids and only erases: a sorted vector.
  const auto it = std::lower_bound(c_.features->begin(), c_.features->end(), id,
                                   [](const MapFeature& mf, int key) { return mf.id < key; });
  if (it != c_.features->end() && it->id == id) return &*it;
  for (const MapFeature& mf : *c_.features)
    if (mf.id == id) return &mf;
  return nullptr;
}

bool Problem::freeze_in_frame(Factor& f, const Snapshot& before) {
  const int dim = static_cast<int>(f.lin_rows.size());
  if (f.kind != FactorKind::Observation || f.lin_nodes.size() != 1 || f.lin_nodes.front() != f.node ||
      before.B.rows() != dim || f.J.cols() != k_ + dim)
    return false;
  FactorLinearization now;
  evaluate_linear(f, now);  // η at the current values (the feature as it was before the change)
  // η per change of x_f: J_f δx_p with δx_p = B_old δx_f (eq. 10).
  return move_into_frame(f, now.eta, f.J.rightCols(dim) * before.B, before.x, f.node, f.sensor);
}

bool Problem::move_into_frame(Factor& f, const Eigen::VectorXd& eta, const Eigen::MatrixXd& G_f,
                              const Eigen::VectorXd& x_f, int node, int sensor) {
  if (x_f.size() != f.feature->layout().size() || G_f.cols() != x_f.size() || G_f.rows() != eta.size())
    return false;
  const Pose6 mount = sensor >= 0 ? c_.mounts[static_cast<std::size_t>(sensor)] : Pose6::Zero();
  const Pose6 x_ms = compound(node_value(node), mount);  // eq. 17
  Eigen::MatrixXd J_of, J_os;
  const Eigen::VectorXd x_o = to_sensor_frame(f.feature->layout(), x_f, x_ms, &J_of, &J_os);  // eqs. 7–9
  const Eigen::FullPivLU<Eigen::MatrixXd> lu(J_of);
  if (J_of.rows() != J_of.cols() || !lu.isInvertible()) return false;
  const Eigen::MatrixXd G = G_f * lu.inverse();  // δx_f = J_of⁻¹ δx_o
  if (!G.allFinite() || !eta.allFinite()) return false;
  f.in_frame = true;
  f.node = node;
  f.sensor = sensor;
  f.eta = eta;
  f.G = G;
  f.x_o_base = x_o;
  f.J = Eigen::MatrixXd(eta.size(), 0);
  f.lin_nodes.clear();
  f.node_base.clear();
  f.lin_rows.clear();
  f.row_base.resize(0);
  return true;
}

bool Problem::evaluate_in_frame(const Factor& f, FactorLinearization& out) const {
  const MapFeature* mf = map_feature(f.feature_id);
  if (mf == nullptr)
    throw std::logic_error("problem: a frozen observation of feature " + std::to_string(f.feature_id) +
                           ", which is no longer in the map");
  const FeatureTypeSlot& type = (*c_.types)[static_cast<std::size_t>(mf->type)];
  Mat6 J_sr;
  const Pose6 mount = f.sensor >= 0 ? c_.mounts[static_cast<std::size_t>(f.sensor)] : Pose6::Zero();
  const Pose6 x_ms = compound(node_value(f.node), mount, &J_sr);  // eq. 17
  Eigen::MatrixXd J_of, J_os;
  const Eigen::VectorXd x_o = to_sensor_frame(mf->feature->layout(), mf->feature->coords(), x_ms, &J_of, &J_os);
  const Eigen::MatrixXd Bd = guarded(type.instance, *type.library, "B_dual", [&] { return mf->feature->B_dual(); });
  out.kind = f.kind;
  out.robust = f.robust;
  out.eta = f.eta + f.G * (x_o - f.x_o_base);
  out.J.resize(f.G.rows(), k_ + Bd.cols());
  out.J.leftCols(k_) = f.G * J_os * select_columns(J_sr, c_.dofs);  // as eq. 30, with G for J_ηo
  out.J.rightCols(Bd.cols()) = f.G * J_of * Bd;
  out.C = f.C;
  out.idx.clear();
  for (int j = 0; j < k_; ++j) out.idx.push_back(pose_node_index(f.node) + j);
  out.idx.insert(out.idx.end(), mf->state_idx.begin(), mf->state_idx.end());
  return true;
}

void Problem::extended(const MapFeature& mf, const StateAugmentation& aug, int first) {
  sync_rows();
  freeze_feature(mf.id);
  added(aug, first);
  // The extension's prior is relative too (the new coordinates as seen from
  // the robot): kept in the robot's frame, over the rows the feature will
  // have (its own rows, the new ones, then shared groups: Slam::extend).
  if (!c_.freeze_in_sensor_frame) return;
  Factor& f = *factors_.back();
  if (f.lin_nodes.size() != 1) return;  // a prior without the robot (a loaded map's) stays as it is
  std::vector<int> new_idx(mf.own_idx.begin(), mf.own_idx.end());
  for (Eigen::Index i = 0; i < aug.C_new.rows(); ++i) new_idx.push_back(first + static_cast<int>(i));
  new_idx.insert(new_idx.end(), mf.state_idx.begin() + static_cast<std::ptrdiff_t>(mf.own_idx.size()),
                 mf.state_idx.end());
  const FeatureTypeSlot& type = (*c_.types)[static_cast<std::size_t>(mf.type)];
  const Eigen::MatrixXd B = guarded(type.instance, *type.library, "B", [&] { return mf.feature->B(); });
  if (B.rows() != static_cast<Eigen::Index>(new_idx.size())) return;
  Eigen::MatrixXd G_f = Eigen::MatrixXd::Zero(f.J.rows(), B.cols());  // Σ over rows of J_row B_row (eq. 10)
  for (std::size_t j = 0; j < f.lin_rows.size(); ++j) {
    const auto pos = std::find(new_idx.begin(), new_idx.end(), f.lin_rows[j]) - new_idx.begin();
    if (pos == static_cast<std::ptrdiff_t>(new_idx.size())) return;
    G_f += f.J.col(k_ + static_cast<Eigen::Index>(j)) * B.row(pos);
  }
  f.feature_id = mf.id;
  f.feature = mf.feature;
  if (!move_into_frame(f, f.eta, G_f, mf.feature->coords(), f.lin_nodes.front(), -1)) {
    f.feature_id = 0;
    f.feature.reset();
  }
}

void Problem::added(const StateAugmentation& aug, int first) {
  sync_rows();
  // δx_new − J_sensor J_sr δx_r − J_own δx_p,old = w ~ N(0, C_new): a linear
  // factor on the current node, the old rows and the new rows, zero at the
  // values of this moment (the extension's own estimate; for a loaded map,
  // the map's joint covariance given the robot).
  const auto n = aug.C_new.rows();
  auto f = std::make_unique<Factor>();
  f->kind = FactorKind::Linear;
  bool robot = false;
  for (int i : aug.idx) {
    if (i < k_) {
      robot = true;
    } else if (std::find(f->lin_rows.begin(), f->lin_rows.end(), i) == f->lin_rows.end()) {
      f->lin_rows.push_back(i);
    }
  }
  for (Eigen::Index i = 0; i < n; ++i) f->lin_rows.push_back(first + static_cast<int>(i));
  const int node_cols = robot ? k_ : 0;
  f->J = Eigen::MatrixXd::Zero(n, node_cols + static_cast<Eigen::Index>(f->lin_rows.size()));
  const auto col_of_row = [&](int row) {
    return node_cols + static_cast<Eigen::Index>(std::find(f->lin_rows.begin(), f->lin_rows.end(), row) -
                                                 f->lin_rows.begin());
  };
  for (std::size_t j = 0; j < aug.idx.size(); ++j) {
    const int i = aug.idx[j];
    const Eigen::Index col = i < k_ ? i : col_of_row(i);
    f->J.col(col) -= aug.J.col(static_cast<Eigen::Index>(j));
  }
  for (Eigen::Index i = 0; i < n; ++i) f->J(i, col_of_row(first + static_cast<int>(i))) += 1.0;
  f->eta = Eigen::VectorXd::Zero(n);
  f->C = aug.C_new;
  if (robot) {
    f->lin_nodes = {static_cast<int>(nodes_.size()) - 1};
    f->node_base = {node_value(f->lin_nodes.front())};
  }
  f->row_base = acc_(f->lin_rows);
  factors_.push_back(std::move(f));
}

void Problem::before_join(const MapFeature& a, const MapFeature& b) {
  join_a_ = a.id;
  join_b_ = b.id;
  B_a_ = a.feature->B();
  B_b_ = b.feature->B();
  old_idx_a_ = a.state_idx;
  old_idx_b_ = b.state_idx;
  x_a_ = a.feature->coords();
  x_b_ = b.feature->coords();
  if (c_.freeze_in_sensor_frame) {
    snapshot(a, B_a_);
    snapshot(b, B_b_);
  }
}

// Folds the perturbations since the factor's linearisation into eta, so that
// its linearisation point is the current values.
void Problem::rebase(Factor& f) {
  FactorLinearization lin;
  evaluate_linear(f, lin);
  f.eta = lin.eta;
  for (std::size_t i = 0; i < f.lin_nodes.size(); ++i) f.node_base[i] = node_value(f.lin_nodes[i]);
  f.row_base = acc_(f.lin_rows);
}

void Problem::joined(const MapFeature& a, const MapFeature& b, std::vector<int> obsolete) {
  sync_rows();
  std::sort(obsolete.begin(), obsolete.end());
  freeze_feature(a.id);
  freeze_feature(b.id);
  // Old perturbations as functions of the new ones: δx_f = B̃_old δp_old =
  // B̃_new δp_new, so δp_old = B_old B̃_new δp_new (eqs. 10–12); share_block
  // also moved x_f (the end point onto the common value), which in the old
  // rows is the jump B_old Δx_f.
  struct Side {
    const std::vector<int>* old_idx;
    const std::vector<int>* new_idx;
    Eigen::MatrixXd M;
    Eigen::VectorXd jump;
  };
  const Side sides[2] = {
      {&old_idx_a_, &a.state_idx, B_a_ * a.feature->B_dual(), B_a_ * (a.feature->coords() - x_a_)},
      {&old_idx_b_, &b.state_idx, B_b_ * b.feature->B_dual(), B_b_ * (b.feature->coords() - x_b_)}};
  const auto is_obsolete = [&](int row) { return std::binary_search(obsolete.begin(), obsolete.end(), row); };

  for (auto& fp : factors_) {
    Factor& f = *fp;
    if (f.kind == FactorKind::Motion || f.live) continue;
    if (std::none_of(f.lin_rows.begin(), f.lin_rows.end(), is_obsolete)) continue;
    rebase(f);
    const int node_cols = k_ * static_cast<int>(f.lin_nodes.size());
    // The jump of the old rows, once per row (a row may be in both features).
    std::vector<int> jumped;
    for (const Side& s : sides) {
      for (std::size_t p = 0; p < s.old_idx->size(); ++p) {
        const int row = (*s.old_idx)[p];
        const auto it = std::find(f.lin_rows.begin(), f.lin_rows.end(), row);
        if (it == f.lin_rows.end() || std::find(jumped.begin(), jumped.end(), row) != jumped.end()) continue;
        jumped.push_back(row);
        f.eta += f.J.col(node_cols + (it - f.lin_rows.begin())) * s.jump[static_cast<Eigen::Index>(p)];
      }
    }
    // Substitute the obsolete columns.
    std::vector<int> rows;
    for (int row : f.lin_rows)
      if (!is_obsolete(row)) rows.push_back(row);
    for (const Side& s : sides)
      for (int row : *s.new_idx)
        if (std::find(rows.begin(), rows.end(), row) == rows.end()) rows.push_back(row);
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(f.J.rows(), node_cols + static_cast<Eigen::Index>(rows.size()));
    J.leftCols(node_cols) = f.J.leftCols(node_cols);
    const auto col_of = [&](int row) {
      return node_cols + static_cast<Eigen::Index>(std::find(rows.begin(), rows.end(), row) - rows.begin());
    };
    std::vector<bool> done(f.lin_rows.size(), false);
    for (std::size_t j = 0; j < f.lin_rows.size(); ++j) {
      const int row = f.lin_rows[j];
      const Eigen::VectorXd col = f.J.col(node_cols + static_cast<Eigen::Index>(j));
      if (!is_obsolete(row)) {
        J.col(col_of(row)) += col;
        continue;
      }
      for (const Side& s : sides) {
        const auto p = std::find(s.old_idx->begin(), s.old_idx->end(), row) - s.old_idx->begin();
        if (p == static_cast<std::ptrdiff_t>(s.old_idx->size())) continue;
        for (std::size_t q = 0; q < s.new_idx->size(); ++q)
          J.col(col_of((*s.new_idx)[q])) += col * s.M(p, static_cast<Eigen::Index>(q));
        break;
      }
    }
    f.J = J;
    f.lin_rows = rows;
    f.row_base = acc_(f.lin_rows);
  }
}

void Problem::removed(const std::vector<int>& rows) {
  if (rows.empty()) return;
  // acc_ still has the rows (synced before the removal).
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < acc_.size(); ++i)
    if (!std::binary_search(rows.begin(), rows.end(), static_cast<int>(i))) keep.push_back(i);
  acc_ = acc_(keep).eval();
  const auto renumber = [&](std::vector<int>& idx) {
    for (int& i : idx) {
      if (std::binary_search(rows.begin(), rows.end(), i))
        throw std::logic_error("problem: a factor still uses removed estimator row " + std::to_string(i));
      i -= static_cast<int>(std::lower_bound(rows.begin(), rows.end(), i) - rows.begin());
    }
  };
  for (auto& f : factors_) {
    if (f->live) renumber(f->rows);
    else f->rows.clear();  // a frozen factor only has its linearisation's rows
    renumber(f->lin_rows);
  }
}

bool Problem::end_of_step(bool end_of_data) {
  if (!node_this_step_ && !end_of_data) return false;
  node_this_step_ = false;
  sync_rows();
  if (end_of_data && !current_) return false;  // the robot moved on from the newest node: nothing to index it by
  return guarded(c_.estimator_instance, *c_.estimator_lib, "relinearize",
                 [&] { return c_.estimator->relinearize(*this, end_of_data); });
}

void Problem::smoothed(std::vector<StampedPose>& trajectory, std::vector<StampedPose>& evaluated,
                       const Pose6* eval_mount) const {
  const auto write = [&](std::size_t r, const Pose6& x) {
    if (r < trajectory.size()) trajectory[r].pose = x;
    if (r < evaluated.size()) evaluated[r].pose = eval_mount != nullptr ? compound(x, *eval_mount) : x;
  };
  // Steps between two nodes: the motion model from the earlier node, the
  // mismatch at the later one spread over the increments.
  std::vector<Pose6> poses;
  for (const auto& f : factors_) {
    if (f->kind != FactorKind::Motion || f->odometry.empty()) continue;
    poses.clear();
    Pose6 x = node_value(f->from);
    for (const OdometryIncrement& u : f->odometry) {
      x = guarded(c_.motion_instance, *c_.motion_lib, "predict", [&] { return c_.motion->predict(x, u.x_d, u.dt); })
              .pose;
      poses.push_back(x);
    }
    const Pose6 mismatch = pose_difference(node_value(f->to), x);
    const double m = static_cast<double>(poses.size());
    for (std::size_t i = 0; i < poses.size(); ++i) {
      Pose6 p = poses[i];
      for (int d : c_.dofs) p[d] += mismatch[d] * static_cast<double>(i + 1) / m;
      for (int a = kTheta; a <= kPsi; ++a) p[a] = wrap_angle(p[a]);
      write(f->odometry_records[i], p);
    }
  }
  for (int node = 0; node < num_pose_nodes(); ++node) write(records_[static_cast<std::size_t>(node)], node_value(node));
}

// ---- linearisation ------------------------------------------------------------

void Problem::evaluate_linear(const Factor& f, FactorLinearization& out) const {
  const int node_cols = k_ * static_cast<int>(f.lin_nodes.size());
  Eigen::VectorXd v(node_cols + static_cast<Eigen::Index>(f.lin_rows.size()));
  out.idx.clear();
  for (std::size_t i = 0; i < f.lin_nodes.size(); ++i) {
    const Pose6 d = pose_difference(node_value(f.lin_nodes[i]), f.node_base[i]);
    const int first = pose_node_index(f.lin_nodes[i]);
    for (int j = 0; j < k_; ++j) {
      v[k_ * static_cast<Eigen::Index>(i) + j] = d[c_.dofs[static_cast<std::size_t>(j)]];
      out.idx.push_back(first + j);
    }
  }
  for (std::size_t j = 0; j < f.lin_rows.size(); ++j) {
    v[node_cols + static_cast<Eigen::Index>(j)] = acc_[f.lin_rows[j]] - f.row_base[static_cast<Eigen::Index>(j)];
    out.idx.push_back(f.lin_rows[j]);
  }
  out.kind = f.kind == FactorKind::Prior ? FactorKind::Prior : FactorKind::Linear;
  out.robust = f.robust;
  out.eta = f.eta + f.J * v;
  out.J = f.J;
  out.C = f.C;
}

void Problem::store_linearisation(Factor& f, const FactorLinearization& lin) {
  f.eta = lin.eta;
  f.J = lin.J;
  f.C = lin.C;
  f.node_base = {node_value(f.node)};
  f.row_base = acc_(f.lin_rows);
}

bool Problem::evaluate_observation(Factor& f, FactorLinearization& out) {
  const FeatureTypeSlot& type = (*c_.types)[static_cast<std::size_t>(f.type)];
  const Feature& feature = *f.feature;
  Mat6 J_sr;
  const Pose6 x_ms = compound(node_value(f.node), c_.mounts[static_cast<std::size_t>(f.sensor)], &J_sr);  // eq. 17
  const CoordLayout& layout = feature.layout();
  Eigen::MatrixXd J_of, J_os;
  const Eigen::VectorXd x_o = to_sensor_frame(layout, feature.coords(), x_ms, &J_of, &J_os);  // eqs. 7–9
  Innovation in;
  const bool ok = guarded(type.instance, *type.library, "innovation", [&] { return feature.innovation(x_o, f.m, in); });
  const auto m = in.eta.size();
  if (!ok || m == 0 || in.J_eta_o.rows() != m || in.J_eta_o.cols() != layout.size() || in.J_eta_v.rows() != m ||
      in.J_eta_v.cols() != f.m.v.size() || !in.eta.allFinite() || !in.J_eta_o.allFinite())
    return false;
  const Eigen::MatrixXd Bd = guarded(type.instance, *type.library, "B_dual", [&] { return feature.B_dual(); });
  Eigen::MatrixXd A(layout.size(), k_ + Bd.cols());
  A.leftCols(k_) = J_os * select_columns(J_sr, c_.dofs);
  A.rightCols(Bd.cols()) = J_of * Bd;
  out.kind = FactorKind::Observation;
  out.robust = true;
  out.eta = in.eta;
  out.J = in.J_eta_o * A;  // eq. 30: J_ηo (J_os J_sr  J_of B̃)
  out.C = in.J_eta_v * f.m.C_v * in.J_eta_v.transpose();
  out.idx.clear();
  for (int j = 0; j < k_; ++j) out.idx.push_back(pose_node_index(f.node) + j);
  out.idx.insert(out.idx.end(), f.rows.begin(), f.rows.end());
  store_linearisation(f, out);
  return true;
}

bool Problem::evaluate_motion(const Factor& f, FactorLinearization& out) {
  // x_j − g(x_i, u…): the motion model run from node i over the stored
  // increments, J_i = −∏ J_rr, C = Σ chained J_rd C_d J_rdᵀ (eqs. 25–27).
  Pose6 x = node_value(f.from);
  Eigen::MatrixXd chain = Eigen::MatrixXd::Identity(k_, k_);
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(k_, k_);
  for (const OdometryIncrement& u : f.odometry) {
    const MotionPrediction p =
        guarded(c_.motion_instance, *c_.motion_lib, "predict", [&] { return c_.motion->predict(x, u.x_d, u.dt); });
    chain = p.J_rr * chain;
    const Eigen::MatrixXd& C_d = u.C_d.size() > 0 ? u.C_d : p.C_d;  // the data's covariance, when it has one
    C = p.J_rr * C * p.J_rr.transpose() + p.J_rd * C_d * p.J_rd.transpose();
    x = p.pose;
  }
  const Pose6 d = pose_difference(node_value(f.to), x);
  out.kind = FactorKind::Motion;
  out.robust = false;
  out.eta.resize(k_);
  for (int j = 0; j < k_; ++j) out.eta[j] = d[c_.dofs[static_cast<std::size_t>(j)]];
  out.J.resize(k_, 2 * k_);
  out.J.leftCols(k_) = -chain;
  out.J.rightCols(k_).setIdentity();
  out.C = C + 1e-12 * Eigen::MatrixXd::Identity(k_, k_);
  out.idx.clear();
  for (int j = 0; j < k_; ++j) out.idx.push_back(pose_node_index(f.from) + j);
  for (int j = 0; j < k_; ++j) out.idx.push_back(pose_node_index(f.to) + j);
  return true;
}

bool Problem::linearize(int i, FactorLinearization& out) {
  if (i < 0 || i >= num_factors()) throw std::out_of_range("problem: factor " + std::to_string(i) + " does not exist");
  sync_rows();
  Factor& f = *factors_[static_cast<std::size_t>(i)];
  if (f.kind == FactorKind::Motion) return evaluate_motion(f, out);
  if (f.kind == FactorKind::Coincidence) return evaluate_coincidence(f, out);
  // The frozen-factor rule, checked again here: a feature that changed its
  // M-space since the factor was recorded no longer re-linearises it.
  if (f.live && f.feature->mspace_dim() != f.dim) freeze(f);
  if (f.live && evaluate_observation(f, out)) return true;
  if (f.in_frame) return evaluate_in_frame(f, out);
  // Frozen, or rejected at the current values: the last linearisation.
  evaluate_linear(f, out);
  if (f.kind == FactorKind::Observation) out.kind = FactorKind::Observation;
  return true;
}

void Problem::retract(const Eigen::VectorXd& delta) {
  sync_rows();
  if (delta.size() != tangent_dim())
    throw std::invalid_argument("problem retract: delta has " + std::to_string(delta.size()) + " rows, expected " +
                                std::to_string(tangent_dim()));
  if (!delta.allFinite()) throw std::invalid_argument("problem retract: delta is not finite");
  const int n = state_dim();
  for (int node = 0; node < num_pose_nodes(); ++node) {
    const int first = pose_node_index(node);
    if (first == 0) continue;
    add_to_pose(nodes_[static_cast<std::size_t>(node)], c_.dofs, delta.segment(first, k_));
  }
  add_to_pose(*c_.x_r, c_.dofs, delta.head(k_));
  acc_.tail(n - k_) += delta.segment(k_, n - k_);
  for (MapFeature& mf : *c_.features) {  // eq. 24: x_f += B̃(x_f) δx_p
    if (mf.state_idx.empty()) continue;
    const Eigen::VectorXd dx_p = delta(mf.state_idx);
    const FeatureTypeSlot& type = (*c_.types)[static_cast<std::size_t>(mf.type)];
    guarded(type.instance, *type.library, "apply_perturbation", [&] { mf.feature->apply_perturbation(dx_p); });
  }
}

// ---- loop closure ------------------------------------------------------------

namespace {

const MapFeature* find_feature(const std::vector<MapFeature>& features, int id) {
  for (const MapFeature& mf : features)
    if (mf.id == id) return &mf;
  return nullptr;
}

}  // namespace

void Problem::warp(const std::function<std::optional<PlanarMotion>(std::size_t record)>& node_motion,
                   const PlanarMotion& current, const std::vector<std::pair<int, PlanarMotion>>& features) {
  sync_rows();
  const auto moved_pose = [&](const Pose6& x, const PlanarMotion& T) {
    Pose6 y = x;
    y.head<2>() = T.apply(Eigen::Vector2d(x.head<2>()));
    y[kTheta] = wrap_angle(x[kTheta] + T.theta);
    return y;
  };
  const auto pose_delta = [&](const Pose6& from, const Pose6& to) {
    Eigen::VectorXd d(k_);
    const Pose6 diff = to - from;
    for (int j = 0; j < k_; ++j) {
      const int a = c_.dofs[static_cast<std::size_t>(j)];
      d[j] = a >= kTheta ? wrap_angle(diff[a]) : diff[a];
    }
    return d;
  };
  std::vector<std::pair<MapFeature*, Eigen::VectorXd>> targets;
  for (const auto& [index, T] : features) {
    MapFeature& mf = (*c_.features)[static_cast<std::size_t>(index)];
    if (mf.state_idx.empty()) continue;
    targets.emplace_back(&mf, T.apply(mf.feature->layout(), mf.feature->coords()));
  }
  // Each pose node's rigid motion (none: it stays).
  const auto motion_of_node = [&](int node) -> std::optional<PlanarMotion> {
    if (pose_node_index(node) == 0) return current;
    return node_motion(records_[static_cast<std::size_t>(node)]);
  };
  const Eigen::VectorXd acc_before = acc_;
  // Poses move exactly in one retraction (they are added coordinate-wise);
  // features through their M-space, whose B changes as they turn.
  constexpr int kPasses = 5;
  for (int pass = 0; pass < kPasses; ++pass) {
    Eigen::VectorXd delta = Eigen::VectorXd::Zero(tangent_dim());
    if (pass == 0) {
      for (int node = 0; node < num_pose_nodes(); ++node) {
        const int first = pose_node_index(node);
        if (first == 0) continue;
        const std::optional<PlanarMotion> T = node_motion(records_[static_cast<std::size_t>(node)]);
        if (!T) continue;
        const Pose6& x = nodes_[static_cast<std::size_t>(node)];
        delta.segment(first, k_) = pose_delta(x, moved_pose(x, *T));
      }
      delta.head(k_) = pose_delta(*c_.x_r, moved_pose(*c_.x_r, current));
    }
    std::vector<char> assigned(static_cast<std::size_t>(state_dim()), 0);
    for (const auto& [mf, target] : targets) {
      const Eigen::VectorXd dx_p = mf->feature->B() * (target - mf->feature->coords());  // eq. 10
      for (std::size_t j = 0; j < mf->state_idx.size(); ++j) {
        const int row = mf->state_idx[j];
        if (assigned[static_cast<std::size_t>(row)]) continue;  // a shared coordinate: its first member moves it
        assigned[static_cast<std::size_t>(row)] = 1;
        delta[row] = dx_p[static_cast<Eigen::Index>(j)];
      }
    }
    retract(delta);
  }
  // A linear factor (frozen, or an extension's prior) whose variables the
  // warp moved all together — its pose node rigidly, its rows with their
  // features — moves its linearisation point with them: what it measures
  // is relative (a feature seen from a pose), so the move changes nothing
  // it knows, while its linearisation, taken at the old place, would see a
  // rotation of several degrees through its second-order error (centimetres
  // at a few metres' lever) and pull the map out of shape. A factor that
  // ties a moved variable to one that stayed keeps its point: that is the
  // tension the closure resolves.
  constexpr double kTogetherRad = 0.1 * 3.14159265358979 / 180.0, kTogetherM = 0.01;
  std::map<int, PlanarMotion> row_motion;  // estimator row → its feature's motion
  for (const auto& [index, T] : features)
    for (int row : (*c_.features)[static_cast<std::size_t>(index)].state_idx) row_motion.emplace(row, T);
  for (auto& f : factors_) {
    const bool linear = f->kind == FactorKind::Linear || (f->kind == FactorKind::Observation && !f->live);
    if (!linear || (f->lin_nodes.empty() && f->lin_rows.empty())) continue;
    std::vector<PlanarMotion> node_moves;
    bool all_moved = true;
    for (int node : f->lin_nodes) {
      const std::optional<PlanarMotion> T = motion_of_node(node);
      if (!T) all_moved = false;
      else node_moves.push_back(*T);
    }
    for (int row : f->lin_rows) {
      const auto it = row_motion.find(row);
      all_moved = all_moved && it != row_motion.end() && acc_[row] != acc_before[row];
      // …and with its pose node: the same motion to a centimetre and 0.1°
      // where the node stands.
      for (std::size_t i = 0; all_moved && i < node_moves.size(); ++i) {
        const Eigen::Vector2d at = f->node_base[i].head<2>();
        all_moved = std::abs(it->second.theta - node_moves[i].theta) < kTogetherRad &&
                    (it->second.apply(at) - node_moves[i].apply(at)).norm() < kTogetherM;
      }
    }
    if (!all_moved) continue;
    for (std::size_t i = 0; i < f->lin_nodes.size(); ++i) f->node_base[i] = moved_pose(f->node_base[i], node_moves[i]);
    for (std::size_t j = 0; j < f->lin_rows.size(); ++j)
      f->row_base[static_cast<Eigen::Index>(j)] += acc_[f->lin_rows[j]] - acc_before[f->lin_rows[j]];
  }
}

void Problem::coincide(int a, int b, double sigma) {
  if (!(sigma > 0.0)) throw std::invalid_argument("problem: a coincidence factor needs σ > 0");
  auto f = std::make_unique<Factor>();
  f->kind = FactorKind::Coincidence;
  f->feature_id = a;
  f->other_id = b;
  f->sigma = sigma;
  factors_.push_back(std::move(f));
  ++loop_closures_;
}

FeatureShape feature_shape(const MapFeature& mf) {
  FeatureShape s;
  s.type = mf.type;
  s.layout = &mf.feature->layout();
  s.x = mf.feature->coords();
  s.free = mf.feature->symmetry_directions();
  if (s.free.cols() == 0) s.free = Eigen::MatrixXd::Zero(s.x.size(), 0);
  return s;
}

FeatureShape feature_shape(const MapFeature& mf, const Eigen::MatrixXd& P_p) {
  FeatureShape s = feature_shape(mf);
  const Eigen::MatrixXd Bt = mf.feature->B_dual();
  s.cov = Bt * P_p * Bt.transpose();
  return s;
}

bool linearize_coincidence(const MapFeature& a, const MapFeature& b, Eigen::VectorXd& r, Eigen::MatrixXd& J,
                           std::vector<int>& idx) {
  CoincidenceResidual res;
  if (!coincidence_residual(feature_shape(a), feature_shape(b), PlanarMotion{}, 0.0, res))
    return false;
  r = res.r;
  // A shared coordinate of both features adds its two columns.
  idx = a.state_idx;
  for (int row : b.state_idx)
    if (std::find(idx.begin(), idx.end(), row) == idx.end()) idx.push_back(row);
  J = Eigen::MatrixXd::Zero(r.size(), static_cast<Eigen::Index>(idx.size()));
  const auto add = [&](const MapFeature& mf, double sign) {
    const Eigen::MatrixXd Jf = sign * res.N.transpose() * mf.feature->B_dual();  // eq. 11: δx_f = B̃ δx_p
    for (std::size_t j = 0; j < mf.state_idx.size(); ++j) {
      const auto col = std::find(idx.begin(), idx.end(), mf.state_idx[j]) - idx.begin();
      J.col(col) += Jf.col(static_cast<Eigen::Index>(j));
    }
  };
  add(a, 1.0);
  add(b, -1.0);
  return true;
}

void Problem::relate(int from, int to, const Eigen::Vector3d& z, const Eigen::Matrix3d& C) {
  if (from < 0 || to <= from || to >= num_pose_nodes())
    throw std::invalid_argument("problem: a pose relation needs two pose nodes, the older first");
  // (LLT: a Cholesky factor exists only for a positive definite C; LDLT also takes semi-definite ones.)
  if (!z.allFinite() || !C.allFinite() || C.llt().info() != Eigen::Success)
    throw std::invalid_argument("problem: a pose relation needs a finite value and a positive definite covariance");
  for (int dof : {kX, kY, kTheta})
    if (std::find(c_.dofs.begin(), c_.dofs.end(), dof) == c_.dofs.end())
      throw std::invalid_argument("problem: a pose relation needs x, y and theta among the estimated pose coordinates");
  auto f = std::make_unique<Factor>();
  f->kind = FactorKind::Coincidence;
  f->feature_id = f->other_id = kNoFeature;
  f->from = from;
  f->to = to;
  f->m.v = z;
  f->m.C_v = C;
  factors_.push_back(std::move(f));
  ++loop_closures_;
}

// r = (R(θ_a)ᵀ (p_b − p_a), θ_b − θ_a) − z; J over the two nodes' planar
// coordinates (the others get zero columns).
bool Problem::evaluate_relation(const Factor& f, FactorLinearization& out) const {
  out = {};
  const Pose6 a = node_value(f.from), b = node_value(f.to);
  const double c = std::cos(a[kTheta]), s = std::sin(a[kTheta]);
  const Eigen::Vector2d d(b[kX] - a[kX], b[kY] - a[kY]);
  Eigen::Matrix2d Rt;
  Rt << c, s, -s, c;
  out.eta.resize(3);
  out.eta.head<2>() = Rt * d - f.m.v.head<2>();
  out.eta[2] = wrap_angle(b[kTheta] - a[kTheta] - f.m.v[2]);
  out.J = Eigen::MatrixXd::Zero(3, 2 * k_);
  Eigen::Matrix2d dRt;  // ∂Rᵀ/∂θ_a
  dRt << -s, c, -c, -s;
  for (int j = 0; j < k_; ++j) {
    const int dof = c_.dofs[static_cast<std::size_t>(j)];
    if (dof == kX || dof == kY) {
      const int axis = dof == kX ? 0 : 1;
      out.J.block<2, 1>(0, j) = -Rt.col(axis);
      out.J.block<2, 1>(0, k_ + j) = Rt.col(axis);
    } else if (dof == kTheta) {
      out.J.block<2, 1>(0, j) = dRt * d;
      out.J(2, j) = -1.0;
      out.J(2, k_ + j) = 1.0;
    }
  }
  out.kind = FactorKind::Coincidence;
  out.C = f.m.C_v;
  out.robust = false;
  for (int j = 0; j < k_; ++j) out.idx.push_back(pose_node_index(f.from) + j);
  for (int j = 0; j < k_; ++j) out.idx.push_back(pose_node_index(f.to) + j);
  return true;
}

bool Problem::evaluate_coincidence(const Factor& f, FactorLinearization& out) const {
  if (f.feature_id == kNoFeature) return evaluate_relation(f, out);
  out = {};
  const MapFeature* a = find_feature(*c_.features, f.feature_id);
  const MapFeature* b = find_feature(*c_.features, f.other_id);
  if (a == nullptr || b == nullptr || a->state_idx.empty() || b->state_idx.empty()) return false;
  if (!linearize_coincidence(*a, *b, out.eta, out.J, out.idx)) return false;
  out.kind = FactorKind::Coincidence;
  out.C = f.sigma * f.sigma * Eigen::MatrixXd::Identity(out.eta.size(), out.eta.size());
  out.robust = false;
  return true;
}

}  // namespace mspace::kernel
