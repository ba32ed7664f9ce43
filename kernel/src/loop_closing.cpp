// loop_closing.cpp — map matching: hypotheses from a Hough transform over
// planar motions, Gauss–Newton refinement, joint compatibility, uniqueness
// (see loop_closing.hpp).
#include "loop_closing.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <sstream>
#include <tuple>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include "chi2.hpp"

namespace mspace::kernel {

namespace {

bool is_point(BlockKind kind) { return kind == BlockKind::Point3D || kind == BlockKind::Point2D; }

Eigen::Matrix2d rotation(double theta) {
  const double c = std::cos(theta), s = std::sin(theta);
  Eigen::Matrix2d R;
  R << c, -s, s, c;
  return R;
}

/// Whether any column of `M` has a non-zero entry in the rows of `block`.
bool touches(const CoordLayout& layout, const Eigen::MatrixXd& M, int block) {
  if (M.cols() == 0) return false;
  const int first = layout.offset(block), size = block_size(layout.kind(block));
  return M.middleRows(first, size).cwiseAbs().maxCoeff() > 1e-12;
}

/// Blocks a single direction (column) touches.
std::vector<int> touched_blocks(const CoordLayout& layout, const Eigen::VectorXd& direction) {
  std::vector<int> out;
  for (int b = 0; b < layout.num_blocks(); ++b)
    if (touches(layout, direction, b)) out.push_back(b);
  return out;
}

// Matrices of at most MaxN rows and columns: with a compile-time bound (the
// coordinates of every feature type shipped today number ≤ kSmallCoords)
// Eigen keeps them on the stack, so the search's many small products and
// factorisations allocate nothing; Eigen::Dynamic gives the unbounded types.
constexpr int kSmallCoords = 6;
template <int MaxN>
using MatN = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, MaxN, MaxN>;
template <int MaxN>
using VecN = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, MaxN, 1>;
template <int MaxN>
using JacN = Eigen::Matrix<double, Eigen::Dynamic, 3, 0, MaxN, 3>;

/// n × n: R(θ) on the (x, y) rows of every point block, identity elsewhere.
template <int MaxN>
MatN<MaxN> block_rotation(const CoordLayout& layout, double theta) {
  MatN<MaxN> Rn = MatN<MaxN>::Identity(layout.size(), layout.size());
  const Eigen::Matrix2d R = rotation(theta);
  for (int b = 0; b < layout.num_blocks(); ++b)
    if (is_point(layout.kind(b))) Rn.template block<2, 2>(layout.offset(b), layout.offset(b)) = R;
  return Rn;
}

/// CoincidenceResidual with bounded sizes.
template <int MaxN>
struct Residual {
  VecN<MaxN> r;
  MatN<MaxN> N, S;
  JacN<MaxN> J;
};

/// What of a pair's residual does not depend on the motion. Which of a's
/// symmetry directions enter N does not (a rotation moves no direction onto
/// another block); when none does, N is b's alone and so are Nᵀx_b and
/// Nᵀ Σ_b N: computed once per pair instead of once per angle and iteration.
template <int MaxN>
struct PairBasis {
  bool usable = false;       ///< same layout and something left to compare
  bool fixed = false;        ///< N does not depend on the motion
  std::vector<int> a_columns;  ///< a's directions that enter N (rotated by T)
  MatN<MaxN> Nt;             ///< m × n, when fixed
  VecN<MaxN> Nt_xb;          ///< Nᵀ x_b, when fixed
  MatN<MaxN> S_b;            ///< Nᵀ Σ_b N + floor² I, when fixed
};

/// An orthonormal basis of the complement of the columns of F (n × k).
template <int MaxN>
MatN<MaxN> complement_basis(const MatN<MaxN>& F, Eigen::Index n) {
  if (F.cols() == 0) return MatN<MaxN>::Identity(n, n);
  Eigen::ColPivHouseholderQR<MatN<MaxN>> qr(F);
  qr.setThreshold(1e-9);
  const Eigen::Index rank = qr.rank();
  MatN<MaxN> Q = qr.householderQ();
  return Q.rightCols(n - rank);
}

/// The free directions of a pair at motion T: b's, then a's chosen columns
/// rotated by T.
template <int MaxN>
MatN<MaxN> free_directions(const FeatureShape& a, const FeatureShape& b, const std::vector<int>& a_columns,
                           double theta) {
  const CoordLayout& layout = *b.layout;
  const Eigen::Index n = layout.size();
  MatN<MaxN> F(n, b.free.cols() + static_cast<Eigen::Index>(a_columns.size()));
  F.leftCols(b.free.cols()) = b.free;
  if (!a_columns.empty()) {
    const MatN<MaxN> Ra = block_rotation<MaxN>(layout, theta);
    for (std::size_t k = 0; k < a_columns.size(); ++k)
      F.col(b.free.cols() + static_cast<Eigen::Index>(k)) = Ra * a.free.col(a_columns[k]);
  }
  return F;
}

template <int MaxN>
PairBasis<MaxN> pair_basis(const FeatureShape& a, const FeatureShape& b, double floor_sigma) {
  PairBasis<MaxN> p;
  if (a.layout == nullptr || b.layout == nullptr || !(*a.layout == *b.layout)) return p;
  const CoordLayout& layout = *b.layout;
  const Eigen::Index n = layout.size();
  // a's directions on blocks b keeps fixed (both on one block would let two
  // crossing lines "coincide" at their intersection).
  for (Eigen::Index c = 0; c < a.free.cols(); ++c) {
    bool only_fixed_blocks = true;
    for (int block : touched_blocks(layout, a.free.col(c)))
      only_fixed_blocks = only_fixed_blocks && !touches(layout, b.free, block);
    if (only_fixed_blocks) p.a_columns.push_back(static_cast<int>(c));
  }
  p.fixed = p.a_columns.empty();
  if (!p.fixed) {
    p.usable = true;  // decided per motion
    return p;
  }
  const MatN<MaxN> N = complement_basis<MaxN>(free_directions<MaxN>(a, b, p.a_columns, 0.0), n);
  if (N.cols() == 0) return p;
  p.usable = true;
  p.Nt = N.transpose();
  p.Nt_xb = p.Nt * b.x;
  p.S_b = floor_sigma * floor_sigma * MatN<MaxN>::Identity(N.cols(), N.cols());
  if (b.cov.size() != 0) p.S_b += p.Nt * b.cov * N;
  return p;
}

/// Never prunes (residual_at's default).
struct KeepAll {
  template <class R, class J>
  bool operator()(const R&, const J&, double) const { return false; }
};

/// The pair's residual at motion T (see coincidence_residual). `prune(r, J,
/// bound)` is asked once r and J are known, with an upper bound on trace(S)
/// (N has orthonormal columns and R(θ) is orthogonal, so trace(Nᵀ R Σ_a Rᵀ N)
/// ≤ trace(Σ_a)); when it says so, S is not formed and false is returned.
template <int MaxN, class Prune = KeepAll>
bool residual_at(const FeatureShape& a, const FeatureShape& b, const PairBasis<MaxN>& basis, const PlanarMotion& T,
                 double floor_sigma, Residual<MaxN>& out, const Prune& prune = Prune{}) {
  if (!basis.usable) return false;
  const CoordLayout& layout = *b.layout;
  const Eigen::Index n = layout.size();
  const Eigen::Matrix2d R = rotation(T.theta);
  VecN<MaxN> xa = a.x;  // T(x_a)
  JacN<MaxN> D = JacN<MaxN>::Zero(n, 3);  // ∂T(x_a)/∂(θ, t_x, t_y)
  for (int block = 0; block < layout.num_blocks(); ++block) {
    if (!is_point(layout.kind(block))) continue;
    const int o = layout.offset(block);
    const Eigen::Vector2d arm = R * (a.x.segment<2>(o) - T.pivot);  // R(θ)(p − pivot)
    xa.template segment<2>(o) = arm + T.pivot + T.t;
    D(o, 0) = -arm.y();
    D(o + 1, 0) = arm.x();
    D(o, 1) = 1.0;
    D(o + 1, 2) = 1.0;
  }
  const double trace_a = a.cov.size() != 0 ? a.cov.trace() : 0.0;
  double trace_bound = 0.0;
  if (basis.fixed) {
    out.N = basis.Nt.transpose();
    out.r.noalias() = basis.Nt * xa;
    out.r -= basis.Nt_xb;
    trace_bound = basis.S_b.trace() + trace_a;
  } else {
    out.N = complement_basis<MaxN>(free_directions<MaxN>(a, b, basis.a_columns, T.theta), n);
    if (out.N.cols() == 0) return false;
    out.r.noalias() = out.N.transpose() * (xa - b.x);
    trace_bound = static_cast<double>(out.N.cols()) * floor_sigma * floor_sigma +
                  (b.cov.size() != 0 ? b.cov.trace() : 0.0) + trace_a;
  }
  out.J.noalias() = out.N.transpose() * D;
  if (prune(out.r, out.J, trace_bound)) return false;
  if (basis.fixed) {
    out.S = basis.S_b;
  } else {
    out.S = floor_sigma * floor_sigma * MatN<MaxN>::Identity(out.N.cols(), out.N.cols());
    if (b.cov.size() != 0) out.S += out.N.transpose() * b.cov * out.N;
  }
  if (a.cov.size() != 0) {
    const MatN<MaxN> NtRa = out.N.transpose() * block_rotation<MaxN>(layout, T.theta);
    out.S += NtRa * a.cov * NtRa.transpose();
  }
  return true;
}

/// Centre of the point blocks' (x, y) and the largest distance from it.
struct Footprint {
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  double radius = 0.0;
  bool placed = false;  ///< has a point block
};

Footprint footprint(const FeatureShape& s) {
  Footprint f;
  int points = 0;
  for (int b = 0; b < s.layout->num_blocks(); ++b)
    if (is_point(s.layout->kind(b))) {
      f.centre += s.x.segment<2>(s.layout->offset(b));
      ++points;
    }
  if (points == 0) return f;
  f.placed = true;
  f.centre /= points;
  for (int b = 0; b < s.layout->num_blocks(); ++b)
    if (is_point(s.layout->kind(b)))
      f.radius = std::max(f.radius, (s.x.segment<2>(s.layout->offset(b)) - f.centre).norm());
  return f;
}

/// The point blocks of a, rotated by θ, lie as b's do up to sliding along
/// the lines between them: every vector between two point blocks of a,
/// rotated, points the way of b's, and departs from its line by at most
/// `tolerance` (m) plus `angle_slack` (rad) of its length (blocks closer
/// than 1 mm in either say nothing). This refuses a segment the other way
/// round and two lines that meet at a corner, whose residual, with the
/// sliding of each copy's unmeasured end projected out, can vanish.
bool same_arrangement(const FeatureShape& a, const FeatureShape& b, double theta, double tolerance,
                      double angle_slack) {
  const CoordLayout& layout = *b.layout;
  const Eigen::Matrix2d R = rotation(theta);
  for (int i = 0; i < layout.num_blocks(); ++i) {
    if (!is_point(layout.kind(i))) continue;
    for (int j = i + 1; j < layout.num_blocks(); ++j) {
      if (!is_point(layout.kind(j))) continue;
      const Eigen::Vector2d da = R * (a.x.segment<2>(layout.offset(j)) - a.x.segment<2>(layout.offset(i)));
      const Eigen::Vector2d db = b.x.segment<2>(layout.offset(j)) - b.x.segment<2>(layout.offset(i));
      const double la = da.norm(), lb = db.norm();
      if (la < 1e-3 || lb < 1e-3) continue;
      if (da.dot(db) < 0.0) return false;
      const double off_line = std::abs(da.x() * db.y() - da.y() * db.x()) / lb;  // |da × b̂|
      if (off_line > tolerance + angle_slack * la) return false;
    }
  }
  return true;
}

/// Where a pair's residual projects sliding out (symmetry directions: an end
/// point not measured may lie anywhere along its line), it cannot tell two
/// copies of one object from two objects on one line — a segment and the
/// next one past a gap — nor from one object with its point blocks the other way
/// round (a segment whose start lies where the other's end does). Such pairs
/// are taken as one object only when, at motion T, their footprints overlap
/// (centres no further apart than the radii plus `margin`) and their point
/// blocks lie the same way (same_arrangement, to `margin` and
/// `angle_slack`).
/// Pairs that slide nothing are decided by their residual alone.
bool same_place(const FeatureShape& a, const Footprint& fa, const FeatureShape& b, const Footprint& fb,
                const PlanarMotion& T, double margin, double angle_slack) {
  if (a.free.cols() == 0 && b.free.cols() == 0) return true;
  if (!fa.placed || !fb.placed) return true;
  if ((T.apply(fa.centre) - fb.centre).norm() > fa.radius + fb.radius + margin) return false;
  return same_arrangement(a, b, T.theta, margin, angle_slack);
}

/// χ² quantiles by dimension, computed once.
class Chi2Table {
 public:
  explicit Chi2Table(double p) : p_(p) {}
  double operator()(int dof) {
    if (dof <= 0) return 0.0;
    auto it = cache_.find(dof);
    if (it == cache_.end()) it = cache_.emplace(dof, chi2_quantile(p_, dof)).first;
    return it->second;
  }

