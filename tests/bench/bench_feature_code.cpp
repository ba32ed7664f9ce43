// What code in a feature's hot path costs.
//
// Fixed-size against dynamic-size Eigen (docs/writing-a-feature-plugin.md
// §10). The in-tree wall predicts the line it expects to measure with
// wall::predict_line() on Eigen::Vector4d / Matrix4d; predict_line_dynamic()
// below is the same maths written on VectorXd / MatrixXd throughout, as an
// author who keeps the interface's types everywhere would write it. Both must give the same numbers (checked
// before timing: a benchmark of a wrong transcription would mean nothing).
// BM_WallInnovation times the in-tree WallFeature::innovation() as a whole
// (fixed-size inside, dynamic only where it fills Innovation), for scale.
//
// A feature_log() message below the run's level (§11): the look-up of the
// feature's logger and the level check, with the arguments not formatted.
//   ./build/bin/bench_feature_code --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <cmath>
#include <memory>
#include <optional>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "mspace/feature_log.hpp"
#include "mspace/params.hpp"
#include "mspace/transform.hpp"
#include "wall_feature.hpp"

namespace {

using mspace::wall::PredictedLine;

struct DynamicLine {
  Eigen::VectorXd h;
  Eigen::MatrixXd J;
};

// wall::predict_line (plugins/wall/wall_feature.cpp) on dynamic-size types.
DynamicLine predict_line_dynamic(const Eigen::VectorXd& x_o) {
  const Eigen::VectorXd p1 = x_o.head(2), p2 = x_o.tail(2);
  const Eigen::VectorXd d = p2 - p1;
  const double L = d.norm();
  const Eigen::VectorXd t = d / L;
  Eigen::VectorXd u(2);
  u << -t(1), t(0);
  const double rho = u.dot(p1);
  const double s1 = t.dot(p1), s2 = t.dot(p2);
  DynamicLine out;
  out.h.resize(4);
  out.h << rho, std::atan2(u(1), u(0)), s1, s2;
  const Eigen::RowVectorXd uL = u.transpose() / L;
  out.J.resize(4, 4);
  out.J.row(0) << u.transpose() + s1 * uL, -s1 * uL;
  out.J.row(1) << -uL, uL;
  out.J.row(2) << t.transpose() - rho * uL, rho * uL;
  out.J.row(3) << -rho * uL, t.transpose() + rho * uL;
  return out;
}

/// A wall seen from the sensor: end points (2, 1) and (−1, 3), with a small
/// change per call so that nothing is hoisted out of the loop.
Eigen::Vector4d ends_at(int i) { return {2.0 + 1e-9 * (i & 7), 1.0, -1.0, 3.0}; }

bool same_numbers() {
  const Eigen::Vector4d x = ends_at(0);
  const PredictedLine a = mspace::wall::predict_line(x);
  const DynamicLine b = predict_line_dynamic(x);
  return (a.h - b.h).cwiseAbs().maxCoeff() <= 1e-15 && (a.J - b.J).cwiseAbs().maxCoeff() <= 1e-15;
}

void BM_WallPredictLine_Fixed(benchmark::State& state) {
  if (!same_numbers()) state.SkipWithError("predict_line_dynamic differs from wall::predict_line");
  int i = 0;
  for (auto _ : state) {
    const PredictedLine p = mspace::wall::predict_line(ends_at(++i));
    benchmark::DoNotOptimize(p);
  }
}
BENCHMARK(BM_WallPredictLine_Fixed);

void BM_WallPredictLine_Dynamic(benchmark::State& state) {
  if (!same_numbers()) state.SkipWithError("predict_line_dynamic differs from wall::predict_line");
  int i = 0;
  for (auto _ : state) {
    const Eigen::VectorXd x = ends_at(++i);  // the interface hands x_o over as a VectorXd
    const DynamicLine p = predict_line_dynamic(x);
    benchmark::DoNotOptimize(p);
  }
}
BENCHMARK(BM_WallPredictLine_Dynamic);

// The whole in-tree innovation of a wall at M-space dimension 4 (both ends
// measured): predict_line, then the chosen rows into Innovation's VectorXd /
// MatrixXd.
void BM_WallInnovation(benchmark::State& state) {
  const mspace::wall::WallType type(
      mspace::PluginArgs{"walls", mspace::Params::defaults(mspace::wall::WallType::param_specs()), nullptr});
  std::optional<mspace::FeatureSample> s = type.sample(4, 1);
  if (!s || !s->feature) {
    state.SkipWithError("the wall gave no sample at dimension 4");
    return;
  }
  const Eigen::VectorXd x_o = mspace::to_sensor_frame(s->feature->layout(), s->feature->coords(), s->x_ms);
  mspace::Innovation out;
  for (auto _ : state) {
    const bool ok = s->feature->innovation(x_o, s->measurement, out);
    benchmark::DoNotOptimize(ok);
    benchmark::DoNotOptimize(out.eta.data());
  }
}
BENCHMARK(BM_WallInnovation);

/// Keeps Info and above; counts what it is given.
class InfoLogger final : public mspace::Logger {
 public:
  void write(mspace::LogLevel, std::string_view) override { ++written; }
  bool enabled(mspace::LogLevel level) const override { return level >= mspace::LogLevel::Info; }
  long written = 0;
};

// A debug message of an attached feature in a run at the default level
// (info), among 1000 other attached features.
void BM_FeatureLogBelowLevel(benchmark::State& state) {
  const mspace::wall::WallType type(
      mspace::PluginArgs{"walls", mspace::Params::defaults(mspace::wall::WallType::param_specs()), nullptr});
  std::vector<std::unique_ptr<mspace::Feature>> features;
  InfoLogger logger;
  for (std::uint64_t seed = 1; seed <= 1000; ++seed) {
    std::optional<mspace::FeatureSample> s = type.sample(2, seed);
    if (!s || !s->feature) {
      state.SkipWithError("the wall gave no sample at dimension 2");
      return;
    }
    mspace::attach_feature_log(*s->feature, &logger);
    features.push_back(std::move(s->feature));
  }
  const mspace::Feature& f = *features[500];
  for (auto _ : state) mspace::feature_log(f).debug("width ", 0.9, " m from ", 10, " observations");
  if (logger.written != 0) state.SkipWithError("a debug message was written at level info");
  for (const auto& p : features) mspace::attach_feature_log(*p, nullptr);
}
BENCHMARK(BM_FeatureLogBelowLevel);

}  // namespace

BENCHMARK_MAIN();
