// Laser odometry speed (issue 18: ≥ 500 increments/s on one core for
// 1080-beam scans): consecutive scans of a simulated 1080-beam, 0.25°, 270°
// laser (2 cm noise, 0.22 m ahead of the robot) in the office floor and the
// hall of tests/fixtures/laser_sim.hpp, logged every 0.6 s at 0.6 m/s and
// 60°/s, seeded with noisy wheel odometry. One iteration = one increment:
// preparing the reference scan (normals, noise) and matching, as the
// carmen_log source does; the *LocalMap variants also match against the last
// key scans of a local map (4 keys 0.3 m apart, weight 0.3, free-space check
// 0.15 m: the settings README.md gives for Intel) and add the scan to it,
// increments taken in driving order. Run e.g.
//   ./build/bin/bench_scan_matching --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
// Measured 2026-11-28 07:55 UTC, load average 3.1 on 2 cores, CPU time, median of 5: previous scan 1.02 ms
// (office) / 0.96 ms (hall); local map 1.64 / 1.49 ms (609 / 671 increments/s; the code before, in the same
// minutes, 1.95 / 1.86 ms; at 07:12, load 6.2, 2.04 / 1.94 ms, and 4.17 / 3.87 ms before the bearings of
// bearings.hpp); far seed 6.0 ms; 181 beams 0.40 ms.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "laser_sim.hpp"
#include "scan_matcher.hpp"

namespace {

namespace sm = mspace::scan_matching;
namespace tl = mspace::test_laser;

struct Increment {
  sm::ScanPoints previous, current;
  Eigen::Vector3d seed;
};

/// `far`: the seed is off by (−0.5 m, −0.45 m, −25°) besides the wheel noise,
/// beyond the local match, so every increment needs the correlative search.
std::vector<Increment> increments(const tl::World& world, int beams, double resolution_deg, double start_deg,
                                  bool far = false) {
  tl::Laser laser;
  laser.beams = beams;
  laser.resolution = resolution_deg * tl::kDeg;
  laser.start = start_deg * tl::kDeg;
  laser.max_range = 80.0;
  laser.sigma = 0.02;
  laser.mount_x = 0.22;
  std::mt19937_64 rng(1);
  std::normal_distribution<double> n(0.0, 1.0);
  const std::vector<Eigen::Vector3d> poses = tl::drive(world, 0.6, 60 * tl::kDeg, 0.6);
  std::vector<Increment> out;
  for (std::size_t i = 0; i + 1 < poses.size() && out.size() < 200; ++i) {
    auto points = [&](const Eigen::Vector3d& pose, int k) {
      const tl::SimScan s = tl::simulate(world, laser, pose, k, rng);
      return sm::scan_to_points(s.ranges, s.bearings, laser.no_return - 1e-6);
    };
    const Eigen::Vector3d truth = tl::relative(poses[i], poses[i + 1]);
    const double d = truth.head<2>().norm();
    const Eigen::Vector3d noise((0.05 * d + 0.01) * n(rng), (0.05 * d + 0.01) * n(rng),
                                (0.05 * std::abs(truth[2]) + tl::kDeg * d + 0.5 * tl::kDeg) * n(rng));
    const Eigen::Vector3d offset = far ? Eigen::Vector3d(-0.5, -0.45, -25 * tl::kDeg) : Eigen::Vector3d::Zero();
    out.push_back({points(poses[i], static_cast<int>(i)), points(poses[i + 1], static_cast<int>(i + 1)),
                   truth + noise + offset});
  }
  return out;
}

/// Items per second and the shares of increments matched / found by the correlative search.
void report(benchmark::State& state, int matched, int correlative) {
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()));
  state.counters["matched_pc"] = 100.0 * matched / static_cast<double>(state.iterations());
  state.counters["correlative_pc"] = 100.0 * correlative / static_cast<double>(state.iterations());
}

