#include "association.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string>

#include <Eigen/Cholesky>

#include "chi2.hpp"
#include "mspace/transform.hpp"
#include "plugin_registry.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

/// Throws a PluginError naming the instance when a plugin hands back NaN/inf.
/// A template, so that a vector is read where it is: a `const MatrixXd&`
/// parameter made a temporary copy of every innovation vector, one
/// allocation per (feature, measurement) pair.
template <class Derived>
void require_finite(const Eigen::PlainObjectBase<Derived>& m, const char* what, const std::string& instance,
                    const LoadedPlugin& lib) {
  // A plain loop: called three times for every (feature, measurement) pair on
  // matrices of a few entries, where Eigen's allFinite() costs several times more.
  const double* data = m.data();
  if (std::all_of(data, data + m.size(), [](double v) { return std::isfinite(v); })) return;
  std::ostringstream os;
  os << instance << " (plugin '" << lib.descriptor->name << "', library '" << lib.path.string()
     << "'): " << what << " contains NaN or infinity";
  throw PluginError(os.str());
}

/// Euclidean distance from p to a box (0 inside).
double box_distance(const PlanarBox& b, const Eigen::Vector2d& p) {
  const double dx = std::max({b.min_x - p.x(), 0.0, p.x() - b.max_x});
  const double dy = std::max({b.min_y - p.y(), 0.0, p.y() - b.max_y});
  return std::sqrt(dx * dx + dy * dy);
}

/// Boxes spanning more cells than this are scanned by every query instead.
constexpr std::int64_t kMaxCellsPerBox = 256;

}  // namespace

// ---- Selection --------------------------------------------------------------

std::vector<int> nearest_neighbour(std::vector<Candidate>& candidates, int num_measurements, int num_features) {
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
    return a.tentative != b.tentative ? b.tentative : a.d2 < b.d2;
  });
  std::vector<bool> meas_used(static_cast<std::size_t>(num_measurements), false);
  std::vector<bool> feature_used(static_cast<std::size_t>(num_features), false);
  std::vector<int> chosen;
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const Candidate& c = candidates[i];
    if (meas_used[c.measurement] || feature_used[c.feature]) continue;
    meas_used[c.measurement] = true;
    feature_used[c.feature] = true;
    chosen.push_back(static_cast<int>(i));
  }
  return chosen;
}

namespace {

/// The interpretation tree of JCBB. Level i is the i-th measurement with a
/// candidate; its branches are its candidates (smallest d² first) and the
/// null pairing. A hypothesis of r innovation rows keeps the Cholesky factor
/// L (r × r) of its joint innovation covariance S and y = L⁻¹ν, so that
/// D² = |y|²; a pairing adds one block row:
///   S' = [S B; Bᵀ D],  L' = [L 0; Xᵀ L_D],  X = L⁻¹B,  L_D L_Dᵀ = D − XᵀX,
///   y' = (y; L_D⁻¹(η − Xᵀy)),  D²' = D² + |L_D⁻¹(η − Xᵀy)|².
class InterpretationTree {
 public:
  InterpretationTree(const std::vector<Candidate>& candidates, const MarginalFn& marginal,
                     const JcbbOptions& options)
      : cands_(candidates), options_(options), chi2_(options.chi2_cache != nullptr ? *options.chi2_cache : own_chi2_) {
    // Levels: measurements in ascending order, candidates by d² within each.
    std::vector<int> order;
    for (std::size_t i = 0; i < cands_.size(); ++i)
      if (!cands_[i].tentative) order.push_back(static_cast<int>(i));
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
      const Candidate& ca = cands_[a];
      const Candidate& cb = cands_[b];
      return ca.measurement != cb.measurement ? ca.measurement < cb.measurement : ca.d2 < cb.d2;
    });
    for (int c : order) {
      if (levels_.empty() || cands_[levels_.back().front()].measurement != cands_[c].measurement) levels_.emplace_back();
      levels_.back().push_back(c);
    }
    if (order.empty()) return;
    for (int c : order)
      if (cands_[c].idx.size() != static_cast<std::size_t>(cands_[c].J_state.cols()) ||
          cands_[c].J_state.rows() != cands_[c].innovation.eta.size())
        throw std::invalid_argument("joint_compatibility: a candidate's J_state is " +
                                    std::to_string(cands_[c].J_state.rows()) + "x" +
                                    std::to_string(cands_[c].J_state.cols()) + " for " +
                                    std::to_string(cands_[c].innovation.eta.size()) + " rows and " +
                                    std::to_string(cands_[c].idx.size()) + " state indices");

    // The union of the candidates' state indices and the covariance over it.
    std::vector<int> all;
    for (int c : order) all.insert(all.end(), cands_[c].idx.begin(), cands_[c].idx.end());
    std::sort(all.begin(), all.end());
    all.erase(std::unique(all.begin(), all.end()), all.end());
    const Eigen::MatrixXd P = marginal(all);

    // Every candidate's J_state over the union, stacked: Z = J P Jᵀ holds
    // every block S and B of every hypothesis.
    offset_.assign(cands_.size(), -1);
    Eigen::Index rows = 0;
    for (int c : order) {
      offset_[c] = static_cast<int>(rows);
      rows += cands_[c].innovation.eta.size();
    }
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(rows, static_cast<Eigen::Index>(all.size()));
    for (int c : order) {
      const Candidate& cand = cands_[c];
      for (std::size_t j = 0; j < cand.idx.size(); ++j) {
        const auto col = std::lower_bound(all.begin(), all.end(), cand.idx[j]) - all.begin();
        J.block(offset_[c], col, cand.J_state.rows(), 1) += cand.J_state.col(static_cast<Eigen::Index>(j));
      }
    }
    Z_.noalias() = J * P * J.transpose();

