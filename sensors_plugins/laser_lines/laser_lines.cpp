// laser_lines.cpp — see laser_lines.hpp.
#include "laser_lines.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

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
      param_bool("range_sigma_from_data", false,
                 "cut each scan into clusters with the range noise the recent segments show (median over the "
                 "last 400 segments of 20 or more points, each its residuals turned back along the beams) where "
                 "that exceeds range_sigma: the breakpoint detector's 3σ term follows a noisier laser than "
                 "configured (trimming and the covariance floor keep range_sigma)"),
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
  sigma_from_data_ = p.get_bool("range_sigma_from_data");
  sigma_in_use_ = config_.range_sigma;
  log_ = args.logger;
}

void LaserLinesExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  if (reading.values.cols() != 2 || !reading.values.allFinite()) {
    std::ostringstream os;
    os << "laser_lines: reading on channel '" << reading.channel << "' at t = " << reading.t
       << " must have 2 finite columns (range, bearing); it has " << reading.values.cols() << " columns"
       << (reading.values.allFinite() ? "" : " and non-finite values");
    throw std::runtime_error(os.str());
  }
  LineConfig scan_config = config_;
  scan_config.breakpoint_sigma = sigma_in_use_;
  const std::vector<Segment> segments = extract_segments(reading.values.col(0), reading.values.col(1), scan_config);
  for (const Segment& s : segments) out.push_back(to_measurement(s));
  learn_range_noise(segments);
}

// The noise is always measured (a pass over the inliers); it is reported
// once the window is full, with a warning when the configured range_sigma
// contradicts it by more than a factor kContradiction, and used only with
// range_sigma_from_data.
void LaserLinesExtractor::learn_range_noise(const std::vector<Segment>& segments) {
  constexpr double kContradiction = 1.25;
  noise_.add(segments, config_.max_incidence);
  if (!sigma_from_data_ && reported_) return;  // without the option the median served the report alone
  const std::optional<double> measured = noise_.median();
  if (sigma_from_data_) sigma_in_use_ = RangeNoiseTracker::sigma_above(measured, config_.range_sigma);
  if (reported_ || !measured || noise_.samples().size() < RangeNoiseTracker::kWindow || log_ == nullptr) return;
  reported_ = true;
  const double ratio = *measured / config_.range_sigma;
  if (ratio > kContradiction || ratio < 1.0 / kContradiction)
    log_->warn("range noise measured on the first ", noise_.samples().size(), " segments: ", *measured,
               " m, against range_sigma ", config_.range_sigma, " m (",
               sigma_from_data_ ? (ratio > 1.0 ? "the scans are cut with the measured value"
                                               : "range_sigma is kept as the least the extractor assumes")
                                : "set range_sigma, or range_sigma_from_data: true",
               ")");
  else
    log_->info("range noise measured on the first ", noise_.samples().size(), " segments: ", *measured,
               " m (range_sigma ", config_.range_sigma, " m)");
}

void LaserLinesExtractor::save_state(StateWriter& out) const {
  const std::deque<double>& kept = noise_.samples();
  Eigen::MatrixXd samples(static_cast<Eigen::Index>(kept.size()), 1);
  for (std::size_t i = 0; i < kept.size(); ++i) samples(static_cast<Eigen::Index>(i), 0) = kept[i];
  out.put("range_noise_samples", samples);
  out.put("range_sigma_in_use", Eigen::MatrixXd::Constant(1, 1, sigma_in_use_));
  out.put("range_noise_reported", Eigen::MatrixXd::Constant(1, 1, reported_ ? 1.0 : 0.0));
}

void LaserLinesExtractor::restore_state(const StateReader& in, int version) {
  const std::string context = "laser_lines restore_state";
  if (version != 1) throw std::invalid_argument(context + ": state version " + std::to_string(version) + " (reads 1)");
  const Eigen::MatrixXd& samples = get_state(in, "range_noise_samples", -1, 1, context);
  const double in_use = get_state(in, "range_sigma_in_use", 1, 1, context)(0, 0);
  const double reported = get_state(in, "range_noise_reported", 1, 1, context)(0, 0);
  if (static_cast<std::size_t>(samples.rows()) > RangeNoiseTracker::kWindow || !samples.allFinite() ||
      (samples.array() < 0).any())
    throw std::invalid_argument(context + ": " + std::to_string(samples.rows()) +
                                " range noise samples, expected at most " + std::to_string(RangeNoiseTracker::kWindow) +
                                " finite non-negative values");
  if (!(std::isfinite(in_use) && in_use >= config_.range_sigma))
    throw std::invalid_argument(context + ": range_sigma_in_use " + std::to_string(in_use) +
                                " is below range_sigma (other parameters?)");
  noise_.set_samples(std::deque<double>(samples.col(0).data(), samples.col(0).data() + samples.rows()));
  sigma_in_use_ = in_use;
  reported_ = reported != 0.0;
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