void run(benchmark::State& state, const std::vector<Increment>& data) {
  const sm::LaserOdometry odometry({0.22, 0.0, 0.0}, sm::MatchOptions{});
  std::size_t k = 0;
  int matched = 0, correlative = 0;
  for (auto _ : state) {
    const Increment& inc = data[k++ % data.size()];
    const sm::OdometryResult r = odometry.match(inc.previous, inc.current, inc.seed);
    matched += r.match.ok ? 1 : 0;
    correlative += r.match.correlative ? 1 : 0;
    benchmark::DoNotOptimize(r.increment);
  }
  report(state, matched, correlative);
}

/// The increments in driving order with carmen_log's local map (scan_match_local_map: 4,
/// scan_match_key_distance: 0.3, scan_match_local_map_weight: 0.3, scan_match_free_space_margin: 0.15).
void run_local_map(benchmark::State& state, const std::vector<Increment>& data) {
  sm::MatchOptions options;
  options.local_map_weight = 0.3;
  options.free_space_margin = 0.15;
  const sm::LaserOdometry odometry({0.22, 0.0, 0.0}, options);
  sm::LocalMapOptions map_options;
  map_options.scans = 4;
  map_options.key_distance = 0.3;
  sm::LocalMap local_map(odometry, map_options);
  std::size_t k = 0;
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();
  int matched = 0, correlative = 0;
  std::int64_t keys = 0;
  for (auto _ : state) {
    const std::size_t i = k++ % data.size();
    const Increment& inc = data[i];
    if (i == 0) {  // back to the start of the drive: a new map
      local_map.clear();
      pose.setZero();
      local_map.add(0, inc.previous, pose);
    }
    const sm::ReferenceScan reference(inc.previous, options);
    const sm::OdometryResult r = odometry.match(reference, inc.current, inc.seed, local_map.placed(i, pose));
    pose = sm::compose(pose, r.increment);
    if (r.match.ok) local_map.add(i + 1, inc.current, pose);
    else local_map.clear();
    keys += static_cast<std::int64_t>(local_map.size());
    matched += r.match.ok ? 1 : 0;
    correlative += r.match.correlative ? 1 : 0;
    benchmark::DoNotOptimize(r.increment);
  }
  report(state, matched, correlative);
  state.counters["keys_mean"] = static_cast<double>(keys) / static_cast<double>(state.iterations());
}

void BM_Match1080Office(benchmark::State& state) {
  static const std::vector<Increment> data = increments(tl::office_floor(), 1080, 0.25, -135.0);
  run(state, data);
}
BENCHMARK(BM_Match1080Office)->Unit(benchmark::kMicrosecond);

void BM_Match1080Hall(benchmark::State& state) {
  static const std::vector<Increment> data = increments(tl::hall(), 1080, 0.25, -135.0);
  run(state, data);
}
BENCHMARK(BM_Match1080Hall)->Unit(benchmark::kMicrosecond);

// The correlative fallback's cost: seeds 0.67 m / 25° off.
void BM_Match1080OfficeFarSeed(benchmark::State& state) {
  static const std::vector<Increment> data = increments(tl::office_floor(), 1080, 0.25, -135.0, true);
  run(state, data);
}
BENCHMARK(BM_Match1080OfficeFarSeed)->Unit(benchmark::kMicrosecond);

/// 1080 beams with the local map, in the office floor or the hall.
void BM_Match1080LocalMap(benchmark::State& state, bool hall) {
  static const std::vector<Increment> office_data = increments(tl::office_floor(), 1080, 0.25, -135.0);
  static const std::vector<Increment> hall_data = increments(tl::hall(), 1080, 0.25, -135.0);
  run_local_map(state, hall ? hall_data : office_data);
}
BENCHMARK_CAPTURE(BM_Match1080LocalMap, Office, false)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Match1080LocalMap, Hall, true)->Unit(benchmark::kMicrosecond);

void BM_Match181Office(benchmark::State& state) {
  static const std::vector<Increment> data = increments(tl::office_floor(), 181, 1.0, -90.0);
  run(state, data);
}
BENCHMARK(BM_Match181Office)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
