// problem_state.cpp — the nonlinear problem in a checkpoint (problem.hpp,
// docs/persistence.md §4): Problem::save_state() and Problem::restore_state().
//
// Everything that decides the problem's future is saved exactly: the pose
// nodes' values and trajectory indices, the odometry since the newest node,
// the accumulated perturbation of every estimator row, and every factor with
// its measurement, rows, M-space dimension when recorded, odometry, and its
// last linearisation (η, J, C and the values it was taken at: a frozen factor
// is nothing else). A live observation factor is bound again to its feature
// by id (the restored features are new objects); frozen factors never read
// their feature. Doubles are kept as doubles (bit for bit); integers as
// doubles too (exact below 2^53), checked when read.
//
// Layout (StateWriter names): "dims" = [k, nodes, factors, current,
// node_this_step, frozen, loop_closures, pending]; "nodes" (6 × nodes);
// "records"; "pending_records"; "acc"; "measurement_kinds" (bytes: the
// distinct measurement kinds); "pending" and "factors": flat columns written
// by FlatWriter below, one factor after the other in the order of
// factors_, the fields in the order of save_factor().
#include <cmath>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "mspace/state.hpp"
#include "persistence.hpp"
#include "problem.hpp"
#include "problem_factor.hpp"
#include "slam.hpp"

namespace mspace::kernel {

namespace {

/// A flat column of doubles: counts, integers, vectors and matrices one after
/// the other.
class FlatWriter {
 public:
  void num(double v) { data_.push_back(v); }
  void ints(const std::vector<int>& v) {
    num(static_cast<double>(v.size()));
    for (int i : v) num(i);
  }
  void vec(const Eigen::VectorXd& v) {
    num(static_cast<double>(v.size()));
    data_.insert(data_.end(), v.data(), v.data() + v.size());
  }
  void mat(const Eigen::MatrixXd& m) {
    num(static_cast<double>(m.rows()));
    num(static_cast<double>(m.cols()));
    data_.insert(data_.end(), m.data(), m.data() + m.size());
  }
  Eigen::MatrixXd column() const {
    return Eigen::Map<const Eigen::MatrixXd>(data_.data(), static_cast<Eigen::Index>(data_.size()), 1);
  }

 private:
  std::vector<double> data_;
};

/// Reads what FlatWriter wrote, checking every count, integer and bound;
/// std::invalid_argument naming `what_` otherwise.
class FlatReader {
 public:
  FlatReader(const Eigen::MatrixXd& column, std::string what) : m_(column), what_(std::move(what)) {
    if (m_.cols() != 1 && m_.size() != 0) fail("is not one column");
  }
  double num() {
    if (at_ >= m_.size()) fail("ends early");
    return m_(at_++, 0);
  }
  /// An integer in [lo, hi].
  std::int64_t integer(double lo, double hi, const char* field) {
    const double v = num();
    if (!(v >= lo && v <= hi) || v != std::floor(v))
      fail(std::string(field) + " (" + std::to_string(v) + ") is not an integer in [" + std::to_string(lo) + ", " +
           std::to_string(hi) + "]");
    return static_cast<std::int64_t>(v);
  }
  std::vector<int> ints(double lo, double hi, const char* field) {
    const auto n = count(field);
    std::vector<int> v(static_cast<std::size_t>(n));
    for (int& i : v) i = static_cast<int>(integer(lo, hi, field));
    return v;
  }
  Eigen::VectorXd vec(const char* field) {
    const auto n = count(field);
    Eigen::VectorXd v = m_.col(0).segment(at_, n);
    at_ += n;
    finite(v, field);
    return v;
  }
  Eigen::MatrixXd mat(const char* field) {
    const auto rows = count(field);
    const auto cols = static_cast<Eigen::Index>(integer(0, 1e6, field));
    if (rows > 0 && cols > (m_.size() - at_) / rows) fail(std::string(field) + " is larger than what is left");
    Eigen::MatrixXd v = Eigen::Map<const Eigen::MatrixXd>(m_.data() + at_, rows, cols);
    at_ += rows * cols;
    finite(v, field);
    return v;
  }
  bool done() const { return at_ >= m_.size(); }
  void finish() const {
    if (at_ != m_.size()) fail("has " + std::to_string(m_.size() - at_) + " numbers left over");
  }
  [[noreturn]] void fail(const std::string& what) const {
    throw std::invalid_argument("nonlinear problem: '" + what_ + "' " + what);
  }

