// mspace/measurements/line_segment2d.hpp — the "line_segment2d" measurement: the contract
// between a 2-D line extractor (laser_lines) and the features that consume it
// (wall). Header-only; no dependencies beyond the SDK.
//
// v = (ρ, α, s_a, s_b) in the sensor frame (m, rad, m, m):
//   - the infinite line is { p : p·u = ρ }, u = (cos α, sin α), ρ > 0, so u
//     points from the sensor to the line (α is the bearing of the line's
//     closest point, the "foot");
//   - the segment runs along t = (sin α, −cos α) (u turned clockwise by 90°):
//     its end points are ρ·u + s_a·t and ρ·u + s_b·t with s_a < s_b.
// C_v is 4 × 4: the (ρ, α) block from the inlier points, and the end-point
// variances (how far the segment may extend before the next beam).
// Measurement::dense holds the inlier points (2 × N, sensor frame, in beam
// order). Measurement::flags says which ends are real ends of the surface (a
// corner or a depth discontinuity) rather than where the scan stopped seeing
// it (occlusion, edge of the field of view, maximum range), and why.
#pragma once

#include <cstdint>

namespace mspace::line_segment {

inline constexpr const char* kKind = "line_segment2d";
inline constexpr int kSize = 4;
enum Index : int { kRho = 0, kAlpha = 1, kSa = 2, kSb = 3 };

/// Why a segment stops at one end.
enum class EndReason : std::uint32_t {
  None = 0,
  Corner = 1,      ///< meets another segment at an angle: real
  Depth = 2,       ///< the next beam goes past the wall's end: real
  Fov = 3,         ///< edge of the field of view: not real
  MaxRange = 4,    ///< next beam has no return: not real
  Occluded = 5,    ///< next beam hits something in front: not real
  Unknown = 6,     ///< grazing angle, outlier, …: not real
};

inline constexpr std::uint32_t kRealA = 1u << 0;  ///< the s_a end is a real end
inline constexpr std::uint32_t kRealB = 1u << 1;  ///< the s_b end is a real end
inline constexpr int kReasonShiftA = 8;
inline constexpr int kReasonShiftB = 12;

inline bool is_real(EndReason r) { return r == EndReason::Corner || r == EndReason::Depth; }

/// Flags for the two ends' reasons.
inline std::uint32_t make_flags(EndReason a, EndReason b) {
  return (is_real(a) ? kRealA : 0u) | (is_real(b) ? kRealB : 0u) |
         (static_cast<std::uint32_t>(a) << kReasonShiftA) | (static_cast<std::uint32_t>(b) << kReasonShiftB);
}
inline EndReason reason_a(std::uint32_t flags) { return static_cast<EndReason>((flags >> kReasonShiftA) & 0xFu); }
inline EndReason reason_b(std::uint32_t flags) { return static_cast<EndReason>((flags >> kReasonShiftB) & 0xFu); }

}  // namespace mspace::line_segment
