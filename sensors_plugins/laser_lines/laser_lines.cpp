// laser_lines.cpp — see laser_lines.hpp.
#include "laser_lines.hpp"

#include <Eigen/Geometry>

#include <cmath>
#include <numbers>
#include <random>
#include <sstream>
#include <stdexcept>

namespace mspace::laser_lines {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

}  // namespace

Measurement to_measurement(const Segment& s) {
  Measurement m;
  m.kind = line_segment::kKind;
  m.v = Eigen::Vector4d(s.rho, s.alpha, s.s_a, s.s_b);
  m.C_v = s.C;
  m.dense = s.inliers;
  m.flags = line_segment::make_flags(s.end_a, s.end_b);
  return m;
}

std::vector<ParamSpec> LaserLinesExtractor::param_specs() {
  const LineConfig d;
  return {
      param_double("range_sigma", d.range_sigma, "range noise std, lower bound of the fit's σ (m)", 1e-6),
      param_double("min_range", d.min_range, "shorter ranges are ignored (m)", 0.0),
      param_double("max_range", d.max_range, "longer ranges count as no return (m)", 0.0),
      param_double("breakpoint_lambda_deg", d.breakpoint_lambda / kDeg,
                   "λ of the adaptive breakpoint detector (deg; smaller splits clusters less often)", 1.0, 89.0),
      param_double("split_distance", d.split_distance, "split-and-merge distance threshold (m)", 1e-4),
      param_int("bridge_no_returns", d.bridge_no_returns,
                "beams without any return (range 0: dropouts) a line may span, and an end's class looks past, "
                "at most in a row; a return beyond max_range is never bridged (0: every no-return cuts a line)",
                0.0, 10.0),
      param_int("min_points", d.min_points, "fewest inliers of a segment", 2.0),
      param_double("min_length", d.min_length, "shortest segment (m)", 0.0),
      param_double("max_rms", d.max_rms, "largest rms residual of a segment (m)", 1e-6),
      param_double("depth_jump", d.depth_jump, "range jump that makes a segment end real or occluded (m)", 0.0),
      param_double("min_corner_angle_deg", d.min_corner_angle / kDeg, "least angle between walls at a corner (deg)",
                   0.0, 90.0),
      param_double("corner_distance", d.corner_distance,
                   "largest distance of a segment end from the corner intersection (m)", 0.0),
      param_double("max_incidence_deg", d.max_incidence / kDeg,
                   "beams farther than this from the line normal are grazing (deg)", 1.0, 89.9),
      param_double("distance_sigma_floor", d.distance_sigma_floor, "systematic error added to σ_ρ (m)", 0.0),
      param_double("angle_sigma_floor_deg", d.angle_sigma_floor / kDeg, "systematic error added to σ_α (deg)", 0.0),
  };
}

LaserLinesExtractor::LaserLinesExtractor(const PluginArgs& args) {
  const Params& p = args.params;
  config_.range_sigma = p.get_double("range_sigma");
  config_.min_range = p.get_double("min_range");
  config_.max_range = p.get_double("max_range");
  config_.breakpoint_lambda = p.get_double("breakpoint_lambda_deg") * kDeg;
  config_.split_distance = p.get_double("split_distance");
  config_.bridge_no_returns = static_cast<int>(p.get_int("bridge_no_returns"));
  config_.min_points = static_cast<int>(p.get_int("min_points"));
  config_.min_length = p.get_double("min_length");
  config_.max_rms = p.get_double("max_rms");
  config_.depth_jump = p.get_double("depth_jump");
  config_.min_corner_angle = p.get_double("min_corner_angle_deg") * kDeg;
  config_.corner_distance = p.get_double("corner_distance");
  config_.max_incidence = p.get_double("max_incidence_deg") * kDeg;
  config_.distance_sigma_floor = p.get_double("distance_sigma_floor");
  config_.angle_sigma_floor = p.get_double("angle_sigma_floor_deg") * kDeg;
  if (config_.min_range >= config_.max_range)
    throw std::invalid_argument("laser_lines: min_range must be below max_range");
}

void LaserLinesExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  if (reading.values.cols() != 2 || !reading.values.allFinite()) {
    std::ostringstream os;
    os << "laser_lines: reading on channel '" << reading.channel << "' at t = " << reading.t
       << " must have 2 finite columns (range, bearing); it has " << reading.values.cols() << " columns"
       << (reading.values.allFinite() ? "" : " and non-finite values");
    throw std::runtime_error(os.str());
  }
  for (const Segment& s : extract_segments(reading.values.col(0), reading.values.col(1), config_))
    out.push_back(to_measurement(s));
}

std::optional<SampleScene> LaserLinesExtractor::sample_scene(std::uint64_t seed) const {
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  constexpr double kPi = std::numbers::pi;
  // The room: corners (0, 0), (W, 0), (W, H), (0, H) in its own frame,
  // turned by `turn` and shifted by `at`; the sensor stands 1.5 m or more
  // from every wall.
  const double W = uniform(4, 10), H = uniform(4, 10), turn = uniform(-kPi, kPi);
  const Eigen::Vector2d at(uniform(-20, 20), uniform(-20, 20));
  const Eigen::Matrix2d R = Eigen::Rotation2Dd(turn).toRotationMatrix();
  const Eigen::Vector2d inside(uniform(1.5, W - 1.5), uniform(1.5, H - 1.5));
  const Eigen::Vector2d sensor = at + R * inside;

  SampleScene scene;
  scene.reading.channel = "laser";
  scene.x_ms = make_pose2d(sensor.x(), sensor.y(), uniform(-kPi, kPi));
  const Eigen::Vector2d corners[4] = {{0, 0}, {W, 0}, {W, H}, {0, H}};
  for (int k = 0; k < 4; ++k) {
    TrueShape wall;
    wall.kind = TrueShape::Kind::Segment;
    wall.a << at + R * corners[k], 0.0;
    wall.b << at + R * corners[(k + 1) % 4], 0.0;
    scene.truth.push_back(wall);
  }
  constexpr int kBeams = 720;
  const Eigen::VectorXd bearings = Eigen::VectorXd::LinSpaced(kBeams, -kPi, kPi - 2 * kPi / kBeams);
  const Eigen::VectorXd ranges = planar_scan(scene.truth, scene.x_ms, bearings, config_.max_range);
  scene.reading.values.resize(kBeams, 2);
  scene.reading.values << ranges, bearings;
  return scene;
}

}  // namespace mspace::laser_lines
