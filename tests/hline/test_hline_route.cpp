// Scoring of the `hline` triangulation on a rendered ceiling route: runs
// config/ceiling_fused.yaml, ceiling_lines.yaml and ceiling_both.yaml as
// `mspace run` would and compares the height of every line at M-space
// dimension 3 with the structure under it — a wall/ceiling joint or a panel
// edge of the route's world.yaml, a line of the corridor's tile grid or a
// door header (these two from the renderer's floor plan).
//
// Not a CTest test (three whole runs, about 10 s): build hline_route_score
// and run it. The route is $MSPACE_CEILING, else the one test_ceiling_runs
// uses (<build>/tests/ceiling_runs/ceiling_route, made by
// `ctest -R render_ceiling_route`); without it the tests are skipped.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "build_path.hpp"
#include "ceiling_world.hpp"
#include "config.hpp"
#include "evaluation.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "slam.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;
namespace fs = std::filesystem;
using Vec3 = Eigen::Vector3d;

constexpr double kWrongHeight = 0.10;  ///< m: a line farther than this from its structure's height is wrong
constexpr double kMaxTurn = 15.0 * std::numbers::pi / 180.0;  ///< a structure under a line runs within this of it
constexpr double kOverhang = 0.3;  ///< m: a line's midpoint lies over its structure, give or take this much
constexpr double kStacked = 0.05;  ///< m: structures this much farther in xy than the nearest are as near

fs::path route_folder() {
  if (const char* env = std::getenv("MSPACE_CEILING")) return env;
  return fs::path(MSPACE_BINARY_DIR) / "tests" / "ceiling_runs" / "ceiling_route";
}

/// A horizontal segment of the true world at height a.z() = b.z().
struct TrueLine {
  Vec3 a, b;
};

void add_segments(const YAML::Node& list, std::vector<TrueLine>& out) {
  for (const YAML::Node& s : list)
    out.push_back({Vec3(s[0][0].as<double>(), s[0][1].as<double>(), s[0][2].as<double>()),
                   Vec3(s[1][0].as<double>(), s[1][1].as<double>(), s[1][2].as<double>())});
}

/// The lines of the tile grid of `region` (each dark band has two edges)
/// and, for a door opening, the edges of its header.
void add_floor_plan_lines(const ceiling_render::Region& r, const ceiling_render::Appearance& a,
                          std::vector<TrueLine>& out) {
  const ceiling_render::Box2& b = r.box;
  const double z = r.ceiling_z;
  if (r.door) {
    out.push_back({Vec3(b.x0, b.y0, z), Vec3(b.x1, b.y0, z)});
    out.push_back({Vec3(b.x1, b.y0, z), Vec3(b.x1, b.y1, z)});
    out.push_back({Vec3(b.x1, b.y1, z), Vec3(b.x0, b.y1, z)});
    out.push_back({Vec3(b.x0, b.y1, z), Vec3(b.x0, b.y0, z)});
  }
  if (!r.tile_grid) return;
  for (double edge : {0.0, a.tile_line_width}) {
    for (double x = a.tile_spacing * std::ceil(b.x0 / a.tile_spacing) + edge; x < b.x1; x += a.tile_spacing)
      out.push_back({Vec3(x, b.y0, z), Vec3(x, b.y1, z)});
    for (double y = a.tile_spacing * std::ceil(b.y0 / a.tile_spacing) + edge; y < b.y1; y += a.tile_spacing)
      out.push_back({Vec3(b.x0, y, z), Vec3(b.x1, y, z)});
  }
}

/// Every true ceiling line of the route: world.yaml's joints and panel
/// edges, and the floor plan's tile grid and door headers (the same for
/// every seed).
std::vector<TrueLine> true_lines(const fs::path& route) {
  const YAML::Node world = YAML::LoadFile((route / "world.yaml").string());
  std::vector<TrueLine> out;
  add_segments(world["joints"], out);
  add_segments(world["fixture_edges"], out);
  const ceiling_render::CeilingWorld plan(1);
  for (const ceiling_render::Region& r : plan.regions()) add_floor_plan_lines(r, plan.appearance(), out);
  return out;
}

double distance_to_line(const Eigen::Vector2d& p, const TrueLine& l) {
  const Eigen::Vector2d d = (l.b - l.a).head<2>().normalized(), w = p - l.a.head<2>();
  return std::abs(d.x() * w.y() - d.y() * w.x());
}

double distance_to_segment(const Eigen::Vector2d& p, const TrueLine& l) {
  const Eigen::Vector2d a = l.a.head<2>(), d = (l.b - l.a).head<2>();
  const double s = std::clamp(d.dot(p - a) / d.squaredNorm(), 0.0, 1.0);
  return (p - a - s * d).norm();
}

