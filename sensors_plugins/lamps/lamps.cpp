// lamps.cpp — see lamps.hpp.
#include "lamps.hpp"

#include <cmath>
#include <numbers>
#include <opencv2/imgproc.hpp>

#include "image_sequence/read_grey.hpp"

namespace mspace::lamps {
namespace {

/// ∂(undistorted normalised x, y)/∂(distorted pixel u, v) by central differences.
Eigen::Matrix2d undistortion_jacobian(const Eigen::Vector2d& uv, const camera::CameraModel& c) {
  constexpr double h = 0.5;  // px
  Eigen::Matrix2d J;
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d step = h * Eigen::Vector2d::Unit(i);
    J.col(i) = (c.normalised_from_pixel(uv + step) - c.normalised_from_pixel(uv - step)) / (2 * h);
  }
  return J;
}

/// Whether a blob passes the shape tests of the header.
bool is_round_lamp(const std::vector<cv::Point>& contour, const cv::Moments& m,
                   const LampConfig& c) {
  const double area = m.m00;
  if (area < c.min_area || area > c.max_area) return false;
  // Eigenvalues of the second central moments: squared half-axes / 4.
  const double mean = 0.5 * (m.mu20 + m.mu02);
  const double spread = std::hypot(0.5 * (m.mu20 - m.mu02), m.mu11);
  const double minor = mean - spread, major = mean + spread;
  if (!(major > 0.0) || std::sqrt(std::max(minor, 0.0) / major) < c.min_roundness) return false;
  const double perimeter = cv::arcLength(contour, true);
  return 4.0 * std::numbers::pi * area / (perimeter * perimeter) >= c.min_circularity;
}

bool touches_border(const cv::Rect& box, int width, int height) {
  return box.x <= 0 || box.y <= 0 || box.x + box.width >= width || box.y + box.height >= height;
}

double positive(const Params& p, const char* name) {
  const double value = p.get_double(name);
  if (!(value > 0.0)) {
    throw std::invalid_argument(std::string("lamps: parameter '") + name + "' must be > 0");
  }
  return value;
}

}  // namespace

struct LampExtractor::Buffers {
  cv::Mat mask;
  std::vector<std::vector<cv::Point>> contours;
};

Measurement bearing_measurement(const Eigen::Vector2d& uv, const camera::CameraModel& camera,
                                double pixel_sigma) {
  const Eigen::Vector2d xy = camera.normalised_from_pixel(uv);
  const Eigen::Vector3d p(xy.x(), xy.y(), 1.0);
  const Eigen::Vector3d b = p.normalized();
  // b = p/|p|: ∂b/∂p = (I − b bᵀ)/|p|, and p depends on (x, y) only.
  const Eigen::Matrix3d db_dp = (Eigen::Matrix3d::Identity() - b * b.transpose()) / p.norm();
  const Eigen::Matrix<double, 3, 2> J = db_dp.leftCols<2>() * undistortion_jacobian(uv, camera);
  Measurement m;
  m.kind = kMeasurementKind;
  m.v = b;
  m.C_v = pixel_sigma * pixel_sigma * J * J.transpose();
  return m;
}

std::vector<ParamSpec> LampExtractor::param_specs() {
  const LampConfig d;
  return {
      param_double("threshold", d.threshold, "grey level (0-255) above which a pixel is lamp",
                   0.0, 255.0),
      param_double("min_area_px", d.min_area, "smallest lamp blob (px^2)", 0.0),
      param_double("max_area_px", d.max_area, "largest lamp blob (px^2)", 0.0),
      param_double("min_roundness", d.min_roundness, "minor/major axis ratio of a lamp blob", 0.0,
                   1.0),
      param_double("min_circularity", d.min_circularity,
                   "4*pi*area/perimeter^2 of a lamp blob (circle 1, square 0.785)", 0.0, 1.0),
      param_double("pixel_sigma", d.pixel_sigma, "std of a lamp centre (px), > 0", 0.0),
  };
}

LampExtractor::LampExtractor(const LampConfig& config)
    : config_(config), buffers_(std::make_unique<Buffers>()) {}

LampExtractor::LampExtractor(const PluginArgs& args)
    : LampExtractor([&] {
        const Params& p = args.params;
        LampConfig c;
        c.threshold = p.get_double("threshold");
        c.min_area = p.get_double("min_area_px");
        c.max_area = p.get_double("max_area_px");
        c.min_roundness = p.get_double("min_roundness");
        c.min_circularity = p.get_double("min_circularity");
        c.pixel_sigma = positive(p, "pixel_sigma");
        return c;
      }()) {}

LampExtractor::~LampExtractor() = default;

void LampExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  const camera::CameraModel cam = camera::camera_from_reading(reading);
  const cv::Mat grey = camera::read_grey(reading, cam);
  extract_image({grey.cols, grey.rows, grey.data, grey.step}, cam, out);
}

void LampExtractor::extract_image(const camera::GreyView& image, const camera::CameraModel& cam,
                                  std::vector<Measurement>& out) {
  Buffers& k = *buffers_;
  cv::threshold(camera::as_mat(image), k.mask, config_.threshold, 255, cv::THRESH_BINARY);
  cv::findContours(k.mask, k.contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
  for (const std::vector<cv::Point>& contour : k.contours) {
    if (touches_border(cv::boundingRect(contour), image.width, image.height)) continue;
    const cv::Moments m = cv::moments(contour);
    if (!is_round_lamp(contour, m, config_)) continue;
    const Eigen::Vector2d centroid(m.m10 / m.m00, m.m01 / m.m00);
    out.push_back(bearing_measurement(centroid, cam, config_.pixel_sigma));
  }
}

}  // namespace mspace::lamps
