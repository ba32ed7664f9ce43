// floor_plan.cpp — see floor_plan.hpp.
#include "floor_plan.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <stdexcept>

#include "sim_world/sim_random.hpp"

namespace mspace::sim_building {
namespace {

using sim_world::SimRandom;

constexpr double kCell = 0.1;  // grid of the free space (m); every plan coordinate lies on it
constexpr double kDoorWidth = 0.9;

/// v rounded to the 0.1 m grid.
double on_grid(double v) { return std::round(v / kCell) * kCell; }

/// Point rotated by 90°·k counter-clockwise about the origin.
Vec2 rot90(const Vec2& p, int k) {
  Vec2 q = p;
  for (int i = 0; i < k; ++i) q = Vec2(-q.y(), q.x());
  return q;
}

Rect rot90(const Rect& r, int k) {
  const Vec2 a = rot90(Vec2(r.x0, r.y0), k), b = rot90(Vec2(r.x1, r.y1), k);
  return {std::min(a.x(), b.x()), std::min(a.y(), b.y()), std::max(a.x(), b.x()), std::max(a.y(), b.y())};
}

double distance_to_segment(const Vec2& p, const Vec2& a, const Vec2& b) {
  const Vec2 d = b - a;
  const double len2 = d.squaredNorm();
  const double u = len2 > 0.0 ? std::clamp((p - a).dot(d) / len2, 0.0, 1.0) : 0.0;
  return (a + u * d - p).norm();
}

/// The free rectangle of corridor edge (a, b), extended by half a width at both ends
/// so that corridors meeting at a node overlap there.
Rect corridor_rect(const Vec2& a, const Vec2& b, double width) {
  const double h = width / 2.0;
  return {std::min(a.x(), b.x()) - h, std::min(a.y(), b.y()) - h, std::max(a.x(), b.x()) + h,
          std::max(a.y(), b.y()) + h};
}

/// Builds one plan: the corridor graph is given, rooms and clutter are drawn.
class Builder {
 public:
  Builder(FloorPlan& plan, SimRandom& rng) : plan_(plan), rng_(rng) {}

  void add_node(double x, double y) { plan_.nodes.emplace_back(on_grid(x), on_grid(y)); }
  void add_edge(int a, int b) {
    plan_.edges.emplace_back(a, b);
    plan_.corridors.push_back(corridor_rect(plan_.nodes[static_cast<std::size_t>(a)],
                                            plan_.nodes[static_cast<std::size_t>(b)], plan_.corridor_width));
  }

  /// Rooms along both sides of every edge (symmetry 1) or, for the symmetric
  /// plan, along edge 0 and copied to the other three edges by 90° rotations.
  void add_rooms(double min_width, double max_width, double min_depth, double max_depth, int symmetry) {
    const std::size_t n_edges = symmetry == 4 ? 1 : plan_.edges.size();
    for (std::size_t e = 0; e < n_edges; ++e)
      for (int side : {+1, -1})
        add_rooms_along(static_cast<int>(e), side, min_width, max_width, min_depth, max_depth, symmetry);
  }

  /// Boxes and pillars in every room (each room's own draw; the symmetric plan
  /// draws for the rooms of edge 0 and rotates them).
  void add_clutter(int symmetry) {
    const std::size_t n = plan_.rooms.size();
    for (std::size_t i = 0; i < n; ++i) {
      const Room& room = plan_.rooms[i];
      if (symmetry == 4 && room.edge != 0) continue;
      const std::size_t first_box = plan_.boxes.size(), first_pillar = plan_.pillars.size();
      const int boxes = static_cast<int>(rng_.index(4));
      const int pillars = static_cast<int>(rng_.index(2));
      for (int b = 0; b < boxes; ++b) {
        const double hx = on_grid(rng_.uniform(0.2, 0.6)), hy = on_grid(rng_.uniform(0.2, 0.5));
        place(room, std::hypot(hx, hy), [&](const Vec2& c) {
          plan_.boxes.push_back({c, hx, hy, rng_.uniform(0.0, std::numbers::pi)});
        });
      }
      for (int p = 0; p < pillars; ++p) {
        const double r = on_grid(rng_.uniform(0.1, 0.25));
        place(room, r, [&](const Vec2& c) { plan_.pillars.push_back({c, r}); });
      }
      if (symmetry == 4) {
        const std::size_t last_box = plan_.boxes.size(), last_pillar = plan_.pillars.size();
        for (int k = 1; k < 4; ++k) {
          for (std::size_t b = first_box; b < last_box; ++b) {
            Box box = plan_.boxes[b];
            box.centre = rot90(box.centre, k);
            box.angle += k * std::numbers::pi / 2.0;
            plan_.boxes.push_back(box);
          }
          for (std::size_t p = first_pillar; p < last_pillar; ++p)
            plan_.pillars.push_back({rot90(plan_.pillars[p].centre, k), plan_.pillars[p].radius});
        }
      }
    }
  }

