// ceiling_lines.cpp — see ceiling_lines.hpp.
#include "ceiling_lines.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <numbers>
#include <optional>
#include <opencv2/imgproc.hpp>

#include "ceiling_render/ceiling_scene.hpp"
#include "image_sequence/read_grey.hpp"

namespace mspace::ceiling_lines {
namespace {

constexpr double kDegree = std::numbers::pi / 180.0;
// Refinement of a Hough segment: edge points within kBand px of it are fitted,
// then refitted with those within kInlierDistance px; kMinPoints are needed.
constexpr int kBand = 2;
constexpr double kInlierDistance = 1.0;
constexpr std::size_t kMinPoints = 10;

/// A segment in the undistorted image (pixels).
struct Segment {
  Eigen::Vector2d a, b;
  bool merged = false;  ///< absorbed other segments (refit it)
  double length() const { return (b - a).norm(); }
  Eigen::Vector2d direction() const { return (b - a).normalized(); }
};

/// Angle between two undirected directions, in [0, π/2].
double undirected_angle(const Eigen::Vector2d& d1, const Eigen::Vector2d& d2) {
  return std::acos(std::min(1.0, std::abs(d1.dot(d2))));
}

/// Merges `s` into `kept` when both lie on nearly the same line and touch or
/// overlap along it; `kept` then spans both (its line is kept: it is the longer).
bool try_merge(Segment& kept, const Segment& s, const LineConfig& c) {
  const Eigen::Vector2d t = kept.direction();
  if (undirected_angle(t, s.direction()) > c.merge_angle) return false;
  const Eigen::Vector2d n(-t.y(), t.x());
  if (std::abs(n.dot(s.a - kept.a)) > c.merge_distance ||
      std::abs(n.dot(s.b - kept.a)) > c.merge_distance) {
    return false;
  }
  const double sa = t.dot(s.a - kept.a), sb = t.dot(s.b - kept.a);
  const double lo = std::min(sa, sb), hi = std::max(sa, sb);
  const double length = kept.length();
  if (lo > length + c.max_gap || hi < -c.max_gap) return false;  // apart along the line
  const Eigen::Vector2d origin = kept.a;
  kept.a = origin + std::min(0.0, lo) * t;
  kept.b = origin + std::max(length, hi) * t;
  kept.merged = true;
  return true;
}

/// Longest first (input and output); each segment is merged into a longer one when it can be.
std::vector<Segment> merge_collinear(std::vector<Segment> segments, const LineConfig& c) {
  std::sort(segments.begin(), segments.end(),
            [](const Segment& x, const Segment& y) { return x.length() > y.length(); });
  std::vector<Segment> kept;
  for (const Segment& s : segments) {
    const bool merged =
        std::any_of(kept.begin(), kept.end(), [&](Segment& k) { return try_merge(k, s, c); });
    if (!merged) kept.push_back(s);
  }
  std::sort(kept.begin(), kept.end(),
            [](const Segment& x, const Segment& y) { return x.length() > y.length(); });
  return kept;
}

/// C_v of one end point: σ_perp normal to the line, σ_along along it.
Eigen::Matrix2d endpoint_covariance(const Eigen::Vector2d& t, const LineConfig& c) {
  const Eigen::Vector2d n(-t.y(), t.x());
  return c.endpoint_sigma * c.endpoint_sigma * t * t.transpose() +
         c.pixel_sigma * c.pixel_sigma * n * n.transpose();
}

/// The eq. 18 measurement of an undistorted segment (see the header).
Measurement to_measurement(Segment s, const camera::CameraModel& cam, const LineConfig& c) {
  const double f = cam.focal();
  auto centred = [&](const Eigen::Vector2d& p) {
    return Eigen::Vector2d((p.x() - cam.cx) * f / cam.fx, (p.y() - cam.cy) * f / cam.fy);
  };
  Eigen::Vector2d start = centred(s.a), end = centred(s.b);
  if (std::make_pair(end.x(), end.y()) < std::make_pair(start.x(), start.y())) {
    std::swap(start, end);
  }
  Measurement m;
  m.kind = kMeasurementKind;
  m.v.resize(5);
  m.v << start, end, f;  // eq. 18: s = (v0, v1, v4), e = (v2, v3, v4) in the camera frame
  const Eigen::Matrix2d C_end = endpoint_covariance((end - start).normalized(), c);
  m.C_v = Eigen::MatrixXd::Zero(5, 5);
  m.C_v.block<2, 2>(0, 0) = C_end;
  m.C_v.block<2, 2>(2, 2) = C_end;
  m.C_v(4, 4) = c.focal_sigma * c.focal_sigma;
  return m;
}

/// Undistorted edge points, also drawn (rounded) into an image for the Hough
/// transform, with the index of the point at each drawn pixel. The image
/// covers the whole undistorted field of view: a point p is drawn at the
/// pixel p − origin (barrel distortion makes the undistorted view larger).
class EdgePoints {
 public:
  void reset(const cv::Rect& undistorted_bounds) {
    origin_ = undistorted_bounds.tl();
    image_ = cv::Mat::zeros(undistorted_bounds.size(), CV_8UC1);
    index_ = cv::Mat(undistorted_bounds.size(), CV_32SC1);
    drawn_.clear();
    points_.clear();
  }
  void clear() {
    for (const cv::Point& p : drawn_) image_.at<std::uint8_t>(p) = 0;
    drawn_.clear();
    points_.clear();
  }
  void add(const cv::Point2f& p) {
    const cv::Point pixel = to_pixel(p.x, p.y);
    if (!inside(pixel)) return;
    if (image_.at<std::uint8_t>(pixel) == 0) drawn_.push_back(pixel);
    image_.at<std::uint8_t>(pixel) = 255;
    index_.at<int>(pixel) = static_cast<int>(points_.size());
    points_.push_back(p);
  }
  /// The drawn image (its pixel (0, 0) is the undistorted position `origin()`).
  const cv::Mat& image() const { return image_; }
  Eigen::Vector2d origin() const { return {origin_.x, origin_.y}; }
  /// Index of the point drawn at the undistorted position q, or -1.
  int at(const Eigen::Vector2d& q) const {
    const cv::Point pixel = to_pixel(q.x(), q.y());
    return inside(pixel) && image_.at<std::uint8_t>(pixel) != 0 ? index_.at<int>(pixel) : -1;
  }
  const cv::Point2f& point(int i) const { return points_[static_cast<std::size_t>(i)]; }

