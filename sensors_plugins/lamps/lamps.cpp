// lamps.cpp — see lamps.hpp.
#include "lamps.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <opencv2/imgproc.hpp>

#include "ceiling_render/ceiling_scene.hpp"
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

/// The largest lamp area (px²) in an image of `image_area` px²: the tighter
/// of the absolute limit (0: none) and the fraction of the image.
double area_limit(const LampConfig& c, double image_area) {
  const double relative = c.max_area_fraction * image_area;
  return c.max_area > 0.0 ? std::min(c.max_area, relative) : relative;
}

/// Minor / major axis of the blob's second moments (1: a disc or a square,
/// 0.25: a 4:1 light panel). The moments' eigenvalues are the squared half
/// axes / 4, so the axis ratio is the square root of their ratio.
double axis_ratio(const cv::Moments& m) {
  const double mean = 0.5 * (m.mu20 + m.mu02);
  const double spread = std::hypot(0.5 * (m.mu20 - m.mu02), m.mu11);
  const double minor = mean - spread, major = mean + spread;
  return major > 0.0 ? std::sqrt(std::max(minor, 0.0) / major) : 0.0;
}

/// Whether a blob passes the shape tests of the header: an area within the
/// limits, compact (axis ratio), convex (solidity: area over the area of its
/// convex hull — 1 for a disc, square or rectangle, less for two lamps run
/// together, a lamp merged with a panel, or a ragged noise blob) and not
/// too ragged (circularity).
bool is_lamp_shape(const std::vector<cv::Point>& contour, const cv::Moments& m, const LampConfig& c,
                   double image_area, std::vector<cv::Point>& hull) {
  const double area = m.m00;
  if (area < c.min_area || area > area_limit(c, image_area)) return false;
  if (axis_ratio(m) < c.min_roundness) return false;
  cv::convexHull(contour, hull);
  const double hull_area = cv::contourArea(hull);
  if (!(hull_area > 0.0) || area / hull_area < c.min_solidity) return false;
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
  cv::Mat1f grey, smooth;
  cv::Mat local_mask, lamp_mask;
  std::vector<std::vector<cv::Point>> contours, local_contours;
  std::vector<cv::Point> hull;
  std::vector<float> values;
  std::vector<int> histogram;
};

