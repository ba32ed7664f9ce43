// sim_world.hpp — a deterministic, seeded simulated world: the data source of
// the built-in default run.
//
// Point landmarks (z = 0) are scattered over a world_width × world_height
// rectangle centred on the origin. A planar robot starts at the origin heading
// along +x and drives `laps` laps of the clover route of route.hpp (loop
// closures at every crossing and on every lap). Each step of dt seconds gives
//   - the true pose (DataStep::ground_truth),
//   - odometry: the true increment (dx, dy, dθ) in the previous true pose's
//     frame plus noise drawn from N(0, C_d) of planar_odometry.hpp,
//   - one reading on `channel` with rows (range, bearing) of the landmarks
//     within max_range and the field of view, each detected with
//     detection_probability, with Gaussian range/bearing noise, plus Poisson
//     clutter; the rows are shuffled.
// Step 0 is at t = 0 at the initial pose and has no odometry.
//
// The readings are taken by a sensor at the pose sensor_mount in the robot
// frame (x_ms = x_mr ⊕ x_rs, eq. 17): each landmark is transformed into the
// sensor frame (eq. 7) and (range, bearing) is the polar form of its sensor
// frame (x, y); its sensor-frame z (height above/below the scan plane) is
// ignored, as for a planar scanner seeing a vertical pole.
//
// Identical parameters give bit-identical output on every machine (own
// samplers on std::mt19937_64, see sim_random.hpp).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "mspace/coords.hpp"
#include "mspace/source.hpp"
#include "odometry2d/planar_odometry.hpp"
#include "route.hpp"
#include "sim_random.hpp"

namespace mspace::sim_world {

/// All settings in SI units (m, s, rad); see param_specs() for meanings and
/// defaults() for the default values (which come from param_specs()).
struct SimConfig {
  std::uint64_t seed = 0;
  std::int64_t world_seed = -1;  ///< the landmark layout's seed; −1: `seed`
  // world and landmarks
  double world_width = 0.0;
  double world_height = 0.0;
  int num_landmarks = 0;
  double min_landmark_spacing = 0.0;
  double route_clearance = 0.0;
  // route and motion
  double route_margin = 0.0;
  int laps = 0;
  double speed = 0.0;
  double dt = 0.0;
  double max_turn_rate = 0.0;
  planar_odometry::NoiseModel odometry_noise;
  // sensor
  std::string channel;
  Pose6 sensor_mount = Pose6::Zero();
  double max_range = 0.0;
  double fov = 0.0;
  double detection_probability = 0.0;
  double range_sigma = 0.0;
  double bearing_sigma = 0.0;
  double clutter_rate = 0.0;

  /// From parameters declared by param_specs() (degrees converted to radians).
  static SimConfig from_params(const Params& params);
  /// The defaults of param_specs().
  static SimConfig defaults();
};

/// The plugin's parameters (names, defaults, units, ranges).
std::vector<ParamSpec> param_specs();

class SimWorld final : public DataSource {
 public:
  /// Builds the landmarks and drives the whole route up front (throws
  /// std::invalid_argument when the world is too small for the route or the
  /// landmarks cannot be placed).
  explicit SimWorld(const SimConfig& config, Logger& log = null_logger());
  explicit SimWorld(const PluginArgs& args);

  bool next(DataStep& step) override;
  std::size_t size_hint() const override { return trajectory_.poses.size(); }
  Pose6 initial_pose() const override { return trajectory_.poses.front(); }
  Eigen::MatrixXd true_landmarks() const override { return landmarks_; }

  /// Checkpoints: the position in the route and both random generators'
  /// states (the world and the route are rebuilt from the parameters).
  bool has_state() const override { return true; }
  void save_state(StateWriter& out) const override;
  void restore_state(const StateReader& in, int version) override;

  const SimConfig& config() const { return config_; }
  /// The waypoints of one lap of the route.
  const std::vector<Eigen::Vector2d>& waypoints() const { return waypoints_; }
  /// The true robot poses, one per step.
  const std::vector<Pose6>& true_poses() const { return trajectory_.poses; }
  /// The noise-free odometry: true_increments()[k] moves true_poses()[k] to [k + 1].
  const std::vector<planar_odometry::Increment>& true_increments() const {
    return trajectory_.increments;
  }

 private:
  Eigen::VectorXd noisy_odometry(const planar_odometry::Increment& truth);
  SensorReading sense(const Pose6& x_mr, double t);
  void add_landmark_rows(const Pose6& x_ms, const Pose6& x_mr, std::vector<Eigen::Vector2d>& rows);
  void add_clutter_rows(std::vector<Eigen::Vector2d>& rows);

  SimConfig config_;
  std::vector<Eigen::Vector2d> waypoints_;
  Trajectory trajectory_;
  Eigen::MatrixXd landmarks_;  ///< 3 × N
  CoordLayout point_layout_{BlockKind::Point3D};
  SimRandom odometry_rng_;
  SimRandom sensor_rng_;
  std::size_t next_step_ = 0;
};

}  // namespace mspace::sim_world
