// Association of one reading against maps of 100, 1 000 and 10 000 point
// features at the same density (one per 25 m², a square of side 5·√N m), the
// sensor (range 10 m, measurements out to 8 m as in config/sim_points.yaml)
// at the centre: with the spatial index the cost per reading depends on the
// features near the sensor, not on the size of the map; the full scan grows
// with it. The features are the `point` plugin's, extended to M-space
// dimension 3 as the kernel does it; e.g.
//   ./build/bin/bench_association --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "association.hpp"
#include "build_path.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "mspace/transform.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

constexpr double kSensorRange = 10.0;   // sensors.<name>.max_range
constexpr double kVisibleRange = 8.0;    // what the sensor measures
constexpr double kTile = 10.0;            // m, four features per tile: one per 25 m²

/// The covariance of robot and features as independent blocks: all that
/// association asks of an estimator is marginal(). The benchmark never
/// updates, so the other operations refuse.
class BlockCovariance final : public Estimator {
 public:
  void reset(const Eigen::MatrixXd& P_rr) override {
    blocks_ = {P_rr};
    first_ = {0};
    dim_ = static_cast<int>(P_rr.rows());
  }
  int dim() const override { return dim_; }
  void predict(const Eigen::MatrixXd&, const Eigen::MatrixXd&) override { refuse("predict"); }
  Eigen::VectorXd update(const std::vector<LinearizedObservation>&) override { refuse("update"); }
  int augment(const StateAugmentation& aug) override {
    blocks_.push_back(aug.C_new);  // the benchmark's features are independent of each other and the robot
    first_.push_back(dim_);
    dim_ += static_cast<int>(aug.C_new.rows());
    return first_.back();
  }
  Eigen::MatrixXd marginal(const std::vector<int>& idx) const override {
    const auto n = static_cast<Eigen::Index>(idx.size());
    Eigen::MatrixXd m = Eigen::MatrixXd::Zero(n, n);
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j < n; ++j) {
        const auto [bi, oi] = locate(idx[static_cast<std::size_t>(i)]);
        const auto [bj, oj] = locate(idx[static_cast<std::size_t>(j)]);
        if (bi == bj) m(i, j) = blocks_[bi](oi, oj);
      }
    return m;
  }
  Eigen::MatrixXd cross(const std::vector<int>&, const std::vector<int>&) const override { refuse("cross"); }
  void remove(std::vector<int>) override { refuse("remove"); }

 private:
  [[noreturn]] static void refuse(const char* what) {
    throw std::logic_error(std::string("bench_association: the benchmark map does not ") + what);
  }
  std::pair<std::size_t, Eigen::Index> locate(int row) const {
    const auto it = std::upper_bound(first_.begin(), first_.end(), row);
    const auto b = static_cast<std::size_t>(it - first_.begin() - 1);
    return {b, row - first_[b]};
  }
  std::vector<Eigen::MatrixXd> blocks_;
  std::vector<int> first_;
  int dim_ = 0;
};

/// A map of n point features and one reading of the sensor at its centre.
struct Scene {
  PluginRegistry registry;
  std::shared_ptr<Logger> log = make_instance_logger("bench");
  std::vector<FeatureTypeSlot> types;
  std::vector<MapFeature> features;
  BlockCovariance estimator;
  SensorSlot sensor;
  std::vector<int> robot_idx = {0, 1, 2};
  Pose6 x_ms = Pose6::Zero();
  Eigen::MatrixXd J_sr = Eigen::MatrixXd::Zero(6, 3);
  std::vector<Measurement> reading;

