#include "occupancy_grid.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <string>

#include "config.hpp"
#include "logging.hpp"
#include "mspace/source.hpp"
#include "outputs.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

// Inverse sensor model in log-odds, log(p / (1 − p)) (Table 9.1 of
// Probabilistic Robotics): a hit says 0.7, a miss 0.45, the prior 0.5 is 0.
// A miss weighs a quarter of a hit: rays that graze a surface at a few degrees
// cross its face cells and would otherwise erase it.
const float kLogOddsHit = static_cast<float>(std::log(0.7 / 0.3));
const float kLogOddsMiss = static_cast<float>(std::log(0.45 / 0.55));
// Clamping keeps a cell able to change its mind (a person who walked past, a
// door that opened): ~18 misses undo the most certain "occupied". A cell
// needs 8 misses to read as free (p < 0.196) and one hit as occupied.
constexpr float kLogOddsMin = -2.0f, kLogOddsMax = 3.5f;

/// Visits the cells of the digital line from a to b (Bresenham), b last.
template <typename Visit>
void bresenham(Eigen::Vector2i a, const Eigen::Vector2i& b, Visit&& visit) {
  const int dx = std::abs(b.x() - a.x()), dy = -std::abs(b.y() - a.y());
  const int sx = a.x() < b.x() ? 1 : -1, sy = a.y() < b.y() ? 1 : -1;
  int err = dx + dy;
  while (true) {
    visit(a.x(), a.y());
    if (a == b) return;
    const int e2 = 2 * err;
    if (e2 >= dy) err += dy, a.x() += sx;
    if (e2 <= dx) err += dx, a.y() += sy;
  }
}

/// The sensor's planar pose (x, y, heading) at a scan.
Eigen::Vector3d sensor_pose(const RangeScan& scan, const std::vector<StampedPose>& trajectory,
                            const std::vector<Pose6>& mounts) {
  // x_ms = x_mr ⊕ x_rs (eq. 17)
  const Pose6 x_ms = compound(trajectory[scan.pose_index].pose, mounts[static_cast<std::size_t>(scan.sensor)]);
  return {x_ms[kX], x_ms[kY], x_ms[kTheta]};
}

}  // namespace

bool is_range_scan(const Eigen::MatrixXd& values) {
  if (values.cols() != 2 || values.rows() < kMinScanBeams) return false;
  const Eigen::Index n = values.rows();
  const double mean_step = (values(n - 1, 1) - values(0, 1)) / static_cast<double>(n - 1);
  if (!(mean_step > 0.0)) return false;
  for (Eigen::Index i = 1; i < n; ++i)
    if (std::abs(values(i, 1) - values(i - 1, 1) - mean_step) > 0.01 * mean_step) return false;
  return true;
}

ScanCollector::ScanCollector(const RunConfig& config) : config_(config) {}

void ScanCollector::add(const DataStep& data, std::size_t pose_index) {
  for (const SensorReading& reading : data.readings) {
    const auto sensor = std::find_if(config_.sensors.begin(), config_.sensors.end(),
                                     [&](const SensorConfig& s) { return s.channel == reading.channel; });
    if (sensor == config_.sensors.end() || !is_range_scan(reading.values)) continue;
    RangeScan scan;
    scan.pose_index = pose_index;
    scan.sensor = static_cast<int>(sensor - config_.sensors.begin());
    scan.ranges.reserve(static_cast<std::size_t>(reading.values.rows()));
    scan.bearings.reserve(static_cast<std::size_t>(reading.values.rows()));
    for (Eigen::Index i = 0; i < reading.values.rows(); ++i) {
      scan.ranges.push_back(static_cast<float>(reading.values(i, 0)));
      scan.bearings.push_back(static_cast<float>(reading.values(i, 1)));
    }
    scans_.push_back(std::move(scan));
  }
}

OccupancyGrid::Cell OccupancyGrid::cell(int i, int j) const {
  const double p = 1.0 / (1.0 + std::exp(-static_cast<double>(at(i, j))));
  if (p > kOccupiedThreshold) return Cell::Occupied;
  if (p < kFreeThreshold) return Cell::Free;
  return Cell::Unknown;
}

Eigen::Vector2i OccupancyGrid::cell_of(const Eigen::Vector2d& p) const {
  return {static_cast<int>(std::floor((p.x() - origin.x()) / resolution)),
          static_cast<int>(std::floor((p.y() - origin.y()) / resolution))};
}