  void add_people(int count) {
    for (int i = 0; i < count; ++i) {
      const auto& [ia, ib] = plan_.edges[rng_.index(plan_.edges.size())];
      const Vec2 a = plan_.nodes[static_cast<std::size_t>(ia)], b = plan_.nodes[static_cast<std::size_t>(ib)];
      const Vec2 along = (b - a).normalized();
      const Vec2 normal(-along.y(), along.x());
      const double offset = rng_.uniform(-0.4, 0.4);
      Person p;
      p.a = a + 1.5 * along + offset * normal;
      p.b = b - 1.5 * along + offset * normal;
      p.speed = rng_.uniform(0.5, 1.2);
      p.radius = rng_.uniform(0.2, 0.25);
      p.phase = rng_.uniform(0.0, 2.0 * (p.b - p.a).norm() / p.speed);
      plan_.people.push_back(p);
    }
  }

 private:
  /// Is the rectangle clear of all free space placed so far, with a wall of at
  /// least the wall thickness between them?
  bool clear(const Rect& r) const {
    const double margin = plan_.wall_thickness - 0.05;
    for (const Rect& c : plan_.corridors)
      if (r.overlaps(c, margin)) return false;
    for (const Room& room : plan_.rooms)
      if (r.overlaps(room.area, margin)) return false;
    return true;
  }

  void add_rooms_along(int e, int side, double min_width, double max_width, double min_depth, double max_depth,
                       int symmetry) {
    const auto& [ia, ib] = plan_.edges[static_cast<std::size_t>(e)];
    const Vec2 a = plan_.nodes[static_cast<std::size_t>(ia)], b = plan_.nodes[static_cast<std::size_t>(ib)];
    const bool horizontal = std::abs(a.y() - b.y()) < 1e-9;
    // Along/across coordinates of the edge: along = x for a horizontal edge.
    const double lo = horizontal ? std::min(a.x(), b.x()) : std::min(a.y(), b.y());
    const double hi = horizontal ? std::max(a.x(), b.x()) : std::max(a.y(), b.y());
    const double centre = horizontal ? a.y() : a.x();
    const double h = plan_.corridor_width / 2.0, t = plan_.wall_thickness;
    auto make = [&](double a0, double a1, double c0, double c1) {
      return horizontal ? Rect{a0, c0, a1, c1} : Rect{c0, a0, c1, a1};
    };
    auto point = [&](double along, double across) { return horizontal ? Vec2(along, across) : Vec2(across, along); };
    double pos = on_grid(lo + h + t);
    while (true) {
      if (rng_.uniform() < 0.15) pos = on_grid(pos + rng_.uniform(1.0, 3.0));  // a stretch of plain wall
      const double width = on_grid(rng_.uniform(min_width, max_width));
      const double depth = on_grid(rng_.uniform(min_depth, max_depth));
      if (pos + width > hi - h - t) break;
      const double near = side > 0 ? centre + h + t : centre - h - t;
      const double far = side > 0 ? near + depth : near - depth;
      Room room;
      room.area = make(pos, pos + width, std::min(near, far), std::max(near, far));
      const double door = on_grid(rng_.uniform(pos + 0.3, pos + width - kDoorWidth - 0.3));
      const double wall_face = side > 0 ? centre + h : centre - h;
      room.door = make(door, door + kDoorWidth, std::min(wall_face, near), std::max(wall_face, near));
      room.edge = e;
      room.door_outside = point(door + kDoorWidth / 2.0, centre);
      room.door_inside = point(door + kDoorWidth / 2.0, near + side * 1.0);
      room.centre = point(pos + width / 2.0, (near + far) / 2.0);
      bool ok = clear(room.area);
      for (int k = 1; ok && k < symmetry; ++k)
        ok = !rot90(room.area, k).overlaps(room.area, t - 0.05) && clear(rot90(room.area, k));
      if (ok) {
        plan_.rooms.push_back(room);
        for (int k = 1; k < symmetry; ++k) {
          Room copy = room;
          copy.area = rot90(room.area, k);
          copy.door = rot90(room.door, k);
          copy.edge = (e + k) % 4;
          copy.door_outside = rot90(room.door_outside, k);
          copy.door_inside = rot90(room.door_inside, k);
          copy.centre = rot90(room.centre, k);
          plan_.rooms.push_back(copy);
        }
        pos = on_grid(pos + width + t);
      } else {
        pos = on_grid(pos + 1.0);
      }
    }
  }