    // The deepest hypothesis pairs every level with its largest candidate.
    Eigen::Index max_rows = 0;
    for (const std::vector<int>& level : levels_) {
      Eigen::Index m = 0;
      for (int c : level) m = std::max(m, cands_[c].innovation.eta.size());
      max_rows += m;
    }
    L_ = Eigen::MatrixXd::Zero(max_rows, max_rows);
    y_ = Eigen::VectorXd::Zero(max_rows);
    int max_feature = 0;
    for (int c : order) max_feature = std::max(max_feature, cands_[c].feature);
    feature_used_.assign(static_cast<std::size_t>(max_feature) + 1, false);
  }

  JcbbResult search() {
    JcbbResult result;
    if (!levels_.empty()) descend(0, 0, 0.0);
    result.nodes = nodes_;
    result.bounded = bounded_;
    if (!bounded_) {
      result.chosen = best_;
      result.d2 = best_pairings_ > 0 ? best_d2_ : 0.0;
      if (options_.find_rivals && best_pairings_ > 0) {
        find_rivals();
        result.rival_nodes = rival_nodes_;
        result.rivals_bounded = rivals_bounded_;
        for (int c : best_)
          if (rivals_bounded_ || disputed_[static_cast<std::size_t>(c)]) result.disputed.push_back(c);
        std::sort(result.disputed.begin(), result.disputed.end());
      }
    }
    return result;
  }

 private:
  double threshold(Eigen::Index dim) {
    if (static_cast<Eigen::Index>(chi2_.size()) <= dim) chi2_.resize(static_cast<std::size_t>(dim) + 1, -1.0);
    double& t = chi2_[static_cast<std::size_t>(dim)];
    if (t < 0.0) t = chi2_quantile(options_.probability, static_cast<int>(dim));
    return t;
  }

  /// Whether a hypothesis that can reach `potential` pairings at joint
  /// distance ≥ d2 may still beat the best one.
  bool promising(int potential, double d2) const {
    return potential > best_pairings_ || (potential == best_pairings_ && d2 < best_d2_);
  }

  /// Adds candidate c to the hypothesis of `rows` rows at distance d2; the
  /// new distance, or +inf when the hypothesis is jointly incompatible.
  double pair(int c, Eigen::Index rows, double d2) {
    const Candidate& cand = cands_[c];
    const Eigen::Index m = cand.innovation.eta.size();
    Eigen::MatrixXd D = Z_.block(offset_[c], offset_[c], m, m) + cand.C_eta;
    if (cand.C_gate.size() > 0) D += cand.C_gate;
    Eigen::VectorXd z = cand.innovation.eta;
    if (rows > 0) {
      B_.resize(rows, m);
      Eigen::Index r = 0;
      for (int h : hypothesis_) {
        const Eigen::Index mh = cands_[h].innovation.eta.size();
        B_.middleRows(r, mh) = Z_.block(offset_[h], offset_[c], mh, m);
        r += mh;
      }
      L_.topLeftCorner(rows, rows).triangularView<Eigen::Lower>().solveInPlace(B_);  // X = L⁻¹B
      D.noalias() -= B_.transpose() * B_;
      z.noalias() -= B_.transpose() * y_.head(rows);
    }
    const Eigen::LLT<Eigen::MatrixXd> llt(D);
    if (llt.info() != Eigen::Success) return kInf;
    const Eigen::MatrixXd L_D = llt.matrixL();
    L_D.triangularView<Eigen::Lower>().solveInPlace(z);
    const double d2_new = d2 + z.squaredNorm();
    if (!(d2_new <= threshold(rows + m))) return kInf;
    if (rows > 0) L_.block(rows, 0, m, rows) = B_.transpose();
    L_.block(rows, rows, m, m) = L_D;
    y_.segment(rows, m) = z;
    return d2_new;
  }

  void descend(std::size_t level, Eigen::Index rows, double d2) {
    if (bounded_) return;
    if (++nodes_ > options_.max_nodes) {
      bounded_ = true;
      return;
    }
    const int pairings = static_cast<int>(hypothesis_.size());
    if (level == levels_.size()) {
      if (promising(pairings, d2)) {
        best_ = hypothesis_;
        best_pairings_ = pairings;
        best_d2_ = d2;
      }
      return;
    }
    const int remaining = static_cast<int>(levels_.size() - level);  // this level included
    for (int c : levels_[level]) {
      if (feature_used_[cands_[c].feature] || !promising(pairings + remaining, d2)) continue;
      const double d2_new = pair(c, rows, d2);
      if (d2_new == kInf || !promising(pairings + remaining, d2_new)) continue;
      feature_used_[cands_[c].feature] = true;
      hypothesis_.push_back(c);
      descend(level + 1, rows + cands_[c].innovation.eta.size(), d2_new);
      hypothesis_.pop_back();
      feature_used_[cands_[c].feature] = false;
      if (bounded_) return;
    }
    if (promising(pairings + remaining - 1, d2)) descend(level + 1, rows, d2);  // the null pairing
  }

  // ---- Rivals: every jointly compatible hypothesis with as many pairings
  // as the best (the search above keeps only the one of smallest D²). No
  // bound on D² beyond the joint gate: two hypotheses that both pass it are
  // both explanations the data allow. The union of what they leave out of
  // the best is disputed.
  void find_rivals() {
    disputed_.assign(cands_.size(), false);
    undisputed_ = static_cast<int>(best_.size());
    descend_rival(0, 0, 0.0);
  }

  void descend_rival(std::size_t level, Eigen::Index rows, double d2) {
    if (rivals_bounded_ || undisputed_ == 0) return;  // nothing left to learn
    if (++rival_nodes_ > (options_.max_rival_nodes < 0 ? options_.max_nodes : options_.max_rival_nodes)) {
      rivals_bounded_ = true;
      return;
    }
    const int pairings = static_cast<int>(hypothesis_.size());
    const int remaining = static_cast<int>(levels_.size() - level);
    if (pairings + remaining < best_pairings_) return;
    if (level == levels_.size()) {  // pairings == best_pairings_ here: no hypothesis has more
      std::vector<bool> in_rival(cands_.size(), false);
      for (int c : hypothesis_) in_rival[static_cast<std::size_t>(c)] = true;
      for (int c : best_)
        if (!in_rival[static_cast<std::size_t>(c)] && !disputed_[static_cast<std::size_t>(c)]) {
          disputed_[static_cast<std::size_t>(c)] = true;
          --undisputed_;
        }
      return;
    }
    for (int c : levels_[level]) {
      if (feature_used_[cands_[c].feature]) continue;
      const double d2_new = pair(c, rows, d2);
      if (d2_new == kInf) continue;
      feature_used_[cands_[c].feature] = true;
      hypothesis_.push_back(c);
      descend_rival(level + 1, rows + cands_[c].innovation.eta.size(), d2_new);
      hypothesis_.pop_back();
      feature_used_[cands_[c].feature] = false;
      if (rivals_bounded_) return;
    }
    if (pairings + remaining - 1 >= best_pairings_) descend_rival(level + 1, rows, d2);  // the null pairing
  }

  const std::vector<Candidate>& cands_;
  JcbbOptions options_;
  std::vector<std::vector<int>> levels_;
  std::vector<int> offset_;  ///< candidate → first row in Z
  Eigen::MatrixXd Z_, L_, B_;
  Eigen::VectorXd y_;
  std::vector<bool> feature_used_;
  std::vector<double> own_chi2_;
  std::vector<double>& chi2_;
  std::vector<int> hypothesis_, best_;
  int best_pairings_ = -1;
  double best_d2_ = kInf;
  std::int64_t nodes_ = 0;
  bool bounded_ = false;
  std::vector<bool> disputed_;  ///< by candidate position: a pairing of the best that a rival leaves out
  int undisputed_ = 0;                   ///< pairings of the best not yet disputed
  std::int64_t rival_nodes_ = 0;
  bool rivals_bounded_ = false;
};

}  // namespace

