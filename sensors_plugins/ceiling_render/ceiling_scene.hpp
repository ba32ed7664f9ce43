// ceiling_scene.hpp — the sample scenes of the ceiling-camera extractors
// (`lamps`, `ceiling_lines`) for the extractor ↔ feature contract check
// (`mspace check EXTRACTOR.so FEATURE.so`, Extractor::sample_scene,
// mspace/scene.hpp).
//
// A scene is one noise-free image of the ceiling renderer (ceiling_renderer.hpp)
// of a single flat ceiling — one region wider than the view, so no wall shows
// — with a few lamps or light panels placed from the seed, seen by the
// default camera (default_camera(): 320×240, f = 260 px, barrel distortion,
// level, 0.4 m above the floor) on a robot at a pose drawn from the seed.
// The reading is what the `image_sequence` source delivers: `values` = the
// camera's intrinsics row (camera_model.hpp), `file` = the image. The truth
// lists only what the extractor must find, in the map frame:
//   * lamp_scene: 2–4 round lamps (radius 0.08–0.12 m), each whole and at
//     least 8 pixels inside the image, as Points at their centres;
//   * panel_scene: 1–2 parallel light strips 0.3–0.6 m wide and longer than
//     the view, along the map's x or y axis, as the two Segments of their long
//     edges, each well inside the image over at least 1.2 m (120 px or more).
//     (Small panels whose four edges are all in view were tried first: the
//     extractor missed 6 % of their 50–110 px edges, so they were not shapes
//     it must find.)
// The ceiling is 1.9–2.5 m above the camera; objects stand 0.25 m or more
// apart, so no two lamps run together and no two strip edges come close.
// The image is noise-free (the renderer's lens blur, no pixel noise).
#pragma once

#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "mspace/extractor.hpp"

namespace mspace::ceiling_render {

struct GreyImage;

/// The image files of sample scenes. A camera reading names its image by path
/// (SensorReading::file), so a scene's image must be on disk: write() puts it
/// under a fresh unique name (mkstemps) in the system's temporary directory,
/// and the destructor deletes every file this object wrote. The extractor
/// that makes the scenes owns one, so a scene's reading can be read as long
/// as that extractor lives — the conformance suite extracts each scene with
/// the extractor that made it.
class SceneImageFiles {
 public:
  SceneImageFiles() = default;
  SceneImageFiles(const SceneImageFiles&) = delete;
  SceneImageFiles& operator=(const SceneImageFiles&) = delete;
  ~SceneImageFiles();

  /// Writes `image` as PNG and returns its path. Throws std::runtime_error
  /// naming the path when it cannot.
  std::string write(const GreyImage& image);

 private:
  std::mutex mutex_;
  std::vector<std::string> paths_;
};

/// A few lamps on a ceiling (see the file comment); the image is written to `files`.
SampleScene lamp_scene(std::uint64_t seed, SceneImageFiles& files);

/// A few light panels on a ceiling, their edges the true lines (see the file
/// comment); the image is written to `files`.
SampleScene panel_scene(std::uint64_t seed, SceneImageFiles& files);

}  // namespace mspace::ceiling_render