 private:
  cv::Point to_pixel(double x, double y) const {
    return {cvRound(x - origin_.x), cvRound(y - origin_.y)};
  }
  bool inside(const cv::Point& p) const {
    return p.x >= 0 && p.y >= 0 && p.x < image_.cols && p.y < image_.rows;
  }

  cv::Point origin_;
  cv::Mat image_, index_;
  std::vector<cv::Point> drawn_;
  std::vector<cv::Point2f> points_;
};

/// The edge points near the segment: along its major axis (x for a flat
/// segment, y for a steep one), from `band` px before to `band` px after it,
/// the pixels within `band` px of the line along the minor axis (each pixel
/// once, so no point twice).
std::vector<Eigen::Vector2d> points_near(const Segment& s, const EdgePoints& edges, int band) {
  const Eigen::Vector2d d = s.b - s.a;
  const int major = std::abs(d.x()) >= std::abs(d.y()) ? 0 : 1;
  const int minor = 1 - major;
  const double slope = d[minor] / d[major];
  const int first = cvFloor(std::min(s.a[major], s.b[major])) - band;
  const int last = cvCeil(std::max(s.a[major], s.b[major])) + band;
  std::vector<Eigen::Vector2d> points;
  Eigen::Vector2d q;
  for (int m = first; m <= last; ++m) {
    const int centre = cvRound(s.a[minor] + (m - s.a[major]) * slope);
    q[major] = m;
    for (int k = centre - band; k <= centre + band; ++k) {
      q[minor] = k;
      const int i = edges.at(q);
      if (i >= 0) points.emplace_back(edges.point(i).x, edges.point(i).y);
    }
  }
  return points;
}

/// Total-least-squares line through the points: the segment between the
/// extreme projections. Empty when there are fewer than 2 points.
std::optional<Segment> fit_segment(const std::vector<Eigen::Vector2d>& points) {
  if (points.size() < 2) return std::nullopt;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const Eigen::Vector2d& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
  for (const Eigen::Vector2d& p : points) scatter += (p - mean) * (p - mean).transpose();
  // Major axis of the scatter matrix.
  const double angle = 0.5 * std::atan2(2.0 * scatter(0, 1), scatter(0, 0) - scatter(1, 1));
  const Eigen::Vector2d t(std::cos(angle), std::sin(angle));
  double lo = 0.0, hi = 0.0;
  for (const Eigen::Vector2d& p : points) {
    lo = std::min(lo, t.dot(p - mean));
    hi = std::max(hi, t.dot(p - mean));
  }
  return Segment{mean + lo * t, mean + hi * t, false};
}

/// Refits a Hough segment to the undistorted edge points around it (sub-pixel
/// position and direction, true extent); twice, the second time with the
/// points within `inlier_distance` of the first fit.
std::optional<Segment> refine(const Segment& rough, const EdgePoints& edges, int band,
                              double inlier_distance, std::size_t min_points) {
  std::vector<Eigen::Vector2d> points = points_near(rough, edges, band);
  std::optional<Segment> fit = fit_segment(points);
  if (!fit) return std::nullopt;
  const Eigen::Vector2d t = fit->direction();
  const Eigen::Vector2d n(-t.y(), t.x());
  std::erase_if(points, [&](const Eigen::Vector2d& p) {
    return std::abs(n.dot(p - fit->a)) > inlier_distance;
  });
  if (points.size() < min_points) return std::nullopt;
  return fit_segment(points);
}

double positive(const Params& p, const char* name) {
  const double value = p.get_double(name);
  if (!(value > 0.0)) {
    throw std::invalid_argument(std::string("ceiling_lines: parameter '") + name +
                                "' must be > 0");
  }
  return value;
}

}  // namespace

/// Per-camera tables and reused buffers.
struct CeilingLineExtractor::Cache {
  Eigen::RowVectorXd camera_row;  ///< the intrinsics the tables were built for
  /// For every pixel of the (distorted) image: its undistorted position (px).
  std::vector<cv::Point2f> undistorted_of;
  int width = 0, height = 0;  ///< image size of the tables
  cv::Mat dx, dy;             ///< Sobel derivatives of the (distorted) image
  cv::Mat edges;              ///< Canny edges of the distorted image
  EdgePoints points;          ///< the edge points, undistorted
  std::vector<cv::Vec4i> hough;
  std::vector<int> magnitude_histogram, derivative_histogram;  ///< relative thresholds

