// scene.cpp — see mspace/scene.hpp.
#include "mspace/scene.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace mspace {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

double cross(const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return a.x() * b.y() - a.y() * b.x(); }

}  // namespace

const char* shape_kind_name(TrueShape::Kind kind) {
  switch (kind) {
    case TrueShape::Kind::Point:
      return "point";
    case TrueShape::Kind::Segment:
      return "segment";
    case TrueShape::Kind::VerticalCylinder:
      return "vertical_cylinder";
  }
  return "?";
}

double ray_segment_distance(const Eigen::Vector2d& o, const Eigen::Vector2d& d, const Eigen::Vector2d& a,
                            const Eigen::Vector2d& b) {
  // o + s·d = a + u·e with e = b − a. Crossing both sides with e and with d:
  //   s·(d × e) = (a − o) × e,   u·(d × e) = (a − o) × d.
  const Eigen::Vector2d e = b - a;
  const double denom = cross(d, e);
  if (std::abs(denom) < 1e-15) return kInf;  // parallel (a collinear ray grazes, it does not stop)
  const Eigen::Vector2d ao = a - o;
  const double s = cross(ao, e) / denom;
  const double u = cross(ao, d) / denom;
  if (s < 0.0 || u < 0.0 || u > 1.0) return kInf;
  return s;
}

double ray_circle_distance(const Eigen::Vector2d& o, const Eigen::Vector2d& d, const Eigen::Vector2d& centre,
                           double radius) {
  // |o + s·d − c|² = r²  ⇔  s² + 2·s·β + γ = 0 with β = d·(o − c), γ = |o − c|² − r²;
  // the entry point is the smaller root s = −β − √(β² − γ).
  const Eigen::Vector2d oc = o - centre;
  const double beta = d.dot(oc);
  const double gamma = oc.squaredNorm() - radius * radius;
  if (gamma <= 0.0) return kInf;  // starts inside
  const double disc2 = beta * beta - gamma;
  if (disc2 < 0.0) return kInf;
  const double s = -beta - std::sqrt(disc2);
  return s >= 0.0 ? s : kInf;
}

Eigen::VectorXd planar_scan(const std::vector<TrueShape>& shapes, const Pose6& x_ms, const Eigen::VectorXd& bearings,
                            double max_range) {
  const Eigen::Vector2d o = x_ms.head<2>();
  Eigen::VectorXd ranges(bearings.size());
  for (Eigen::Index i = 0; i < bearings.size(); ++i) {
    const double angle = x_ms[kTheta] + bearings[i];
    const Eigen::Vector2d d(std::cos(angle), std::sin(angle));
    double best = kInf;
    for (const TrueShape& s : shapes) {
      if (s.kind == TrueShape::Kind::Segment)
        best = std::min(best, ray_segment_distance(o, d, s.a.head<2>(), s.b.head<2>()));
      else if (s.kind == TrueShape::Kind::VerticalCylinder)
        best = std::min(best, ray_circle_distance(o, d, s.a.head<2>(), s.radius));
    }
    ranges[i] = best <= max_range ? best : 0.0;
  }
  return ranges;
}

}  // namespace mspace