  /// Tries up to 30 positions in the room for an object of bounding radius r
  /// that keeps clear of the walls, of the way door → centre and of the other
  /// objects; calls put(centre) for the first that fits.
  void place(const Room& room, double r, const std::function<void(const Vec2&)>& put) {
    const Rect& a = room.area;
    if (a.x1 - a.x0 < 2 * r + 0.4 || a.y1 - a.y0 < 2 * r + 0.4) return;
    for (int attempt = 0; attempt < 30; ++attempt) {
      const Vec2 c(rng_.uniform(a.x0 + r + 0.2, a.x1 - r - 0.2), rng_.uniform(a.y0 + r + 0.2, a.y1 - r - 0.2));
      // Keep the robot's way (door → 1 m inside → centre) free.
      if (distance_to_segment(c, room.door_outside, room.door_inside) < r + 0.7 ||
          distance_to_segment(c, room.door_inside, room.centre) < r + 0.7 || (c - room.centre).norm() < r + 0.8)
        continue;
      bool free = true;
      for (const Box& b : plan_.boxes) free = free && (b.centre - c).norm() > r + std::hypot(b.hx, b.hy) + 0.3;
      for (const Disc& p : plan_.pillars) free = free && (p.centre - c).norm() > r + p.radius + 0.3;
      if (!free) continue;
      put(c);
      return;
    }
  }

