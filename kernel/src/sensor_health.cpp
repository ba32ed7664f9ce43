#include "sensor_health.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>

#include "chi2.hpp"
#include "mspace/state.hpp"
#include "persistence.hpp"

namespace mspace::kernel {
namespace {

/// k at grid point g: kScaleMin · 10^(g / kScaleSteps).
double scale_at(int g) {
  return SensorHealth::kScaleMin * std::pow(10.0, static_cast<double>(g) / SensorHealth::kScaleSteps);
}

/// NIS(α) = ηᵀ (A + α R)⁻¹ η at α = k² for every k of the grid, added to
/// `at_scale` (the file comment of the header: one Cholesky factor of
/// S = A + R and one eigen-decomposition of L⁻¹ R L⁻ᵀ). Returns NIS(1), or
/// −1 when S is not positive definite (nothing added).
template <std::size_t N>
double add_nis_on_grid(const Eigen::VectorXd& eta, const Eigen::MatrixXd& A, const Eigen::MatrixXd& R,
                       std::array<double, N>& at_scale) {
  const Eigen::LLT<Eigen::MatrixXd> llt(A + R);
  if (llt.info() != Eigen::Success) return -1.0;
  const Eigen::MatrixXd Li_R = llt.matrixL().solve(R);                        // L⁻¹ R
  const Eigen::MatrixXd M = llt.matrixL().solve(Li_R.transpose().eval());     // L⁻¹ R L⁻ᵀ
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (M + M.transpose()));
  const Eigen::VectorXd z = eig.eigenvectors().transpose() * llt.matrixL().solve(eta);
  const Eigen::VectorXd d = eig.eigenvalues().cwiseMax(0.0).cwiseMin(1.0);
  // α − 1 at every grid point, computed once.
  static const std::array<double, N> alpha_minus_1 = [] {
    std::array<double, N> a{};
    for (std::size_t g = 0; g < N; ++g) a[g] = scale_at(static_cast<int>(g)) * scale_at(static_cast<int>(g)) - 1.0;
    return a;
  }();
  for (std::size_t g = 0; g < N; ++g) {
    double nis = 0.0;
    for (Eigen::Index i = 0; i < z.size(); ++i) nis += z[i] * z[i] / (1.0 + alpha_minus_1[g] * d[i]);
    at_scale[g] += nis;
  }
  return z.squaredNorm();
}

/// The k where the observed NIS sum, decreasing in k, equals the expected
/// one: log-linear between grid points; `beyond` says when it is off the grid.
template <std::size_t N>
double solve_scale(const std::array<double, N>& at_scale, double expected, int& beyond) {
  beyond = 0;
  if (at_scale.front() < expected) {
    beyond = -1;
    return scale_at(0);
  }
  for (std::size_t g = 0; g + 1 < N; ++g) {
    if (at_scale[g + 1] > expected) continue;
    const double a = std::log(at_scale[g] / expected), b = std::log(at_scale[g + 1] / expected);
    const double f = a > b ? a / (a - b) : 0.0;
    return scale_at(static_cast<int>(g)) * std::pow(10.0, f / SensorHealth::kScaleSteps);
  }
  beyond = 1;
  return scale_at(static_cast<int>(N) - 1);
}

}  // namespace

std::optional<Pose6> robot_truth(const DataStep& data, int ground_truth_sensor, const std::vector<int>& dofs) {
  if (ground_truth_sensor >= 0 || !data.ground_truth) return std::nullopt;
  for (int i : dofs)
    if (!(data.ground_truth_known & (1u << i))) return std::nullopt;
  return data.ground_truth;
}

Eigen::VectorXd robot_error(const Pose6& truth, const Pose6& estimate, const std::vector<int>& dofs) {
  const Pose6 e = pose_difference(truth, estimate);
  Eigen::VectorXd out(static_cast<Eigen::Index>(dofs.size()));
  for (std::size_t i = 0; i < dofs.size(); ++i) out[static_cast<Eigen::Index>(i)] = e[dofs[i]];
  return out;
}

SensorHealth::SensorHealth(std::string sensor, std::string extractor_hint, std::int64_t silent_span, int nis_window,
                           double gate_probability)
    : extractor_hint_(std::move(extractor_hint)),
      silent_span_(silent_span),
      nis_window_(nis_window),
      gate_probability_(gate_probability) {
  r_.sensor = std::move(sensor);
}