  void prepare(const camera::CameraModel& cam) {
    const Eigen::RowVectorXd row = camera::reading_row(cam);
    if (row.size() == camera_row.size() && row == camera_row) return;
    undistorted_of.resize(static_cast<std::size_t>(cam.width * cam.height));
    cv::Point2f lo(1e9f, 1e9f), hi(-1e9f, -1e9f);
    for (int v = 0; v < cam.height; ++v) {
      for (int u = 0; u < cam.width; ++u) {
        const Eigen::Vector2d xy = cam.normalised_from_pixel({u, v});
        const cv::Point2f p(static_cast<float>(cam.fx * xy.x() + cam.cx),
                            static_cast<float>(cam.fy * xy.y() + cam.cy));
        undistorted_of[static_cast<std::size_t>(v * cam.width + u)] = p;
        lo = {std::min(lo.x, p.x), std::min(lo.y, p.y)};
        hi = {std::max(hi.x, p.x), std::max(hi.y, p.y)};
      }
    }
    const cv::Point origin(cvFloor(lo.x) - 1, cvFloor(lo.y) - 1);
    points.reset(cv::Rect(origin, cv::Point(cvCeil(hi.x) + 2, cvCeil(hi.y) + 2)));
    width = cam.width;
    height = cam.height;
    camera_row = row;
  }

