#include "sim_world.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "mspace/transform.hpp"

namespace mspace::sim_world {

using planar_odometry::Increment;
using planar_odometry::kDegree;

namespace {

// Independent random streams of one seed.
constexpr std::uint64_t kLandmarkStream = 1;
constexpr std::uint64_t kOdometryStream = 2;
constexpr std::uint64_t kSensorStream = 3;

constexpr double kInf = std::numeric_limits<double>::infinity();

std::vector<ParamSpec> world_params() {
  return {
      param_int("seed", 1, "random seed: identical seeds give bit-identical worlds and data", 0),
      param_int("world_seed", -1,
                "seed of the landmark layout alone (-1: `seed`), so that runs with other noise (`seed`, --seed) "
                "see the same world",
                -1),
      param_double("world_width", 60.0, "extent of the world along x, centred on the origin (m)",
                   1.0),
      param_double("world_height", 40.0, "extent of the world along y, centred on the origin (m)",
                   1.0),
      param_int("num_landmarks", 120, "number of point landmarks (z = 0)", 0, 100000),
      param_double("min_landmark_spacing", 2.0, "minimum distance between two landmarks (m)", 0.0),
      param_double("route_clearance", 1.0,
                   "minimum distance from a landmark to the robot's path (m)", 0.0),
  };
}

std::vector<ParamSpec> motion_params() {
  std::vector<ParamSpec> specs = {
      param_double("route_margin", 6.0,
                   "distance from the world's edge to the outer rim of the clover route (m)", 0.0),
      param_int("laps", 2,
                "laps of the clover route (one lap: 8*(a+b) m, a/b = half width/height "
                "minus route_margin)",
                1, 1000),
      param_double("speed", 1.0, "robot speed (m/s)", 0.01),
      param_double("dt", 0.1, "time step between data steps (s)", 0.001),
      param_double("max_turn_rate_deg", 45.0, "bound on the robot's turn rate (deg/s)", 1.0,
                   3600.0),
  };
  for (ParamSpec& spec : planar_odometry::noise_param_specs()) specs.push_back(std::move(spec));
  return specs;
}

std::vector<ParamSpec> sensor_params() {
  return {
      param_string("channel", "laser", "channel name of the (range, bearing) readings"),
      param_list("sensor_mount", {0, 0, 0, 0, 0, 0},
                 "sensor pose in the robot frame [x, y, z (m), theta, phi, psi (deg)]", 6),
      param_double("max_range", 8.0, "maximum range of the sensor (m)", 0.0),
      param_double("fov_deg", 180.0, "field of view, centred on the sensor's x axis (deg)", 0.0,
                   360.0),
      param_double("detection_probability", 0.9, "probability that a landmark in view is reported",
                   0.0, 1.0),
      param_double("range_sigma", 0.05, "range noise std (m)", 0.0),
      param_double("bearing_sigma_deg", 0.5, "bearing noise std (deg)", 0.0),
      param_double("clutter_rate", 0.0,
                   "mean number of spurious readings per scan (Poisson), uniform in range and fov",
                   0.0, 50.0),
  };
}

Pose6 mount_from_list(const std::vector<double>& v) {
  return make_pose(v[0], v[1], v[2], v[3] * kDegree, v[4] * kDegree, v[5] * kDegree);
}

/// Distance from p to the nearest true robot position.
double distance_to_path(const Eigen::Vector2d& p, const std::vector<Pose6>& poses) {
  double best = kInf;
  for (const Pose6& pose : poses)
    best = std::min(best, std::hypot(p.x() - pose[kX], p.y() - pose[kY]));
  return best;
}

bool far_from_landmarks(const Eigen::Vector2d& p, const std::vector<Eigen::Vector2d>& placed,
                        double spacing) {
  return std::all_of(placed.begin(), placed.end(),
                     [&](const Eigen::Vector2d& q) { return (p - q).norm() >= spacing; });
}

/// Uniform random landmarks (rejection sampling), at least `spacing` apart and
/// `clearance` from the path. Returns 3 × N with z = 0.
Eigen::MatrixXd place_landmarks(const SimConfig& c, const std::vector<Pose6>& path) {
  SimRandom rng(c.world_seed < 0 ? c.seed : static_cast<std::uint64_t>(c.world_seed), kLandmarkStream);
  const auto wanted = static_cast<std::size_t>(c.num_landmarks);
  const std::size_t max_attempts = 200 * wanted + 1000;
  std::vector<Eigen::Vector2d> placed;
  for (std::size_t attempt = 0; placed.size() < wanted; ++attempt) {
    if (attempt == max_attempts) {
      throw std::invalid_argument(
          "sim_world: cannot place " + std::to_string(wanted) + " landmarks " +
          std::to_string(c.min_landmark_spacing) + " m apart and " +
          std::to_string(c.route_clearance) + " m from the route (placed " +
          std::to_string(placed.size()) +
          "); lower num_landmarks, min_landmark_spacing or route_clearance");
    }
    const Eigen::Vector2d p(rng.uniform(-0.5 * c.world_width, 0.5 * c.world_width),
                            rng.uniform(-0.5 * c.world_height, 0.5 * c.world_height));
    if (far_from_landmarks(p, placed, c.min_landmark_spacing) &&
        distance_to_path(p, path) >= c.route_clearance) {
      placed.push_back(p);
    }
  }
  Eigen::MatrixXd landmarks = Eigen::MatrixXd::Zero(3, static_cast<Eigen::Index>(placed.size()));
  for (std::size_t i = 0; i < placed.size(); ++i)
    landmarks.col(static_cast<Eigen::Index>(i)).head<2>() = placed[i];
  return landmarks;
}

std::vector<Eigen::Vector2d> route_waypoints(const SimConfig& c) {
  const double a = 0.5 * c.world_width - c.route_margin;
  const double b = 0.5 * c.world_height - c.route_margin;
  // Each leaf needs room for two rounded corners of the turning radius.
  const double min_half_size = 2.0 * c.speed / c.max_turn_rate + c.speed * c.dt;
  if (a < min_half_size || b < min_half_size) {
    throw std::invalid_argument(
        "sim_world: world_width/world_height minus 2*route_margin leave a route of " +
        std::to_string(2 * a) + " x " + std::to_string(2 * b) +
        " m, too small for the turning radius speed/max_turn_rate = " +
        std::to_string(c.speed / c.max_turn_rate) +
        " m (each half needs >= " + std::to_string(min_half_size) + " m)");
  }
  return clover_waypoints(a, b);
}

}  // namespace

std::vector<ParamSpec> param_specs() {
  std::vector<ParamSpec> specs = world_params();
  for (auto* group : {motion_params, sensor_params}) {
    for (ParamSpec& spec : group()) specs.push_back(std::move(spec));
  }
  return specs;
}

SimConfig SimConfig::from_params(const Params& p) {
  SimConfig c;
  c.seed = static_cast<std::uint64_t>(p.get_int("seed"));
  c.world_seed = p.get_int("world_seed");
  c.world_width = p.get_double("world_width");
  c.world_height = p.get_double("world_height");
  c.num_landmarks = static_cast<int>(p.get_int("num_landmarks"));
  c.min_landmark_spacing = p.get_double("min_landmark_spacing");
  c.route_clearance = p.get_double("route_clearance");
  c.route_margin = p.get_double("route_margin");
  c.laps = static_cast<int>(p.get_int("laps"));
  c.speed = p.get_double("speed");
  c.dt = p.get_double("dt");
  c.max_turn_rate = p.get_double("max_turn_rate_deg") * kDegree;
  c.odometry_noise = planar_odometry::noise_from_params(p);
  c.channel = p.get_string("channel");
  c.sensor_mount = mount_from_list(p.get_list("sensor_mount"));
  c.max_range = p.get_double("max_range");
  c.fov = p.get_double("fov_deg") * kDegree;
  c.detection_probability = p.get_double("detection_probability");
  c.range_sigma = p.get_double("range_sigma");
  c.bearing_sigma = p.get_double("bearing_sigma_deg") * kDegree;
  c.clutter_rate = p.get_double("clutter_rate");
  return c;
}

SimConfig SimConfig::defaults() { return from_params(Params::defaults(param_specs())); }

SimWorld::SimWorld(const SimConfig& config, Logger& log)
    : config_(config),
      waypoints_(route_waypoints(config)),
      trajectory_(
          drive_route(waypoints_, {config.laps, config.speed, config.dt, config.max_turn_rate})),
      landmarks_(place_landmarks(config, trajectory_.poses)),
      odometry_rng_(config.seed, kOdometryStream),
      sensor_rng_(config.seed, kSensorStream) {
  log.info("simulated world ", config.world_width, " x ", config.world_height, " m, ",
           landmarks_.cols(), " landmarks, ", config.laps, " laps of ", route_length(waypoints_),
           " m: ", size_hint(), " steps of ", config.dt, " s");
}

SimWorld::SimWorld(const PluginArgs& args)
    : SimWorld(SimConfig::from_params(args.params), args.log()) {}

bool SimWorld::next(DataStep& step) {
  if (next_step_ >= trajectory_.poses.size()) return false;
  const std::size_t k = next_step_++;
  step = DataStep{};
  step.t = static_cast<double>(k) * config_.dt;
  if (k > 0) step.odometry = noisy_odometry(trajectory_.increments[k - 1]);
  step.ground_truth = trajectory_.poses[k];
  step.readings.push_back(sense(trajectory_.poses[k], step.t));
  return true;
}

void SimWorld::save_state(StateWriter& out) const {
  out.put("next_step", Eigen::MatrixXd::Constant(1, 1, static_cast<double>(next_step_)));
  out.put_bytes("odometry_rng", odometry_rng_.state());
  out.put_bytes("sensor_rng", sensor_rng_.state());
}

void SimWorld::restore_state(const StateReader& in, int version) {
  const std::string context = "sim_world restore_state";
  if (version != 1) throw std::invalid_argument(context + ": state version " + std::to_string(version) + " (reads 1)");
  const double next = get_state(in, "next_step", 1, 1, context)(0, 0);
  if (!(next >= 0 && next <= static_cast<double>(trajectory_.poses.size())) || next != std::floor(next))
    throw std::invalid_argument(context + ": saved step " + std::to_string(next) + " is not within the route's " +
                                std::to_string(trajectory_.poses.size()) + " steps (other parameters?)");
  SimRandom odometry = odometry_rng_, sensor = sensor_rng_;
  try {
    odometry.set_state(in.get_bytes("odometry_rng"));
    sensor.set_state(in.get_bytes("sensor_rng"));
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(context + ": " + e.what());
  }
  next_step_ = static_cast<std::size_t>(next);
  odometry_rng_ = odometry;
  sensor_rng_ = sensor;
}

Eigen::VectorXd SimWorld::noisy_odometry(const Increment& truth) {
  const Eigen::Vector3d sigma = config_.odometry_noise.sigmas(truth);
  Eigen::VectorXd odometry = truth;
  for (int i = 0; i < 3; ++i) odometry[i] += sigma[i] * odometry_rng_.normal();
  return odometry;
}

SensorReading SimWorld::sense(const Pose6& x_mr, double t) {
  const Pose6 x_ms = compound(x_mr, config_.sensor_mount);  // eq. 17
  std::vector<Eigen::Vector2d> rows;
  add_landmark_rows(x_ms, x_mr, rows);
  add_clutter_rows(rows);

  SensorReading reading;
  reading.channel = config_.channel;
  reading.t = t;
  reading.values.resize(static_cast<Eigen::Index>(rows.size()), 2);
  for (std::size_t i = 0; i < rows.size(); ++i)
    reading.values.row(static_cast<Eigen::Index>(i)) = rows[i];
  sensor_rng_.shuffle_rows(reading.values);  // no ordering leak (landmark index, clutter last)
  return reading;
}

void SimWorld::add_landmark_rows(const Pose6& x_ms, const Pose6& x_mr,
                                 std::vector<Eigen::Vector2d>& rows) {
  // A landmark farther than this from the robot is farther than max_range from the sensor.
  const double reach = config_.max_range + config_.sensor_mount.head<3>().norm();
  for (Eigen::Index j = 0; j < landmarks_.cols(); ++j) {
    const Eigen::Vector3d landmark = landmarks_.col(j);
    if ((landmark - x_mr.head<3>()).norm() > reach) continue;
    const Eigen::VectorXd x_o = to_sensor_frame(point_layout_, landmark, x_ms);  // eq. 7
    const double range = std::hypot(x_o[0], x_o[1]);
    const double bearing = std::atan2(x_o[1], x_o[0]);
    if (range > config_.max_range || std::abs(bearing) > 0.5 * config_.fov) continue;
    if (sensor_rng_.uniform() >= config_.detection_probability) continue;
    const double noisy_range = range + config_.range_sigma * sensor_rng_.normal();
    const double noisy_bearing = wrap_angle(bearing + config_.bearing_sigma * sensor_rng_.normal());
    rows.emplace_back(noisy_range, noisy_bearing);
  }
}

void SimWorld::add_clutter_rows(std::vector<Eigen::Vector2d>& rows) {
  const int count = sensor_rng_.poisson(config_.clutter_rate);
  for (int i = 0; i < count; ++i) {
    const double range = sensor_rng_.uniform(0.0, config_.max_range);
    const double bearing = sensor_rng_.uniform(-0.5 * config_.fov, 0.5 * config_.fov);
    rows.emplace_back(range, bearing);
  }
}

}  // namespace mspace::sim_world