 private:
  double p_;
  std::map<int, double> cache_;
};

template <int MaxN>
double mahalanobis2(const VecN<MaxN>& r, const MatN<MaxN>& S) {
  return r.dot(S.ldlt().solve(r));
}

struct Peak {
  int votes = 0;
  double theta = 0.0;
  Eigen::Vector2d t = Eigen::Vector2d::Zero();
};

}  // namespace

// ---- PlanarMotion -----------------------------------------------------------

Eigen::Vector2d PlanarMotion::apply(const Eigen::Vector2d& p) const { return rotation(theta) * (p - pivot) + pivot + t; }

Eigen::VectorXd PlanarMotion::apply(const CoordLayout& layout, const Eigen::VectorXd& x) const {
  Eigen::VectorXd out = x;
  for (int b = 0; b < layout.num_blocks(); ++b)
    if (is_point(layout.kind(b))) out.segment<2>(layout.offset(b)) = apply(Eigen::Vector2d(x.segment<2>(layout.offset(b))));
  return out;
}

Eigen::MatrixXd PlanarMotion::rotate(const CoordLayout& layout, const Eigen::MatrixXd& directions) const {
  if (directions.cols() == 0) return directions;
  return block_rotation<Eigen::Dynamic>(layout, theta) * directions;
}

PlanarMotion PlanarMotion::scaled(double fraction) const { return PlanarMotion{theta * fraction, t * fraction, pivot}; }

// ---- The residual of one pair -----------------------------------------------

bool coincidence_residual(const FeatureShape& a, const FeatureShape& b, const PlanarMotion& T, double floor_sigma,
                          CoincidenceResidual& out) {
  const PairBasis<Eigen::Dynamic> basis = pair_basis<Eigen::Dynamic>(a, b, floor_sigma);
  Residual<Eigen::Dynamic> r;
  if (!residual_at(a, b, basis, T, floor_sigma, r)) return false;
  out.r = r.r;
  out.N = r.N;
  out.S = r.S;
  out.J = r.J;
  return true;
}

std::string pair_refusal(const FeatureShape& a, const FeatureShape& b, const PlanarMotion& T,
                         const MapMatchOptions& o) {
  std::ostringstream why;
  why.precision(3);
  if (a.type != b.type) return "another type";
  const Footprint fa = footprint(a), fb = footprint(b);
  const double margin = 3.0 * o.floor_sigma;
  if (!same_place(a, fa, b, fb, T, margin, 0.0)) {
    const double apart = (T.apply(fa.centre) - fb.centre).norm();
    if (apart > fa.radius + fb.radius + margin)
      why << "footprints apart (centres " << apart << " m, radii " << fa.radius << " + " << fb.radius << " m)";
    else
      why << "point blocks arranged otherwise";
    return why.str();
  }
  CoincidenceResidual r;
  if (!coincidence_residual(a, b, T, o.floor_sigma, r)) return "nothing to compare";
  const double d2 = r.r.dot(r.S.ldlt().solve(r.r));
  const double gate = chi2_quantile(o.probability, static_cast<int>(r.r.size()));
  if (d2 <= gate) return "";
  why << "D² " << d2 << " > " << gate << " (residual " << r.r.transpose() << ", σ "
      << r.S.diagonal().cwiseSqrt().transpose() << ")";
  return why.str();
}

// ---- The search ---------------------------------------------------------------

namespace {

/// |a − b| as an angle in [0, π]: a search over every heading has ±π on
/// both ends of its grid, and refinement may carry an angle past them.
double angle_apart(double a, double b) { return std::abs(std::remainder(a - b, 2.0 * std::numbers::pi)); }

template <int MaxN>
MapMatch search(const std::vector<FeatureShape>& local, const std::vector<FeatureShape>& old,
                const Eigen::Vector2d& pivot, const MapMatchOptions& options) {
  MapMatch result;
  // Hypotheses come from the enlarged window (rivals); the accepted one must
  // lie in the window itself.
  MapMatchOptions o = options;
  o.max_translation *= std::max(1.0, options.rival_window_factor);
  o.max_rotation = std::min(std::numbers::pi, o.max_rotation * std::max(1.0, options.rival_window_factor));
  // A wide window is searched on a coarser grid, so that a search costs at
  // most ~81² cells × 61 angles whatever the drift allowance (the grid's
  // half steps enter the first pairing as uncertainty, below).
  o.cell = std::max(o.cell, o.max_translation / 40.0);
  o.rotation_step = std::max(o.rotation_step, o.max_rotation / 30.0);
  Chi2Table chi2(o.probability);
  // same_place's margin: the local map's own distortion, 3σ.
  const double overlap_margin = 3.0 * o.floor_sigma;

  // Candidate partners: same type and close enough for some motion in the window.
  std::vector<Footprint> local_fp, old_fp;
  for (const FeatureShape& s : local) local_fp.push_back(footprint(s));
  for (const FeatureShape& s : old) old_fp.push_back(footprint(s));
  std::vector<std::vector<int>> partners(local.size());
  for (std::size_t i = 0; i < local.size(); ++i) {
    if (!local_fp[i].placed) continue;
    const double swing = (local_fp[i].centre - pivot).norm() * std::min(o.max_rotation, std::numbers::pi);
    for (std::size_t j = 0; j < old.size(); ++j) {
      if (old[j].type != local[i].type || !old_fp[j].placed) continue;
      const double reach = o.max_translation + swing + local_fp[i].radius + old_fp[j].radius;
      if ((local_fp[i].centre - old_fp[j].centre).norm() <= reach) partners[i].push_back(static_cast<int>(j));
    }
  }
  // How far each old feature may be moved onto (MapMatchOptions::drift_per_metre). Only the accepted
  // hypothesis is held to it: the search and the rivals are not, so that a place that repeats (a symmetric
  // building) still makes the answer ambiguous however far the drift says the robot can be from it.
  std::vector<double> reach_t(old.size(), std::numeric_limits<double>::infinity()), reach_r(reach_t);
  if (options.drift_per_metre > 0.0 || options.drift_rad_per_metre > 0.0)
    for (std::size_t j = 0; j < old.size(); ++j) {
      if (!std::isfinite(old[j].travel_unseen)) continue;
      const double travel = std::max(0.0, old[j].travel_unseen);
      reach_t[j] = options.pair_base_translation + options.drift_per_metre * travel;
      reach_r[j] = options.pair_base_rotation + options.drift_rad_per_metre * travel;
    }
  const auto within_reach = [&](std::size_t j, const PlanarMotion& T) {
    return T.t.norm() <= reach_t[j] + o.cell && std::abs(T.theta) <= reach_r[j] + o.rotation_step;
  };

  // Each candidate pair's motion-independent part, made when first needed.
  std::vector<std::vector<PairBasis<MaxN>>> bases(local.size());
  std::vector<std::vector<char>> based(local.size());
  for (std::size_t i = 0; i < local.size(); ++i) {
    bases[i].resize(partners[i].size());
    based[i].assign(partners[i].size(), 0);
  }
  const auto basis = [&](std::size_t i, std::size_t k) -> const PairBasis<MaxN>& {
    if (!based[i][k]) {
      bases[i][k] = pair_basis<MaxN>(local[i], old[static_cast<std::size_t>(partners[i][k])], o.floor_sigma);
      based[i][k] = 1;
    }
    return bases[i][k];
  };

  // 1. Hough transform: for each angle, votes of the pairs for translations.
  const int half = static_cast<int>(std::ceil(o.max_translation / o.cell));
  const int side = 2 * half + 1;
  std::vector<int> votes(static_cast<std::size_t>(side * side)), stamp(votes.size());
  const int steps = static_cast<int>(std::ceil(o.max_rotation / o.rotation_step));
  const double half_step = 0.5 * o.rotation_step;
  std::vector<Peak> peaks;
  Residual<MaxN> res;
  for (int k = -steps; k <= steps; ++k) {
    const double theta = k * o.rotation_step;
    std::fill(votes.begin(), votes.end(), 0);
    std::fill(stamp.begin(), stamp.end(), -1);
    const PlanarMotion T0{theta, Eigen::Vector2d::Zero(), pivot};
    auto vote = [&](const Eigen::Vector2d& t, int voter) {
      const int ci = static_cast<int>(std::lround(t.x() / o.cell)) + half;
      const int cj = static_cast<int>(std::lround(t.y() / o.cell)) + half;
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) {
          const int i = ci + di, j = cj + dj;
          if (i < 0 || j < 0 || i >= side || j >= side) continue;
          const std::size_t cell = static_cast<std::size_t>(i * side + j);
          if (stamp[cell] == voter) continue;  // one vote per local feature and cell
          stamp[cell] = voter;
          ++votes[cell];
        }
    };
    for (std::size_t i = 0; i < local.size(); ++i) {
      // The partner test above at this angle: the rotated footprint must
      // reach the old one with a translation inside the window (the swing
      // of half an angle step is the only rotation left to allow for).
      const Eigen::Vector2d turned = T0.apply(local_fp[i].centre);
      const double slack = o.max_translation + local_fp[i].radius + (local_fp[i].centre - pivot).norm() * half_step;
      for (std::size_t k = 0; k < partners[i].size(); ++k) {
        const auto j = static_cast<std::size_t>(partners[i][k]);
        const Footprint& fj = old_fp[j];
        if ((turned - fj.centre).norm() > slack + fj.radius) continue;
        if (!residual_at(local[i], old[j], basis(i, k), T0, o.floor_sigma, res)) continue;
        // The angle grid is coarse: its half step enters as uncertainty.
        res.S += half_step * half_step * res.J.col(0) * res.J.col(0).transpose();
        const Eigen::Matrix<double, Eigen::Dynamic, 2, 0, MaxN, 2> M = res.J.rightCols(2);
        const Eigen::LDLT<MatN<MaxN>> W(res.S);
        const Eigen::Matrix2d A = M.transpose() * W.solve(M);
        const Eigen::Vector2d g = M.transpose() * W.solve(res.r);
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(A);
        const double l1 = es.eigenvalues()[0], l2 = es.eigenvalues()[1];
        if (!(l2 > 0.0)) continue;  // the pair says nothing about the translation
        const auto m = static_cast<int>(res.r.size());
        const int voter = static_cast<int>(i);
        if (l1 > 1e-6 * l2) {  // both directions fixed: one translation
          const Eigen::Vector2d t = -A.ldlt().solve(g);
          const VecN<MaxN> e = res.r + M * t;
          if (m > 2 && e.dot(W.solve(e)) > chi2(m - 2)) continue;
          if (t.norm() <= o.max_translation) vote(t, voter);
        } else {  // one direction free (a sliding end point): a line of translations
          const Eigen::Vector2d u = es.eigenvectors().col(1), v = es.eigenvectors().col(0);
          const Eigen::Vector2d t0 = -(u.dot(g) / l2) * u;
          const VecN<MaxN> e = res.r + M * t0;
          if (m > 1 && e.dot(W.solve(e)) > chi2(m - 1)) continue;
          if (t0.norm() > o.max_translation) continue;
          if (!same_arrangement(local[i], old[j], theta, overlap_margin, half_step)) continue;
          // Only where the two overlap (same_place), a cell of slack.
          const double overlap = local_fp[i].radius + fj.radius + overlap_margin + o.cell;
          const double reach = std::sqrt(o.max_translation * o.max_translation - t0.squaredNorm());
          for (double s = -reach; s <= reach; s += 0.5 * o.cell) {
            const Eigen::Vector2d t = t0 + s * v;
            if ((turned + t - fj.centre).norm() <= overlap) vote(t, voter);
          }
        }
      }
    }
    if (options.probe && std::lround(options.probe->theta / o.rotation_step) == k) {
      const int pi = static_cast<int>(std::lround(options.probe->t.x() / o.cell)) + half;
      const int pj = static_cast<int>(std::lround(options.probe->t.y() / o.cell)) + half;
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj)
          if (pi + di >= 0 && pj + dj >= 0 && pi + di < side && pj + dj < side)
            result.probe_votes =
                std::max(result.probe_votes, votes[static_cast<std::size_t>((pi + di) * side + pj + dj)]);
    }
    for (int i = 0; i < side; ++i)
      for (int j = 0; j < side; ++j) {
        const int c = votes[static_cast<std::size_t>(i * side + j)];
        if (c < o.min_matches) continue;
        bool is_max = true;
        for (int di = -1; di <= 1 && is_max; ++di)
          for (int dj = -1; dj <= 1 && is_max; ++dj) {
            const int a = i + di, b = j + dj;
            if ((di != 0 || dj != 0) && a >= 0 && b >= 0 && a < side && b < side &&
                votes[static_cast<std::size_t>(a * side + b)] > c)
              is_max = false;
          }
        if (is_max) peaks.push_back({c, theta, Eigen::Vector2d((i - half) * o.cell, (j - half) * o.cell)});
      }
  }
  if (result.probe_votes >= 0)
    result.probe_outvoted = static_cast<int>(
        std::count_if(peaks.begin(), peaks.end(), [&](const Peak& p) { return p.votes > result.probe_votes; }));
  // Most votes first; among equals (a ridge along a corridor) the smallest
  // motion, which the prior favours.
  std::stable_sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) {
    if (a.votes != b.votes) return a.votes > b.votes;
    return a.t.norm() + std::abs(a.theta) < b.t.norm() + std::abs(b.theta);
  });
  std::vector<Peak> kept;  // non-maximum suppression over neighbouring angles and cells
  for (const Peak& p : peaks) {
    bool near = false;
    for (const Peak& q : kept)
      near = near || (angle_apart(p.theta, q.theta) <= 1.01 * o.rotation_step && (p.t - q.t).norm() <= 2.01 * o.cell);
    if (!near) kept.push_back(p);
    if (static_cast<int>(kept.size()) >= o.max_hypotheses) break;
  }

  // The pass of the old map (MapMatchOptions::pass_gap) that holds most of
  // the old features `chosen` pairs (positions in `gated`): their spans of
  // observation sorted by start and chained while each starts within
  // pass_gap of the chain's latest end; ties to the pass whose pairs fit
  // better. Leaves `allowed` true for the old features whose span lies
  // within pass_gap of that pass's (or that were never timed) and false for
  // the rest; says whether a chosen pair fell outside the pass.
  const auto keep_one_pass = [&](const std::vector<std::tuple<double, int, int, std::size_t>>& gated,
                                 const std::vector<std::size_t>& chosen, std::vector<char>& allowed) {
    struct Span {
      double first, last, d2;
    };
    std::vector<Span> spans;  // of the chosen pairs' old features
    for (const std::size_t g : chosen) {
      const FeatureShape& f = old[static_cast<std::size_t>(std::get<2>(gated[g]))];
      if (std::isfinite(f.seen_first) && std::isfinite(f.seen_last))
        spans.push_back({f.seen_first, std::max(f.seen_first, f.seen_last), std::get<0>(gated[g])});
    }
    if (spans.size() < 2) return false;
    std::sort(spans.begin(), spans.end(), [](const Span& a, const Span& b) { return a.first < b.first; });
    struct Pass {
      double first = 0.0, last = 0.0, d2 = 0.0;
      std::size_t count = 0;
    };
    Pass best, now;
    for (const Span& s : spans) {
      if (now.count > 0 && s.first > now.last + o.pass_gap) now = Pass{};
      if (now.count == 0) now.first = now.last = s.first;
      now.last = std::max(now.last, s.last);
      now.d2 += s.d2;
      ++now.count;
      if (now.count > best.count || (now.count == best.count && now.d2 < best.d2)) best = now;
    }
    for (std::size_t j = 0; j < old.size(); ++j)  // NaN compares false: allowed
      allowed[j] = !(old[j].seen_last < best.first - o.pass_gap || old[j].seen_first > best.last + o.pass_gap);
    return best.count < spans.size();
  };

  // 2. Verification: pair one to one, refine the motion, test jointly.
  auto pair_up = [&](const PlanarMotion& T, bool coarse, MapMatchHypothesis& h, Eigen::Matrix3d& H,
                     Eigen::Vector3d& grad) {
    // (d², local, old, which gated residual)
    std::vector<std::tuple<double, int, int, std::size_t>> gated;
    std::vector<Residual<MaxN>> kept_res;
    Residual<MaxN> r;
    const double margin = overlap_margin + (coarse ? o.cell : 0.0);
    for (std::size_t i = 0; i < local.size(); ++i)
      for (std::size_t k = 0; k < partners[i].size(); ++k) {
        const int j = partners[i][k];
        if (!same_place(local[i], local_fp[i], old[static_cast<std::size_t>(j)], old_fp[static_cast<std::size_t>(j)],
                        T, margin, coarse ? half_step : 0.0))
          continue;
        // A pair the gate below must refuse is dropped before S is formed:
        // d² = rᵀS⁻¹r ≥ |r|² / λ_max(S) ≥ |r|² / trace(S), so |r|² >
        // χ²·trace(S) already decides it (an exact test, not a heuristic).
        const auto hopeless = [&](const VecN<MaxN>& rr, const JacN<MaxN>& J, double trace_bound) {
          if (coarse)
            trace_bound += half_step * half_step * J.col(0).squaredNorm() +
                           0.25 * o.cell * o.cell * J.rightCols(2).squaredNorm();
          return rr.squaredNorm() > chi2(static_cast<int>(rr.size())) * trace_bound;
        };
        if (!residual_at(local[i], old[static_cast<std::size_t>(j)], basis(i, k), T, o.floor_sigma, r, hopeless))
          continue;
        if (coarse) {
          r.S += half_step * half_step * r.J.col(0) * r.J.col(0).transpose();
          r.S += 0.25 * o.cell * o.cell * r.J.rightCols(2) * r.J.rightCols(2).transpose();
        }
        const double d2 = mahalanobis2<MaxN>(r.r, r.S);
        if (d2 > chi2(static_cast<int>(r.r.size()))) continue;
        gated.emplace_back(d2, static_cast<int>(i), j, kept_res.size());
        kept_res.push_back(r);
      }
    std::sort(gated.begin(), gated.end());
    // One to one, most compatible first; with pass_gap, a second time within
    // the pass the first pairing mostly fell on.
    const auto one_to_one = [&](const std::vector<char>& allowed_old) {
      std::vector<char> used_local(local.size(), 0), used_old(old.size(), 0);
      std::vector<std::size_t> chosen;  // positions in `gated`
      for (std::size_t g = 0; g < gated.size(); ++g) {
        const auto& [d2, i, j, at] = gated[g];
        if (!allowed_old[static_cast<std::size_t>(j)]) continue;
        if (used_local[static_cast<std::size_t>(i)] || used_old[static_cast<std::size_t>(j)]) continue;
        used_local[static_cast<std::size_t>(i)] = used_old[static_cast<std::size_t>(j)] = 1;
        chosen.push_back(g);
      }
      return chosen;
    };
    std::vector<char> allowed_old(old.size(), 1);
    std::vector<std::size_t> chosen = one_to_one(allowed_old);
    if (o.pass_gap > 0.0 && keep_one_pass(gated, chosen, allowed_old)) chosen = one_to_one(allowed_old);
    std::vector<int> gated_local(local.size(), 0), gated_old(old.size(), 0);
    for (const auto& [d2, i, j, at] : gated) {
      if (!allowed_old[static_cast<std::size_t>(j)]) continue;
      ++gated_local[static_cast<std::size_t>(i)];
      ++gated_old[static_cast<std::size_t>(j)];
    }
    h.pairs.clear();
    h.pair_d2.clear();
    h.pair_rivals.clear();
    h.d2 = 0.0;
    int rows = 0;
    H.setZero();
    grad.setZero();
    for (const std::size_t c : chosen) {
      const auto& [d2, i, j, at] = gated[c];
      h.pairs.emplace_back(i, j);
      h.pair_d2.push_back(d2);
      h.pair_rivals.push_back(gated_local[static_cast<std::size_t>(i)] + gated_old[static_cast<std::size_t>(j)] - 2);
      h.d2 += d2;
      const Residual<MaxN>& g = kept_res[at];
      rows += static_cast<int>(g.r.size());
      const Eigen::LDLT<MatN<MaxN>> W(g.S);
      H += g.J.transpose() * W.solve(g.J);
      grad += g.J.transpose() * W.solve(g.r);
    }
    h.dof = rows - 3;
  };

  std::vector<MapMatchHypothesis> verified;
  std::string seed_fate;  // why a placement of the other evidence was dropped (for the reason below)
  std::vector<std::pair<PlanarMotion, bool>> starts;  // (motion, seeded)
  for (const Peak& p : kept) starts.emplace_back(PlanarMotion{p.theta, p.t, pivot}, false);
  for (const PlanarMotion& seed : options.seeds) starts.emplace_back(seed, true);
  for (const auto& [start, seeded] : starts) {
    MapMatchHypothesis h;
    h.motion = start;
    h.seeded = seeded;
    Eigen::Matrix3d H;
    Eigen::Vector3d grad;
    constexpr int kIterations = 6;
    for (int it = 0; it < kIterations; ++it) {
      pair_up(h.motion, it == 0, h, H, grad);
      if (h.pairs.empty()) break;
      const Eigen::Vector3d step = -(H + 1e-9 * Eigen::Matrix3d::Identity()).ldlt().solve(grad);
      h.motion.theta += step[0];
      h.motion.t += step.tail<2>();
      if (step[0] * step[0] < 1e-10 && step.tail<2>().squaredNorm() < 1e-8) break;
    }
    h.motion.theta = std::remainder(h.motion.theta, 2.0 * std::numbers::pi);
    pair_up(h.motion, false, h, H, grad);  // the pairing at the refined motion
    if (h.pairs.empty()) {
      if (seeded) seed_fate = "no feature pairs there";
      continue;
    }
    h.jointly_compatible = h.dof > 0 && h.d2 <= chi2(h.dof);
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(H);
    if (ldlt.info() == Eigen::Success && ldlt.isPositive() && ldlt.vectorD().minCoeff() > 0.0) {
      const Eigen::Matrix3d cov = ldlt.solve(Eigen::Matrix3d::Identity());
      h.sigma_rotation = std::sqrt(std::max(0.0, cov(0, 0)));
      h.sigma_translation =
          std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov.bottomRightCorner<2, 2>())
                                      .eigenvalues()[1]));
      h.determined = h.sigma_translation <= o.max_translation_std && h.sigma_rotation <= o.max_rotation_std;
    }
    if (h.seeded && !h.determined) {  // what the pairing leaves free, the seed's evidence fixed (to the bound)
      h.sigma_translation = o.max_translation_std;
      h.sigma_rotation = o.max_rotation_std;
    }
    const bool inside = std::abs(h.motion.theta) <= o.max_rotation + o.rotation_step &&
                        h.motion.t.norm() <= o.max_translation + o.cell;
    if (options.dense_score) h.dense_score = options.dense_score(h.motion);
    const bool kept_to_seed =
        !seeded || ((h.motion.apply(pivot) - start.apply(pivot)).norm() <= options.seed_tolerance_translation &&
                    angle_apart(h.motion.theta, start.theta) <= options.seed_tolerance_rotation);
    if (seeded && !(inside && kept_to_seed)) {
      std::ostringstream fate;
      fate.precision(3);
      fate << "its " << h.pairs.size() << " feature pairs pull it "
           << (h.motion.apply(pivot) - start.apply(pivot)).norm() << " m, "
           << angle_apart(h.motion.theta, start.theta) * 180.0 / std::numbers::pi << " deg away"
           << (inside ? "" : ", outside the window");
      seed_fate = fate.str();
    }
    if (inside && kept_to_seed) verified.push_back(std::move(h));
  }
  result.hypotheses = static_cast<int>(verified.size());

  // 3. The best acceptable hypothesis, and its best clearly different rival.
  const int needed = std::max(o.min_matches, static_cast<int>(std::ceil(o.min_fraction * static_cast<double>(local.size()))));
  auto in_window = [&](const MapMatchHypothesis& h) {
    return std::abs(h.motion.theta) <= options.max_rotation + o.rotation_step &&
           h.motion.t.norm() <= options.max_translation + o.cell &&
           std::all_of(h.pairs.begin(), h.pairs.end(),
                       [&](const std::pair<int, int>& p) { return within_reach(static_cast<std::size_t>(p.second), h.motion); });
  };
  // (Without dense evidence every hypothesis passes.)
  auto uncontradicted = [&](const MapMatchHypothesis& h) {
    return !options.dense_score || h.dense_score >= options.dense_floor;
  };
  auto valid = [&](const MapMatchHypothesis& h) {
    return h.jointly_compatible && (h.determined || h.seeded) &&
           static_cast<int>(h.pairs.size()) >= (h.seeded ? options.seeded_min_matches : needed) && in_window(h) &&
           uncontradicted(h);
  };
  auto better = [&](const MapMatchHypothesis& a, const MapMatchHypothesis& b) {
    if (valid(a) != valid(b)) return valid(a);
    if (in_window(a) != in_window(b)) return in_window(a);
    if (a.pairs.size() != b.pairs.size()) return a.pairs.size() > b.pairs.size();
    return a.d2 < b.d2;
  };
  if (verified.empty()) {
    result.reason = kept.empty() ? "no translation got " + std::to_string(o.min_matches) + " votes"
                                 : "no hypothesis survived refinement";
    if (!seed_fate.empty()) result.reason += "; the other evidence's placement dropped: " + seed_fate;
    return result;
  }
  std::size_t best = 0;
  for (std::size_t i = 1; i < verified.size(); ++i)
    if (better(verified[i], verified[best])) best = i;
  result.best = verified[best];
  result.best_matches = static_cast<int>(result.best.pairs.size());
  const double same_t = std::max(3.0 * o.cell, 0.5);
  double rival_moved = 0.0, rival_turned = 0.0;  // how far the rival puts the pivot from the best
  for (const MapMatchHypothesis& h : verified) {
    const bool different = angle_apart(h.motion.theta, result.best.motion.theta) > 2.0 * o.rotation_step ||
                           (h.motion.t - result.best.motion.t).norm() > same_t;
    if (different && h.jointly_compatible && uncontradicted(h) &&
        static_cast<int>(h.pairs.size()) > result.rival_matches) {
      result.rival_matches = static_cast<int>(h.pairs.size());
      rival_moved = (h.motion.t - result.best.motion.t).norm();
      rival_turned = angle_apart(h.motion.theta, result.best.motion.theta) * 180.0 / std::numbers::pi;
    }
  }
  // Why hypothesis b is not acceptable by itself ("" when it is), rivals
  // aside; `best` words it for the best one (the search's reason).
  const auto refusal = [&](const MapMatchHypothesis& b, bool best) -> std::string {
    if (valid(b)) return "";
    const std::string pairing = best ? "best pairing" : "pairing";
    const int wanted = b.seeded ? options.seeded_min_matches : needed;
    if (static_cast<int>(b.pairs.size()) < wanted)
      return std::string(best ? "best hypothesis" : "hypothesis") + " pairs only " + std::to_string(b.pairs.size()) +
             " of " + std::to_string(local.size()) + " features (" + std::to_string(wanted) + " needed)";
    if (!b.jointly_compatible)
      return pairing + " is not jointly compatible (D² " + std::to_string(b.d2) + ", " + std::to_string(b.dof) +
             " dof)";
    if (!uncontradicted(b))
      return "the other evidence contradicts the " + pairing + " (score " + std::to_string(b.dense_score) +
             ", at least " + std::to_string(options.dense_floor) + " needed)";
    if (!in_window(b)) {
      std::string what = std::string(best ? "the best placement (" : "the placement (") +
                         std::to_string(b.motion.t.norm()) + " m, " +
                         std::to_string(b.motion.theta * 180.0 / std::numbers::pi) +
                         " deg) lies outside the window, or moves an old feature further than the odometry can have "
                         "drifted since it was last seen";
      // Which of the two: the window, or how many pairs lie beyond their reach (and the nearest-seen of them).
      if (std::abs(b.motion.theta) > options.max_rotation + o.rotation_step ||
          b.motion.t.norm() > options.max_translation + o.cell)
        return what + " (the window: " + std::to_string(options.max_translation) + " m, " +
               std::to_string(options.max_rotation * 180.0 / std::numbers::pi) + " deg)";
      int beyond = 0;
      std::size_t tightest = old.size();
      for (const auto& [li, oi] : b.pairs) {
        const auto j = static_cast<std::size_t>(oi);
        if (within_reach(j, b.motion)) continue;
        ++beyond;
        if (tightest == old.size() || reach_t[j] < reach_t[tightest]) tightest = j;
      }
      if (tightest < old.size())
        what += " (" + std::to_string(beyond) + " of its " + std::to_string(b.pairs.size()) +
                " pairs beyond their reach; the tightest: an old feature unseen for " +
                std::to_string(old[tightest].travel_unseen) + " m of travel, reach " + std::to_string(reach_t[tightest]) +
                " m, " + std::to_string(reach_r[tightest] * 180.0 / std::numbers::pi) + " deg)";
      return what;
    }
    return pairing + " does not fix the motion (σ " + std::to_string(b.sigma_translation) + " m, " +
           std::to_string(b.sigma_rotation * 180.0 / std::numbers::pi) + " deg)";
  };
  if (options.keep_verified)
    for (const MapMatchHypothesis& h : verified) result.verified.emplace_back(h, refusal(h, false));
  if (!valid(result.best)) {
    result.reason = refusal(result.best, true);
    if (!seed_fate.empty()) result.reason += "; the other evidence's placement dropped: " + seed_fate;
    return result;
  }
  if (result.rival_matches >= o.ambiguity_ratio * result.best_matches) {
    result.reason = "ambiguous: another placement (" + std::to_string(rival_moved) + " m, " +
                    std::to_string(rival_turned) + " deg from the best) pairs " + std::to_string(result.rival_matches) +
                    " of the " + std::to_string(result.best_matches) + " features";
    return result;
  }
  result.accepted = true;
  return result;
}

}  // namespace

