// The whole Victoria Park run (config/victoria_park.yaml) against GPS: the
// absolute trajectory error after SE(2) alignment, only at GPS fixes, must
// meet the targets of issue 4 (RMSE ≤ 3 m, median ≤ 1.5 m).
//
// GPS measures the antenna, which sits at the laser; the filter estimates the
// rear-axle centre. So the estimate is interpolated at each fix time and
// carried to the antenna through the laser mount (x_r ⊕ x_rs) before the
// comparison. Fixes where the estimate's bracketing poses are more than 2 s
// apart are skipped (there are none: the estimate has a pose every 25 ms).
//
// The GPS unit was failing: besides 67 gaps longer than 2 s it has isolated
// fixes between gaps, one of them 141 m off (t = 1223.28 s, 2.2 s after the
// previous fix and 4.4 s before the next). The source leaves out fixes with no
// other fix within 2 s (its gps_isolated_gap, "skipping gaps": 6 of 4466), so
// the run summary and this test score the same 4460 fixes.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <vector>

#include "build_path.hpp"
#include "config.hpp"
#include "evaluation.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "runner.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

constexpr double kMaxGap = 2.0;       ///< s, see the file comment
constexpr double kTargetRmse = 3.0;   ///< m, issue 4
constexpr double kTargetMedian = 1.5; ///< m, issue 4

/// ../shared/datasets/victoria_park next to the source tree, or
/// $MSPACE_DATA/victoria_park.
std::filesystem::path data_dir() {
  const char* env = std::getenv("MSPACE_DATA");
  const std::filesystem::path base = env != nullptr && *env != '\0'
                                         ? std::filesystem::path(env)
                                         : std::filesystem::path(MSPACE_SOURCE_DIR).parent_path() / "shared" / "datasets";
  return base / "victoria_park";
}

struct AteResult {
  std::size_t pairs = 0;
  double rmse = 0.0, median = 0.0, max = 0.0;
};

/// ATE of the point `mount` of the robot against position-only reference
/// fixes, after SE(2) alignment.
AteResult ate_at_point(const std::vector<StampedPose>& estimate, const std::vector<StampedPose>& fixes,
                       const Pose6& mount) {
  std::vector<Eigen::Vector2d> est, ref;
  for (const StampedPose& fix : fixes) {
    const std::optional<Pose6> x_r = interpolate(estimate, fix.t, kMaxGap);
    if (!x_r) continue;
    const Pose6 antenna = compound(*x_r, mount);
    est.emplace_back(antenna[kX], antenna[kY]);
    ref.emplace_back(fix.pose[kX], fix.pose[kY]);
  }
  AteResult r;
  r.pairs = est.size();
  if (est.empty()) return r;
  const Se2Alignment a = align_se2(est, ref);
  std::vector<double> err;
  for (std::size_t i = 0; i < est.size(); ++i) err.push_back((a.apply(est[i]) - ref[i]).norm());
  double sum2 = 0.0;
  for (double e : err) sum2 += e * e;
  r.rmse = std::sqrt(sum2 / static_cast<double>(err.size()));
  r.max = *std::max_element(err.begin(), err.end());
  std::nth_element(err.begin(), err.begin() + static_cast<std::ptrdiff_t>(err.size() / 2), err.end());
  r.median = err[err.size() / 2];
  return r;
}

/// config/victoria_park.yaml on the data set; skips when the data is absent.
class VictoriaParkRun : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::filesystem::path data = data_dir();
    if (!std::filesystem::is_directory(data)) {
      GTEST_SKIP() << "Victoria Park data set not found at " << data
                   << " (set MSPACE_DATA to the folder holding victoria_park/)";
    }
    set_log_level(LogLevel::Warn);
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    config = load_config(std::filesystem::path(MSPACE_SOURCE_DIR) / "config" / "victoria_park.yaml", registry);
    config.source.params.set("data_dir", data.string());
    ASSERT_EQ(config.sensors.size(), 1u);
  }
  PluginRegistry registry;
  RunConfig config;
};

TEST_F(VictoriaParkRun, TrajectoryMatchesGpsWithinTargets) {
  const Pose6 laser_mount = config.sensors[0].mount;

  const auto start = std::chrono::steady_clock::now();
  Slam slam(config, registry);
  RunOptions options;
  options.progress = false;
  options.write_outputs = false;
  run_to_end(slam, options);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  int poles = 0;
  for (const MapFeature& f : slam.features()) poles += f.feature->mspace_dim() == 3 ? 1 : 0;
  const std::vector<StampedPose>& fixes = slam.ground_truth();
  const AteResult antenna = ate_at_point(slam.trajectory(), fixes, laser_mount);
  const AteResult axle = ate_at_point(slam.trajectory(), fixes, Pose6::Zero());
  std::cout << "victoria_park: " << fixes.size() << " GPS fixes, " << antenna.pairs << " paired\n"
            << "  ATE at the GPS antenna: RMSE " << antenna.rmse << " m, median " << antenna.median << " m, max "
            << antenna.max << " m\n"
            << "  (rear-axle centre instead of the antenna: RMSE " << axle.rmse << " m, median " << axle.median
            << " m)\n"
            << "  poles in the map: " << poles << ", steps " << slam.stats().steps << ", wall time " << wall
            << " s\n";

  EXPECT_EQ(fixes.size(), 4466u - 6u);
  EXPECT_EQ(antenna.pairs, fixes.size());
  EXPECT_LE(antenna.rmse, kTargetRmse);
  EXPECT_LE(antenna.median, kTargetMedian);
}

// The same file under the smoother with noise estimation (variance
// components, plugins/smoother/variance_components.hpp): `mspace run
// config/victoria_park.yaml --set estimator.plugin=smoother --set
// estimator.noise_estimation=variance_components`. Issue 10's targets, RMSE ≤
// 2.0 m and median ≤ 1.0 m (measured 1.483 m and 0.907 m on 2026-11-25; the
// noise settings are the config's, rescaled by the smoother from its own
// residuals, none chosen against the GPS). The margin on the median is small
// (0.09 m) and the result is not robust: README "Victoria Park" lists the
// settings (±50 % of one σ, another iteration schedule) that land on the other
// self-consistent noise level and give 2.1–2.3 m / 1.2–1.3 m.
TEST_F(VictoriaParkRun, SmootherWithNoiseEstimationMeetsIssue10Targets) {
  override_estimator(config, "smoother", registry);
  config.estimator.params.set("noise_estimation", std::string("variance_components"));
  const Pose6 laser_mount = config.sensors[0].mount;
  Slam slam(config, registry);
  RunOptions options;
  options.progress = false;
  options.write_outputs = false;
  run_to_end(slam, options);
  const AteResult antenna = ate_at_point(slam.trajectory(), slam.ground_truth(), laser_mount);
  std::cout << "victoria_park, smoother + noise estimation: ATE RMSE " << antenna.rmse << " m, median "
            << antenna.median << " m, max " << antenna.max << " m\n";
  EXPECT_LE(antenna.rmse, 2.0);
  EXPECT_LE(antenna.median, 1.0);
}

}  // namespace