/// The height error of the line (p1, p2) against the structure under it:
/// among the true lines within kMaxTurn of its direction whose extent (give
/// or take kOverhang) holds its midpoint, those nearest in xy (the mean
/// distance of five of its points to the true line, within kStacked of the
/// nearest: structures stacked at one place, e.g. a joint above a door
/// header), the one closest in height. std::nullopt when there is none.
std::optional<double> height_error(const Vec3& p1, const Vec3& p2, const std::vector<TrueLine>& truth) {
  const Eigen::Vector2d dir = (p2 - p1).head<2>().normalized(), mid = 0.5 * (p1 + p2).head<2>();
  std::vector<std::pair<double, double>> candidates;  // (xy distance, height error)
  for (const TrueLine& l : truth) {
    const Eigen::Vector2d d = (l.b - l.a).head<2>().normalized();
    if (std::abs(dir.x() * d.y() - dir.y() * d.x()) > std::sin(kMaxTurn)) continue;
    if (distance_to_segment(mid, l) > distance_to_line(mid, l) + kOverhang) continue;
    double sum = 0.0;
    for (double s : {0.0, 0.25, 0.5, 0.75, 1.0}) sum += distance_to_line((p1 + s * (p2 - p1)).head<2>(), l);
    candidates.emplace_back(sum / 5.0, p1.z() - l.a.z());
  }
  if (candidates.empty()) return std::nullopt;
  double nearest = std::numeric_limits<double>::infinity();
  for (const auto& [xy, dz] : candidates) nearest = std::min(nearest, xy);
  std::optional<double> best;
  for (const auto& [xy, dz] : candidates)
    if (xy <= nearest + kStacked && (!best || std::abs(dz) < std::abs(*best))) best = dz;
  return best;
}

/// What one run gives.
struct Score {
  int dim3 = 0;         ///< lines at M-space dimension 3
  int wrong = 0;        ///< of those, farther than kWrongHeight from their structure's height (or over none)
  int lower_dims = 0;   ///< lines at dimensions 0 and 1
  double final_translation = 0.0;  ///< m
  double final_heading = 0.0;      ///< rad
  double mean_nees = 0.0;          ///< robot, over the poses with ground truth
};

class HLineRoute : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(route_folder() / "world.yaml"))
      GTEST_SKIP() << "no rendered route at " << route_folder()
                   << " (set MSPACE_CEILING or run `ctest -R render_ceiling_route`)";
  }

  /// Runs config/ceiling_<name>.yaml on the route (once per program) and scores it.
  static const Score& run(const std::string& name) {
    const auto found = scores_.find(name);
    if (found != scores_.end()) return found->second;
    set_log_level(LogLevel::Warn);
    setenv("MSPACE_CEILING", route_folder().c_str(), 1);
    PluginRegistry registry;
    registry.add_search_dir(MSPACE_PLUGIN_DIR);
    const fs::path file = fs::path(MSPACE_SOURCE_DIR) / "config" / ("ceiling_" + name + ".yaml");
    const RunConfig config = load_config(file, registry);
    Slam slam(config, registry);
    while (slam.step()) {
    }
    Score s;
    const std::vector<TrueLine> truth = true_lines(route_folder());
    for (const MapFeature& f : slam.features()) {
      if (slam.feature_types()[static_cast<std::size_t>(f.type)].plugin != "hline") continue;
      if (f.feature->mspace_dim() != 3) {
        ++s.lower_dims;
        continue;
      }
      ++s.dim3;
      const Eigen::VectorXd& x = f.feature->coords();
      const std::optional<double> dz = height_error(x.head<3>(), x.tail<3>(), truth);
      if (!dz || !(std::abs(*dz) <= kWrongHeight)) ++s.wrong;
    }
    const TrajectoryErrors errors = evaluate_trajectory(slam.evaluated_trajectory(), slam.ground_truth(), 0.5);
    s.final_translation = errors.final_translation;
    s.final_heading = errors.final_heading.value_or(0.0);
    const std::vector<double>& nees = slam.stats().nees;
    for (double v : nees) s.mean_nees += v / static_cast<double>(std::max<std::size_t>(nees.size(), 1));
    std::cout << std::fixed << std::setprecision(3) << "| " << name << " | " << s.dim3 << " at dim 3 (" << s.lower_dims
              << " below) | " << s.wrong << " more than " << kWrongHeight << " m off | final " << s.final_translation
              << " m / " << std::setprecision(2) << s.final_heading * 180.0 / std::numbers::pi << "° | mean NEES "
              << s.mean_nees << " |\n";
    return scores_.emplace(name, s).first->second;
  }

  static std::map<std::string, Score> scores_;
};

std::map<std::string, Score> HLineRoute::scores_;

// The scoring itself on known lines along x: under the corridor's joint at
// its height and 0.3 m too low, under door A's header (stacked below the
// joint) at the header's height, under a tile line 0.1 m too low, and over
// no structure at all.
TEST_F(HLineRoute, ScoresKnownLines) {
  const std::vector<TrueLine> truth = true_lines(route_folder());
  const auto error = [&](double x1, double x2, double y, double z) {
    return height_error(Vec3(x1, y, z), Vec3(x2, y, z), truth);
  };
  ASSERT_TRUE(error(-3.0, 3.0, 1.0, 2.6));
  EXPECT_NEAR(*error(-3.0, 3.0, 1.0, 2.6), 0.0, 1e-12);
  EXPECT_NEAR(*error(-3.0, 3.0, 1.01, 2.3), -0.3, 1e-12);
  EXPECT_NEAR(*error(-5.5, -4.5, 1.0, 2.06), 0.01, 1e-12);
  EXPECT_NEAR(*error(-1.0, 1.0, 0.6, 2.5), -0.1, 1e-12);
  EXPECT_FALSE(error(20.0, 21.0, 0.0, 2.6));
}

// Fewer than 3 of the triangulated lines of each run more than 10 cm off the
// height of the structure under them (before the robust extension: 10–16 of
// about 72), with at least 45 lines triangulated.
TEST_F(HLineRoute, FewLinesAtAWrongHeight) {
  for (const std::string name : {"fused", "lines", "both"}) {
    const Score& s = run(name);
    EXPECT_LT(s.wrong, 3) << name;
    EXPECT_GE(s.dim3, 45) << name;
  }
}

}  // namespace