namespace {
/// A shape moved by T: its points, and its sliding directions turned with it (no covariance: a truth check).
FeatureShape moved_shape(const FeatureShape& f, const PlanarMotion& T) {
  FeatureShape m = f;
  m.x = T.apply(*f.layout, f.x);
  if (f.free.cols() > 0) m.free = T.rotate(*f.layout, f.free);
  m.cov.resize(0, 0);
  return m;
}
}  // namespace

std::optional<double> distance_apart(const FeatureShape& a, const PlanarMotion& a_motion, const FeatureShape& b,
                                     const PlanarMotion& b_motion) {
  if (a.layout == nullptr || b.layout == nullptr) return std::nullopt;
  CoincidenceResidual r;
  if (!coincidence_residual(moved_shape(a, a_motion), moved_shape(b, b_motion), PlanarMotion{}, 0.0, r))
    return std::nullopt;
  return r.r.lpNorm<Eigen::Infinity>();
}

bool footprints_overlap(const FeatureShape& a, const PlanarMotion& a_motion, const FeatureShape& b,
                        const PlanarMotion& b_motion, double margin) {
  if (a.layout == nullptr || b.layout == nullptr) return false;
  const Footprint fa = footprint(moved_shape(a, a_motion)), fb = footprint(moved_shape(b, b_motion));
  return fa.placed && fb.placed && (fa.centre - fb.centre).norm() <= fa.radius + fb.radius + margin;
}

