// bench_ekf.cpp — time of one M-space EKF step (predict + update) against map size.
//
// A planar robot (k = 3) and N point features of 3 M-space dimensions each
// (state 3 + 3N). Every step predicts (eqs. 26–27, which also keeps putting
// process noise back into the state) and applies ten 3-row observations
// (range/bearing/elevation-like), each of the robot and one feature (eqs. 28–32).
// The map is built with augment() before the timed loop; observation batches
// are generated up front and reused in turn.
//
// Counters: state_dim; cov_MB, the bytes of the covariance storage (its
// capacity, which doubles as the map grows); rss_MB, the peak resident set
// size of the process so far (getrusage), which with sizes run in increasing
// order is the peak for the current size.
#include <benchmark/benchmark.h>
#include <sys/resource.h>

#include <Eigen/Core>
#include <random>
#include <vector>

#include "mspace/ekf_filter.hpp"

namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using mspace::LinearizedObservation;
using mspace::StateAugmentation;
using mspace::ekf::EkfFilter;

constexpr int kRobotDim = 3;
constexpr int kFeatureDim = 3;
constexpr int kObservationsPerStep = 10;
constexpr int kBatches = 32;  ///< distinct observation batches cycled through

MatrixXd near_identity(int n, double spread, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-spread, spread);
  return MatrixXd::Identity(n, n) + MatrixXd::NullaryExpr(n, n, [&] { return u(rng); });
}

/// The map: every feature initialised from the robot pose, δx_f = J δx_r + w.
void build_map(EkfFilter& ekf, int features, std::mt19937& rng) {
  ekf.reset(0.01 * MatrixXd::Identity(kRobotDim, kRobotDim));
  const MatrixXd C_new = 0.25 * MatrixXd::Identity(kFeatureDim, kFeatureDim);
  for (int f = 0; f < features; ++f) {
    ekf.augment(StateAugmentation{{0, 1, 2}, near_identity(kFeatureDim, 0.1, rng), C_new});
  }
}

/// One observation of feature `f`: η ≈ J_r δx_r + J_f δx_f, J_r ≈ −J_f as for a
/// relative measurement, with a well-conditioned diagonal noise.
LinearizedObservation observe(int f, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-0.1, 0.1);
  const int first = kRobotDim + kFeatureDim * f;
  const MatrixXd J_f = near_identity(kFeatureDim, 0.2, rng);
  LinearizedObservation o;
  o.idx = {0, 1, 2, first, first + 1, first + 2};
  o.J.resize(kFeatureDim, kRobotDim + kFeatureDim);
  o.J << -J_f + 0.1 * near_identity(kRobotDim, 0.5, rng), J_f;
  o.eta = VectorXd::NullaryExpr(kFeatureDim, [&] { return u(rng); });
  o.C_eta = VectorXd::Constant(kFeatureDim, 0.01).asDiagonal();
  o.C_eta(0, 0) = 0.02;
  return o;
}

std::vector<std::vector<LinearizedObservation>> observation_batches(int features,
                                                                    std::mt19937& rng) {
  std::uniform_int_distribution<int> pick(0, features - 1);
  std::vector<std::vector<LinearizedObservation>> batches(kBatches);
  for (auto& batch : batches) {
    for (int i = 0; i < kObservationsPerStep; ++i) batch.push_back(observe(pick(rng), rng));
  }
  return batches;
}

double peak_rss_mb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

void BM_EkfStep(benchmark::State& state) {
  const auto features = static_cast<int>(state.range(0));
  std::mt19937 rng(42);
  EkfFilter ekf;
  build_map(ekf, features, rng);
  const auto batches = observation_batches(features, rng);
  MatrixXd J_rr = MatrixXd::Identity(kRobotDim, kRobotDim);
  J_rr(0, 2) = -0.05;
  J_rr(1, 2) = 0.1;
  const MatrixXd Q = VectorXd::Constant(kRobotDim, 1e-3).asDiagonal();

  std::size_t step = 0;
  for (auto _ : state) {
    ekf.predict(J_rr, Q);
    const VectorXd dx = ekf.update(batches[step++ % batches.size()]);
    benchmark::DoNotOptimize(dx.data());
  }
  const double capacity = ekf.capacity();
  state.counters["state_dim"] = ekf.dim();
  state.counters["cov_MB"] = capacity * capacity * sizeof(double) / 1e6;
  state.counters["rss_MB"] = peak_rss_mb();
}

BENCHMARK(BM_EkfStep)
    ->ArgName("features")
    ->Arg(100)
    ->Arg(500)
    ->Arg(1000)
    ->Arg(2000)
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

}  // namespace

BENCHMARK_MAIN();
