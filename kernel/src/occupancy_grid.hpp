// occupancy_grid.hpp — an occupancy grid of a run's range scans, in the
// format of ROS map_server (grid.pgm + grid.yaml), for navigation stacks
// (Nav2, move_base) and for looking at the map the way laser-SLAM users do.
//
// Generic: the kernel names no feature type or sensor. It keeps every raw
// reading that looks like a range scan (two columns, range and bearing, at
// least kMinScanBeams beams at evenly spaced, increasing bearings — what a
// scanning range finder delivers; point detections and images do not look
// like that) with the index of its step's pose, and casts the beams only at
// the end, from the final trajectory (after a smoother's last optimisation,
// so loop closures show) composed with the sensor's mount (eq. 17).
//
// Each beam updates log-odds along its ray (Thrun, Burgard & Fox,
// Probabilistic Robotics, ch. 9, Table 9.1, the occupancy grid algorithm in
// log-odds form, with inverse sensor model probabilities p_hit = 0.7 and
// p_miss = 0.45 and prior 0.5): the cells the ray crosses
// (Bresenham's line) are missed, the end cell is hit. A beam longer than
// output.grid.max_range misses the cells up to that range and hits none; a
// range ≤ 0 (no return) or not finite is skipped.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include <Eigen/Core>

#include "evaluation.hpp"

namespace mspace {
struct DataStep;
}

namespace mspace::kernel {

struct GridConfig;
struct RunConfig;
class Slam;

/// A reading counts as a range scan with at least this many beams.
inline constexpr int kMinScanBeams = 30;

/// True when `values` looks like one scan of a scanning range finder: two
/// columns (range m, bearing rad), at least kMinScanBeams rows, the bearings
/// increasing in steps equal to within 1 % of their mean step.
bool is_range_scan(const Eigen::MatrixXd& values);

/// One range scan kept for the grid.
struct RangeScan {
  std::size_t pose_index = 0;  ///< into Slam::trajectory()
  int sensor = 0;              ///< index into RunConfig::sensors (its mount)
  std::vector<float> ranges;   ///< m
  std::vector<float> bearings; ///< rad, in the sensor frame
};

/// Keeps the range scans of a run as its steps go by (Slam::set_step_observer).
class ScanCollector {
 public:
  explicit ScanCollector(const RunConfig& config);
  /// Keeps the readings of `data` that are range scans of a configured sensor
  /// (the first sensor on the reading's channel gives the mount).
  void add(const DataStep& data, std::size_t pose_index);
  const std::vector<RangeScan>& scans() const { return scans_; }

 private:
  const RunConfig& config_;
  std::vector<RangeScan> scans_;
};

/// Log-odds occupancy on a regular grid. Cell (i, j) covers
/// [origin.x + i·resolution, +resolution) × [origin.y + j·resolution, +resolution).
struct OccupancyGrid {
  double resolution = 0.05;                        ///< m
  Eigen::Vector2d origin = Eigen::Vector2d::Zero(); ///< lower-left corner of cell (0, 0), map frame (m)
  int width = 0, height = 0;                       ///< cells in x and y
  std::vector<float> log_odds;                     ///< width × height, row j = y index

  /// The thresholds of map_server's trinary mode: a cell is occupied when its
  /// probability exceeds kOccupiedThreshold, free below kFreeThreshold, else
  /// unknown (the values ROS's map_saver writes).
  static constexpr double kOccupiedThreshold = 0.65;
  static constexpr double kFreeThreshold = 0.196;
  enum class Cell : std::uint8_t { Unknown, Free, Occupied };

  std::size_t index(int i, int j) const {
    return static_cast<std::size_t>(j) * static_cast<std::size_t>(width) + static_cast<std::size_t>(i);
  }
  float at(int i, int j) const { return log_odds[index(i, j)]; }
  Cell cell(int i, int j) const;
  bool contains(int i, int j) const { return i >= 0 && j >= 0 && i < width && j < height; }
  /// The cell holding point p (may be outside the grid).
  Eigen::Vector2i cell_of(const Eigen::Vector2d& p) const;
};

/// Casts every scan from trajectory[scan.pose_index] ⊕ mounts[scan.sensor].
/// The grid covers every sensor position and beam end point (beams cut at
/// max_range) with one cell to spare. Throws std::runtime_error naming
/// output.grid.resolution when that would take more than kMaxGridCells cells.
inline constexpr std::size_t kMaxGridCells = 100'000'000;
OccupancyGrid build_occupancy_grid(const std::vector<RangeScan>& scans, const std::vector<StampedPose>& trajectory,
                                   const std::vector<Pose6>& mounts, const GridConfig& options);

/// grid.pgm (8-bit, top row = largest y: occupied 0, free 254, unknown 205)
/// and grid.yaml (image, resolution, origin, negate, thresholds, mode trinary)
/// in `dir`, each written atomically.
void write_grid_files(const std::filesystem::path& dir, const OccupancyGrid& grid);

/// For a finished run: builds the grid from the collected scans at the
/// final trajectory, writes grid.pgm + grid.yaml and, when output.picture is
/// on, grid.png (the grid under the map's features, picture.cpp). Nothing
/// when no scan was collected. Logs the size and the time it took; returns
/// the files written.
std::vector<std::filesystem::path> write_grid_outputs(const std::filesystem::path& dir, const Slam& slam,
                                                     const ScanCollector& scans);

/// The grid with the features and the trajectory of the run drawn over it
/// (picture.cpp, the same drawing as map.png's top view).
void write_grid_picture(const std::filesystem::path& file, const Slam& slam, const OccupancyGrid& grid, int size_px);

}  // namespace mspace::kernel
