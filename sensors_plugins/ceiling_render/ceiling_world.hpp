// ceiling_world.hpp — the 3-D indoor world of the ceiling renderer.
//
// Floor plan (metres, z up, floor at z = 0), fixed; the seed moves the lamps
// and light fixtures a little and changes the surface greys:
//
//        room A (ceiling 2.3)                  room B (ceiling 2.9)
//   y 6.2 ┌──────────────┐          y 7.2 ┌────────────────────────┐
//         │  ○       ○   │                │   ○      ○      ○      │
//         │  ○  ▭    ○   │                │   ○  ▭   ○      ○      │
//   y 1.2 └────┤door├────┘          y 1.2 └─────────┤door├─────────┘
//   y 1.0 ┌────┘    └─────────────────────────────────┘    └────────┐
//         │ corridor (ceiling 2.6, fine tile grid, panels ▭ and lamps ○)│
//   y-1.0 └───────────────────────────────────────────────────────────┘
//        x -8                  x 0 (start)                          x 10
//
// Doors are 1.2 m wide, 0.2 m deep, with a header at 2.05 m. Walls reach from
// the floor to the ceiling, so every room's ceiling meets its four walls in
// four horizontal lines at ceiling height (the "wall/ceiling joints"); the
// wall above a door continues up to the ceiling, so the joint runs on above it.
// Light fixtures are bright rectangular panels, lamps bright discs (or, with
// Appearance, squares and rectangles with halos, rings, other greys), both flat
// on the ceiling. The corridor ceiling has a fine tile grid (thin dark lines
// every 0.6 m) that gives the extractor false, repetitive line readings.
//
// radiance() ray-casts through the floor plan: the ray climbs through the
// region it is in until it either meets that region's ceiling or leaves the
// region's rectangle; it then enters the neighbouring region if that one's
// ceiling is higher than the ray there, else it has hit a wall.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace mspace::ceiling_render {

struct Box2 {
  double x0 = 0.0, y0 = 0.0, x1 = 0.0, y1 = 0.0;
  bool contains(const Eigen::Vector2d& p) const {
    return p.x() >= x0 && p.x() <= x1 && p.y() >= y0 && p.y() <= y1;
  }
};

/// A room, the corridor or a door opening: free space up to `ceiling_z`.
struct Region {
  Box2 box;
  double ceiling_z = 0.0;    ///< m above the floor
  double ceiling_grey = 0.0;  ///< grey level of the plain ceiling (0–255)
  bool tile_grid = false;     ///< fine tile grid on the ceiling
  bool door = false;          ///< a door opening (its "ceiling" is the door header)
};

/// A rectangular light panel flat on a ceiling at height z.
struct Fixture {
  Box2 box;
  double z = 0.0;
};

/// A lamp flat on a ceiling: a bright disc, or a square / rectangle (with
/// sharp or rounded corners, sides along the world axes) of half width
/// `radius` across y (and radius × Appearance::lamp_aspect along x).
struct Lamp {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double radius = 0.0;
  double grey = 255.0;  ///< radiance at the lamp's centre
};

/// The outline of the lamps.
enum class LampShape { Disc, Square, RoundedSquare };

/// A horizontal line segment in the world (wall/ceiling joint or panel edge).
struct Segment3 {
  Eigen::Vector3d a = Eigen::Vector3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
};

/// Grey levels and sizes of the world's surfaces.
struct Appearance {
  double wall_grey_low = 95.0;    ///< wall grey at floor level
  double wall_grey_high = 130.0;  ///< wall grey at the ceiling
  double fixture_grey = 238.0;
  double lamp_grey = 255.0;
  double tile_spacing = 0.6;      ///< m
  double tile_line_width = 0.012; ///< m
  double tile_line_darkening = 30.0;
  double lamp_radius = 0.10;      ///< m
  // The lamps of other buildings and renderers (defaults: the first renderer's
  // flat white discs; none of these settings changes its images).
  bool lamps = true;                       ///< false: a ceiling without lamps
  LampShape lamp_shape = LampShape::Disc;  ///< square/rounded: half width lamp_radius
  double lamp_aspect = 1.0;       ///< square/rounded: length along x / width along y
  double lamp_grey_spread = 0.0;  ///< each lamp's grey is lamp_grey × (1 − spread · U(0, 1))
  double lamp_falloff = 0.0;      ///< not uniformly bright: × (1 − falloff · s²), s = 0 centre, 1 rim
  double ring_width = 0.0;        ///< m: a fixture ring of grey ring_grey around each lamp (0: none)
  double ring_grey = 70.0;
  double halo_grey = 0.0;         ///< glow on the ceiling around a lamp: grey levels added at its rim …
  double halo_width = 0.1;        ///< … falling off as exp(−distance / halo_width) (m)
};

class CeilingWorld {
 public:
  /// The world of the file comment; `seed` jitters lamps, panels and greys.
  explicit CeilingWorld(std::uint64_t seed, const Appearance& appearance = {});

  /// A world of the given regions, light panels and lamps, as they are (the
  /// extractors' sample scenes, ceiling_scene.hpp). A lamp or panel shows on
  /// the region whose ceiling_z equals its height. Throws
  /// std::invalid_argument when there is no region.
  CeilingWorld(std::vector<Region> regions, std::vector<Fixture> fixtures, std::vector<Lamp> lamps,
               const Appearance& appearance = {});

  /// Grey level (0–255, not clamped) seen along the ray from `origin` (which
  /// must lie in free space) in direction `dir` (any length, dir.z > 0 to see
  /// a ceiling).
  double radiance(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const;

  /// Distance from `origin` (in free space) along the unit floor-plan
  /// direction `dir` to the first wall, as a planar laser below the door
  /// headers sees it (doors are open); 0 when farther than max_range.
  double range(const Eigen::Vector2d& origin, const Eigen::Vector2d& dir, double max_range) const;

  /// Index of the region containing the floor-plan point p, or -1 (in a wall).
  int region_at(const Eigen::Vector2d& p) const;

  const std::vector<Region>& regions() const { return regions_; }
  const std::vector<Fixture>& fixtures() const { return fixtures_; }
  const std::vector<Lamp>& lamps() const { return lamps_; }
  const Appearance& appearance() const { return appearance_; }
  /// The radius of the circle around a lamp's centre that holds all of it
  /// (corners and fixture ring included).
  double lamp_extent(const Lamp& lamp) const;

  /// The wall/ceiling joints (four per room and corridor) — the true ceiling lines.
  std::vector<Segment3> joints() const;
  /// The four edges of every light panel.
  std::vector<Segment3> fixture_edges() const;

  /// The robot's route: starts at the origin heading +x along the corridor,
  /// loops through room B, then room A, and returns to the origin.
  static std::vector<Eigen::Vector2d> route_waypoints();

 private:
  double ceiling_shade(const Region& region, const Eigen::Vector3d& p) const;
  /// Signed distance (m) of the ceiling point p from the lamp's outline, < 0 inside.
  double lamp_distance(const Eigen::Vector2d& p, const Lamp& lamp) const;
  double wall_shade(double z, double ceiling_z) const;

  Appearance appearance_;
  std::vector<Region> regions_;
  std::vector<Fixture> fixtures_;
  std::vector<Lamp> lamps_;
};

}  // namespace mspace::ceiling_render
