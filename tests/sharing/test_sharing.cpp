// Shared coordinates through the kernel (T-RO §VI) with the fixture feature
// type `segment`: two segments meeting at a corner must end up sharing one
// estimator coordinate for it, keep both copies identical through every
// later update, and keep the state as small as the sharing implies.
#include <gtest/gtest.h>

#include <Eigen/LU>

#include "build_path.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "outputs.hpp"
#include "plugin_registry.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

std::string config_text(double join_distance) {
  return R"(
run: {name: sharing}
source: {plugin: segment_world, steps: 40, sigma: 0.01}
motion: {plugin: odometry2d}
estimator: {plugin: ekf}
features:
  seg: {plugin: segment}
sensors:
  cam:
    channel: segments
    mount: [0, 0, 0, 0, 0, 0]
    extractor: {plugin: segment_pass, sigma: 0.01}
    feeds: [seg]
association: {join_distance: )" +
         std::to_string(join_distance) + "}\n";
}

class Sharing : public ::testing::Test {
 protected:
  void SetUp() override {
    registry_.add_search_dir(MSPACE_SHARING_FIXTURE_DIR);
    registry_.add_search_dir(MSPACE_PLUGIN_DIR);
    set_log_level(LogLevel::Warn);
  }
  PluginRegistry registry_;
};

Eigen::Vector2d block(const MapFeature& f, int b) { return f.feature->coords().segment<2>(2 * b); }

TEST_F(Sharing, CornerBecomesOneSharedCoordinate) {
  const RunConfig config = parse_config(config_text(0.2), "sharing.yaml", registry_);
  Slam slam(config, registry_);
  while (slam.step()) {
  }
  ASSERT_EQ(slam.features().size(), 2u);
  ASSERT_EQ(slam.shared_coordinates().size(), 1u);
  const SharedCoordinate& corner = slam.shared_coordinates().front();
  EXPECT_EQ(corner.kind, BlockKind::Point2D);
  ASSERT_EQ(corner.members.size(), 2u);

  // Which feature is which: A has its end (block 1) at the corner, B its start.
  const MapFeature* a = &slam.features()[0];
  const MapFeature* b = &slam.features()[1];
  if (block(*a, 0).x() > block(*b, 0).x()) std::swap(a, b);
  EXPECT_EQ(a->shared.at(1), corner.id);
  EXPECT_EQ(b->shared.at(0), corner.id);

  // Both copies identical after every update since the join; near the truth.
  EXPECT_EQ(block(*a, 1), block(*b, 0));
  EXPECT_LT((block(*a, 1) - Eigen::Vector2d(3.0, 1.0)).norm(), 0.02);
  EXPECT_LT((block(*a, 0) - Eigen::Vector2d(2.0, -1.0)).norm(), 0.02);
  EXPECT_LT((block(*b, 1) - Eigen::Vector2d(5.0, 1.5)).norm(), 0.02);

  // Columns: own block first, then the shared one (the same estimator rows).
  ASSERT_EQ(a->state_idx.size(), 4u);
  ASSERT_EQ(b->state_idx.size(), 4u);
  EXPECT_EQ(std::vector<int>(a->state_idx.begin() + 2, a->state_idx.end()), corner.state_idx);
  EXPECT_EQ(std::vector<int>(b->state_idx.begin() + 2, b->state_idx.end()), corner.state_idx);

  // State: robot (3) + A's own point (2) + B's own point (2) + the corner (2).
  const RunSummary summary = summarize(slam, 0.0);
  EXPECT_EQ(summary.state_dimension, 9);
  const Eigen::MatrixXd C = slam.state_covariance(corner.state_idx);
  EXPECT_GT(C.determinant(), 0.0);
  // Observed by both segments, the corner is better known than either free end.
  EXPECT_LT(C.trace(), slam.state_covariance({a->state_idx[0], a->state_idx[1]}).trace());
}

TEST_F(Sharing, NothingIsSharedWhenJoiningIsOff) {
  const RunConfig config = parse_config(config_text(0.0), "sharing.yaml", registry_);
  Slam slam(config, registry_);
  while (slam.step()) {
  }
  EXPECT_TRUE(slam.shared_coordinates().empty());
  EXPECT_EQ(summarize(slam, 0.0).state_dimension, 3 + 4 + 4);
}

}  // namespace
