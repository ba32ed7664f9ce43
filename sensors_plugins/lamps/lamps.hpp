// lamps.hpp — the `lamps` extractor: bright, roughly circular blobs in an
// upward-looking camera's image (round ceiling lamps) become bearing vectors.
//
// Input: a camera SensorReading of the `image_sequence` source (`file` = the
// image, `values` = the intrinsics row of camera_model.hpp).
//
// Pipeline (OpenCV, in the .cpp). The lamp mask comes from one of two modes:
//
//  * `threshold_mode: relative` (the default) — thresholds relative to the
//    image, so that auto exposure, a dimmer lamp or a noisier sensor do not
//    lose the lamps. The image is smoothed (Gaussian, `smoothing_sigma_px`);
//    its pixel noise σ_n is estimated from the median absolute difference
//    between image and smoothed image (scaled for the Gaussian so that it is
//    unbiased for white noise); the background level b is the median grey and
//    the peak p the brightest smoothed pixel. Without a contrast p − b of at
//    least `min_contrast_sigma`·σ_n (and `min_contrast_grey`) the frame has no
//    lamp. Otherwise the mask is the smoothed image above b + ½(p − b), and
//    each blob that passes the shape tests below is re-thresholded locally at
//    half its own peak over its own surroundings (the median of a ring
//    around it): the half-maximum contour of a blurred disc is its true edge,
//    so the centroid does not depend on exposure or on a neighbouring lamp;
//    a blob without `min_contrast_sigma`·σ_n over its surroundings is dropped.
//  * `threshold_mode: absolute` — the first version: the raw image above the
//    grey level `threshold`.
//
// Then outer contours, and blobs are kept that
//   - have an area within [min_area_px, max_area_px],
//   - are round: minor/major axis ratio of the second moments ≥ min_roundness
//     and circularity 4π·area/perimeter² ≥ min_circularity (a square has
//     π/4 ≈ 0.785 at most; elongated light panels fail the axis ratio),
//   - do not touch the image border (a cut-off lamp has a biased centre).
// The blob's centroid (distorted pixel) is undistorted with the camera model.
//
// Measurement (kind "bearing3d"): v = b, the unit vector from the camera
// towards the lamp centre in the camera frame (z = optical axis, x = image u,
// y = image v). C_v (3×3) is the first-order propagation of an isotropic
// centroid noise of `pixel_sigma` pixels through undistortion and
// normalisation; it has rank 2 (b stays a unit vector: no variance along b).
#pragma once

#include <memory>
#include <vector>

#include "image_sequence/camera_model.hpp"
#include "mspace/extractor.hpp"
#include "mspace/params.hpp"
#include "mspace/plugin.hpp"

namespace mspace::lamps {

inline constexpr const char* kMeasurementKind = "bearing3d";

enum class ThresholdMode { Relative, Absolute };

struct LampConfig {
  ThresholdMode mode = ThresholdMode::Relative;
  double threshold = 245.0;       ///< absolute mode: grey level of a lamp pixel (0–255)
  double smoothing_sigma = 1.0;   ///< relative mode: Gaussian smoothing (px)
  double min_contrast_sigma = 8.0;  ///< relative mode: lamp peak over its surroundings, in smoothed-noise σ
  double min_contrast_grey = 12.0;  ///< relative mode: … and at least this many grey levels
  double min_area = 12.0;         ///< px²
  double max_area = 6000.0;       ///< px²
  double min_roundness = 0.7;     ///< minor / major axis
  double min_circularity = 0.8;   ///< 4π·area / perimeter²
  double pixel_sigma = 0.5;       ///< std of the centroid (px)
};

class LampExtractor : public Extractor {
 public:
  static std::vector<ParamSpec> param_specs();
  explicit LampExtractor(const PluginArgs& args);
  explicit LampExtractor(const LampConfig& config);
  ~LampExtractor() override;

  /// Reads the image (grey) and extracts. Throws std::runtime_error naming the
  /// file when it cannot be read or its size differs from the intrinsics'.
  void extract(const SensorReading& reading, std::vector<Measurement>& out) override;

  /// The same on an image already in memory (benchmarks, tests).
  void extract_image(const camera::GreyView& image, const camera::CameraModel& camera,
                     std::vector<Measurement>& out);

  const LampConfig& config() const { return config_; }

  struct Buffers;  ///< reused OpenCV work buffers (defined in the .cpp)

  /// What the relative mode measured on the last image (tests, health reports).
  struct ImageStatistics {
    double noise_sigma = 0.0;  ///< estimated pixel noise σ_n (grey levels)
    double smoothed_noise_sigma = 0.0;  ///< σ of the smoothed image's noise
    double background = 0.0;   ///< median grey of the smoothed image
    double peak = 0.0;         ///< brightest smoothed pixel
  };
  const ImageStatistics& last_statistics() const { return stats_; }

 private:
  LampConfig config_;
  std::unique_ptr<Buffers> buffers_;
  ImageStatistics stats_;
};

/// The bearing measurement of a blob centroid at the distorted pixel uv.
Measurement bearing_measurement(const Eigen::Vector2d& uv, const camera::CameraModel& camera,
                                double pixel_sigma);

}  // namespace mspace::lamps
