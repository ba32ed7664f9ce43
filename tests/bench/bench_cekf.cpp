// bench_cekf.cpp — time of one filter step (predict + update) against map size
// when the robot sees a local working set: the compressed EKF (cekf) against
// the full EKF (ekf).
//
// A planar robot (k = 3) and N point features of 3 M-space dimensions each
// (state 3 + 3N), built with one augmentation from the robot before the timed
// loop. Every step predicts (eqs. 26–27) and applies seven 3-row observations
// (eqs. 28–32), each of the robot and one feature of a window of 12
// consecutive features; the window moves on by one feature every 4 steps (and
// wraps around), so about one feature per 4 steps enters the working set. This
// is roughly the Victoria Park run: about 7 trees per scan, a new one in view
// every few scans. The observation Jacobians come from a pool
// generated up front; only their indices follow the window. The cekf time
// includes its global updates, amortised over the run.
//
// BM_CekfMaxActive runs the cekf at N = 1000 for several max_active.
//
// BM_RangeBearing (issue 13): whole runs of range_bearing_scenario.hpp — 500 /
// 1000 / 2000 landmarks, 1000 steps at 1, 2, 5 and 10 m per step — for the ekf
// (cekf:0), the cekf with its defaults (cekf:1) and the cekf without its churn
// fallback (cekf:2, the algorithm before issue 13), on identical input
// (tests/cekf checks that they give the same final state). The time
// is the whole run (predict, update, augment and the driver's own arithmetic);
// the log is generated before the clock starts. Counters: state_dim at the
// end, rows (measurement rows in updates), global (cekf global updates),
// fallbacks (cekf switches to every row active).
//   ./build/bin/bench_cekf --benchmark_filter=RangeBearing --benchmark_counters_tabular=true
//
// Counters: state_dim; for the cekf, global_per_kstep (global updates per
// 1000 steps), active_dim and basis_dim at the end, fallbacks (to every row
// active, see cekf_filter.hpp; none expected here).
//
//   ./build/bin/bench_cekf --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include "mspace/cekf_filter.hpp"
#include "mspace/dense_product.hpp"
#include "mspace/ekf_filter.hpp"
#include "range_bearing_scenario.hpp"

namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using mspace::Estimator;
using mspace::LinearizedObservation;
using mspace::StateAugmentation;
using mspace::cekf::CekfFilter;
using mspace::ekf::EkfFilter;

constexpr int kRobotDim = 3;
constexpr int kFeatureDim = 3;
constexpr int kObservationsPerStep = 7;
constexpr int kWindow = 12;          ///< features in the working set
constexpr int kStepsPerFeature = 4;  ///< the window moves on by one feature this often
constexpr int kBatches = 32;         ///< distinct observation batches cycled through

MatrixXd near_identity(int n, double spread, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-spread, spread);
  return MatrixXd::Identity(n, n) + MatrixXd::NullaryExpr(n, n, [&] { return u(rng); });
}

/// The map: every feature initialised from the robot pose, δx_f = J_f δx_r + w,
/// as one augmentation of 3N rows (block-diagonal noise).
void build_map(Estimator& filter, int features, std::mt19937& rng) {
  filter.reset(0.01 * MatrixXd::Identity(kRobotDim, kRobotDim));
  const int rows = kFeatureDim * features;
  StateAugmentation aug{{0, 1, 2}, MatrixXd(rows, kRobotDim), 0.25 * MatrixXd::Identity(rows, rows)};
  for (int f = 0; f < features; ++f)
    aug.J.middleRows(kFeatureDim * f, kFeatureDim) = near_identity(kFeatureDim, 0.1, rng);
  filter.augment(aug);
}

/// Observations of features at random offsets in the window: a relative
/// measurement (J_r ≈ −J_f) with a well-conditioned diagonal noise. The feature
/// columns of idx are filled in by aim().
struct Batch {
  std::vector<int> offsets;
  std::vector<LinearizedObservation> obs;
};