void SensorHealth::warn(std::string text) {
  r_.warnings.push_back(text);
  new_warnings_.push_back(std::move(text));
}

void SensorHealth::record_reading(std::int64_t measurements, std::int64_t matched, double extract_seconds) {
  ++r_.readings;
  r_.measurements += measurements;
  r_.matched += matched;
  r_.extract_seconds += extract_seconds;
  if (silent_span_ <= 0) return;
  if (!warned_silent_ && r_.measurements == 0 && r_.readings >= silent_span_) {
    warned_silent_ = true;
    warn("sensor " + r_.sensor + ": 0 measurements in " + std::to_string(r_.readings) +
         " readings — check the extractor's parameters (" + extractor_hint_ + ")");
  }
  if (measurements > 0) readings_since_match_ = matched > 0 ? 0 : readings_since_match_ + 1;
  if (!warned_unmatched_ && readings_since_match_ >= silent_span_ && r_.matched == 0) {
    warned_unmatched_ = true;
    warn("sensor " + r_.sensor + ": none of its " + std::to_string(r_.measurements) + " measurements in " +
         std::to_string(r_.readings) +
         " readings matched a feature — check its mount, its measurement noise and the features it feeds");
  }
}

double SensorHealth::expected_nis(int rows) {
  if (rows >= static_cast<int>(expected_by_rows_.size())) expected_by_rows_.resize(static_cast<std::size_t>(rows) + 1, -1.0);
  double& e = expected_by_rows_[static_cast<std::size_t>(rows)];
  if (e < 0.0) {
    const double q = chi2_quantile(gate_probability_, rows);
    e = rows * chi2_cdf(q, rows + 2) / chi2_cdf(q, rows);
  }
  return e;
}

void SensorHealth::record_update(double nis, int rows) {
  if (rows <= 0) return;
  const double expected = expected_nis(rows);
  ++r_.updates;
  nis_sum_ += nis;
  expected_sum_ += expected;
  rows_sum_ += rows;
  window_nis_ += nis;
  window_expected_ += expected;
  if (++window_count_ < nis_window_) return;
  const double ratio = window_nis_ / window_expected_;
  window_nis_ = window_expected_ = 0.0;
  window_count_ = 0;
  // Persistently: kPersistentWindows windows in a row beyond the same bound.
  const int side = ratio > kNisRatioHigh ? 1 : ratio < kNisRatioLow ? -1 : 0;
  windows_out_ = side != 0 && side == last_side_ ? windows_out_ + 1 : (side != 0 ? 1 : 0);
  last_side_ = side;
  window_ratio_sum_ = windows_out_ == 1 ? ratio : window_ratio_sum_ + ratio;
  if (windows_out_ < kPersistentWindows) return;
  const double mean_ratio = window_ratio_sum_ / windows_out_;
  char figures[200];
  std::snprintf(figures, sizeof figures,
                "NIS %.2f times its expected value over %d consecutive windows of %d updates (up to update %lld)",
                mean_ratio, windows_out_, nis_window_, static_cast<long long>(r_.updates));
  if (side > 0 && !warned_high_) {
    warned_high_ = true;
    warn("sensor " + r_.sensor + ": " + figures +
         " — the filter is overconfident: its measurement noise (or the motion noise) is set smaller than the "
         "data shows");
  } else if (side < 0 && !warned_low_) {
    // Not a warning: noise set larger on purpose (errors correlated from
    // reading to reading, e.g. one line seen in many frames) shows this way.
    warned_low_ = true;
    std::string text = "sensor " + r_.sensor + ": " + figures +
                       " — its measurement noise is set larger than these innovations show (fine if chosen to cover "
                       "errors correlated from reading to reading)";
    r_.notes.push_back(text);
    new_notes_.push_back(std::move(text));
  }
}