 private:
  /// A length that fits in what is left.
  Eigen::Index count(const char* field) {
    return static_cast<Eigen::Index>(integer(0, static_cast<double>(m_.size() - at_ - 1), field));
  }
  void finite(const Eigen::MatrixXd& v, const char* field) const {
    if (!v.allFinite()) fail(std::string(field) + " is not finite");
  }

  const Eigen::MatrixXd& m_;
  std::string what_;
  Eigen::Index at_ = 0;
};

constexpr double kMaxIndex = 2e9;

}  // namespace

void Problem::save_state(StateWriter& out) const {
  Eigen::MatrixXd dims(1, 8);
  dims << k_, static_cast<double>(nodes_.size()), static_cast<double>(factors_.size()), current_ ? 1 : 0,
      node_this_step_ ? 1 : 0, frozen_, loop_closures_, static_cast<double>(pending_.size());
  out.put("dims", dims);
  Eigen::MatrixXd nodes(6, static_cast<Eigen::Index>(nodes_.size()));
  for (std::size_t i = 0; i < nodes_.size(); ++i) nodes.col(static_cast<Eigen::Index>(i)) = nodes_[i];
  out.put("nodes", nodes);
  put_ints(out, "records", records_);
  put_ints(out, "pending_records", pending_records_);
  out.put("acc", acc_);
  FlatWriter pending;
  for (const OdometryIncrement& u : pending_) {
    pending.vec(u.x_d);
    pending.num(u.dt);
    pending.mat(u.C_d);
  }
  out.put("pending", pending.column());

  std::vector<std::string> kinds;
  std::map<std::string, int> kind_index;
  FlatWriter w;
  for (const auto& fp : factors_) {
    const Factor& f = *fp;
    w.num(static_cast<double>(f.kind));
    w.num(f.live ? 1 : 0);
    w.num(f.robust ? 1 : 0);
    w.num(f.feature_id);
    w.num(f.other_id);
    w.num(f.sigma);
    w.num(f.type);
    const auto [it, added] = kind_index.emplace(f.m.kind, static_cast<int>(kinds.size()));
    if (added) kinds.push_back(f.m.kind);
    w.num(it->second);
    w.vec(f.m.v);
    w.mat(f.m.C_v);
    w.num(f.m.flags);
    w.num(std::max(f.sensor, 0));  // an in-frame factor's own (−1: the robot) is in frame_factors
    w.num(f.node);
    w.ints(f.rows);
    w.num(f.dim);
    w.num(f.from);
    w.num(f.to);
    w.num(static_cast<double>(f.odometry.size()));
    for (const OdometryIncrement& u : f.odometry) {
      w.vec(u.x_d);
      w.num(u.dt);
      w.mat(u.C_d);
    }
    std::vector<int> records(f.odometry_records.begin(), f.odometry_records.end());
    w.ints(records);
    w.vec(f.eta);
    w.mat(f.J);
    w.mat(f.C);
    w.ints(f.lin_nodes);
    w.num(static_cast<double>(f.node_base.size()));
    for (const Pose6& x : f.node_base) w.vec(x);
    w.ints(f.lin_rows);
    w.vec(f.row_base);
  }
  out.put("factors", w.column());
  out.put_bytes("measurement_kinds", pack_strings(kinds));
  // Linear factors kept in a sensor's frame (the frozen-factor rule,
  // problem.hpp): their frame and linearisation point. A checkpoint written
  // before they existed has no such key: every factor is then as saved.
  FlatWriter frame;
  for (std::size_t i = 0; i < factors_.size(); ++i) {
    const Factor& f = *factors_[i];
    if (!f.in_frame) continue;
    frame.num(static_cast<double>(i));
    frame.num(f.sensor);
    frame.vec(f.x_o_base);
    frame.mat(f.G);
  }
  out.put("frame_factors", frame.column());
}

void Problem::restore_state(const StateReader& in, const std::vector<MapFeature>& features) {
  const std::string context = "nonlinear problem";
  const Eigen::MatrixXd dims = get_state(in, "dims", 1, 8, context).transpose();
  FlatReader d(dims, "dims");
  if (d.integer(1, 6, "k") != k_) d.fail("k differs from the motion model's estimated coordinates");
  const auto n_nodes = static_cast<std::size_t>(d.integer(1, kMaxIndex, "nodes"));
  const auto n_factors = static_cast<std::size_t>(d.integer(1, kMaxIndex, "factors"));
  const bool current = d.integer(0, 1, "current") != 0;
  const bool node_this_step = d.integer(0, 1, "node_this_step") != 0;
  const int frozen = static_cast<int>(d.integer(0, kMaxIndex, "frozen"));
  const int loop_closures = static_cast<int>(d.integer(0, kMaxIndex, "loop_closures"));
  const auto n_pending = static_cast<std::size_t>(d.integer(0, kMaxIndex, "pending"));

  const Eigen::MatrixXd& node_values = get_state(in, "nodes", 6, static_cast<Eigen::Index>(n_nodes), context);
  if (!node_values.allFinite()) throw std::invalid_argument(context + ": a pose node is not finite");
  std::vector<Pose6> nodes(n_nodes);
  for (std::size_t i = 0; i < n_nodes; ++i) nodes[i] = node_values.col(static_cast<Eigen::Index>(i));
  const std::vector<std::size_t> records = get_ints<std::size_t>(in, "records", 0, 1e15, context);
  const std::vector<std::size_t> pending_records = get_ints<std::size_t>(in, "pending_records", 0, 1e15, context);
  if (records.size() != n_nodes || pending_records.size() != n_pending)
    throw std::invalid_argument(context + ": the trajectory indices do not match the nodes and the pending odometry");
  const int state = state_dim();
  // acc_ follows the estimator's rows lazily (sync_rows): it may be shorter.
  const Eigen::MatrixXd& acc = in.get("acc");
  if ((acc.cols() != 1 && acc.size() != 0) || acc.size() > state || !acc.allFinite())
    throw std::invalid_argument(context + ": 'acc' is not a finite column of at most " + std::to_string(state) +
                                " rows");
  std::vector<OdometryIncrement> pending(n_pending);
  {
    FlatReader r(in.get("pending"), "pending");
    for (OdometryIncrement& u : pending) {
      u.x_d = r.vec("odometry");
      u.dt = r.num();
      u.C_d = r.mat("odometry covariance");
    }
    r.finish();
  }

  const std::vector<std::string> kinds = unpack_strings(in.get_bytes("measurement_kinds"));
  std::unordered_map<int, const MapFeature*> by_id;
  for (const MapFeature& mf : features) by_id[mf.id] = &mf;
  const auto n_types = static_cast<double>(c_.types->size());
  const auto n_sensors = static_cast<double>(c_.mounts.size());
  const double last_node = static_cast<double>(n_nodes) - 1;
  std::vector<std::unique_ptr<Factor>> factors;
  factors.reserve(n_factors);
  FlatReader r(in.get("factors"), "factors");
  for (std::size_t i = 0; i < n_factors; ++i) {
    auto f = std::make_unique<Factor>();
    f->kind = static_cast<FactorKind>(r.integer(0, kFactorKinds - 1, "kind"));
    f->live = r.integer(0, 1, "live") != 0;
    f->robust = r.integer(0, 1, "robust") != 0;
    f->feature_id = static_cast<int>(r.integer(-kMaxIndex, kMaxIndex, "feature_id"));
    f->other_id = static_cast<int>(r.integer(-kMaxIndex, kMaxIndex, "other_id"));
    f->sigma = r.num();
    f->type = static_cast<int>(r.integer(0, std::max(0.0, n_types - 1), "type"));
    f->m.kind = kinds.at(static_cast<std::size_t>(r.integer(0, static_cast<double>(kinds.size()) - 1, "kind")));
    f->m.v = r.vec("v");
    f->m.C_v = r.mat("C_v");
    f->m.flags = static_cast<std::uint32_t>(r.integer(0, std::numeric_limits<std::uint32_t>::max(), "flags"));
    f->sensor = static_cast<int>(r.integer(0, std::max(0.0, n_sensors - 1), "sensor"));
    f->node = static_cast<int>(r.integer(0, last_node, "node"));
    // A frozen factor's recorded rows are never read again (removed() clears them).
    f->rows = r.ints(0, f->live ? state - 1 : kMaxIndex, "rows");
    f->dim = static_cast<int>(r.integer(0, kMaxIndex, "dim"));
    f->from = static_cast<int>(r.integer(0, last_node, "from"));
    f->to = static_cast<int>(r.integer(0, last_node, "to"));
    f->odometry.resize(static_cast<std::size_t>(r.integer(0, kMaxIndex, "odometry")));
    for (OdometryIncrement& u : f->odometry) {
      u.x_d = r.vec("odometry");
      u.dt = r.num();
      u.C_d = r.mat("odometry covariance");
    }
    const std::vector<int> odometry_records = r.ints(0, kMaxIndex, "odometry_records");
    if (odometry_records.size() != f->odometry.size()) r.fail("odometry_records do not match the odometry");
    f->odometry_records.assign(odometry_records.begin(), odometry_records.end());
    f->eta = r.vec("eta");
    f->J = r.mat("J");
    f->C = r.mat("C");
    f->lin_nodes = r.ints(0, last_node, "lin_nodes");
    f->node_base.resize(static_cast<std::size_t>(r.integer(0, kMaxIndex, "node_base")));
    for (Pose6& x : f->node_base) {
      const Eigen::VectorXd v = r.vec("node_base");
      if (v.size() != 6) r.fail("node_base is not a pose");
      x = v;
    }
    f->lin_rows = r.ints(k_, state - 1, "lin_rows");
    f->row_base = r.vec("row_base");
    // The linearisation's shapes: J over k columns per node, then one per row.
    const auto m = f->eta.size();
    const auto cols = static_cast<Eigen::Index>(k_ * f->lin_nodes.size() + f->lin_rows.size());
    const bool linearisation_ok = f->kind == FactorKind::Motion || f->kind == FactorKind::Coincidence ||
                                  (f->J.rows() == m && f->J.cols() == cols && f->C.rows() == m && f->C.cols() == m &&
                                   f->node_base.size() == f->lin_nodes.size() &&
                                   f->row_base.size() == static_cast<Eigen::Index>(f->lin_rows.size()));
    if (!linearisation_ok) r.fail("factor " + std::to_string(i) + ": its linearisation has inconsistent sizes");
    if (f->kind == FactorKind::Coincidence && f->feature_id == kNoFeature &&
        (f->from >= f->to || f->m.v.size() != 3 || f->m.C_v.rows() != 3 || f->m.C_v.cols() != 3))
      r.fail("factor " + std::to_string(i) + ": a pose relation must go forward and hold a planar pose and its covariance");
    if (f->kind == FactorKind::Motion && (f->from >= f->to || f->odometry.empty()))
      r.fail("factor " + std::to_string(i) + ": a motion factor must go forward over some odometry");
    if (f->live) {  // re-linearised through its feature: bind it again
      const auto it = by_id.find(f->feature_id);
      if (f->kind != FactorKind::Observation || it == by_id.end())
        r.fail("factor " + std::to_string(i) + ": a live observation of feature " + std::to_string(f->feature_id) +
               ", which is not in the map");
      f->feature = it->second->feature;
    }
    factors.push_back(std::move(f));
  }
  r.finish();
  if (in.has("frame_factors")) {
    FlatReader fr(in.get("frame_factors"), "frame_factors");
    while (!fr.done()) {
      const auto i = static_cast<std::size_t>(fr.integer(0, static_cast<double>(n_factors) - 1, "factor"));
      Factor& f = *factors[i];
      f.in_frame = true;
      f.sensor = static_cast<int>(fr.integer(-1, std::max(0.0, n_sensors - 1), "sensor"));
      f.x_o_base = fr.vec("x_o_base");
      f.G = fr.mat("G");
      const auto it = by_id.find(f.feature_id);
      if (f.live || it == by_id.end())
        fr.fail("factor " + std::to_string(i) + ": a frozen factor of feature " + std::to_string(f.feature_id) +
                ", which is not in the map");
      if (f.G.rows() != f.eta.size() || f.G.cols() != f.x_o_base.size() ||
          f.x_o_base.size() != it->second->feature->layout().size() || !f.lin_rows.empty() || !f.lin_nodes.empty())
        fr.fail("factor " + std::to_string(i) + ": its frame linearisation has inconsistent sizes");
      f.feature = it->second->feature;
    }
  }

  // Everything read and checked: take it.
  nodes_ = std::move(nodes);
  records_ = records;
  current_ = current;
  node_this_step_ = node_this_step;
  pending_ = std::move(pending);
  pending_records_ = pending_records;
  acc_ = acc.size() == 0 ? Eigen::VectorXd() : Eigen::VectorXd(acc.col(0));
  factors_ = std::move(factors);
  frozen_ = frozen;
  loop_closures_ = loop_closures;
}

}  // namespace mspace::kernel
