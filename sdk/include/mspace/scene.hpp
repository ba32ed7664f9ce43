// mspace/scene.hpp — true geometry, the shared reference of the extractor ↔
// feature contract check (`mspace check EXTRACTOR.so FEATURE.so`).
//
// A round trip through one plugin cannot see a convention that two plugins
// disagree on (an angle measured clockwise, a frame, a flag's meaning): the
// extractor and the feature type would both be self-consistent. So both
// describe the world in a third vocabulary that neither defines: the shapes
// below, in the map frame. An extractor renders a synthetic reading of shapes
// it places itself (Extractor::sample_scene); a feature type builds the
// feature that *is* a shape (FeatureType::from_true_shape). The suite then
// asks the true feature for its innovation η against every measurement the
// extractor found: on a noise-free reading η ≈ 0 exactly when both plugins
// read the measurement v the same way.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "mspace/pose.hpp"

namespace mspace {

/// One piece of true geometry in the map frame.
struct TrueShape {
  enum class Kind : std::uint8_t {
    Point,             ///< a point at `a` (a lamp, a landmark)
    Segment,           ///< the straight segment from `a` to `b` (a wall's trace at the sensor's height, a ceiling line)
    VerticalCylinder,  ///< the vertical cylinder of `radius` whose axis passes through `a` (a tree trunk)
  };
  Kind kind = Kind::Point;
  Eigen::Vector3d a = Eigen::Vector3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();  ///< Segment only
  double radius = 0.0;                          ///< VerticalCylinder only
};

/// "point", "segment", "vertical_cylinder".
const char* shape_kind_name(TrueShape::Kind kind);

// ---- Planar ray casting, closed form (for simulated laser scans) ----------

/// Distance s ≥ 0 along the ray o + s·d (|d| = 1) to the segment [a, b], or
/// +inf when the ray misses it (parallel rays miss: a collinear ray grazes).
double ray_segment_distance(const Eigen::Vector2d& o, const Eigen::Vector2d& d, const Eigen::Vector2d& a,
                            const Eigen::Vector2d& b);
/// Distance s ≥ 0 along the ray o + s·d (|d| = 1) to the circle of `radius`
/// about `centre`, or +inf when it misses; a ray starting inside ignores it.
double ray_circle_distance(const Eigen::Vector2d& o, const Eigen::Vector2d& d, const Eigen::Vector2d& centre,
                           double radius);

/// A noise-free planar scan of `shapes` (map frame; Segments are vertical
/// walls on their x–y trace, VerticalCylinders their circles, Points are
/// invisible) by a horizontal laser at x_ms (x, y and yaw are used): one range
/// per bearing (rad, sensor frame), the nearest hit, or 0 (no return) beyond
/// max_range.
Eigen::VectorXd planar_scan(const std::vector<TrueShape>& shapes, const Pose6& x_ms, const Eigen::VectorXd& bearings,
                            double max_range);

}  // namespace mspace