void SensorHealth::record_update(const UpdateInnovation& u) {
  const auto m = u.eta.size();
  if (m == 0) return;
  const int k = u.robot_columns;
  const auto n = u.J_state.cols();
  const double expected = expected_nis(static_cast<int>(m));
  KindSums& sums = kinds_[u.kind];
  // S = A + R, A = J P Jᵀ (eq. 29).
  const double nis = add_nis_on_grid(u.eta, u.J_state * u.P * u.J_state.transpose(), u.R, sums.filter.at_scale);
  if (nis < 0.0) return;
  record_update(nis, static_cast<int>(m));
  NisSums& f = sums.filter;
  ++f.updates;
  f.rows += m;
  f.nis += nis;
  f.expected += expected;
  if (u.robot_error.size() != k || k == 0) return;
  // Given the robot's true pose: the robot's error e_r, and the part of the
  // feature's error that the filter correlates with it, P_fr P_rr⁻¹ e_r, are
  // taken out of η; what remains has S' = J_f (P_ff − P_fr P_rr⁻¹ P_rf) J_fᵀ + R
  // (the Gaussian conditional of the feature's error on the robot's).
  const Eigen::LDLT<Eigen::MatrixXd> P_rr(u.P.topLeftCorner(k, k));
  if (P_rr.info() != Eigen::Success) return;
  const Eigen::MatrixXd P_fr = u.P.bottomLeftCorner(n - k, k);
  const Eigen::MatrixXd J_f = u.J_state.rightCols(n - k);
  const Eigen::VectorXd eta =
      u.eta + u.J_state.leftCols(k) * u.robot_error + J_f * (P_fr * P_rr.solve(u.robot_error));
  const Eigen::MatrixXd P_f_given_r = u.P.bottomRightCorner(n - k, n - k) - P_fr * P_rr.solve(P_fr.transpose());
  const Eigen::MatrixXd A = J_f * P_f_given_r * J_f.transpose();
  NisSums& t = sums.true_pose;
  const double nis_true = add_nis_on_grid(eta, A, u.R, t.at_scale);
  if (nis_true < 0.0) return;
  ++t.updates;
  t.rows += m;
  t.nis += nis_true;
  t.expected += expected;
}

std::vector<std::string> SensorHealth::take_new_warnings() { return std::exchange(new_warnings_, {}); }

std::vector<std::string> SensorHealth::take_new_notes() { return std::exchange(new_notes_, {}); }

SensorHealthReport SensorHealth::report() const {
  SensorHealthReport out = r_;
  if (r_.updates > 0) {
    out.nis_ratio = nis_sum_ / expected_sum_;
    out.mean_nis_per_row = nis_sum_ / rows_sum_;
    out.expected_nis_per_row = expected_sum_ / rows_sum_;
  }
  for (const auto& [kind, sums] : kinds_) {
    if (sums.filter.updates == 0) continue;
    KindNisReport r;
    r.kind = kind;
    r.updates = sums.filter.updates;
    r.rows = sums.filter.rows;
    r.mean_nis = sums.filter.nis / static_cast<double>(r.updates);
    r.expected_nis = sums.filter.expected / static_cast<double>(r.updates);
    r.nis_ratio = sums.filter.nis / sums.filter.expected;
    r.sigma_scale = solve_scale(sums.filter.at_scale, sums.filter.expected, r.sigma_scale_beyond);
    const NisSums& t = sums.true_pose;
    r.true_pose_updates = t.updates;
    if (t.updates > 0) {
      r.nis_ratio_true_pose = t.nis / t.expected;
      r.sigma_scale_true_pose = solve_scale(t.at_scale, t.expected, r.sigma_scale_true_pose_beyond);
    }
    out.kinds.push_back(std::move(r));
  }
  return out;
}

}  // namespace mspace::kernel

