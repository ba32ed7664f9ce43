#include "sensor_health.hpp"

#include <cmath>
#include <cstdio>
#include <utility>

#include "chi2.hpp"
#include "mspace/state.hpp"
#include "persistence.hpp"

namespace mspace::kernel {

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

std::vector<std::string> SensorHealth::take_new_warnings() { return std::exchange(new_warnings_, {}); }

std::vector<std::string> SensorHealth::take_new_notes() { return std::exchange(new_notes_, {}); }

SensorHealthReport SensorHealth::report() const {
  SensorHealthReport out = r_;
  if (r_.updates > 0) {
    out.nis_ratio = nis_sum_ / expected_sum_;
    out.mean_nis_per_row = nis_sum_ / rows_sum_;
    out.expected_nis_per_row = expected_sum_ / rows_sum_;
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