std::vector<Batch> observation_batches(std::mt19937& rng) {
  std::uniform_int_distribution<int> pick(0, kWindow - 1);
  std::uniform_real_distribution<double> u(-0.1, 0.1);
  std::vector<Batch> batches(kBatches);
  for (Batch& batch : batches) {
    for (int i = 0; i < kObservationsPerStep; ++i) {
      const MatrixXd J_f = near_identity(kFeatureDim, 0.2, rng);
      LinearizedObservation o;
      o.idx = {0, 1, 2, 0, 0, 0};
      o.J.resize(kFeatureDim, kRobotDim + kFeatureDim);
      o.J << -J_f + 0.1 * near_identity(kRobotDim, 0.5, rng), J_f;
      o.eta = VectorXd::NullaryExpr(kFeatureDim, [&] { return u(rng); });
      o.C_eta = VectorXd::Constant(kFeatureDim, 0.01).asDiagonal();
      o.C_eta(0, 0) = 0.02;
      int offset = pick(rng);
      while (std::find(batch.offsets.begin(), batch.offsets.end(), offset) != batch.offsets.end()) offset = pick(rng);
      batch.offsets.push_back(offset);
      batch.obs.push_back(std::move(o));
    }
  }
  return batches;
}

/// Points the batch's observations at the window starting at feature `start`.
void aim(Batch& batch, int start, int features) {
  for (std::size_t i = 0; i < batch.obs.size(); ++i) {
    const int first = kRobotDim + kFeatureDim * ((start + batch.offsets[i]) % features);
    for (int c = 0; c < kFeatureDim; ++c) batch.obs[i].idx[static_cast<std::size_t>(kRobotDim + c)] = first + c;
  }
}

/// The map and the observation pool; run() does the timed steps.
class Scenario {
 public:
  Scenario(Estimator& filter, int features) : filter_(filter), features_(features) {
    build_map(filter_, features_, rng_);
    batches_ = observation_batches(rng_);
    J_rr_(0, 2) = -0.05;
    J_rr_(1, 2) = 0.1;
  }

  /// Returns the number of steps done.
  std::int64_t run(benchmark::State& state) {
    std::int64_t step = 0;
    for (auto _ : state) {
      Batch& batch = batches_[static_cast<std::size_t>(step) % batches_.size()];
      aim(batch, static_cast<int>(step / kStepsPerFeature), features_);
      filter_.predict(J_rr_, Q_);
      const VectorXd dx = filter_.update(batch.obs);
      benchmark::DoNotOptimize(dx.data());
      ++step;
    }
    state.counters["state_dim"] = filter_.dim();
    return step;
  }

 private:
  Estimator& filter_;
  int features_;
  std::mt19937 rng_{42};
  std::vector<Batch> batches_;
  MatrixXd J_rr_ = MatrixXd::Identity(kRobotDim, kRobotDim);
  MatrixXd Q_ = VectorXd::Constant(kRobotDim, 1e-3).asDiagonal();
};

void BM_EkfLocalStep(benchmark::State& state) {
  EkfFilter ekf;
  Scenario(ekf, static_cast<int>(state.range(0))).run(state);
}

/// Arguments: features, and optionally max_active (else the default).
void BM_CekfLocalStep(benchmark::State& state) {
  CekfFilter cekf(state.range(1) > 0 ? static_cast<int>(state.range(1)) : CekfFilter::kDefaultMaxActive);
  Scenario scenario(cekf, static_cast<int>(state.range(0)));
  const std::int64_t before = cekf.global_updates();  // the one after building the map
  const std::int64_t steps = scenario.run(state);
  state.counters["global_per_kstep"] =
      1000.0 * static_cast<double>(cekf.global_updates() - before) / static_cast<double>(steps);
  state.counters["active_dim"] = cekf.active_dim();
  state.counters["basis_dim"] = cekf.basis_dim();
  state.counters["fallbacks"] = static_cast<double>(cekf.fallbacks());
}