  /// Canny edges of the (distorted) image, located to sub-pixel accuracy and
  /// undistorted into `points`; the thresholds used go to `stats`.
  void find_edge_points(const cv::Mat& grey, const LineConfig& c, CeilingLineExtractor::ImageStatistics& stats) {
    cv::Sobel(grey, dx, CV_16S, 1, 0, 3);
    cv::Sobel(grey, dy, CV_16S, 0, 1, 3);
    double scale = 1.0;
    if (c.mode == ThresholdMode::Relative) {
      measure_gradients(stats);
      // The header's s = min(1, E / reference_edge), kept above the noise floor.
      const double floor = c.min_threshold_sigma * stats.noise_sigma / c.canny_high;
      scale = std::min(1.0, std::max(stats.edge_contrast / c.reference_edge, floor));
    }
    stats.canny_low = scale * c.canny_low;
    stats.canny_high = scale * c.canny_high;
    cv::Canny(dx, dy, edges, stats.canny_low, stats.canny_high);
    undistort_edges();
  }

  /// The image's edge contrast E (99.9th percentile of |dx| + |dy|, Canny's
  /// magnitude) and the σ of the Sobel derivative's noise (1.4826 · median
  /// |dx|), both read off histograms: O(pixels), no sorting.
  void measure_gradients(CeilingLineExtractor::ImageStatistics& stats) {
    constexpr int kMaxMagnitude = 2 * 4 * 255;  // |dx| + |dy| of the 3×3 Sobel on 8-bit grey
    magnitude_histogram.assign(kMaxMagnitude + 1, 0);
    derivative_histogram.assign(kMaxMagnitude / 2 + 1, 0);
    for (int v = 1; v + 1 < dx.rows; ++v) {
      const std::int16_t* gx = dx.ptr<std::int16_t>(v);
      const std::int16_t* gy = dy.ptr<std::int16_t>(v);
      for (int u = 1; u + 1 < dx.cols; ++u) {
        ++magnitude_histogram[static_cast<std::size_t>(std::abs(gx[u]) + std::abs(gy[u]))];
        ++derivative_histogram[static_cast<std::size_t>(std::abs(gx[u]))];
      }
    }
    stats.edge_contrast = quantile(magnitude_histogram, 0.999);
    stats.noise_sigma = 1.4826 * quantile(derivative_histogram, 0.5);
  }

  /// The value below which the fraction q of a histogram's counts lie (its
  /// bins are the integer values).
  static double quantile(const std::vector<int>& histogram, double q) {
    std::int64_t total = 0;
    for (int count : histogram) total += count;
    std::int64_t seen = 0;
    for (std::size_t b = 0; b < histogram.size(); ++b) {
      seen += histogram[b];
      if (static_cast<double>(seen) >= q * static_cast<double>(total)) return static_cast<double>(b);
    }
    return static_cast<double>(histogram.size() - 1);
  }

  /// Hough segments of the undistorted edge points, each refitted to them.
  std::vector<Segment> refined_hough_segments(const LineConfig& c) {
    cv::HoughLinesP(points.image(), hough, 1.0, c.hough_theta, c.hough_threshold, c.min_length,
                    c.max_gap);
    const Eigen::Vector2d origin = points.origin();
    std::vector<Segment> segments;
    for (const cv::Vec4i& h : hough) {
      const Segment rough{origin + Eigen::Vector2d(h[0], h[1]),
                          origin + Eigen::Vector2d(h[2], h[3]), false};
      const auto fine = refine(rough, points, kBand, kInlierDistance, kMinPoints);
      if (fine && fine->length() >= c.min_length) segments.push_back(*fine);
    }
    return segments;
  }

