// ceiling_world.cpp — see ceiling_world.hpp.
#include "ceiling_world.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <utility>

#include "sim_world/sim_random.hpp"

namespace mspace::ceiling_render {
namespace {

using sim_world::SimRandom;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kDoorHeader = 2.05;  ///< m
// Independent random streams of one seed.
constexpr std::uint64_t kGreyStream = 11;
constexpr std::uint64_t kLampStream = 12;
constexpr std::uint64_t kFixtureStream = 13;
constexpr std::uint64_t kLampGreyStream = 14;

/// Plain ceiling greys before the seed's jitter.
constexpr double kCorridorGrey = 192.0;
constexpr double kRoomAGrey = 205.0;
constexpr double kRoomBGrey = 182.0;

Box2 centred_box(const Eigen::Vector2d& c, double half_x, double half_y) {
  return {c.x() - half_x, c.y() - half_y, c.x() + half_x, c.y() + half_y};
}

/// Where a ray leaves a box in the floor plan: the distance along the ray
/// and the outward normal of the side it crosses.
struct Exit {
  double t = kInf;
  Eigen::Vector2d normal = Eigen::Vector2d::Zero();
};

/// The exit of the ray p + t·dir (p inside the box) from the box's rectangle.
Exit exit_from(const Box2& box, const Eigen::Vector3d& p, const Eigen::Vector3d& dir) {
  Exit e;
  auto consider = [&](double t, double nx, double ny) {
    if (t < e.t) e = {std::max(t, 0.0), {nx, ny}};
  };
  if (dir.x() > 0.0) consider((box.x1 - p.x()) / dir.x(), 1.0, 0.0);
  if (dir.x() < 0.0) consider((box.x0 - p.x()) / dir.x(), -1.0, 0.0);
  if (dir.y() > 0.0) consider((box.y1 - p.y()) / dir.y(), 0.0, 1.0);
  if (dir.y() < 0.0) consider((box.y0 - p.y()) / dir.y(), 0.0, -1.0);
  return e;
}

/// True when x lies on a grid line of the given spacing and width.
bool on_grid_line(double x, double spacing, double width) {
  const double offset = x - spacing * std::floor(x / spacing);
  return offset < width;
}

double disc_distance2(const Eigen::Vector3d& p, const Lamp& lamp) {
  return (p.head<2>() - lamp.centre.head<2>()).squaredNorm();
}

void add_box_edges(const Box2& b, double z, std::vector<Segment3>& out) {
  const Eigen::Vector3d c00(b.x0, b.y0, z), c10(b.x1, b.y0, z), c11(b.x1, b.y1, z),
      c01(b.x0, b.y1, z);
  out.push_back({c00, c10});
  out.push_back({c10, c11});
  out.push_back({c11, c01});
  out.push_back({c01, c00});
}

}  // namespace

CeilingWorld::CeilingWorld(std::uint64_t seed, const Appearance& appearance)
    : appearance_(appearance) {
  SimRandom grey(seed, kGreyStream);
  auto jittered_grey = [&](double base) { return base + grey.uniform(-8.0, 8.0); };
  const double corridor_grey = jittered_grey(kCorridorGrey);
  const double room_a_grey = jittered_grey(kRoomAGrey);
  const double room_b_grey = jittered_grey(kRoomBGrey);
  regions_ = {
      {{-8.0, -1.0, 10.0, 1.0}, 2.6, corridor_grey, true, false},     // corridor
      {{-8.0, 1.2, -2.0, 6.2}, 2.3, room_a_grey, false, false},       // room A
      {{2.0, 1.2, 10.0, 7.2}, 2.9, room_b_grey, false, false},        // room B
      {{-5.6, 1.0, -4.4, 1.2}, kDoorHeader, room_a_grey, false, true},  // door A
      {{5.4, 1.0, 6.6, 1.2}, kDoorHeader, room_b_grey, false, true},    // door B
  };

  // Lamps above the route (see route_waypoints()), jittered by up to 0.2 m.
  SimRandom lamp_rng(seed, kLampStream);
  auto add_lamp = [&](double x, double y, int region) {
    const Eigen::Vector3d c(x + lamp_rng.uniform(-0.2, 0.2), y + lamp_rng.uniform(-0.2, 0.2),
                            regions_[static_cast<std::size_t>(region)].ceiling_z);
    lamps_.push_back({c, appearance_.lamp_radius, appearance_.lamp_grey});
  };
  for (double x : {-4.0, 0.0, 4.0, 8.0}) add_lamp(x, 0.45, 0);
  for (double x : {-6.5, -3.5})
    for (double y : {3.0, 5.0}) add_lamp(x, y, 1);
  for (double x : {3.5, 6.0, 8.5})
    for (double y : {3.0, 5.8}) add_lamp(x, y, 2);
  if (appearance_.lamp_grey_spread > 0.0) {
    SimRandom lamp_grey_rng(seed, kLampGreyStream);
    for (Lamp& lamp : lamps_) lamp.grey *= 1.0 - appearance_.lamp_grey_spread * lamp_grey_rng.uniform(0.0, 1.0);
  }
  if (!appearance_.lamps) lamps_.clear();

  // Light panels 1.2 m × 0.3 m, jittered by up to 0.05 m.
  SimRandom fixture_rng(seed, kFixtureStream);
  auto add_panel = [&](double x, double y, bool along_x, int region) {
    const Eigen::Vector2d c(x + fixture_rng.uniform(-0.05, 0.05),
                            y + fixture_rng.uniform(-0.05, 0.05));
    const Box2 box = along_x ? centred_box(c, 0.6, 0.15) : centred_box(c, 0.15, 0.6);
    fixtures_.push_back({box, regions_[static_cast<std::size_t>(region)].ceiling_z});
  };
  // Corridor panels sit between the tile lines (edges ≥ 0.1 m from them).
  for (double x : {-5.7, -2.1, 2.1, 5.7}) add_panel(x, -0.3, true, 0);
  add_panel(-5.0, 4.0, true, 1);
  add_panel(4.75, 4.4, false, 2);
  add_panel(7.25, 4.4, false, 2);
}

CeilingWorld::CeilingWorld(std::vector<Region> regions, std::vector<Fixture> fixtures, std::vector<Lamp> lamps,
                           const Appearance& appearance)
    : appearance_(appearance),
      regions_(std::move(regions)),
      fixtures_(std::move(fixtures)),
      lamps_(std::move(lamps)) {
  if (regions_.empty()) throw std::invalid_argument("ceiling world: at least one region is needed");
}

std::vector<Eigen::Vector2d> CeilingWorld::route_waypoints() {
  return {{6.0, 0.0},  {6.0, 3.0},  {8.5, 3.0},  {8.5, 5.8},  {3.5, 5.8},  {3.5, 3.0},
          {6.0, 3.0},  {6.0, 0.0},  {-5.0, 0.0}, {-5.0, 3.0}, {-3.5, 3.0}, {-3.5, 5.0},
          {-6.5, 5.0}, {-6.5, 3.0}, {-5.0, 3.0}, {-5.0, 0.0}, {0.0, 0.0}};
}

int CeilingWorld::region_at(const Eigen::Vector2d& p) const {
  for (std::size_t i = 0; i < regions_.size(); ++i) {
    if (regions_[i].box.contains(p)) return static_cast<int>(i);
  }
  return -1;
}

double CeilingWorld::radiance(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const {
  int r = region_at(origin.head<2>());
  if (r < 0) return wall_shade(origin.z(), origin.z());
  Eigen::Vector3d p = origin;
  for (std::size_t hop = 0; hop <= regions_.size(); ++hop) {
    const Region& region = regions_[static_cast<std::size_t>(r)];
    const double t_ceiling = dir.z() > 0.0 ? (region.ceiling_z - p.z()) / dir.z() : kInf;
    const Exit exit = exit_from(region.box, p, dir);
    if (t_ceiling <= exit.t) return ceiling_shade(region, p + t_ceiling * dir);
    const Eigen::Vector3d q = p + exit.t * dir;
    // The region just across the side the ray leaves by (-1: a wall).
    const int next = region_at(q.head<2>() + 1e-9 * exit.normal);
    if (next < 0 || next == r || q.z() >= regions_[static_cast<std::size_t>(next)].ceiling_z) {
      return wall_shade(q.z(), region.ceiling_z);
    }
    p = q;
    r = next;
  }
  return wall_shade(p.z(), p.z());
}

double CeilingWorld::range(const Eigen::Vector2d& origin, const Eigen::Vector2d& dir,
                           double max_range) const {
  int r = region_at(origin);
  if (r < 0) return 0.0;
  const Eigen::Vector3d d(dir.x(), dir.y(), 0.0);
  Eigen::Vector3d p(origin.x(), origin.y(), 0.0);
  double travelled = 0.0;
  for (std::size_t hop = 0; hop <= regions_.size(); ++hop) {
    const Exit exit = exit_from(regions_[static_cast<std::size_t>(r)].box, p, d);
    travelled += exit.t;
    if (travelled > max_range) return 0.0;
    p += exit.t * d;
    const int next = region_at(p.head<2>() + 1e-9 * exit.normal);
    if (next < 0 || next == r) return travelled;
    r = next;
  }
  return travelled;
}

double CeilingWorld::lamp_distance(const Eigen::Vector2d& p, const Lamp& lamp) const {
  const Eigen::Vector2d d = p - lamp.centre.head<2>();
  if (appearance_.lamp_shape == LampShape::Disc) return d.norm() - lamp.radius;
  // A rectangle of half sizes h, its corners rounded with radius rc: the
  // distance from the rectangle of half sizes h − rc, minus rc (the standard
  // signed distance of a box: outside, the distance to its nearest point;
  // inside, minus the distance to its nearest side).
  const double rc = appearance_.lamp_shape == LampShape::RoundedSquare ? 0.5 * lamp.radius : 0.0;
  const Eigen::Vector2d h(lamp.radius * appearance_.lamp_aspect - rc, lamp.radius - rc);
  const Eigen::Vector2d q = d.cwiseAbs() - h;
  return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0) - rc;
}

double CeilingWorld::lamp_extent(const Lamp& lamp) const {
  const double half_length = lamp.radius * std::max(appearance_.lamp_aspect, 1.0);
  const double corner = appearance_.lamp_shape == LampShape::Disc
                            ? half_length
                            : std::hypot(lamp.radius * appearance_.lamp_aspect, lamp.radius);
  return corner + appearance_.ring_width;
}

double CeilingWorld::ceiling_shade(const Region& region, const Eigen::Vector3d& p) const {
  const Appearance& a = appearance_;
  const bool plain_discs = a.lamp_shape == LampShape::Disc && a.lamp_falloff == 0.0 && a.ring_width == 0.0 &&
                           a.halo_grey == 0.0;
  double glow = 0.0;  // the lamps' halos on the ceiling (grey levels)
  for (const Lamp& lamp : lamps_) {
    if (lamp.centre.z() != region.ceiling_z) continue;
    if (plain_discs) {  // the first renderer's test, bit for bit
      if (disc_distance2(p, lamp) <= lamp.radius * lamp.radius) return lamp.grey;
      continue;
    }
    const double d = lamp_distance(p.head<2>(), lamp);
    if (d <= 0.0) {
      // s: 0 at the centre, 1 on the rim (d = −radius at the centre of a disc or square).
      const double s = std::clamp(1.0 + d / lamp.radius, 0.0, 1.0);
      return lamp.grey * (1.0 - a.lamp_falloff * s * s);
    }
    if (d <= a.ring_width) return a.ring_grey;
    if (a.halo_grey > 0.0) glow += a.halo_grey * std::exp(-(d - a.ring_width) / a.halo_width);
  }
  for (const Fixture& f : fixtures_) {
    if (f.z == region.ceiling_z && f.box.contains(p.head<2>())) return a.fixture_grey;
  }
  if (region.tile_grid && (on_grid_line(p.x(), a.tile_spacing, a.tile_line_width) ||
                           on_grid_line(p.y(), a.tile_spacing, a.tile_line_width))) {
    return region.ceiling_grey - a.tile_line_darkening + glow;
  }
  return region.ceiling_grey + glow;
}

double CeilingWorld::wall_shade(double z, double ceiling_z) const {
  const double s = ceiling_z > 0.0 ? std::clamp(z / ceiling_z, 0.0, 1.0) : 0.0;
  return appearance_.wall_grey_low + s * (appearance_.wall_grey_high - appearance_.wall_grey_low);
}

std::vector<Segment3> CeilingWorld::joints() const {
  std::vector<Segment3> out;
  for (const Region& r : regions_) {
    if (!r.door) add_box_edges(r.box, r.ceiling_z, out);
  }
  return out;
}

std::vector<Segment3> CeilingWorld::fixture_edges() const {
  std::vector<Segment3> out;
  for (const Fixture& f : fixtures_) add_box_edges(f.box, f.z, out);
  return out;
}

}  // namespace mspace::ceiling_render
