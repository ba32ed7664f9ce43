// Features have a logger (mspace/feature_log.hpp): feature_log(feature)
// writes through the logger of the feature's type instance with "#<id>: " in
// front once the kernel has adopted the feature (FeatureTypeSlot::adopt: after
// create() in a run, after restore() when a map is loaded), and drops
// everything before that. The run
// path is also checked end to end by the CTest `cli_feature_logs_with_its_id`.
#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "build_path.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "mspace/feature_log.hpp"
#include "mspace/source.hpp"
#include "persistence.hpp"
#include "plugin_registry.hpp"
#include "point_feature.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

/// Keeps every message at or above `threshold`.
class CapturingLogger final : public Logger {
 public:
  explicit CapturingLogger(LogLevel threshold) : threshold_(threshold) {}
  void write(LogLevel level, std::string_view message) override {
    lines.push_back({level, std::string(message)});
  }
  bool enabled(LogLevel level) const override { return level >= threshold_; }

  struct Line {
    LogLevel level;
    std::string text;
  };
  std::vector<Line> lines;

 private:
  LogLevel threshold_;
};

bool starts_with(const std::string& text, const std::string& prefix) { return text.rfind(prefix, 0) == 0; }

// A point fed its own measurement until it enters the map says so, with the
// id the kernel gave it, at debug level and only there.
TEST(FeatureLogger, AdoptedFeatureLogsThroughItsTypeWithItsId) {
  const point::PointType type(PluginArgs{"points", Params::defaults(point::PointType::param_specs()), nullptr});
  for (const LogLevel threshold : {LogLevel::Debug, LogLevel::Info}) {
    auto capture = std::make_shared<CapturingLogger>(threshold);
    FeatureTypeSlot slot;
    slot.instance = "points";
    slot.plugin = "point";
    slot.log = capture;
    std::optional<FeatureSample> s = type.sample(0, 6);  // seed % 3 == 0: range, bearing, elevation
    ASSERT_TRUE(s && s->feature);
    feature_log(*s->feature).error("before adoption");  // dropped: no logger yet
    std::shared_ptr<Feature> f = slot.adopt(std::move(s->feature), 42);
    SensorView view;
    view.x_ms = s->x_ms;
    int fed = 0;
    while (f->mspace_dim() == 0 && fed < 50) {
      view.t = 0.1 * ++fed;
      f->add_dense_information(s->measurement, view);
      f->extend(view);
    }
    ASSERT_GT(f->mspace_dim(), 0) << "the sample never entered the map in " << fed << " observations";
    if (threshold == LogLevel::Info) {
      EXPECT_TRUE(capture->lines.empty()) << capture->lines.front().text;  // debug messages are filtered
      continue;
    }
    ASSERT_EQ(capture->lines.size(), 1u);
    EXPECT_EQ(capture->lines[0].level, LogLevel::Debug);
    EXPECT_TRUE(starts_with(capture->lines[0].text, "#42: placed from the newest of ")) << capture->lines[0].text;
  }
}

// Features restored from a map file log with their ids from the file, through
// the logger of the run's type instance.
TEST(FeatureLogger, RestoredFeaturesLogWithTheirIds) {
  set_log_level(LogLevel::Warn);
  PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  RunConfig config = load_config(std::filesystem::path(MSPACE_SOURCE_DIR) / "config" / "sim_points.yaml", registry);
  config.max_steps = 300;
  Slam slam(config, registry);
  while (slam.step()) {
  }
  ASSERT_GT(slam.features().size(), 5u);
  const std::filesystem::path dir =
      std::filesystem::path(MSPACE_BINARY_DIR) / "test-output" / "feature_logger";
  std::filesystem::create_directories(dir);
  const std::filesystem::path file = dir / "map.bin";
  write_map_bin(file, slam);

  auto capture = std::make_shared<CapturingLogger>(LogLevel::Trace);
  std::vector<FeatureTypeSlot> slots = slam.feature_types();
  for (FeatureTypeSlot& s : slots) s.log = capture;
  const std::vector<RestoredFeature> restored = restore_features(read_map_file(file), file, slots);
  ASSERT_EQ(restored.size(), slam.features().size());
  for (const RestoredFeature& r : restored) feature_log(*r.feature).warn("restored");
  ASSERT_EQ(capture->lines.size(), restored.size());
  for (std::size_t i = 0; i < restored.size(); ++i) {
    EXPECT_EQ(capture->lines[i].level, LogLevel::Warn);
    EXPECT_EQ(capture->lines[i].text, "#" + std::to_string(slam.features()[i].id) + ": restored");
  }
}

}  // namespace
