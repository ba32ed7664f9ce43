// lamps.hpp — the `lamps` extractor: bright, compact blobs in an
// upward-looking camera's image (ceiling lamps: round, square or a little
// oblong) become bearing vectors.
//
// Input: a camera SensorReading of the `image_sequence` source (`file` = the
// image, `values` = the intrinsics row of camera_model.hpp).
//
// Pipeline (OpenCV, in the .cpp). The lamp mask comes from one of two modes:
//
//  * `threshold_mode: relative` (the default) — thresholds relative to the
//    image, so that another camera, exposure, lamp or building does not lose
//    the lamps. The image is smoothed (Gaussian, `smoothing_sigma_px`); its
//    pixel noise σ_n is estimated from the median absolute difference between
//    image and smoothed image (scaled for the Gaussian so that it is unbiased
//    for white noise); d is its darkest level (1st percentile) and p its
//    brightest smoothed pixel. A lamp needs a contrast C over its own
//    surroundings of at least `min_contrast_sigma`·σ (σ the smoothed image's
//    noise) and `min_contrast_grey`. Candidates are the blobs above a ladder
//    of levels from p down to d, at most C/2 apart (at most 16 levels), from
//    the top down — no single level relative to the frame finds every lamp
//    when the brightest thing in view is not a lamp, lamps differ in
//    brightness or vignetting darkens some below the middle of the ceiling.
//    Each candidate is re-thresholded locally at half its own peak (the 90th
//    percentile of its pixels, not the noise's maximum) over its own
//    surroundings (the median of a window around it): the half-maximum
//    contour of a blurred lamp is its true edge, so the centroid depends
//    neither on exposure nor on a halo, a fixture ring or a neighbour; a
//    blob without contrast C over its surroundings is dropped. A candidate
//    whose brightest pixel lies in a lamp already found is that lamp again.
//  * `threshold_mode: absolute` — the first version: the raw image above the
//    grey level `threshold`.
//
// The lamp's contour (its outer contour) must
//   - have an area within [min_area_px, the smaller of max_area_px (0: no
//     absolute limit) and max_area_fraction × the image's area],
//   - be compact: minor/major axis ratio of the second moments ≥
//     min_roundness (0.5: lamps up to 2:1 pass; a 4:1 light panel, 0.25, and
//     lines do not),
//   - be convex: solidity, area / area of the convex hull, ≥ min_solidity
//     (discs, squares and rectangles ≈ 1; two lamps run together, a lamp
//     merged with a panel, ragged noise blobs less),
//   - optionally, circularity 4π·area/perimeter² ≥ min_circularity (off by
//     default: disc 1, square π/4 ≈ 0.785, 2:1 rectangle 0.70, and far less
//     on the pixel staircase of a noisy contour; the first version's 0.8
//     rejected square lamps),
//   - not touch the image border (a cut-off lamp has a biased centre),
// and, in the relative mode, be a lamp rather than a bright patch:
//   - isolated: little else in its window above its half maximum (a patch
//     of plain ceiling framed by tile lines has more ceiling beside it),
//   - an edge all round: the gradient along its contour, in its lowest
//     tenth, at least 0.35 of its median, and its mean in each eighth of the
//     contour at least 0.35 of the median eighth's (the part of a panel that
//     vignetting lifts above a level is bounded on one side by a shallow
//     fall-off).
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

namespace mspace::ceiling_render {
class SceneImageFiles;
}

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
  double max_area = 0.0;          ///< px² (0: no absolute limit)
  double max_area_fraction = 0.1;  ///< largest lamp as a fraction of the image's area
  double min_roundness = 0.5;     ///< minor / major axis
  double min_solidity = 0.85;     ///< area / convex hull area
  double min_circularity = 0.0;   ///< 4π·area / perimeter² (0: no test)
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

  /// A noise-free image of the ceiling renderer from the default camera:
  /// a few round lamps on a flat ceiling; the true shapes are their centres (Points) (ceiling_render/ceiling_scene.hpp). The image is a
  /// temporary file that this extractor deletes when it is destroyed.
  std::optional<SampleScene> sample_scene(std::uint64_t seed) const override;

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
    double dark = 0.0;         ///< 1st percentile of the smoothed image
    double peak = 0.0;         ///< brightest smoothed pixel
  };
  const ImageStatistics& last_statistics() const { return stats_; }

 private:
  LampConfig config_;
  std::unique_ptr<Buffers> buffers_;
  ImageStatistics stats_;
  /// The sample scenes' image files, deleted with this extractor. A pointer,
  /// so that the const sample_scene() can add to it.
  std::unique_ptr<ceiling_render::SceneImageFiles> scene_files_;
};

/// The bearing measurement of a blob centroid at the distorted pixel uv.
Measurement bearing_measurement(const Eigen::Vector2d& uv, const camera::CameraModel& camera,
                                double pixel_sigma);

}  // namespace mspace::lamps
