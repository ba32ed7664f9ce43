// pole_scene.hpp — the conformance scene of both pole extractors
// (Extractor::sample_scene, mspace/scene.hpp): a few trunks in front of a
// planar sensor, far enough apart in bearing that none hides another.
#pragma once

#include <cstdint>
#include <vector>

#include "mspace/pose.hpp"
#include "mspace/scene.hpp"

namespace mspace::laser_poles {

/// One trunk as the sensor sees it: range and bearing of its centre (m, rad,
/// anticlockwise from the sensor's x axis) and its diameter (m).
struct Trunk {
  double range = 0.0, bearing = 0.0, diameter = 0.0;
};

/// 1–4 trunks drawn from `seed` at 3–10 m, bearings within ±80° (one per
/// 40° sector, so their silhouettes never overlap), diameters 0.3–1 m.
std::vector<Trunk> sample_trunks(std::uint64_t seed);

/// A planar sensor pose drawn from `seed` (yaw any, no tilt).
Pose6 sample_planar_pose(std::uint64_t seed);

/// The trunk as a true shape in the map frame, seen from x_ms.
TrueShape trunk_shape(const Trunk& trunk, const Pose6& x_ms);

}  // namespace mspace::laser_poles
