// floor_plan.hpp — seeded office floor plans for the 2-D laser simulator.
//
// A plan is built from axis-aligned free-space rectangles on a 0.1 m grid:
// corridors (the edges of a corridor graph, `corridor_width` wide), rooms off
// them (separated from the corridor and from each other by `wall_thickness`
// of solid wall) and doors (0.9 m wide free rectangles through that wall).
// The walls are the boundary between free and solid grid cells, merged into
// maximal straight segments — so every wall is exact, axis aligned and lies on
// the 0.1 m grid, door jambs included. Clutter (boxes at any angle, round
// pillars) stands in rooms; people are discs walking to and fro along a
// corridor.
//
// Plan families (`plan_names()`), each a parameter set drawn from world_seed:
//   ring       one rectangular corridor ring, rooms inside and outside
//   ladder     two long corridors joined by three cross corridors (3 loops)
//   l_ring     an L-shaped ring (six corners)
//   long_loop  a long thin loop (196–284 m) with rooms along both sides
//   grid       a 3 × 3 corridor grid (four small loops, one big)
//   symmetric  a square ring whose rooms, doors and clutter repeat under a
//              90° rotation about its centre: four identical wings, so a
//              robot that lost its heading cannot tell them apart (for
//              false-loop-closure tests). No people.
// Every loop of every plan is 50–300 m long (tests/sim_building checks it).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace mspace::sim_building {

using Vec2 = Eigen::Vector2d;

/// A wall piece from a to b (m).
struct Segment {
  Vec2 a = Vec2::Zero();
  Vec2 b = Vec2::Zero();
};

/// A round obstacle (pillar) or a person.
struct Disc {
  Vec2 centre = Vec2::Zero();
  double radius = 0.0;
};

/// Axis-aligned rectangle [x0, x1] × [y0, y1] (m).
struct Rect {
  double x0 = 0.0, y0 = 0.0, x1 = 0.0, y1 = 0.0;
  bool overlaps(const Rect& o, double margin) const {
    return x0 < o.x1 + margin && o.x0 < x1 + margin && y0 < o.y1 + margin && o.y0 < y1 + margin;
  }
};

/// A room off a corridor edge with its door.
struct Room {
  Rect area;
  Rect door;                         ///< the opening through the wall
  int edge = -1;                     ///< corridor edge the door opens onto
  Vec2 door_outside = Vec2::Zero();  ///< on the corridor's centre line, in front of the door
  Vec2 door_inside = Vec2::Zero();   ///< 1 m into the room, behind the door
  Vec2 centre = Vec2::Zero();
};

/// A box (table, cupboard): a rectangle of half sizes (hx, hy) turned by angle.
struct Box {
  Vec2 centre = Vec2::Zero();
  double hx = 0.0, hy = 0.0, angle = 0.0;
  /// Its four sides.
  std::vector<Segment> sides() const;
};

/// A person walking to and fro between a and b at `speed` (a disc).
struct Person {
  Vec2 a = Vec2::Zero(), b = Vec2::Zero();
  double speed = 1.0;   ///< m/s
  double radius = 0.2;  ///< m
  double phase = 0.0;   ///< s: where on its walk it is at t = 0
  /// The person's disc at time t (s from the start of the log).
  Disc at(double t) const;
};

struct FloorPlan {
  std::string name;  ///< family name (plan_names())
  std::uint64_t world_seed = 0;
  bool symmetric = false;       ///< deliberately ambiguous plan
  double corridor_width = 2.0;  ///< m
  double wall_thickness = 0.2;  ///< m

  // Corridor graph: centre lines; loops are closed node sequences (first node not repeated).
  std::vector<Vec2> nodes;
  std::vector<std::pair<int, int>> edges;
  std::vector<std::vector<int>> loops;

  std::vector<Rect> corridors;  ///< free rectangles of the corridors
  std::vector<Room> rooms;
  std::vector<Box> boxes;
  std::vector<Disc> pillars;
  std::vector<Person> people;

  std::vector<Segment> walls;  ///< free/solid boundary, merged (after build())

  /// Length of loop i along the corridor centre lines (m).
  double loop_length(std::size_t i) const;
  /// Every static segment: walls and box sides.
  std::vector<Segment> static_segments() const;
  /// Bounding box of the free space.
  Rect bounds() const;
};

/// The plan families, in index order (--plan NAME or INDEX).
const std::vector<std::string>& plan_names();

/// Index of a family given by name or by its index as text; throws
/// std::invalid_argument listing the choices.
std::size_t plan_index(const std::string& name_or_index);

struct PlanOptions {
  int people = -1;      ///< moving people; −1: the family's default (2, none in `symmetric`)
  bool clutter = true;  ///< boxes and pillars in rooms
};

/// The plan of family `family` (plan_index) for world_seed. Deterministic.
FloorPlan generate_plan(std::size_t family, std::uint64_t world_seed, const PlanOptions& options = {});

}  // namespace mspace::sim_building