namespace {

/// The median of `values` (reordered).
double median_of(std::vector<float>& values) {
  if (values.empty()) return 0.0;
  const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  return *mid;
}

/// The centre of the bin that holds the q-quantile of a histogram (bin units).
double histogram_quantile(const std::vector<int>& histogram, double q) {
  std::int64_t total = 0;
  for (int count : histogram) total += count;
  std::int64_t seen = 0;
  for (std::size_t b = 0; b < histogram.size(); ++b) {
    seen += histogram[b];
    if (static_cast<double>(seen) >= q * static_cast<double>(total)) return static_cast<double>(b) + 0.5;
  }
  return 0.0;
}

/// For white noise of unit σ and G the separable Gaussian of `sigma` px: the
/// σ of the residual I − G∗I, √(1 − 2 g₀ + Σ g²), and the σ of the smoothed
/// image G∗I, √(Σ g²) — with g₀ the 2-D kernel's centre weight and Σ g² its
/// sum of squares, both the squares of the 1-D kernel's.
struct NoiseFactors {
  double residual = 1.0;
  double smoothed = 1.0;
};
NoiseFactors noise_factors(double sigma, int ksize) {
  const cv::Mat k = cv::getGaussianKernel(ksize, sigma, CV_64F);
  const double centre = k.at<double>(ksize / 2);
  const double sum_sq = k.dot(k);
  return {std::sqrt(1.0 - 2.0 * centre * centre + sum_sq * sum_sq), sum_sq};
}

/// The contrast (grey levels) a lamp needs over its surroundings.
double min_contrast(const LampConfig& c, double smoothed_noise_sigma) {
  return std::max(c.min_contrast_sigma * smoothed_noise_sigma, c.min_contrast_grey);
}

/// Relative mode, first pass: smooths the image and estimates its noise,
/// background, darkest level and peak; false when nothing in the frame stands
/// out enough to be a lamp.
bool relative_statistics(LampExtractor::Buffers& k, const LampConfig& c, const camera::GreyView& image,
                         LampExtractor::ImageStatistics& stats) {
  camera::as_mat(image).convertTo(k.grey, CV_32F);
  const int ksize = 2 * static_cast<int>(std::ceil(3.0 * c.smoothing_sigma)) + 1;
  cv::GaussianBlur(k.grey, k.smooth, cv::Size(ksize, ksize), c.smoothing_sigma, c.smoothing_sigma,
                   cv::BORDER_REPLICATE);
  // Noise from the median absolute residual (1.4826·MAD is σ for a Gaussian);
  // edges and texture are few pixels and do not move the median. Both medians
  // are read off histograms (1/16 grey level bins): O(pixels), no sorting.
  constexpr double kBinsPerGrey = 16.0;
  constexpr int kResidualBins = 64 * 16;  // residuals up to 64 grey levels; larger ones land in the last bin
  constexpr int kGreyBins = 256 * 16;
  k.histogram.assign(kResidualBins, 0);
  for (int v = 0; v < k.grey.rows; ++v) {
    const float* g = k.grey.ptr<float>(v);
    const float* s = k.smooth.ptr<float>(v);
    for (int u = 0; u < k.grey.cols; ++u)
      ++k.histogram[static_cast<std::size_t>(std::min(kResidualBins - 1, static_cast<int>(std::abs(g[u] - s[u]) * kBinsPerGrey)))];
  }
  const NoiseFactors factors = noise_factors(c.smoothing_sigma, ksize);
  stats.noise_sigma = 1.4826 * histogram_quantile(k.histogram, 0.5) / kBinsPerGrey / factors.residual;
  // Peak and background are read off the smoothed image: its noise decides
  // whether a peak stands out.
  stats.smoothed_noise_sigma = stats.noise_sigma * factors.smoothed;
  k.histogram.assign(kGreyBins, 0);
  for (int v = 0; v < k.smooth.rows; ++v) {
    const float* s = k.smooth.ptr<float>(v);
    for (int u = 0; u < k.smooth.cols; ++u)
      ++k.histogram[static_cast<std::size_t>(std::clamp(static_cast<int>(s[u] * kBinsPerGrey), 0, kGreyBins - 1))];
  }
  stats.background = histogram_quantile(k.histogram, 0.5) / kBinsPerGrey;
  stats.dark = histogram_quantile(k.histogram, 0.01) / kBinsPerGrey;
  double peak = 0.0;
  cv::minMaxLoc(k.smooth, nullptr, &peak);
  stats.peak = peak;
  return stats.peak - stats.dark >= min_contrast(c, stats.smoothed_noise_sigma);
}

/// What may lie above a lamp's half maximum in its window besides the lamp,
/// as a fraction of the lamp's area (noise specks; the edge of a panel).
constexpr double kMaxBrightSurroundings = 0.25;

/// Whether the contour is an edge all round. A lamp's half-maximum contour
/// is its blurred rim, about equally steep all round (a halo makes it less
/// steep, but all round); the part of a flat bright surface (a light panel,
/// the ceiling) that a smooth fall-off (vignetting) lifts above a level is
/// bounded on one side by that fall-off, far less steep than its real edges.
/// Two tests on the gradient of the smoothed image at the contour's pixels,
/// both against kMinEdgeUniformity: its lowest tenth against its median, and
/// its mean in each eighth of the contour around `centre` against the median
/// eighth's (sector means: a shallow side that pixel noise hides from the
/// first test).
constexpr double kMinEdgeUniformity = 0.35;
bool sharp_all_round(const cv::Mat1f& patch, const std::vector<cv::Point>& contour, const Eigen::Vector2d& centre,
                     std::vector<float>& gradients) {
  constexpr int kSectors = 8;
  std::array<double, kSectors> sum{};
  std::array<int, kSectors> count{};
  gradients.clear();
  for (const cv::Point& q : contour) {
    if (q.x <= 0 || q.y <= 0 || q.x >= patch.cols - 1 || q.y >= patch.rows - 1) continue;
    const float gradient = std::hypot(0.5F * (patch(q.y, q.x + 1) - patch(q.y, q.x - 1)),
                                      0.5F * (patch(q.y + 1, q.x) - patch(q.y - 1, q.x)));
    gradients.push_back(gradient);
    const double angle = std::atan2(q.y - centre.y(), q.x - centre.x()) + std::numbers::pi;  // 0 … 2π
    const auto sector = static_cast<std::size_t>(
        std::min(kSectors - 1, static_cast<int>(angle / (2.0 * std::numbers::pi) * kSectors)));
    sum[sector] += gradient;
    ++count[sector];
  }
  if (gradients.size() >= 8) {  // fewer: too small a contour to tell
    const auto tenth = gradients.begin() + static_cast<std::ptrdiff_t>(gradients.size() / 10);
    std::nth_element(gradients.begin(), tenth, gradients.end());
    const double low = *tenth;
    if (low < kMinEdgeUniformity * median_of(gradients)) return false;
  }
  std::vector<double> means;
  for (std::size_t i = 0; i < kSectors; ++i)
    if (count[i] > 0) means.push_back(sum[i] / count[i]);
  if (means.size() < kSectors) return true;  // a contour of a few pixels: too small to tell
  std::sort(means.begin(), means.end());
  return means.front() >= kMinEdgeUniformity * means[means.size() / 2];
}

/// Pixels of a candidate's window that its surroundings' median is taken from (about).
constexpr double kMedianSamples = 1024.0;

/// The brightness of a candidate blob: the 90th percentile of the smoothed
/// image over its pixels (those of its box above `level`), not its brightest
/// pixel. On a large flat blob — a stretch of ceiling that vignetting lifts a
/// little above its neighbours — the brightest pixel is the noise's maximum
/// over thousands of pixels, 3–4σ above the blob's level, which is enough to
/// pass a contrast test; on a lamp the two hardly differ.
double robust_peak(LampExtractor::Buffers& k, const cv::Rect& box, double level) {
  k.values.clear();
  const cv::Mat1f blob = k.smooth(box);
  for (int v = 0; v < blob.rows; ++v)
    for (int u = 0; u < blob.cols; ++u)
      if (blob(v, u) > level) k.values.push_back(blob(v, u));
  if (k.values.empty()) return level;
  const auto at = k.values.begin() + static_cast<std::ptrdiff_t>(0.9 * static_cast<double>(k.values.size() - 1));
  std::nth_element(k.values.begin(), at, k.values.end());
  return *at;
}

/// A lamp found by the relative mode: its centroid (distorted pixel) and the
/// bounding box of its half-maximum contour.
struct FoundLamp {
  Eigen::Vector2d centroid;
  cv::Rect box;
};

/// Relative mode, second pass: the lamp around the candidate pixel `seed` at
/// the half maximum of its own `peak` (robust_peak) over its surroundings — the median of
/// the smoothed image in a window around the candidate blob `box` (the box's
/// size again on every side), outside the box. The window grows until the
/// lamp's contour lies inside it. False when the blob does not stand out of
/// its surroundings by the configured contrast, or is not a lamp: fails the
/// shape tests, is not isolated, or is not an edge all round. (With a window
/// half as wide the surroundings took in more of the lamp's blurred skirt:
/// bearings moved by less than 0.01° on average, yet two of the nine
/// lines + lamps runs of tests/ceiling_runs then missed their return targets.)
bool refine_locally(LampExtractor::Buffers& k, const LampConfig& c, double contrast_needed, const cv::Point& seed,
                    const cv::Rect& box, double peak, FoundLamp& lamp) {
  const cv::Rect image_rect(0, 0, k.smooth.cols, k.smooth.rows);
  const double image_area = image_rect.area();
  int margin = std::max(4, std::max(box.width, box.height));
  for (int attempt = 0; attempt < 4; ++attempt, margin *= 2) {
    const cv::Rect window = (box + cv::Size(2 * margin, 2 * margin) - cv::Point(margin, margin)) & image_rect;
    const cv::Mat1f patch = k.smooth(window);
    const cv::Point inside = seed - window.tl();
    // Surroundings: the median of the window outside the candidate's box,
    // from a grid of at most about kMedianSamples of its pixels (a median of
    // n samples is within ≈ 1.25σ/√n of the true one: 0.04σ of the ceiling's
    // spread for 1000; large candidates — bright stretches of ceiling at the
    // lower levels — would otherwise take most of the extractor's time).
    const int stride = std::max(1, static_cast<int>(std::sqrt(patch.total() / kMedianSamples)));
    k.values.clear();
    for (int v = stride / 2; v < patch.rows; v += stride)
      for (int u = stride / 2; u < patch.cols; u += stride)
        if (!box.contains(cv::Point(u, v) + window.tl())) k.values.push_back(patch(v, u));
    const double surroundings = median_of(k.values);
    const double contrast = peak - surroundings;
    if (contrast < contrast_needed) return false;
    cv::threshold(patch, k.local_mask, surroundings + 0.5 * contrast, 255, cv::THRESH_BINARY);
    k.local_mask.convertTo(k.local_mask, CV_8U);
    cv::findContours(k.local_mask, k.local_contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
    for (std::size_t i = 0; i < k.local_contours.size(); ++i) {
      const std::vector<cv::Point>& local = k.local_contours[i];
      if (cv::pointPolygonTest(local, cv::Point2f(static_cast<float>(inside.x), static_cast<float>(inside.y)),
                               false) < 0)
        continue;
      const cv::Rect local_box = cv::boundingRect(local) + window.tl();
      if (touches_border(local_box, k.smooth.cols, k.smooth.rows)) return false;
      const bool cut_by_window = (local_box & window) != local_box || local_box.x <= window.x ||
                                 local_box.y <= window.y || local_box.br().x >= window.br().x ||
                                 local_box.br().y >= window.br().y;
      if (cut_by_window) break;  // grow the window
      const cv::Moments m = cv::moments(local);
      if (!(m.m00 > 0.0) || !is_lamp_shape(local, m, c, image_area, k.hull)) return false;
      // Isolated: a lamp is brighter than everything around it, so little else
      // in the window is above its half maximum. A patch of plain ceiling
      // that only stands out of darker ceiling (vignetting) or walls, framed
      // by tile lines or a corner, has more of the same ceiling beside it.
      k.lamp_mask.create(k.local_mask.size(), CV_8U);
      k.lamp_mask.setTo(0);
      cv::drawContours(k.lamp_mask, k.local_contours, static_cast<int>(i), 255, cv::FILLED);
      const double lamp_pixels = cv::countNonZero(k.lamp_mask);
      const double other_pixels = cv::countNonZero(k.local_mask) - lamp_pixels;
      if (other_pixels > kMaxBrightSurroundings * lamp_pixels) return false;
      const Eigen::Vector2d centre(m.m10 / m.m00, m.m01 / m.m00);
      if (!sharp_all_round(patch, local, centre, k.values)) return false;
      lamp = {centre + Eigen::Vector2d(window.x, window.y), local_box};
      return true;
    }
  }
  return false;
}

/// The candidate levels of the relative mode: at most this many, evenly
/// spaced from the frame's darkest level (1st percentile) up to its peak.
/// The brightest thing in view need not be a lamp (a white panel, a window,
/// a lamp brighter than the others, the centre of a vignetted image), and a
/// dim lamp in a dark corner may be darker than the middle of the ceiling, so
/// no one level relative to the frame finds every lamp; but every lamp with
/// contrast C over its surroundings is a blob of its own at some level in the
/// upper part of its profile when the levels are at most C/2 apart. Each
/// candidate is then measured at its own half maximum (refine_locally).
constexpr int kMaxLevels = 16;

}  // namespace

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
      param_string("threshold_mode", "relative",
                   "relative: levels from the image's own darkest level, peak and noise, each lamp measured against "
                   "its own surroundings (survives "
                   "exposure changes); absolute: a fixed grey level `threshold`"),
      param_double("threshold", d.threshold,
                   "absolute mode: grey level (0-255) above which a pixel is lamp", 0.0, 255.0),
      param_double("smoothing_sigma_px", d.smoothing_sigma,
                   "relative mode: Gaussian smoothing before thresholding (px)", 0.3, 5.0),
      param_double("min_contrast_sigma", d.min_contrast_sigma,
                   "relative mode: a lamp's peak over its surroundings, in sigmas of the smoothed image's "
                   "noise (estimated from the image)",
                   0.0),
      param_double("min_contrast_grey", d.min_contrast_grey,
                   "relative mode: … and at least this many grey levels", 0.0, 255.0),
      param_double("min_area_px", d.min_area, "smallest lamp blob (px^2)", 0.0),
      param_double("max_area_px", d.max_area,
                   "largest lamp blob (px^2); 0: no absolute limit, max_area_fraction decides (the first "
                   "version's 6000 px^2 lost the lamps of cameras with more pixels)",
                   0.0),
      param_double("max_area_fraction", d.max_area_fraction,
                   "largest lamp blob as a fraction of the image's area (any resolution)", 0.0, 1.0),
      param_double("min_roundness", d.min_roundness,
                   "minor/major axis ratio of a lamp blob's second moments (0.5: lamps up to 2:1; a 4:1 "
                   "light panel has 0.25)",
                   0.0, 1.0),
      param_double("min_solidity", d.min_solidity,
                   "area / convex hull area of a lamp blob (discs, squares, rectangles ~1; lamps run "
                   "together or merged with a panel less)",
                   0.0, 1.0),
      param_double("min_circularity", d.min_circularity,
                   "4*pi*area/perimeter^2 of a lamp blob (circle 1, square 0.785, 2:1 rectangle 0.70, less "
                   "on the pixel staircase of a noisy contour); 0: no test (default); the first version's 0.8 "
                   "rejected square lamps",
                   0.0, 1.0),
      param_double("pixel_sigma", d.pixel_sigma, "std of a lamp centre (px), > 0", 0.0),
  };
}