namespace mspace::kernel {

void SensorHealth::save(StateWriter& out, const std::string& prefix) const {
  Eigen::MatrixXd counts(1, 8);
  counts << static_cast<double>(r_.readings), static_cast<double>(r_.measurements), static_cast<double>(r_.matched),
      static_cast<double>(r_.updates), static_cast<double>(readings_since_match_), window_count_, windows_out_,
      last_side_;
  out.put(prefix + "counts", counts);
  Eigen::MatrixXd sums(1, 7);
  sums << r_.extract_seconds, nis_sum_, expected_sum_, rows_sum_, window_nis_, window_expected_, window_ratio_sum_;
  out.put(prefix + "sums", sums);
  Eigen::MatrixXd flags(1, 4);
  flags << warned_silent_, warned_unmatched_, warned_high_, warned_low_;
  out.put(prefix + "flags", flags);
  out.put_bytes(prefix + "warnings", pack_strings(r_.warnings));
  out.put_bytes(prefix + "notes", pack_strings(r_.notes));
  out.put_bytes(prefix + "new_warnings", pack_strings(new_warnings_));
  out.put_bytes(prefix + "new_notes", pack_strings(new_notes_));
  // NIS by measurement kind: one row per kind, the filter's sums then the
  // true pose's (updates, rows, nis, expected, at_scale…).
  constexpr int kSumColumns = 4 + kScaleGrid;
  std::vector<std::string> names;
  Eigen::MatrixXd kinds(static_cast<Eigen::Index>(kinds_.size()), 2 * kSumColumns);
  Eigen::Index row = 0;
  for (const auto& [name, sums] : kinds_) {
    names.push_back(name);
    Eigen::Index col = 0;
    for (const NisSums* n : {&sums.filter, &sums.true_pose}) {
      kinds(row, col++) = static_cast<double>(n->updates);
      kinds(row, col++) = static_cast<double>(n->rows);
      kinds(row, col++) = n->nis;
      kinds(row, col++) = n->expected;
      for (double v : n->at_scale) kinds(row, col++) = v;
    }
    ++row;
  }
  out.put_bytes(prefix + "kind_names", pack_strings(names));
  out.put(prefix + "kinds", kinds);
}

void SensorHealth::restore(const StateReader& in, const std::string& prefix) {
  const std::string context = "sensor health of " + r_.sensor;
  const Eigen::MatrixXd& counts = get_state(in, prefix + "counts", 1, 8, context);
  const Eigen::MatrixXd& sums = get_state(in, prefix + "sums", 1, 7, context);
  const Eigen::MatrixXd& flags = get_state(in, prefix + "flags", 1, 4, context);
  for (Eigen::Index i = 0; i < counts.cols(); ++i)
    if (!(std::abs(counts(0, i)) <= 1e15) || counts(0, i) != std::floor(counts(0, i)))
      throw std::invalid_argument(context + ": saved count " + std::to_string(i) + " is not an integer");
  SensorHealthReport r = r_;
  r.readings = static_cast<std::int64_t>(counts(0, 0));
  r.measurements = static_cast<std::int64_t>(counts(0, 1));
  r.matched = static_cast<std::int64_t>(counts(0, 2));
  r.updates = static_cast<std::int64_t>(counts(0, 3));
  r.extract_seconds = sums(0, 0);
  r.warnings = unpack_strings(in.get_bytes(prefix + "warnings"));
  r.notes = unpack_strings(in.get_bytes(prefix + "notes"));
  new_warnings_ = unpack_strings(in.get_bytes(prefix + "new_warnings"));
  new_notes_ = unpack_strings(in.get_bytes(prefix + "new_notes"));
  const std::vector<std::string> names = unpack_strings(in.get_bytes(prefix + "kind_names"));
  const Eigen::MatrixXd& kinds =
      get_state(in, prefix + "kinds", static_cast<Eigen::Index>(names.size()), 2 * (4 + kScaleGrid), context);
  std::map<std::string, KindSums> restored;
  for (std::size_t i = 0; i < names.size(); ++i) {
    KindSums& sums = restored[names[i]];
    Eigen::Index col = 0;
    const auto row = static_cast<Eigen::Index>(i);
    for (NisSums* n : {&sums.filter, &sums.true_pose}) {
      n->updates = static_cast<std::int64_t>(kinds(row, col++));
      n->rows = static_cast<std::int64_t>(kinds(row, col++));
      n->nis = kinds(row, col++);
      n->expected = kinds(row, col++);
      for (double& v : n->at_scale) v = kinds(row, col++);
    }
  }
  kinds_ = std::move(restored);
  r_ = std::move(r);
  readings_since_match_ = static_cast<std::int64_t>(counts(0, 4));
  window_count_ = static_cast<int>(counts(0, 5));
  windows_out_ = static_cast<int>(counts(0, 6));
  last_side_ = static_cast<int>(counts(0, 7));
  nis_sum_ = sums(0, 1);
  expected_sum_ = sums(0, 2);
  rows_sum_ = sums(0, 3);
  window_nis_ = sums(0, 4);
  window_expected_ = sums(0, 5);
  window_ratio_sum_ = sums(0, 6);
  warned_silent_ = flags(0, 0) != 0.0;
  warned_unmatched_ = flags(0, 1) != 0.0;
  warned_high_ = flags(0, 2) != 0.0;
  warned_low_ = flags(0, 3) != 0.0;
}

}  // namespace mspace::kernel