  /// Moves every edge pixel to its sub-pixel, undistorted position.
  void undistort_edges() {
    points.clear();
    for (int v = 1; v + 1 < edges.rows; ++v) {
      const std::uint8_t* row = edges.ptr<std::uint8_t>(v);
      for (int u = 1; u + 1 < edges.cols; ++u) {
        if (row[u] != 0) points.add(undistorted_at(subpixel_edge(u, v)));
      }
    }
  }

  /// The edge's position across itself to sub-pixel accuracy: the peak of a
  /// parabola through the gradient magnitudes at the pixel and its two
  /// neighbours along the gradient (quantised to 8 directions, as Canny's
  /// non-maximum suppression).
  cv::Point2f subpixel_edge(int u, int v) const {
    const int gx = dx.at<std::int16_t>(v, u), gy = dy.at<std::int16_t>(v, u);
    cv::Point step(1, 0);
    if (std::abs(gy) * 5 > std::abs(gx) * 12) {
      step = {0, 1};  // gradient within 22.5° of vertical
    } else if (std::abs(gx) * 5 <= std::abs(gy) * 12) {
      step = {1, (gx > 0) == (gy > 0) ? 1 : -1};  // diagonal
    }
    const cv::Point p(u, v);
    const double before = magnitude(p - step), here = magnitude(p), after = magnitude(p + step);
    const double curvature = before - 2.0 * here + after;
    const double offset =
        curvature < 0.0 ? std::clamp(0.5 * (before - after) / curvature, -0.5, 0.5) : 0.0;
    return {static_cast<float>(u + offset * step.x), static_cast<float>(v + offset * step.y)};
  }

  double magnitude(const cv::Point& p) const {
    return std::abs(dx.at<std::int16_t>(p)) + std::abs(dy.at<std::int16_t>(p));
  }