LampExtractor::LampExtractor(const LampConfig& config)
    : config_(config),
      buffers_(std::make_unique<Buffers>()),
      scene_files_(std::make_unique<ceiling_render::SceneImageFiles>()) {}

LampExtractor::LampExtractor(const PluginArgs& args)
    : LampExtractor([&] {
        const Params& p = args.params;
        LampConfig c;
        const std::string mode = p.get_string("threshold_mode");
        if (mode == "relative") c.mode = ThresholdMode::Relative;
        else if (mode == "absolute") c.mode = ThresholdMode::Absolute;
        else
          throw std::invalid_argument("lamps: threshold_mode must be 'relative' or 'absolute', not '" + mode +
                                      "'");
        c.threshold = p.get_double("threshold");
        c.smoothing_sigma = p.get_double("smoothing_sigma_px");
        c.min_contrast_sigma = p.get_double("min_contrast_sigma");
        c.min_contrast_grey = p.get_double("min_contrast_grey");
        c.min_area = p.get_double("min_area_px");
        c.max_area = p.get_double("max_area_px");
        c.max_area_fraction = p.get_double("max_area_fraction");
        c.min_roundness = p.get_double("min_roundness");
        c.min_solidity = p.get_double("min_solidity");
        c.min_circularity = p.get_double("min_circularity");
        c.pixel_sigma = positive(p, "pixel_sigma");
        return c;
      }()) {}