bool arranged_alike(const FeatureShape& a, const PlanarMotion& a_motion, const FeatureShape& b,
                    const PlanarMotion& b_motion, double tolerance) {
  if (a.layout == nullptr || b.layout == nullptr || a.layout->size() != b.layout->size()) return false;
  return same_arrangement(moved_shape(a, a_motion), moved_shape(b, b_motion), 0.0, tolerance, 0.0);
}

MapMatch match_local_map(const std::vector<FeatureShape>& local, const std::vector<FeatureShape>& old,
                         const Eigen::Vector2d& pivot, const MapMatchOptions& options) {
  int largest = 0;
  for (const auto* shapes : {&local, &old})
    for (const FeatureShape& s : *shapes)
      if (s.layout != nullptr) largest = std::max(largest, s.layout->size());
  if (largest <= kSmallCoords) return search<kSmallCoords>(local, old, pivot, options);
  return search<Eigen::Dynamic>(local, old, pivot, options);
}

MapMatch locate_local_map(const std::vector<FeatureShape>& local, const std::vector<FeatureShape>& old,
                          const Eigen::Vector2d& robot, MapMatchOptions options) {
  // The old map's extent: the bounding box of its footprints' centres, and
  // the disc about the box's centre that holds every footprint.
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(INFINITY), hi = -lo;
  std::vector<Footprint> fp;
  for (const FeatureShape& s : old) {
    fp.push_back(footprint(s));
    if (!fp.back().placed) continue;
    lo = lo.cwiseMin(fp.back().centre);
    hi = hi.cwiseMax(fp.back().centre);
  }
  if (!(lo.x() <= hi.x())) {
    MapMatch none;
    none.reason = "the map has no placed feature";
    return none;
  }
  const Eigen::Vector2d centre = 0.5 * (lo + hi);
  double radius = 0.0;
  for (const Footprint& f : fp)
    if (f.placed) radius = std::max(radius, (f.centre - centre).norm() + f.radius);
  // The local map with the robot at the centre: the translation that places
  // it is then at most `radius` long.
  const PlanarMotion to_centre{0.0, centre - robot, robot};
  std::vector<FeatureShape> moved = local;
  for (FeatureShape& s : moved) s.x = to_centre.apply(*s.layout, s.x);
  options.max_translation = std::max(radius, options.cell);
  options.max_rotation = std::numbers::pi;
  options.rival_window_factor = 1.0;
  MapMatch match = match_local_map(moved, old, centre, options);
  // T(p) = R (p + d − c) + c + t = R (p − robot) + robot + (d + t), d = c − robot.
  match.best.motion = PlanarMotion{match.best.motion.theta, to_centre.t + match.best.motion.t, robot};
  return match;
}

bool placements_agree(const PlanarMotion& a, double a_sigma_translation, double a_sigma_rotation,
                      const MapMatchHypothesis& b, const Eigen::Vector2d& robot, double floor_sigma, double& moved,
                      double& turned) {
  const double st = std::hypot(a_sigma_translation, b.sigma_translation);
  const double sr = std::hypot(a_sigma_rotation, b.sigma_rotation);
  moved = (a.apply(robot) - b.motion.apply(robot)).norm();
  turned = std::abs(std::remainder(a.theta - b.motion.theta, 2.0 * std::numbers::pi));
  return moved <= 3.0 * std::hypot(st, floor_sigma) && turned <= 3.0 * sr;
}

}  // namespace mspace::kernel