OccupancyGrid build_occupancy_grid(const std::vector<RangeScan>& scans, const std::vector<StampedPose>& trajectory,
                                   const std::vector<Pose6>& mounts, const GridConfig& options) {
  OccupancyGrid grid;
  grid.resolution = options.resolution;
  const double max_range = options.max_range;
  auto usable = [&](float r) { return std::isfinite(r) && r > 0.0f; };

  // Bounds: every sensor position and beam end point (cut at max_range).
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector2d hi = -lo;
  for (const RangeScan& scan : scans) {
    const Eigen::Vector3d s = sensor_pose(scan, trajectory, mounts);
    lo = lo.cwiseMin(s.head<2>()), hi = hi.cwiseMax(s.head<2>());
    for (std::size_t k = 0; k < scan.ranges.size(); ++k) {
      if (!usable(scan.ranges[k])) continue;
      const double r = std::min<double>(scan.ranges[k], max_range), a = s.z() + scan.bearings[k];
      const Eigen::Vector2d end(s.x() + r * std::cos(a), s.y() + r * std::sin(a));
      lo = lo.cwiseMin(end), hi = hi.cwiseMax(end);
    }
  }
  if (scans.empty()) return grid;
  grid.origin = lo - Eigen::Vector2d::Constant(grid.resolution);
  const Eigen::Vector2d cells = (hi - grid.origin) / grid.resolution;
  const double total = (std::floor(cells.x()) + 2.0) * (std::floor(cells.y()) + 2.0);
  if (total > static_cast<double>(kMaxGridCells))
    throw std::runtime_error("output.grid.resolution: " + std::to_string(grid.resolution) + " m over " +
                             std::to_string(hi.x() - lo.x()) + " × " + std::to_string(hi.y() - lo.y()) +
                             " m would need " + std::to_string(static_cast<long long>(total)) +
                             " cells (at most " + std::to_string(kMaxGridCells) +
                             "); use a coarser resolution or a smaller output.grid.max_range");
  grid.width = static_cast<int>(std::floor(cells.x())) + 2;
  grid.height = static_cast<int>(std::floor(cells.y())) + 2;
  grid.log_odds.assign(static_cast<std::size_t>(grid.width) * static_cast<std::size_t>(grid.height), 0.0f);

  auto update = [&](int i, int j, float delta) {
    if (!grid.contains(i, j)) return;
    float& l = grid.log_odds[grid.index(i, j)];
    l = std::clamp(l + delta, kLogOddsMin, kLogOddsMax);
  };
  for (const RangeScan& scan : scans) {
    const Eigen::Vector3d s = sensor_pose(scan, trajectory, mounts);
    const Eigen::Vector2i from = grid.cell_of(s.head<2>());
    for (std::size_t k = 0; k < scan.ranges.size(); ++k) {
      if (!usable(scan.ranges[k])) continue;
      const bool hit = scan.ranges[k] <= max_range;
      const double r = hit ? static_cast<double>(scan.ranges[k]) : max_range, a = s.z() + scan.bearings[k];
      const Eigen::Vector2i to = grid.cell_of({s.x() + r * std::cos(a), s.y() + r * std::sin(a)});
      // Every cell on the way is missed; the end cell is hit (or, for a beam
      // that went beyond max_range, missed as well).
      bresenham(from, to, [&](int i, int j) {
        if (i == to.x() && j == to.y()) update(i, j, hit ? kLogOddsHit : kLogOddsMiss);
        else update(i, j, kLogOddsMiss);
      });
    }
  }
  return grid;
}

void write_grid_files(const std::filesystem::path& dir, const OccupancyGrid& grid) {
  namespace fs = std::filesystem;
  write_atomically(dir / "grid.pgm", [&](const fs::path& file) {
    std::ofstream out(file, std::ios::binary);
    if (!out) throw std::runtime_error("cannot write '" + file.string() + "'");
    out << "P5\n# mspace occupancy grid, " << grid.resolution << " m/cell; see grid.yaml\n"
        << grid.width << ' ' << grid.height << "\n255\n";
    std::vector<unsigned char> row(static_cast<std::size_t>(grid.width));
    for (int j = grid.height - 1; j >= 0; --j) {  // the image's top row is the largest y
      for (int i = 0; i < grid.width; ++i) {
        const OccupancyGrid::Cell c = grid.cell(i, j);
        row[static_cast<std::size_t>(i)] =
            c == OccupancyGrid::Cell::Occupied ? 0 : c == OccupancyGrid::Cell::Free ? 254 : 205;
      }
      out.write(reinterpret_cast<const char*>(row.data()), static_cast<std::streamsize>(row.size()));
    }
    if (!out.flush()) throw std::runtime_error("cannot write '" + file.string() + "'");
  });
  write_atomically(dir / "grid.yaml", [&](const fs::path& file) {
    std::ofstream out(file);
    if (!out) throw std::runtime_error("cannot write '" + file.string() + "'");
    out.precision(10);
    out << "# mspace occupancy grid in ROS map_server format (map frame of the run; origin = lower-left cell)\n"
        << "image: grid.pgm\n"
        << "resolution: " << grid.resolution << "\n"
        << "origin: [" << grid.origin.x() << ", " << grid.origin.y() << ", 0.0]\n"
        << "negate: 0\n"
        << "occupied_thresh: " << OccupancyGrid::kOccupiedThreshold << "\n"
        << "free_thresh: " << OccupancyGrid::kFreeThreshold << "\n"
        << "mode: trinary\n";
    if (!out.flush()) throw std::runtime_error("cannot write '" + file.string() + "'");
  });
}

std::vector<std::filesystem::path> write_grid_outputs(const std::filesystem::path& dir, const Slam& slam,
                                                     const ScanCollector& scans) {
  if (scans.scans().empty()) return {};
  const auto start = std::chrono::steady_clock::now();
  const RunConfig& config = slam.config();
  std::vector<Pose6> mounts;
  for (const SensorConfig& s : config.sensors) mounts.push_back(s.mount);
  const OccupancyGrid grid = build_occupancy_grid(scans.scans(), slam.trajectory(), mounts, config.output.grid);
  write_grid_files(dir, grid);
  std::vector<std::filesystem::path> written = {dir / "grid.pgm", dir / "grid.yaml"};
  if (config.output.picture) {
    write_atomically(dir / "grid.png", [&](const std::filesystem::path& f) {
      write_grid_picture(f, slam, grid, config.output.picture_size);
    });
    written.push_back(dir / "grid.png");
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  kernel_log().info("occupancy grid: ", grid.width, " x ", grid.height, " cells of ", grid.resolution, " m from ",
                    scans.scans().size(), " scans in ", seconds, " s (grid.pgm, grid.yaml)");
  return written;
}

}  // namespace mspace::kernel