BENCHMARK(BM_EkfLocalStep)
    ->ArgName("features")
    ->Arg(500)
    ->Arg(1000)
    ->Arg(2000)
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

BENCHMARK(BM_CekfLocalStep)
    ->ArgNames({"features", "max_active"})
    ->Args({500, 0})
    ->Args({1000, 0})
    ->Args({2000, 0})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(2.0)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

// The trade-off behind the default max_active: a larger active part makes
// each step dearer (O(max_active² m)) and global updates (O(N² max_active))
// rarer. Run with --benchmark_filter=MaxActive.
BENCHMARK(BM_CekfLocalStep)
    ->Name("BM_CekfMaxActive")
    ->ArgNames({"features", "max_active"})
    ->ArgsProduct({{1000}, {48, 64, 96, 128, 192, 256}})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(2.0)
    ->Repetitions(3)
    ->ReportAggregatesOnly(true);

/// Arguments: landmarks, speed (m per step), estimator (0 ekf, 1 cekf, 2 cekf without churn fallback).
void BM_RangeBearing(benchmark::State& state) {
  mspace::bench::RangeBearingSettings settings;
  settings.landmarks = static_cast<int>(state.range(0));
  settings.speed = static_cast<double>(state.range(1));
  const mspace::bench::RangeBearingLog log = mspace::bench::make_range_bearing_log(settings);
  const bool compressed = state.range(2) > 0;
  for (auto _ : state) {
    EkfFilter ekf;
    CekfFilter cekf(CekfFilter::kDefaultMaxActive, CekfFilter::kDefaultKeepSteps, false, state.range(2) == 1);
    Estimator& filter = compressed ? static_cast<Estimator&>(cekf) : ekf;
    const mspace::bench::RangeBearingResult result = mspace::bench::run_estimator(filter, log);
    benchmark::DoNotOptimize(result.mean.data());
    state.counters["state_dim"] = filter.dim();
    state.counters["rows"] = result.rows;
    state.counters["global"] = compressed ? static_cast<double>(cekf.global_updates()) : 0.0;
    state.counters["fallbacks"] = compressed ? static_cast<double>(cekf.fallbacks()) : 0.0;
  }
}

BENCHMARK(BM_RangeBearing)
    ->ArgNames({"landmarks", "speed", "cekf"})
    ->ArgsProduct({{500, 1000, 2000}, {1, 2, 5, 10}, {0, 1, 2}})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true)
    ->UseRealTime();

/// Arguments: n, k, kernel (0 Eigen, 1 AVX2/FMA). C ← C − A Bᵀ on the lower
/// triangle of n × n, A and B n × k: a global update of the cekf (n slots, a
/// basis of k rows) and, with small k, the EKF's eq. 32 on the whole covariance.
void BM_LowerProduct(benchmark::State& state) {
  const Eigen::Index n = state.range(0), k = state.range(1);
  const auto kernel = state.range(2) == 0 ? mspace::ProductKernel::eigen : mspace::ProductKernel::avx2_fma;
  if (kernel == mspace::ProductKernel::avx2_fma && !mspace::avx2_fma_available()) {
    state.SkipWithError("no AVX2/FMA on this processor");
    return;
  }
  const Eigen::MatrixXd A = Eigen::MatrixXd::Random(n, k), B = Eigen::MatrixXd::Random(n, k);
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n, n);
  for (auto _ : state) {
    mspace::add_product(C, -1.0, A, B, mspace::ProductPart::lower, kernel);
    benchmark::DoNotOptimize(C.data());
  }
  state.counters["GMAC/s"] = benchmark::Counter(static_cast<double>(n * n * k) / 2e9 * static_cast<double>(state.iterations()),
                                               benchmark::Counter::kIsRate);
}

BENCHMARK(BM_LowerProduct)
    ->ArgNames({"n", "k", "avx2"})
    ->ArgsProduct({{500, 1300, 2500}, {8, 90}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

}  // namespace

BENCHMARK_MAIN();