  FloorPlan& plan_;
  SimRandom& rng_;
};

/// The free/solid boundary of the union of free rectangles, as maximal
/// straight segments on the 0.1 m grid.
std::vector<Segment> extract_walls(const std::vector<Rect>& free_rects) {
  Rect box{1e18, 1e18, -1e18, -1e18};
  for (const Rect& r : free_rects)
    box = {std::min(box.x0, r.x0), std::min(box.y0, r.y0), std::max(box.x1, r.x1), std::max(box.y1, r.y1)};
  // Cells in integer units of kCell, with two solid cells of margin.
  const long gx0 = std::lround(box.x0 / kCell) - 2, gy0 = std::lround(box.y0 / kCell) - 2;
  const long nx = std::lround(box.x1 / kCell) + 2 - gx0, ny = std::lround(box.y1 / kCell) + 2 - gy0;
  std::vector<std::uint8_t> free(static_cast<std::size_t>(nx * ny), 0);
  auto at = [&](long i, long j) -> std::uint8_t& { return free[static_cast<std::size_t>(j * nx + i)]; };
  for (const Rect& r : free_rects)
    for (long j = std::lround(r.y0 / kCell) - gy0; j < std::lround(r.y1 / kCell) - gy0; ++j)
      for (long i = std::lround(r.x0 / kCell) - gx0; i < std::lround(r.x1 / kCell) - gx0; ++i) at(i, j) = 1;

  std::vector<Segment> walls;
  // A run of unit edges with the same free side is one wall.
  auto flush = [&](int& sign, long start, long end, auto&& make) {
    if (sign != 0) walls.push_back(make(start, end));
    sign = 0;
  };
  for (long i = 1; i < nx; ++i) {  // vertical boundaries at x = (gx0 + i)·kCell
    int sign = 0;
    long start = 0;
    auto make = [&](long j0, long j1) {
      const double x = static_cast<double>(gx0 + i) * kCell;
      return Segment{{x, static_cast<double>(gy0 + j0) * kCell}, {x, static_cast<double>(gy0 + j1) * kCell}};
    };
    for (long j = 0; j <= ny; ++j) {
      const int s = j < ny ? at(i - 1, j) - at(i, j) : 0;
      if (s != sign) {
        flush(sign, start, j, make);
        sign = s;
        start = j;
      }
    }
  }
  for (long j = 1; j < ny; ++j) {  // horizontal boundaries at y = (gy0 + j)·kCell
    int sign = 0;
    long start = 0;
    auto make = [&](long i0, long i1) {
      const double y = static_cast<double>(gy0 + j) * kCell;
      return Segment{{static_cast<double>(gx0 + i0) * kCell, y}, {static_cast<double>(gx0 + i1) * kCell, y}};
    };
    for (long i = 0; i <= nx; ++i) {
      const int s = i < nx ? at(i, j - 1) - at(i, j) : 0;
      if (s != sign) {
        flush(sign, start, i, make);
        sign = s;
        start = i;
      }
    }
  }
  return walls;
}

struct Family {
  const char* name;
  double corridor_width;
  int default_people;
  std::function<void(Builder&, SimRandom&)> graph;  ///< nodes, edges, loops
  int symmetry;
};

/// A closed loop through the given nodes (in order).
void add_loop(FloorPlan& plan, std::vector<int> nodes) { plan.loops.push_back(std::move(nodes)); }

}  // namespace

std::vector<Segment> Box::sides() const {
  const double c = std::cos(angle), s = std::sin(angle);
  const Vec2 ax(c * hx, s * hx), ay(-s * hy, c * hy);
  const Vec2 p[4] = {centre - ax - ay, centre + ax - ay, centre + ax + ay, centre - ax + ay};
  return {{p[0], p[1]}, {p[1], p[2]}, {p[2], p[3]}, {p[3], p[0]}};
}

Disc Person::at(double t) const {
  const double length = (b - a).norm();
  if (length <= 0.0 || speed <= 0.0) return {a, radius};
  const double period = 2.0 * length / speed;
  double s = std::fmod(t + phase, period);
  if (s < 0.0) s += period;
  s *= speed;
  if (s > length) s = 2.0 * length - s;  // walking back
  return {a + (b - a) * (s / length), radius};
}

double FloorPlan::loop_length(std::size_t i) const {
  const std::vector<int>& loop = loops.at(i);
  double length = 0.0;
  for (std::size_t k = 0; k < loop.size(); ++k)
    length += (nodes[static_cast<std::size_t>(loop[(k + 1) % loop.size()])] - nodes[static_cast<std::size_t>(loop[k])])
                  .norm();
  return length;
}

std::vector<Segment> FloorPlan::static_segments() const {
  std::vector<Segment> out = walls;
  for (const Box& b : boxes)
    for (const Segment& s : b.sides()) out.push_back(s);
  return out;
}

Rect FloorPlan::bounds() const {
  Rect box{1e18, 1e18, -1e18, -1e18};
  auto grow = [&](const Rect& r) {
    box = {std::min(box.x0, r.x0), std::min(box.y0, r.y0), std::max(box.x1, r.x1), std::max(box.y1, r.y1)};
  };
  for (const Rect& r : corridors) grow(r);
  for (const Room& r : rooms) grow(r.area);
  return box;
}

namespace {

const std::vector<Family>& families() {
  static const std::vector<Family> list = {
      {"ring", 2.0, 2,
       [](Builder& b, SimRandom& r) {
         const double w = r.uniform(25.0, 45.0), h = r.uniform(12.0, 22.0);  // perimeter 74–134 m
         b.add_node(0, 0), b.add_node(w, 0), b.add_node(w, h), b.add_node(0, h);
         for (int i = 0; i < 4; ++i) b.add_edge(i, (i + 1) % 4);
       },
       1},
      {"ladder", 2.4, 2,
       [](Builder& b, SimRandom& r) {
         const double l = r.uniform(40.0, 60.0), s = r.uniform(12.0, 18.0);  // loops 64–96 m and 104–156 m
         b.add_node(0, 0), b.add_node(l / 2, 0), b.add_node(l, 0);
         b.add_node(0, s), b.add_node(l / 2, s), b.add_node(l, s);
         b.add_edge(0, 1), b.add_edge(1, 2), b.add_edge(3, 4), b.add_edge(4, 5);
         b.add_edge(0, 3), b.add_edge(1, 4), b.add_edge(2, 5);
       },
       1},
      {"l_ring", 1.8, 2,
       [](Builder& b, SimRandom& r) {
         const double a = r.uniform(30.0, 45.0), h = r.uniform(25.0, 35.0);  // perimeter 110–160 m
         const double a2 = a * r.uniform(0.4, 0.6), h1 = h * r.uniform(0.4, 0.6);
         b.add_node(0, 0), b.add_node(a, 0), b.add_node(a, h1), b.add_node(a2, h1), b.add_node(a2, h), b.add_node(0, h);
         for (int i = 0; i < 6; ++i) b.add_edge(i, (i + 1) % 6);
       },
       1},
      {"long_loop", 2.0, 2,
       [](Builder& b, SimRandom& r) {
         const double l = r.uniform(90.0, 130.0), s = r.uniform(8.0, 12.0);  // perimeter 196–284 m
         b.add_node(0, 0), b.add_node(l, 0), b.add_node(l, s), b.add_node(0, s);
         for (int i = 0; i < 4; ++i) b.add_edge(i, (i + 1) % 4);
       },
       1},
      {"grid", 2.2, 3,
       [](Builder& b, SimRandom& r) {
         const double a = r.uniform(14.0, 20.0), c = r.uniform(12.0, 18.0);  // cells 52–76 m, outer 104–152 m
         for (int j = 0; j < 3; ++j)
           for (int i = 0; i < 3; ++i) b.add_node(i * a, j * c);
         for (int j = 0; j < 3; ++j)
           for (int i = 0; i < 2; ++i) b.add_edge(3 * j + i, 3 * j + i + 1);
         for (int j = 0; j < 2; ++j)
           for (int i = 0; i < 3; ++i) b.add_edge(3 * j + i, 3 * (j + 1) + i);
       },
       1},
      {"symmetric", 2.0, 0,
       [](Builder& b, SimRandom& r) {
         const double h = std::round(r.uniform(10.0, 17.5));  // half side on whole metres: perimeter 80–140 m
         b.add_node(-h, -h), b.add_node(h, -h), b.add_node(h, h), b.add_node(-h, h);
         for (int i = 0; i < 4; ++i) b.add_edge(i, (i + 1) % 4);
       },
       4},
  };
  return list;
}

}  // namespace

const std::vector<std::string>& plan_names() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> out;
    for (const Family& f : families()) out.emplace_back(f.name);
    return out;
  }();
  return names;
}