  /// Undistorted position of a (sub-pixel) image position: bilinear in the table.
  cv::Point2f undistorted_at(const cv::Point2f& p) const {
    const int u = std::clamp(static_cast<int>(p.x), 0, width - 2);
    const int v = std::clamp(static_cast<int>(p.y), 0, height - 2);
    const float fu = p.x - static_cast<float>(u), fv = p.y - static_cast<float>(v);
    auto at = [&](int du, int dv) {
      return undistorted_of[static_cast<std::size_t>((v + dv) * width + u + du)];
    };
    return (1 - fv) * ((1 - fu) * at(0, 0) + fu * at(1, 0)) +
           fv * ((1 - fu) * at(0, 1) + fu * at(1, 1));
  }
};

std::vector<ParamSpec> CeilingLineExtractor::param_specs() {
  const LineConfig d;
  return {
      param_string("threshold_mode", "relative",
                   "relative: canny_low/high scaled down by the image's edge contrast (survives darker exposure "
                   "and blur); absolute: canny_low/high as they are"),
      param_double("canny_low", d.canny_low, "Canny lower hysteresis threshold (Sobel |dx|+|dy|)", 0.0),
      param_double("canny_high", d.canny_high, "Canny upper hysteresis threshold (Sobel |dx|+|dy|)", 0.0),
      param_double("reference_edge", d.reference_edge,
                   "relative mode: edge contrast (99.9th percentile of the gradient magnitude) of a well-exposed "
                   "sharp image, at which canny_low/high apply unscaled",
                   1.0),
      param_double("min_threshold_sigma", d.min_threshold_sigma,
                   "relative mode: canny_high is kept at least this many sigmas of the image's Sobel noise", 0.0),
      param_int("hough_threshold", d.hough_threshold, "Hough accumulator votes for a line", 1),
      param_double("hough_theta_deg", d.hough_theta / kDegree,
                   "Hough angle resolution (deg); segments are refitted afterwards", 0.1, 10.0),
      param_double("min_length_px", d.min_length, "shortest segment kept (px)", 1.0),
      param_double("max_gap_px", d.max_gap, "largest gap bridged along a segment (px)", 0.0),
      param_int("max_lines", d.max_lines, "at most this many (longest) segments per image", 1),
      param_double("merge_angle_deg", d.merge_angle / kDegree,
                   "segments within this angle and merge_distance_px are merged (deg)", 0.0, 90.0),
      param_double("merge_distance_px", d.merge_distance,
                   "segments within this normal distance and merge_angle_deg are merged (px)", 0.0),
      param_double("pixel_sigma", d.pixel_sigma, "end-point std normal to the line (px), > 0", 0.0),
      param_double("endpoint_sigma", d.endpoint_sigma, "end-point std along the line (px), > 0",
                   0.0),
      param_double("focal_sigma", d.focal_sigma, "std of the focal length v4 (px), > 0", 0.0),
  };
}

CeilingLineExtractor::CeilingLineExtractor(const LineConfig& config)
    : config_(config),
      cache_(std::make_unique<Cache>()),
      scene_files_(std::make_unique<ceiling_render::SceneImageFiles>()) {}

CeilingLineExtractor::CeilingLineExtractor(const PluginArgs& args)
    : CeilingLineExtractor([&] {
        const Params& p = args.params;
        LineConfig c;
        const std::string mode = p.get_string("threshold_mode");
        if (mode == "relative") c.mode = ThresholdMode::Relative;
        else if (mode == "absolute") c.mode = ThresholdMode::Absolute;
        else
          throw std::invalid_argument("ceiling_lines: threshold_mode must be 'relative' or 'absolute', not '" +
                                      mode + "'");
        c.canny_low = p.get_double("canny_low");
        c.reference_edge = p.get_double("reference_edge");
        c.min_threshold_sigma = p.get_double("min_threshold_sigma");
        c.canny_high = p.get_double("canny_high");
        c.hough_threshold = static_cast<int>(p.get_int("hough_threshold"));
        c.hough_theta = p.get_double("hough_theta_deg") * kDegree;
        c.min_length = p.get_double("min_length_px");
        c.max_gap = p.get_double("max_gap_px");
        c.max_lines = static_cast<int>(p.get_int("max_lines"));
        c.merge_angle = p.get_double("merge_angle_deg") * kDegree;
        c.merge_distance = p.get_double("merge_distance_px");
        c.pixel_sigma = positive(p, "pixel_sigma");
        c.endpoint_sigma = positive(p, "endpoint_sigma");
        c.focal_sigma = positive(p, "focal_sigma");
        return c;
      }()) {}

CeilingLineExtractor::~CeilingLineExtractor() = default;

std::optional<SampleScene> CeilingLineExtractor::sample_scene(std::uint64_t seed) const {
  return ceiling_render::panel_scene(seed, *scene_files_);
}

void CeilingLineExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  const camera::CameraModel cam = camera::camera_from_reading(reading);
  const cv::Mat grey = camera::read_grey(reading, cam);
  extract_image({grey.cols, grey.rows, grey.data, grey.step}, cam, out);
}

void CeilingLineExtractor::extract_image(const camera::GreyView& image,
                                         const camera::CameraModel& cam,
                                         std::vector<Measurement>& out) {
  Cache& k = *cache_;
  k.prepare(cam);
  k.find_edge_points(camera::as_mat(image), config_, stats_);
  std::vector<Segment> lines = merge_collinear(k.refined_hough_segments(config_), config_);
  for (Segment& line : lines) {  // a merged segment is refitted over its whole extent
    if (!line.merged) continue;
    if (const auto fine = refine(line, k.points, kBand, kInlierDistance, kMinPoints)) line = *fine;
  }
  if (lines.size() > static_cast<std::size_t>(config_.max_lines)) {
    lines.resize(static_cast<std::size_t>(config_.max_lines));  // sorted longest first
  }
  for (const Segment& s : lines) out.push_back(to_measurement(s, cam, config_));
}

}  // namespace mspace::ceiling_lines
