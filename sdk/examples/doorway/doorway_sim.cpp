// doorway_sim.cpp — the `doorway_sim` data source: a planar robot drives
// `laps` circles of radius `radius` around the origin (starting at
// (radius, 0) heading +y) among the doorways listed in `doorways`
// (x1 y1 x2 y2 per doorway, map frame). Each step gives the true pose, noisy
// odometry (dx, dy, dθ) with the noise model of the odometry2d plugin
// (σ_xy = xy_noise_per_m·d + xy_noise_floor, σ_θ = theta_noise_per_rad·|dθ|
// + theta_noise_per_m·d + theta_noise_floor, the last two in degrees as in
// odometry2d) and one reading on `channel`:
// a row (r1, b1, r2, b2) for every doorway whose two jambs are within
// max_range and in front of the robot, with Gaussian noise.
#include <cmath>
#include <memory>
#include <random>
#include <stdexcept>

#include "mspace/plugin_export.hpp"
#include "mspace/pose.hpp"
#include "mspace/source.hpp"

namespace {

using namespace mspace;

class DoorwaySim final : public DataSource {
 public:
  explicit DoorwaySim(const PluginArgs& args) : p_(args.params), rng_(static_cast<std::uint64_t>(p_.get_int("seed"))) {
    const std::vector<double>& d = p_.get_list("doorways");
    if (d.empty() || d.size() % 4 != 0) throw std::invalid_argument("doorway_sim: doorways needs 4 numbers per doorway");
    doors_ = Eigen::Map<const Eigen::MatrixXd>(d.data(), 4, static_cast<Eigen::Index>(d.size() / 4));
    const double radius = p_.get_double("radius");
    steps_ = static_cast<std::size_t>(std::ceil(p_.get_double("laps") * 2 * M_PI * radius / p_.get_double("speed") /
                                                p_.get_double("dt")));
    pose_ = initial_pose();
  }

  Pose6 initial_pose() const override { return make_pose2d(p_.get_double("radius"), 0.0, M_PI / 2); }
  std::size_t size_hint() const override { return steps_ + 1; }
  Eigen::MatrixXd true_landmarks() const override {
    Eigen::MatrixXd l = Eigen::MatrixXd::Zero(3, 2 * doors_.cols());
    for (Eigen::Index i = 0; i < doors_.cols(); ++i) {
      l.block<2, 1>(0, 2 * i) = doors_.block<2, 1>(0, i);
      l.block<2, 1>(0, 2 * i + 1) = doors_.block<2, 1>(2, i);
    }
    return l;
  }

  bool next(DataStep& step) override {
    if (k_ > steps_) return false;
    step = DataStep{};
    step.t = static_cast<double>(k_) * p_.get_double("dt");
    if (k_ > 0) step.odometry = move();
    step.ground_truth = pose_;
    step.readings.push_back(sense(step.t));
    ++k_;
    return true;
  }

 private:
  double gauss(double sigma) { return std::normal_distribution<double>(0.0, 1.0)(rng_) * sigma; }

  /// One step along the circle; returns the noisy odometry increment.
  Eigen::VectorXd move() {
    const double radius = p_.get_double("radius");
    const double dtheta = p_.get_double("speed") * p_.get_double("dt") / radius;
    const Eigen::Vector3d inc(radius * std::sin(dtheta), radius * (1 - std::cos(dtheta)), dtheta);
    pose_ = compound(pose_, make_pose2d(inc[0], inc[1], inc[2]));
    const double d = std::hypot(inc[0], inc[1]);
    const double s_xy = p_.get_double("xy_noise_per_m") * d + p_.get_double("xy_noise_floor");
    const double deg = M_PI / 180.0;
    const double s_th = p_.get_double("theta_noise_per_rad") * std::abs(inc[2]) +
                        (p_.get_double("theta_noise_per_m") * d + p_.get_double("theta_noise_floor")) * deg;
    return Eigen::Vector3d(inc[0] + gauss(s_xy), inc[1] + gauss(s_xy), inc[2] + gauss(s_th));
  }

  SensorReading sense(double t) {
    SensorReading r{p_.get_string("channel"), t, Eigen::MatrixXd(0, 4), {}};
    const double sr = p_.get_double("range_sigma"), sb = p_.get_double("bearing_sigma_deg") * M_PI / 180.0;
    const Eigen::Matrix2d Rt = rotation(pose_).topLeftCorner<2, 2>().transpose();
    for (Eigen::Index i = 0; i < doors_.cols(); ++i) {
      Eigen::Vector4d row;
      bool visible = true;
      for (int j = 0; j < 2; ++j) {
        const Eigen::Vector2d q = Rt * (doors_.block<2, 1>(2 * j, i) - pose_.head<2>());
        visible = visible && q.x() > 0 && q.norm() < p_.get_double("max_range");
        row.segment<2>(2 * j) << q.norm() + gauss(sr), wrap_angle(std::atan2(q.y(), q.x()) + gauss(sb));
      }
      if (!visible) continue;
      r.values.conservativeResize(r.values.rows() + 1, 4);
      r.values.bottomRows<1>() = row.transpose();
    }
    return r;
  }

  Params p_;
  std::mt19937_64 rng_;
  Eigen::MatrixXd doors_;
  std::size_t steps_ = 0, k_ = 0;
  Pose6 pose_;
};

PluginDescriptor describe() {
  PluginDescriptor d;
  d.name = "doorway_sim";
  d.kind = PluginKind::Source;
  d.description = "A robot circling the origin among doorways: odometry, jamb readings and ground truth";
  d.params = {
      param_int("seed", 1, "random seed", 0),
      param_list("doorways", {3, 4, 4, 4, -4, 3, -4, 2, 0, -4.5, -0.9, -4.5}, "x1 y1 x2 y2 per doorway (m)"),
      param_double("radius", 2.5, "radius of the circle (m)", 0.1),
      param_double("laps", 2, "laps driven", 0.01),
      param_double("speed", 0.5, "speed (m/s)", 0.01),
      param_double("dt", 0.1, "time step (s)", 1e-3),
      param_double("max_range", 8, "sensor range (m)", 0.1),
      param_double("range_sigma", 0.03, "range noise std (m)", 0),
      param_double("bearing_sigma_deg", 0.5, "bearing noise std (deg)", 0),
      param_double("xy_noise_per_m", 0.03, "odometry σ_xy per m", 0),
      param_double("xy_noise_floor", 0.001, "odometry σ_xy floor (m)", 0),
      param_double("theta_noise_per_rad", 0.02, "odometry σ_θ per rad turned", 0),
      param_double("theta_noise_per_m", 1.0, "odometry σ_θ per m travelled (deg/m)", 0),
      param_double("theta_noise_floor", 0.05, "odometry σ_θ floor (deg)", 0),
      param_string("channel", "doors", "channel of the readings"),
  };
  d.factory = [](const PluginArgs& args) -> std::unique_ptr<PluginObject> { return std::make_unique<DoorwaySim>(args); };
  return d;
}

}  // namespace

MSPACE_EXPORT_PLUGIN(describe)