std::size_t plan_index(const std::string& name_or_index) {
  const auto& names = plan_names();
  for (std::size_t i = 0; i < names.size(); ++i)
    if (names[i] == name_or_index || std::to_string(i) == name_or_index) return i;
  std::string choices;
  for (std::size_t i = 0; i < names.size(); ++i) choices += (i ? ", " : "") + std::to_string(i) + " " + names[i];
  throw std::invalid_argument("unknown plan '" + name_or_index + "' (choices: " + choices + ")");
}

FloorPlan generate_plan(std::size_t family, std::uint64_t world_seed, const PlanOptions& options) {
  const Family& f = families().at(family);
  FloorPlan plan;
  plan.name = f.name;
  plan.world_seed = world_seed;
  plan.symmetric = f.symmetry == 4;
  plan.corridor_width = f.corridor_width;
  SimRandom rng(world_seed, 0x5eed0000u + family);
  Builder builder(plan, rng);
  f.graph(builder, rng);
  // Loops: the ring families have one, ladder and grid their cells and the outer ring.
  if (plan.name == "ladder") {
    add_loop(plan, {0, 1, 4, 3}), add_loop(plan, {1, 2, 5, 4}), add_loop(plan, {0, 1, 2, 5, 4, 3});
  } else if (plan.name == "grid") {
    add_loop(plan, {0, 1, 4, 3}), add_loop(plan, {1, 2, 5, 4}), add_loop(plan, {4, 5, 8, 7}),
        add_loop(plan, {3, 4, 7, 6}), add_loop(plan, {0, 1, 2, 5, 8, 7, 6, 3});
  } else {
    std::vector<int> all(plan.nodes.size());
    for (std::size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
    add_loop(plan, all);
  }
  builder.add_rooms(3.0, 6.0, 3.5, 6.0, f.symmetry);
  if (options.clutter) builder.add_clutter(f.symmetry);
  builder.add_people(options.people >= 0 ? options.people : f.default_people);

  std::vector<Rect> free = plan.corridors;
  for (const Room& r : plan.rooms) free.push_back(r.area), free.push_back(r.door);
  plan.walls = extract_walls(free);
  return plan;
}

}  // namespace mspace::sim_building