LampExtractor::~LampExtractor() = default;

std::optional<SampleScene> LampExtractor::sample_scene(std::uint64_t seed) const {
  return ceiling_render::lamp_scene(seed, *scene_files_);
}

void LampExtractor::extract(const SensorReading& reading, std::vector<Measurement>& out) {
  const camera::CameraModel cam = camera::camera_from_reading(reading);
  const cv::Mat grey = camera::read_grey(reading, cam);
  extract_image({grey.cols, grey.rows, grey.data, grey.step}, cam, out);
}

void LampExtractor::extract_image(const camera::GreyView& image, const camera::CameraModel& cam,
                                  std::vector<Measurement>& out) {
  Buffers& k = *buffers_;
  if (config_.mode == ThresholdMode::Absolute) {
    cv::threshold(camera::as_mat(image), k.mask, config_.threshold, 255, cv::THRESH_BINARY);
    cv::findContours(k.mask, k.contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
    for (const std::vector<cv::Point>& contour : k.contours) {
      if (touches_border(cv::boundingRect(contour), image.width, image.height)) continue;
      const cv::Moments m = cv::moments(contour);
      if (!(m.m00 > 0.0) || !is_lamp_shape(contour, m, config_, static_cast<double>(image.width) * image.height, k.hull))
        continue;
      out.push_back(bearing_measurement({m.m10 / m.m00, m.m01 / m.m00}, cam, config_.pixel_sigma));
    }
    return;
  }
  if (!relative_statistics(k, config_, image, stats_)) return;
  const double contrast_needed = min_contrast(config_, stats_.smoothed_noise_sigma);
  const double image_area = static_cast<double>(image.width) * image.height;
  const double step = std::max(0.5 * contrast_needed, (stats_.peak - stats_.dark) / kMaxLevels);
  std::vector<FoundLamp> found;
  const auto inside_found = [&](const cv::Point& p) {
    return std::any_of(found.begin(), found.end(), [&](const FoundLamp& f) { return f.box.contains(p); });
  };
  // From the top down: a lamp is first met at a level where it is a blob of
  // its own, before its halo or a neighbour joins it at a lower one.
  for (double level = stats_.peak - 0.5 * step; level > stats_.dark; level -= step) {
    cv::compare(k.smooth, level, k.mask, cv::CMP_GT);  // 255 above the level, 8-bit
    cv::findContours(k.mask, k.contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
    for (const std::vector<cv::Point>& contour : k.contours) {
      const cv::Rect box = cv::boundingRect(contour);
      if (touches_border(box, image.width, image.height)) continue;
      // Cheap tests first: the blob's size, and that it is not elongated
      // (lines, panels) — loosely, as its halo or fixture may distort it at
      // this level; refine_locally applies the shape tests to the lamp itself.
      const cv::Moments m = cv::moments(contour);
      if (m.m00 < config_.min_area || m.m00 > 4.0 * area_limit(config_, image_area) ||
          axis_ratio(m) < 0.5 * config_.min_roundness)
        continue;
      // The candidate's brightest pixel seeds the local measurement; a blob
      // around a lamp found at a higher level is that lamp again.
      cv::Point seed;
      double peak = 0.0;
      cv::minMaxLoc(k.smooth(box), nullptr, &peak, nullptr, &seed);
      seed += box.tl();
      if (inside_found(seed) || peak - level < 0.25 * contrast_needed) continue;
      FoundLamp lamp;
      if (!refine_locally(k, config_, contrast_needed, seed, box, robust_peak(k, box, level), lamp)) continue;
      if (inside_found(cv::Point(static_cast<int>(std::lround(lamp.centroid.x())),
                                 static_cast<int>(std::lround(lamp.centroid.y())))))
        continue;
      found.push_back(lamp);
      out.push_back(bearing_measurement(lamp.centroid, cam, config_.pixel_sigma));
    }
  }
}

}  // namespace mspace::lamps