  explicit Scene(int n) {
    set_log_level(LogLevel::Warn);
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    FeatureTypeSlot slot;
    slot.instance = "point";
    slot.plugin = "point";
    slot.library = registry.load("point");
    PluginArgs args{"point", Params::defaults(slot.library->descriptor->params), log.get()};
    slot.type = registry.create<FeatureType>("point", PluginKind::Feature, args);
    types.push_back(slot);
    Measurement ahead;
    ahead.kind = "range_bearing_elevation";
    ahead.v = Eigen::Vector3d(5.0, 0.0, 0.1);
    ahead.C_v = Eigen::Matrix3d::Identity() * 1e-4;
    probe = slot.type->create(ahead, SensorView{});
    if (!probe) throw std::runtime_error("point did not create a feature");
    sensor.config.name = "sensor";
    sensor.config.max_range = kSensorRange;
    sensor.feeds = {0};

    Eigen::Matrix3d P_rr = Eigen::Vector3d(0.05 * 0.05, 0.05 * 0.05, 0.01 * 0.01).asDiagonal();
    estimator.reset(P_rr);
    J_sr(kX, 0) = J_sr(kY, 1) = J_sr(kTheta, 2) = 1.0;  // sensor at the robot (x, y, θ estimated)

    // Tiles of 10 m × 10 m with four features each, placed by a generator
    // seeded with the tile's coordinates: every map has the same features
    // near the centre, whatever its size.
    const int tiles = static_cast<int>(std::lround(std::sqrt(n / 4.0)));
    std::vector<Eigen::Vector3d> points;
    for (int ix = -tiles / 2; ix < tiles - tiles / 2; ++ix)
      for (int iy = -tiles / 2; iy < tiles - tiles / 2; ++iy) {
        std::mt19937 tile_rng(static_cast<unsigned>((ix + 1000) * 4093 + (iy + 1000)));
        std::uniform_real_distribution<double> u(0.0, 1.0);
        for (int k = 0; k < 4; ++k) points.emplace_back(kTile * (ix + u(tile_rng)), kTile * (iy + u(tile_rng)),
                                                         0.5 + u(tile_rng));
      }
    std::mt19937 rng(1);
    std::normal_distribution<double> noise(0.0, 1.0);
    const Eigen::Vector3d sigma(0.05, 0.5 * std::numbers::pi / 180.0, 1.0 * std::numbers::pi / 180.0);
    for (std::size_t i = 0; i < points.size(); ++i) {
      // The sensor, placed 5 m from the feature, sees it and the feature
      // extends after three observations (point's min_observations).
      const Eigen::Vector3d& p = points[i];
      SensorView view;
      view.x_ms = Pose6::Zero();
      view.x_ms[kX] = p.x() - 5.0;
      view.x_ms[kY] = p.y();
      view.C_ms = Mat6::Identity() * 1e-4;
      Measurement m = measure(p, view.x_ms);
      m.C_v = sigma.cwiseAbs2().asDiagonal();
      std::unique_ptr<Feature> created = slot.type->create(m, view);
      if (!created) throw std::runtime_error("point did not create a feature");
      MapFeature mf;
      mf.id = static_cast<int>(i) + 1;
      auto library = slot.library;
      mf.feature = std::shared_ptr<Feature>(created.release(), [library](Feature* f) { delete f; });
      for (int k = 0; k < 3; ++k) mf.feature->add_dense_information(m, view);
      const std::optional<Extension> ext = mf.feature->extend(view);
      if (!ext) throw std::runtime_error("point did not extend");
      StateAugmentation aug;
      aug.C_new = ext->C_new;
      const int first = estimator.augment(aug);
      for (int k = 0; k < ext->new_dims; ++k) mf.own_idx.push_back(first + k);
      mf.state_idx = mf.own_idx;
      features.push_back(std::move(mf));
    }

    // One reading at the centre: every feature within the visible range, with noise.
    for (const MapFeature& mf : features) {
      const Eigen::Vector3d p = mf.feature->coords();
      if (std::hypot(p.x(), p.y()) > kVisibleRange) continue;
      Measurement m = measure(p, x_ms);
      m.C_v = sigma.cwiseAbs2().asDiagonal();
      for (int k = 0; k < 3; ++k) m.v[k] += sigma[k] * noise(rng);
      reading.push_back(m);
    }
  }

  /// The range/bearing/elevation of p from a sensor at x_ms, as the point
  /// plugin predicts it: the innovation of any point against a zero
  /// measurement is h(x_o) (it depends on x_o only).
  Measurement measure(const Eigen::Vector3d& p, const Pose6& at) const {
    Measurement zero;
    zero.kind = "range_bearing_elevation";
    zero.v = Eigen::Vector3d::Zero();
    zero.C_v = Eigen::Matrix3d::Identity();
    Innovation in;
    if (!probe->innovation(to_sensor_frame(probe->layout(), p, at), zero, in))
      throw std::runtime_error("point gave no innovation");
    Measurement m = zero;
    m.v = in.eta;
    return m;
  }

  std::unique_ptr<Feature> probe;
};

void associate_reading(benchmark::State& state, bool indexed) {
  const int n = static_cast<int>(state.range(0));
  Scene scene(n);
  AssociationConfig config;
  config.spatial_index = indexed;
  Associator associator(config, {scene.sensor.config}, scene.log);
  associator.sync(scene.features);
  const AssociationView map{scene.features, scene.types,
                            [&](const std::vector<int>& rows) { return scene.estimator.marginal(rows); }, scene.robot_idx, 0,
                            {}};
  std::size_t matched = 0;
  for (auto _ : state) {
    const AssociationResult r = associator.associate(map, scene.sensor, scene.x_ms, scene.J_sr, scene.reading);
    matched = r.matches.size();
    benchmark::DoNotOptimize(matched);
  }
  state.counters["features"] = static_cast<double>(scene.features.size());
  state.counters["measurements"] = static_cast<double>(scene.reading.size());
  state.counters["matched"] = static_cast<double>(matched);
}

void BM_AssociateIndexed(benchmark::State& state) { associate_reading(state, true); }
void BM_AssociateFullScan(benchmark::State& state) { associate_reading(state, false); }

// Keeping the index in step after an update moved every feature (a few cm):
// linear in the map, like the update that moved them.
void BM_SyncAfterUpdate(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  Scene scene(n);
  AssociationConfig config;
  Associator associator(config, {scene.sensor.config}, scene.log);
  associator.sync(scene.features);
  Eigen::VectorXd dx = Eigen::Vector3d(0.01, -0.01, 0.0);
  for (auto _ : state) {
    state.PauseTiming();
    dx = -dx;
    for (MapFeature& mf : scene.features) mf.feature->apply_perturbation(dx);
    state.ResumeTiming();
    associator.sync(scene.features);
  }
  state.counters["features"] = static_cast<double>(scene.features.size());
}

}  // namespace

BENCHMARK(BM_AssociateIndexed)->Arg(100)->Arg(1000)->Arg(10000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_AssociateFullScan)->Arg(100)->Arg(1000)->Arg(10000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_SyncAfterUpdate)->Arg(100)->Arg(1000)->Arg(10000)->Unit(benchmark::kMicrosecond);
BENCHMARK_MAIN();