JcbbResult joint_compatibility(const std::vector<Candidate>& candidates, const MarginalFn& marginal,
                               const JcbbOptions& options) {
  InterpretationTree tree(candidates, marginal, options);
  return tree.search();
}

// ---- Re-entries -------------------------------------------------------------

MarginalFn widen_robot(MarginalFn marginal, std::vector<int> robot_idx, Eigen::MatrixXd extra) {
  const auto k = static_cast<Eigen::Index>(robot_idx.size());
  if (extra.rows() != k || extra.cols() != k)
    throw std::invalid_argument("widen_robot: a " + std::to_string(extra.rows()) + "x" + std::to_string(extra.cols()) +
                                " widening for " + std::to_string(k) + " robot rows");
  return [marginal = std::move(marginal), robot_idx = std::move(robot_idx),
          extra = std::move(extra)](const std::vector<int>& rows) {
    Eigen::MatrixXd P = marginal(rows);
    std::vector<Eigen::Index> at(robot_idx.size(), -1);  // where each robot row falls among `rows`
    for (std::size_t i = 0; i < rows.size(); ++i)
      for (std::size_t j = 0; j < robot_idx.size(); ++j)
        if (rows[i] == robot_idx[j]) at[j] = static_cast<Eigen::Index>(i);
    for (std::size_t a = 0; a < at.size(); ++a)
      for (std::size_t b = 0; b < at.size(); ++b)
        if (at[a] >= 0 && at[b] >= 0)
          P(at[a], at[b]) += extra(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
    return P;
  };
}

ReentryVerdict confirm_reentries(const std::vector<Candidate>& wide, const std::vector<std::pair<int, int>>& asked,
                                 const MarginalFn& widened, JcbbOptions options) {
  ReentryVerdict verdict;
  verdict.confirmed.assign(asked.size(), false);
  options.find_rivals = true;
  verdict.search = joint_compatibility(wide, widened, options);
  const JcbbResult& jc = verdict.search;
  if (jc.bounded || jc.rivals_bounded) return verdict;
  for (std::size_t a = 0; a < asked.size(); ++a)
    for (int c : jc.chosen)
      if (wide[c].measurement == asked[a].first && wide[c].feature == asked[a].second)
        verdict.confirmed[a] = !std::binary_search(jc.disputed.begin(), jc.disputed.end(), c);
  return verdict;
}

// ---- Spatial index ----------------------------------------------------------

PlanarBox planar_box(const Feature& f) {
  const CoordLayout& layout = f.layout();
  PlanarBox box{kInf, kInf, -kInf, -kInf, false};
  bool any = false;
  for (int b = 0; b < layout.num_blocks(); ++b) {
    if (layout.kind(b) == BlockKind::Scalar) continue;
    const Eigen::Vector2d q = f.coords().segment<2>(layout.offset(b));
    box.min_x = std::min(box.min_x, q.x());
    box.min_y = std::min(box.min_y, q.y());
    box.max_x = std::max(box.max_x, q.x());
    box.max_y = std::max(box.max_y, q.y());
    any = true;
    if (!q.allFinite()) box.everywhere = true;
  }
  if (!any) box.everywhere = true;
  if (box.everywhere) box = PlanarBox{0.0, 0.0, 0.0, 0.0, true};
  return box;
}

double planar_distance(const Feature& f, const Eigen::Vector2d& p) {
  const CoordLayout& layout = f.layout();
  double best = kInf;
  bool any = false;
  Eigen::Vector2d previous;
  for (int b = 0; b < layout.num_blocks(); ++b) {
    if (layout.kind(b) == BlockKind::Scalar) continue;
    const Eigen::Vector2d q = f.coords().segment<2>(layout.offset(b));
    if (!any) {
      best = (q - p).norm();
    } else {
      const Eigen::Vector2d d = q - previous;
      const double len2 = d.squaredNorm();
      const double s = len2 > 0.0 ? std::clamp((p - previous).dot(d) / len2, 0.0, 1.0) : 0.0;
      best = std::min(best, (previous + s * d - p).norm());
    }
    previous = q;
    any = true;
  }
  return any ? best : 0.0;
}

PlanarGrid::PlanarGrid(double cell_size) : cell_(cell_size) {}

PlanarGrid::Cells PlanarGrid::cells_of(const PlanarBox& box) const {
  Cells c;
  if (box.everywhere) {
    c.wide = true;
    return c;
  }
  const double limit = 1e15;  // cells beyond this are out of the int64 range
  const double x0 = std::floor(box.min_x / cell_), y0 = std::floor(box.min_y / cell_);
  const double x1 = std::floor(box.max_x / cell_), y1 = std::floor(box.max_y / cell_);
  if (!(std::abs(x0) < limit && std::abs(y0) < limit && std::abs(x1) < limit && std::abs(y1) < limit) ||
      (x1 - x0 + 1.0) * (y1 - y0 + 1.0) > static_cast<double>(kMaxCellsPerBox)) {
    c.wide = true;
    return c;
  }
  c.x0 = static_cast<std::int64_t>(x0);
  c.y0 = static_cast<std::int64_t>(y0);
  c.x1 = static_cast<std::int64_t>(x1);
  c.y1 = static_cast<std::int64_t>(y1);
  return c;
}

void PlanarGrid::insert_cells(int key, const Cells& c) {
  if (c.wide) {
    wide_.push_back(key);
    return;
  }
  for (std::int64_t x = c.x0; x <= c.x1; ++x)
    for (std::int64_t y = c.y0; y <= c.y1; ++y) grid_[hash(x, y)].push_back(key);
}

void PlanarGrid::erase_cells(int key, const Cells& c) {
  const auto drop = [key](std::vector<int>& keys) {
    const auto it = std::find(keys.begin(), keys.end(), key);
    if (it == keys.end()) return;
    *it = keys.back();
    keys.pop_back();
  };
  if (c.wide) {
    drop(wide_);
    return;
  }
  for (std::int64_t x = c.x0; x <= c.x1; ++x)
    for (std::int64_t y = c.y0; y <= c.y1; ++y) {
      const auto it = grid_.find(hash(x, y));
      if (it == grid_.end()) continue;
      drop(it->second);
      if (it->second.empty()) grid_.erase(it);
    }
}

void PlanarGrid::set(int key, const PlanarBox& box) {
  const Cells cells = cells_of(box);
  const auto it = boxes_.find(key);
  if (it == boxes_.end()) {
    boxes_.emplace(key, Entry{box, cells});
    insert_cells(key, cells);
    return;
  }
  Entry& e = it->second;
  e.box = box;
  const Cells& old = e.cells;
  if (old.wide == cells.wide && (cells.wide || (old.x0 == cells.x0 && old.y0 == cells.y0 && old.x1 == cells.x1 &&
                                                old.y1 == cells.y1)))
    return;  // moved within its cells
  erase_cells(key, old);
  e.cells = cells;
  insert_cells(key, cells);
}

void PlanarGrid::erase(int key) {
  const auto it = boxes_.find(key);
  if (it == boxes_.end()) return;
  erase_cells(key, it->second.cells);
  boxes_.erase(it);
}

void PlanarGrid::query(const Eigen::Vector2d& p, double range, std::vector<int>& keys) const {
  const std::size_t first = keys.size();
  // A little slack: planar_distance and box_distance round differently, and
  // the index must never miss a feature the full scan would try.
  const double r = range * (1.0 + 1e-9) + 1e-9;
  const auto keep = [&](int key) {
    const PlanarBox& box = boxes_.at(key).box;
    if (box.everywhere || box_distance(box, p) <= r) keys.push_back(key);
  };
  const double x0 = std::floor((p.x() - r) / cell_), x1 = std::floor((p.x() + r) / cell_);
  const double y0 = std::floor((p.y() - r) / cell_), y1 = std::floor((p.y() + r) / cell_);
  const double cells = (x1 - x0 + 1.0) * (y1 - y0 + 1.0);
  if (!(cells <= static_cast<double>(boxes_.size()))) {  // cheaper (or only possible) to look at every box
    for (const auto& [key, entry] : boxes_) keep(key);
  } else {
    for (auto x = static_cast<std::int64_t>(x0); x <= static_cast<std::int64_t>(x1); ++x)
      for (auto y = static_cast<std::int64_t>(y0); y <= static_cast<std::int64_t>(y1); ++y) {
        const auto it = grid_.find(hash(x, y));
        if (it == grid_.end()) continue;
        for (int key : it->second) keep(key);
      }
    for (int key : wide_) keep(key);
  }
  std::sort(keys.begin() + static_cast<std::ptrdiff_t>(first), keys.end());
  keys.erase(std::unique(keys.begin() + static_cast<std::ptrdiff_t>(first), keys.end()), keys.end());
}

// ---- The associator ---------------------------------------------------------

namespace {

/// The configured cell size, or the largest max_range of the sensors (a query
/// then covers at most 4 × 4 cells), or 10 m.
double cell_size(const AssociationConfig& config, const std::vector<SensorConfig>& sensors) {
  if (config.index_cell_size > 0.0) return config.index_cell_size;
  double largest = 0.0;
  for (const SensorConfig& s : sensors) largest = std::max(largest, s.max_range);
  return largest > 0.0 ? largest : 10.0;
}

}  // namespace

Associator::Associator(const AssociationConfig& config, const std::vector<SensorConfig>& sensors,
                       std::shared_ptr<Logger> log)
    : config_(config), log_(std::move(log)), grid_(cell_size(config, sensors)) {}

Associator::~Associator() = default;

double Associator::threshold(std::vector<double>& cache, double p, int dim) {
  if (static_cast<int>(cache.size()) <= dim) cache.resize(static_cast<std::size_t>(dim) + 1, -1.0);
  if (cache[dim] < 0.0) cache[dim] = chi2_quantile(p, dim);
  return cache[dim];
}

namespace {

/// Whether `outer` holds all of `inner`.
bool holds(const PlanarBox& outer, const PlanarBox& inner) {
  if (outer.everywhere) return inner.everywhere;
  return !inner.everywhere && inner.min_x >= outer.min_x && inner.max_x <= outer.max_x &&
         inner.min_y >= outer.min_y && inner.max_y <= outer.max_y;
}

PlanarBox grown(PlanarBox b, double margin) {
  if (b.everywhere) return b;
  b.min_x -= margin;
  b.min_y -= margin;
  b.max_x += margin;
  b.max_y += margin;
  return b;
}

}  // namespace

PlanarBox Associator::box_of(Slot& slot, const Feature& f) {
  const Eigen::VectorXd& x = f.coords();
  if (slot.coords_size != x.size()) {  // first look (or the coordinates changed shape): read the layout
    const CoordLayout& layout = f.layout();
    slot.coords_size = x.size();
    slot.points = 0;
    for (int b = 0; b < layout.num_blocks() && slot.points >= 0; ++b) {
      if (layout.kind(b) == BlockKind::Scalar) continue;
      if (slot.points == static_cast<int>(slot.point_offsets.size())) {
        slot.points = -1;
        break;
      }
      slot.point_offsets[static_cast<std::size_t>(slot.points++)] = layout.offset(b);
    }
  }
  if (slot.points < 0) return planar_box(f);
  if (slot.points == 0) return PlanarBox{0.0, 0.0, 0.0, 0.0, true};
  PlanarBox box{kInf, kInf, -kInf, -kInf, false};
  for (int i = 0; i < slot.points; ++i) {
    const double px = x[slot.point_offsets[static_cast<std::size_t>(i)]];
    const double py = x[slot.point_offsets[static_cast<std::size_t>(i)] + 1];
    if (!std::isfinite(px) || !std::isfinite(py)) return PlanarBox{0.0, 0.0, 0.0, 0.0, true};
    box.min_x = std::min(box.min_x, px);
    box.min_y = std::min(box.min_y, py);
    box.max_x = std::max(box.max_x, px);
    box.max_y = std::max(box.max_y, py);
  }
  return box;
}

void Associator::sync(const std::vector<MapFeature>& features) {
  if (!config_.spatial_index) return;
  const double margin = 0.05 * grid_.cell_size();
  if (slots_.size() == features.size()) {  // the common case: features moved (an update)
    bool same_features = true;
    for (std::size_t i = 0; i < features.size(); ++i) {
      Slot& slot = slots_[i];
      if (slot.id != features[i].id) {
        same_features = false;
        break;
      }
      const PlanarBox box = box_of(slot, *features[i].feature);
      if (holds(slot.loose, box)) continue;
      slot.loose = grown(box, margin);
      grid_.set(slot.id, slot.loose);
    }
    if (same_features) {
      dirty_ = false;
      return;
    }
  }
  // Features were created or removed: carry the slots over by id.
  std::unordered_map<int, Slot> old;
  old.reserve(slots_.size());
  for (const Slot& slot : slots_) old.emplace(slot.id, slot);
  slots_.resize(features.size());
  position_.clear();
  position_.reserve(features.size());
  for (std::size_t i = 0; i < features.size(); ++i) {
    const int id = features[i].id;
    position_[id] = static_cast<int>(i);
    const auto it = old.find(id);
    const bool indexed = it != old.end();
    if (indexed) {
      slots_[i] = it->second;
      old.erase(it);
    } else {
      slots_[i] = Slot{};
      slots_[i].id = id;
    }
    const PlanarBox box = box_of(slots_[i], *features[i].feature);
    if (indexed && holds(slots_[i].loose, box)) continue;
    slots_[i].loose = grown(box, margin);
    grid_.set(id, slots_[i].loose);
  }
  for (const auto& [id, slot] : old) grid_.erase(id);  // removed from the map
  dirty_ = false;
}

void Associator::features_in_range(const AssociationView& map, const SensorSlot& sensor, const Eigen::Vector2d& p,
                                   std::vector<int>& out) {
  out.clear();
  const double range = sensor.config.max_range;
  const auto fed = [&](const MapFeature& mf) {  // a duplicate found by a loop closure is never matched again
    return mf.merged_into == 0 && std::find(sensor.feeds.begin(), sensor.feeds.end(), mf.type) != sensor.feeds.end();
  };
  if (!(range > 0.0) || !config_.spatial_index) {  // the full scan
    for (std::size_t fi = 0; fi < map.features.size(); ++fi) {
      const MapFeature& mf = map.features[fi];
      if (!fed(mf)) continue;
      if (range > 0.0 && planar_distance(*mf.feature, p) > range) continue;
      out.push_back(static_cast<int>(fi));
    }
    return;
  }
  ++stats_.index_queries;
  // The index is brought up to date after map_changed() or when the number
  // of features changed; a key whose position is stale forces a sync too.
  if (dirty_ || slots_.size() != map.features.size()) sync(map.features);
  for (int attempt = 0; attempt < 2; ++attempt) {
    keys_.clear();
    grid_.query(p, range, keys_);
    bool stale = false;
    for (int key : keys_) {
      const auto it = position_.find(key);
      if (it == position_.end() || it->second >= static_cast<int>(map.features.size()) ||
          map.features[it->second].id != key) {
        stale = true;
        break;
      }
      const MapFeature& mf = map.features[it->second];
      if (!fed(mf) || planar_distance(*mf.feature, p) > range) continue;
      out.push_back(it->second);
    }
    if (!stale) break;
    out.clear();
    sync(map.features);
  }
  std::sort(out.begin(), out.end());
}

const Eigen::MatrixXd& Associator::KeptProduct::of(const Eigen::MatrixXd& J, const Eigen::MatrixXd& X,
                                                    Eigen::MatrixXd& scratch) {
  const auto same_bits = [](const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
    return a.rows() == b.rows() && a.cols() == b.cols() &&
           std::memcmp(a.data(), b.data(), static_cast<std::size_t>(a.size()) * sizeof(double)) == 0;
  };
  if (valid && same_bits(J, factor)) return product;
  factor = J;
  scratch.noalias() = J * X;  // J X Jᵀ with the left product evaluated into kept storage
  product.noalias() = scratch * J.transpose();
  valid = true;
  return product;
}

// Gating (ICRA §IV, "Prediction"). For each feature the sensor feeds within
// its range, the state part of the innovation covariance is computed once per
// reading in sensor-frame coordinates,
//   M = A P Aᵀ + J_of Σ_gate J_ofᵀ,  A = (J_os J_sr  J_of B̃)   (eqs. 19–21),
// and each measurement then costs only S = J_ηo M J_ηoᵀ + J_ηv C_v J_ηvᵀ.
AssociationResult Associator::associate(const AssociationView& map, const SensorSlot& sensor, const Pose6& x_ms,
                                        const Eigen::MatrixXd& J_sr, const std::vector<Measurement>& meas) {
  const AssociationConfig& ac = config_;
  const bool joint = ac.method == AssociationConfig::Method::Jcbb;
  const int k = static_cast<int>(map.robot_idx.size());

  std::vector<Candidate> candidates;
  // With association.reentry_joint_test, the reading's pairs with features
  // unseen over loop_min_gap_path, gated with the robot's covariance widened
  // by (scale² − 1) Σ_r (computed at the first such feature).
  const bool reentry_test = joint && ac.reentry_joint_test && map.travel_unseen;
  std::vector<Candidate> reentry_candidates;
  std::vector<bool> is_reentry(reentry_test ? map.features.size() : 0, false);
  Eigen::MatrixXd widening;
  // Per measurement: min over features of d² / (new-feature threshold).
  std::vector<double> closest(meas.size(), kInf);
  const Eigen::Vector2d sensor_xy(x_ms[kX], x_ms[kY]);
  features_in_range(map, sensor, sensor_xy, in_range_);
  // The per-feature matrices below live in members and keep their storage
  // from feature to feature and reading to reading (this loop runs for every
  // feature in range of every reading); the products are the same
  // expressions, evaluated into them instead of into temporaries.
  Eigen::MatrixXd& J_of = scratch_J_of_;
  Eigen::MatrixXd& J_os = scratch_J_os_;
  Eigen::MatrixXd& A = scratch_A_;
  Eigen::MatrixXd& M = scratch_M_;
  std::vector<int>& idx = scratch_idx_;
  // The two products of eq. 29 per pair, J_ηv C_v J_ηvᵀ and J_ηo M J_ηoᵀ,
  // are kept with their factors and recomputed only when a factor's bits
  // changed: a J_ηo that depends on the feature alone (not on the measurement)
  // serves every measurement of the reading, and an extractor whose J_ηv is
  // the same for every feature (η = h − v: −I) makes one C_η per measurement.
  // Same inputs, same operations: the same numbers as computing them afresh.
  if (measurement_products_.size() < meas.size()) measurement_products_.resize(meas.size());
  // Asked once per reading, not per pair: whether every d² is logged (then no
  // pair is skipped unfactorised), and per measurement dimension the larger
  // of the gate and new-feature thresholds.
  const bool tracing = log_->enabled(LogLevel::Trace);
  std::vector<double>& far_by_dim = scratch_far_;
  far_by_dim.clear();
  const auto far_threshold = [&](int dim) {
    if (static_cast<int>(far_by_dim.size()) <= dim) far_by_dim.resize(static_cast<std::size_t>(dim) + 1, -1.0);
    double& far = far_by_dim[static_cast<std::size_t>(dim)];
    if (far < 0.0)
      far = std::max(threshold(gate_chi2_, ac.gate_probability, dim),
                     threshold(new_feature_chi2_, ac.new_feature_probability, dim));
    return far;
  };
  for (KeptProduct& kept : measurement_products_) kept.valid = false;
  for (int fi : in_range_) {
    const MapFeature& mf = map.features[fi];
    const FeatureTypeSlot& type = map.types[mf.type];
    const Feature& f = *mf.feature;
    const CoordLayout& layout = f.layout();
    const Eigen::VectorXd x_o = to_sensor_frame(layout, f.coords(), x_ms, &J_of, &J_os);  // eqs. 7–9, 18

    const int dim = f.mspace_dim();
    A.resize(layout.size(), k + dim);
    A.leftCols(k).noalias() = J_os * J_sr;
    idx.assign(map.robot_idx.begin(), map.robot_idx.end());
    if (dim > 0) {
      const Eigen::MatrixXd Bd = guarded(type.instance, *type.library, "B_dual", [&] { return f.B_dual(); });
      if (Bd.rows() != layout.size() || Bd.cols() != dim)
        throw PluginError(type.instance + " (plugin '" + type.plugin + "'): B_dual is " +
                          std::to_string(Bd.rows()) + "x" + std::to_string(Bd.cols()) + ", expected " +
                          std::to_string(layout.size()) + "x" + std::to_string(dim));
      require_finite(Bd, "B_dual", type.instance, *type.library);
      A.rightCols(dim).noalias() = J_of * Bd;
      idx.insert(idx.end(), mf.state_idx.begin(), mf.state_idx.end());
    }
    scratch_AP_.noalias() = A * map.marginal(idx);
    M.noalias() = scratch_AP_ * A.transpose();
    const Eigen::MatrixXd gate_cov =
        guarded(type.instance, *type.library, "gating_covariance", [&] { return f.gating_covariance(); });
    if (gate_cov.size() > 0) M += J_of * gate_cov * J_of.transpose();
    feature_product_.valid = false;  // M is this feature's
    // A re-entry (association.reentry_joint_test): for the wide gate, M with
    // the robot's covariance Σ_r taken as scale² Σ_r,
    //   M_wide = M + A_r (scale² − 1) Σ_r A_rᵀ,  A_r = A's robot columns.
    const bool reentering = reentry_test && dim > 0 && map.travel_unseen(mf) > ac.loop_min_gap_path;
    if (reentering) {
      if (widening.size() == 0)
        widening = (ac.reentry_covariance_scale * ac.reentry_covariance_scale - 1.0) * map.marginal(map.robot_idx);
      scratch_M_wide_.noalias() = A.leftCols(k) * widening * A.leftCols(k).transpose();
      scratch_M_wide_ += M;
      is_reentry[static_cast<std::size_t>(fi)] = true;
    }

    for (std::size_t mi = 0; mi < meas.size(); ++mi) {
      // The scratch objects keep their storage from pair to pair: this loop
      // runs for every (feature, measurement) pair of every reading.
      Innovation& in = scratch_innovation_;
      const bool ok = guarded(type.instance, *type.library, "innovation",
                              [&] { return f.innovation(x_o, meas[mi], in); });
      if (!ok) continue;
      const auto m = in.eta.size();
      if (m == 0 || in.J_eta_o.rows() != m || in.J_eta_o.cols() != layout.size() || in.J_eta_v.rows() != m ||
          in.J_eta_v.cols() != meas[mi].v.size())
        throw PluginError(type.instance + " (plugin '" + type.plugin +
                          "'): innovation returned Jacobians of the wrong size");
      require_finite(in.eta, "innovation", type.instance, *type.library);
      require_finite(in.J_eta_o, "J_eta_o", type.instance, *type.library);
      require_finite(in.J_eta_v, "J_eta_v", type.instance, *type.library);
      const Eigen::MatrixXd& C_eta = measurement_products_[mi].of(in.J_eta_v, meas[mi].C_v, scratch_T_);
      Eigen::MatrixXd& S = scratch_S_;
      S = feature_product_.of(in.J_eta_o, M, scratch_T_) + C_eta;  // eq. 29
      const int mi_dim = static_cast<int>(m);
      // Most pairs are far apart: d² = ηᵀS⁻¹η ≥ |η|²/λ_max(S) ≥ |η|²/trace(S),
      // so when that bound is beyond both thresholds the pair can neither be
      // gated in nor make the measurement ambiguous — no factorisation needed.
      const double far = far_threshold(mi_dim);
      if (reentering) {
        // The wide gate first: it admits every pair the filter's gate does.
        const Eigen::MatrixXd S_wide = in.J_eta_o * scratch_M_wide_ * in.J_eta_o.transpose() + C_eta;
        if (!tracing && in.eta.squaredNorm() > far * S_wide.trace()) continue;
        const Eigen::LDLT<Eigen::MatrixXd> wide_ldlt(S_wide);
        const double d2_wide = wide_ldlt.info() == Eigen::Success ? in.eta.dot(wide_ldlt.solve(in.eta)) : kInf;
        if (d2_wide <= threshold(gate_chi2_, ac.gate_probability, mi_dim)) {
          Candidate c;
          c.d2 = d2_wide;
          c.innovation = in;
          c.C_eta = C_eta;
          c.measurement = static_cast<int>(mi);
          c.feature = fi;
          c.J_state = in.J_eta_o * A;  // eq. 30
          c.idx = idx;
          if (gate_cov.size() > 0) c.C_gate = in.J_eta_o * J_of * gate_cov * J_of.transpose() * in.J_eta_o.transpose();
          reentry_candidates.push_back(std::move(c));
        }
      } else if (!tracing && S.trace() > 0.0 && in.eta.squaredNorm() > far * S.trace()) {
        continue;
      }
      scratch_ldlt_.compute(S);
      if (scratch_ldlt_.info() != Eigen::Success || !(scratch_ldlt_.vectorD().array() > 0.0).all()) continue;
      const double d2 = in.eta.dot(scratch_ldlt_.solve(in.eta));
      closest[mi] = std::min(closest[mi], d2 / threshold(new_feature_chi2_, ac.new_feature_probability, mi_dim));
      if (tracing)
        log_->trace("step ", map.step, ": measurement ", mi, " vs #", mf.id, " (dim ", dim, "): d2 ", d2, " eta ",
                    in.eta.transpose());
      if (d2 > threshold(gate_chi2_, ac.gate_probability, mi_dim)) continue;
      Candidate c;
      c.d2 = d2;
      c.tentative = dim == 0;
      c.innovation = in;
      c.C_eta = C_eta;
      c.measurement = static_cast<int>(mi);
      c.feature = fi;
      c.J_state = in.J_eta_o * A;  // eq. 30: J_ηo (J_or  J_of B̃)
      if (joint) {
        c.idx = idx;
        if (gate_cov.size() > 0) c.C_gate = in.J_eta_o * J_of * gate_cov * J_of.transpose() * in.J_eta_o.transpose();
      }
      candidates.push_back(std::move(c));
    }
  }

  std::vector<int> chosen;
  if (joint) {
    ++stats_.jcbb_readings;
    const JcbbResult jc = joint_compatibility(candidates, map.marginal,
                                              {ac.gate_probability, ac.jcbb_max_nodes, &joint_chi2_, ac.refuse_ambiguous});
    stats_.jcbb_nodes += jc.nodes + jc.rival_nodes;
    if (jc.bounded) {
      ++stats_.jcbb_bounded;
      if (log_->enabled(LogLevel::Debug))
        log_->debug("step ", map.step, ": joint compatibility gave up after ", jc.nodes,
                    " nodes; nearest neighbour used");
      chosen = nearest_neighbour(candidates, static_cast<int>(meas.size()), static_cast<int>(map.features.size()));
    } else {
      // The jointly compatible pairings that no rival disputes, then
      // tentative features as nearest neighbour pairs them (dense information
      // only). A disputed measurement stays unpaired and, lying in the gate
      // of a feature, starts none.
      for (int c : jc.chosen)
        if (!std::binary_search(jc.disputed.begin(), jc.disputed.end(), c)) chosen.push_back(c);
      if (!jc.disputed.empty()) {
        ++stats_.ambiguous_readings;
        stats_.disputed_pairings += static_cast<std::int64_t>(jc.disputed.size());
        if (log_->enabled(LogLevel::Debug)) {
          std::ostringstream os;
          for (int c : jc.disputed)
            os << " measurement " << candidates[c].measurement << " to #" << map.features[candidates[c].feature].id
               << " (d2 " << candidates[c].d2 << ")";
          log_->debug("step ", map.step, ": ", jc.disputed.size(), " of ", jc.chosen.size(),
                      " pairings disputed by a rival hypothesis", jc.rivals_bounded ? " (rival search gave up)" : "",
                      ", not used:", os.str());
        }
      }
      std::vector<bool> meas_used(meas.size(), false);
      std::vector<bool> feature_used(map.features.size(), false);
      for (int c : chosen) {
        meas_used[candidates[c].measurement] = true;
        feature_used[candidates[c].feature] = true;
      }
      std::vector<int> rest;
      for (std::size_t i = 0; i < candidates.size(); ++i)
        if (candidates[i].tentative) rest.push_back(static_cast<int>(i));
      std::stable_sort(rest.begin(), rest.end(), [&](int a, int b) { return candidates[a].d2 < candidates[b].d2; });
      for (int c : rest) {
        if (meas_used[candidates[c].measurement] || feature_used[candidates[c].feature]) continue;
        meas_used[candidates[c].measurement] = true;
        feature_used[candidates[c].feature] = true;
        chosen.push_back(c);
      }
    }
  } else {
    chosen = nearest_neighbour(candidates, static_cast<int>(meas.size()), static_cast<int>(map.features.size()));
  }
  if (reentry_test) confirm_reentry_pairings(map, candidates, reentry_candidates, is_reentry, widening, chosen);

  AssociationResult result;
  std::vector<bool> meas_used(meas.size(), false);
  for (int c : chosen) {
    meas_used[candidates[c].measurement] = true;
    result.matches.push_back(std::move(candidates[c]));
  }
  // An unmatched measurement starts a new feature only when it lies beyond
  // the (wider) new-feature threshold of every feature: ambiguous
  // measurements create nothing.
  result.may_create.assign(meas.size(), false);
  for (std::size_t mi = 0; mi < meas.size(); ++mi) result.may_create[mi] = !meas_used[mi] && closest[mi] > 1.0;
  return result;
}

// The re-entry test (association.reentry_joint_test) on the pairings chosen:
// those with features unseen over loop_min_gap_path stay only when the
// widened joint test confirms them (confirm_reentries); the others are
// dropped, and their measurements, lying in a feature's gate, start nothing.
void Associator::confirm_reentry_pairings(const AssociationView& map, const std::vector<Candidate>& candidates,
                                          const std::vector<Candidate>& wide, const std::vector<bool>& is_reentry,
                                          const Eigen::MatrixXd& widening, std::vector<int>& chosen) {
  std::vector<std::pair<int, int>> asked;
  std::vector<int> asked_at;  // positions in `chosen`
  for (std::size_t i = 0; i < chosen.size(); ++i) {
    const Candidate& c = candidates[chosen[i]];
    if (c.tentative || !is_reentry[static_cast<std::size_t>(c.feature)]) continue;
    asked.emplace_back(c.measurement, c.feature);
    asked_at.push_back(static_cast<int>(i));
  }
  if (asked.empty()) return;
  ++stats_.reentry_readings;
  const ReentryVerdict verdict =
      confirm_reentries(wide, asked, widen_robot(map.marginal, map.robot_idx, widening),
                        {config_.gate_probability, config_.jcbb_max_nodes, &joint_chi2_, true});
  stats_.jcbb_nodes += verdict.search.nodes + verdict.search.rival_nodes;
  std::vector<bool> drop(chosen.size(), false);
  std::ostringstream refused;
  for (std::size_t a = 0; a < asked.size(); ++a) {
    if (verdict.confirmed[a]) {
      ++stats_.reentry_confirmed;
      continue;
    }
    ++stats_.reentry_refused;
    drop[static_cast<std::size_t>(asked_at[a])] = true;
    refused << " measurement " << asked[a].first << " to #" << map.features[asked[a].second].id;
  }
  if (refused.tellp() > 0 && log_->enabled(LogLevel::Debug))
    log_->debug("step ", map.step, ": re-entry test:", refused.str(),
                " not confirmed", verdict.search.bounded || verdict.search.rivals_bounded ? " (the search gave up)" : "",
                "; ", verdict.search.disputed.size(), " of ", verdict.search.chosen.size(),
                " widened pairings disputed");
  std::vector<int> kept;
  for (std::size_t i = 0; i < chosen.size(); ++i)
    if (!drop[i]) kept.push_back(chosen[i]);
  chosen = std::move(kept);
}

}  // namespace mspace::kernel
