// The laser_lines extractor on synthetic 180-beam scans of a known floor of
// walls, with range noise, clutter (small objects) and occlusion (pillars):
// precision and recall of segments and of real-end flags, and whether the
// (ρ, α) covariance and the real ends' positions are honest (normalised
// squared errors against the true walls).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <numbers>
#include <optional>
#include <random>
#include <vector>

#include <Eigen/Dense>

#include "line_extraction.hpp"

namespace {

using namespace mspace;
using namespace mspace::laser_lines;
using Vec2 = Eigen::Vector2d;
namespace ls = mspace::line_segment;

constexpr int kBeams = 180;
constexpr double kNoReturn = 81.83;

struct Wall {
  Vec2 a, b;
};

/// The same 14 m × 10 m floor as the laser_room fixture (tests/intel).
std::vector<Wall> floor_plan() {
  auto w = [](double x1, double y1, double x2, double y2) { return Wall{{x1, y1}, {x2, y2}}; };
  return {w(0, 0, 14, 0),  w(14, 0, 14, 10), w(14, 10, 0, 10), w(0, 10, 0, 0),  w(3, 3, 11, 3),
          w(11, 3, 11, 7), w(11, 7, 3, 7),   w(3, 7, 3, 3),    w(6, 0, 6, 1.2), w(9, 10, 9, 8.6),
          w(1.5, 5, 0, 5), w(12.5, 5.5, 14, 5.5)};
}

/// A square obstacle of side `size` centred at c (clutter or a pillar), as 4 walls.
void add_box(std::vector<Wall>& walls, const Vec2& c, double size) {
  const double h = 0.5 * size;
  const Vec2 p[4] = {c + Vec2(-h, -h), c + Vec2(h, -h), c + Vec2(h, h), c + Vec2(-h, h)};
  for (int i = 0; i < 4; ++i) walls.push_back({p[i], p[(i + 1) % 4]});
}

/// Ray cast: range to the first wall hit and its index (-1: none).
std::pair<double, int> cast(const std::vector<Wall>& walls, const Vec2& p, const Vec2& d) {
  double best = std::numeric_limits<double>::infinity();
  int hit = -1;
  for (std::size_t i = 0; i < walls.size(); ++i) {
    const Vec2 e = walls[i].b - walls[i].a;
    const double den = d.x() * e.y() - d.y() * e.x();
    if (std::abs(den) < 1e-12) continue;
    const Vec2 q = walls[i].a - p;
    const double t = (q.x() * e.y() - q.y() * e.x()) / den;
    const double s = (q.x() * d.y() - q.y() * d.x()) / den;
    if (t > 1e-9 && s >= 0.0 && s <= 1.0 && t < best) {
      best = t;
      hit = static_cast<int>(i);
    }
  }
  return {best, hit};
}

/// A wall's line in the sensor frame (ρ > 0, α) for a sensor at (p, θ).
std::pair<double, double> true_line(const Wall& w, const Vec2& p, double theta) {
  const Vec2 t = (w.b - w.a).normalized();
  Vec2 n(-t.y(), t.x());
  double rho = n.dot(w.a - p);
  if (rho < 0) {
    n = -n;
    rho = -rho;
  }
  return {rho, std::remainder(std::atan2(n.y(), n.x()) - theta, 2 * std::numbers::pi)};
}

struct Scan {
  Eigen::VectorXd ranges = Eigen::VectorXd(kBeams), bearings = Eigen::VectorXd(kBeams);
  std::vector<int> hit;  ///< wall index per beam, -1 for no return
};

Scan simulate(const std::vector<Wall>& walls, const Vec2& p, double theta, double sigma, std::mt19937_64& rng) {
  std::normal_distribution<double> noise(0.0, sigma);
  Scan s;
  s.hit.resize(kBeams);
  for (int i = 0; i < kBeams; ++i) {
    s.bearings[i] = (-90.0 + i) * std::numbers::pi / 180.0;
    const double a = theta + s.bearings[i];
    const auto [r, w] = cast(walls, p, {std::cos(a), std::sin(a)});
    s.hit[static_cast<std::size_t>(i)] = w;
    s.ranges[i] = w >= 0 ? r + noise(rng) : kNoReturn;
  }
  return s;
}

struct Tally {
  int true_pieces = 0, found_pieces = 0;      // segment recall
  int segments = 0, correct_segments = 0;     // segment precision
  int true_real_ends = 0, found_real_ends = 0;  // real-end recall
  int flagged_real = 0, correct_real = 0;       // real-end precision
  double line_nees = 0.0;
  int line_n = 0;
  double end_nees = 0.0, end_bias = 0.0;
  int end_n = 0;
};

/// The wall that at least all but one of a segment's beams hit (a corner
/// beam may belong to the other wall), or -1 when there is none.
int segment_wall(const Segment& seg, const Scan& scan) {
  for (int w : {scan.hit[static_cast<std::size_t>(seg.first)], scan.hit[static_cast<std::size_t>(seg.last)]}) {
    int off = 0;
    for (int i = seg.first; i <= seg.last; ++i) off += scan.hit[static_cast<std::size_t>(i)] != w;
    if (w >= 0 && off <= 1) return w;
  }
  return -1;
}

/// Is the wall point hit by beam `beam` within `tol` of one of the wall's true end points?
std::optional<Vec2> true_end_near(const Wall& w, const Vec2& hit_point, double tol) {
  for (const Vec2& e : {w.a, w.b})
    if ((e - hit_point).norm() <= tol) return e;
  return std::nullopt;
}

void score_scan(const std::vector<Wall>& walls, int real_walls, const Vec2& p, double theta, const Scan& scan,
                const LineConfig& c, Tally& t) {
  const std::vector<Segment> segs = extract_segments(scan.ranges, scan.bearings, c);
  auto beam_point = [&](int i) {
    const double a = theta + scan.bearings[i];
    return Vec2(p + scan.ranges[i] * Vec2(std::cos(a), std::sin(a)));
  };
  // Recall: runs of consecutive beams on one structural wall long enough to be a segment.
  for (int i = 0; i < kBeams;) {
    const int w = scan.hit[static_cast<std::size_t>(i)];
    int j = i;
    while (j + 1 < kBeams && scan.hit[static_cast<std::size_t>(j + 1)] == w) ++j;
    if (w >= 0 && w < real_walls && j - i + 1 >= c.min_points + 4 &&
        (beam_point(j) - beam_point(i)).norm() >= c.min_length + 0.2 && scan.ranges[i] < c.max_range &&
        scan.ranges[j] < c.max_range) {
      ++t.true_pieces;
      for (const Segment& s : segs)
        if (segment_wall(s, scan) == w && std::min(j, s.last) - std::max(i, s.first) + 1 >= (j - i + 1) / 2) {
          ++t.found_pieces;
          break;
        }
    }
    i = j + 1;
  }
  for (const Segment& s : segs) {
    ++t.segments;
    const int w = segment_wall(s, scan);
    if (w < 0) continue;
    ++t.correct_segments;
    const auto [rho, alpha] = true_line(walls[static_cast<std::size_t>(w)], p, theta);
    const Eigen::Vector2d e(s.rho - rho, std::remainder(s.alpha - alpha, 2 * std::numbers::pi));
    t.line_nees += e.dot(s.C.topLeftCorner<2, 2>().ldlt().solve(e));
    ++t.line_n;
    // Ends: truly real when the wall's true end point is within a beam gap of the end beam's hit
    // and that end point is visible (the next beam hits something farther away or nothing).
    const Vec2 u(std::cos(s.alpha), std::sin(s.alpha)), tv(std::sin(s.alpha), -std::cos(s.alpha));
    for (int k = 0; k < 2; ++k) {
      const double along = k == 0 ? s.s_a : s.s_b;
      const Vec2 end_sensor = s.rho * u + along * tv;
      const Vec2 end_map = p + Eigen::Rotation2Dd(theta) * end_sensor;
      const double gap = scan.ranges[s.first] * std::numbers::pi / 180.0 * 3.0 + 0.1;
      const std::optional<Vec2> e_true = true_end_near(walls[static_cast<std::size_t>(w)], end_map, gap);
      const bool truly_real = e_true.has_value();
      const ls::EndReason reason = k == 0 ? s.end_a : s.end_b;
      const bool flagged = ls::is_real(reason);
      t.true_real_ends += truly_real;
      t.found_real_ends += truly_real && flagged;
      t.flagged_real += flagged;
      t.correct_real += truly_real && flagged;
      if (truly_real && flagged) {
        const Vec2 e_s = Eigen::Rotation2Dd(-theta) * (*e_true - p);
        const double err = (along - tv.dot(e_s)) * (k == 0 ? 1.0 : -1.0);  // > 0: inwards
        t.end_bias += err;
        t.end_nees += err * err / s.C(2 + k, 2 + k);
        ++t.end_n;
      }
    }
  }
}

LineConfig intel_config() {
  LineConfig c;  // the extractor settings of config/intel_walls.yaml (without the systematic floors)
  c.range_sigma = 0.01;
  c.max_range = 20;
  c.split_distance = 0.06;
  c.min_points = 10;
  c.min_length = 0.6;
  c.max_rms = 0.03;
  c.depth_jump = 0.2;
  return c;
}

/// `scenes` scans with range noise `sigma`; with a tracker, each scan is cut
/// with the noise measured on the scans before it (range_sigma_from_data).
Tally run_scenes(bool clutter, int scenes, std::uint64_t seed, double sigma = 0.01,
                 RangeNoiseTracker* noise = nullptr) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  Tally t;
  LineConfig c = intel_config();
  for (int k = 0; k < scenes; ++k) {
    std::vector<Wall> walls = floor_plan();
    const int real_walls = static_cast<int>(walls.size());
    // The robot somewhere in the corridor ring around the inner block.
    Vec2 p;
    do p = Vec2(0.5 + 13.0 * uni(rng), 0.5 + 9.0 * uni(rng));
    while (p.x() > 2.5 && p.x() < 11.5 && p.y() > 2.5 && p.y() < 7.5);
    const double theta = 2 * std::numbers::pi * uni(rng);
    if (clutter) {
      for (int i = 0; i < 3; ++i) {  // chair legs / bins: 5–15 cm boxes near the robot
        const double a = 2 * std::numbers::pi * uni(rng), r = 0.6 + 1.5 * uni(rng);
        add_box(walls, p + r * Vec2(std::cos(a), std::sin(a)), 0.05 + 0.1 * uni(rng));
      }
      const double a = 2 * std::numbers::pi * uni(rng);  // a 30 cm pillar that occludes
      add_box(walls, p + (0.8 + uni(rng)) * Vec2(std::cos(a), std::sin(a)), 0.3);
    }
    const Scan scan = simulate(walls, p, theta, sigma, rng);
    if (noise != nullptr) c.breakpoint_sigma = noise->sigma(intel_config().range_sigma);
    score_scan(walls, real_walls, p, theta, scan, c, t);
    if (noise != nullptr) noise->add(extract_segments(scan.ranges, scan.bearings, c), c.max_incidence);
  }
  return t;
}

void print(const char* name, const Tally& t) {
  std::cout << name << ": segments precision " << double(t.correct_segments) / t.segments << " (" << t.segments
            << "), recall " << double(t.found_pieces) / t.true_pieces << " (" << t.true_pieces
            << "); real ends precision " << double(t.correct_real) / t.flagged_real << " (" << t.flagged_real
            << "), recall " << double(t.found_real_ends) / t.true_real_ends << " (" << t.true_real_ends
            << "); (rho, alpha) NEES " << t.line_nees / t.line_n << " (2 dof), real-end NEES "
            << t.end_nees / std::max(1, t.end_n) << " (1 dof, " << t.end_n << "), mean inward end error " << t.end_bias / std::max(1, t.end_n) << " m\n";
}

double ratio(int a, int b) { return static_cast<double>(a) / std::max(1, b); }

// Bounds, with what 300 scenes gave (clean / cluttered):
//  - segments: precision 0.996 / 0.983, recall 0.994 / 0.981 (a segment is
//    correct when all its beams but one — a shared corner beam — hit one
//    wall; a piece counts when ≥ 14 beams and ≥ 0.8 m of one wall are
//    visible). Bounds 0.97 / 0.95: a few misses per hundred, not more.
//  - real-end flags: precision 0.82 / 0.84, recall 0.81 / 0.75 (truth: the
//    wall's true end within 3 beam gaps + 0.1 m). Part of the "misses" are
//    the truth criterion's (ends just beyond a grazing beam), so the bounds
//    0.75 / 0.65 are regression bounds, not the extractor's limit.
//  - (ρ, α): mean NEES 1.39 / 1.33 for 2 dof: the covariance is honest to
//    conservative (σ² from the residuals, a lower bound range_sigma). Bound:
//    ≤ 2.4 (the sampling std of the mean over ~1100 segments is ≈ 0.1).
//  - real ends: mean NEES 0.29 / 0.34 and mean inward error 1 mm. Before the
//    end was placed in the middle of the gap (Depth) or at the corner
//    intersection (Corner) it was the last inlier: 3.6 cm short on average,
//    NEES 2.5. Bounds: NEES ≤ 1.2, |bias| ≤ 1 cm.
void expect_bounds(const Tally& t, double min_seg_recall, double min_end_recall) {
  EXPECT_GE(ratio(t.correct_segments, t.segments), 0.97);
  EXPECT_GE(ratio(t.found_pieces, t.true_pieces), min_seg_recall);
  EXPECT_GE(ratio(t.correct_real, t.flagged_real), 0.75);
  EXPECT_GE(ratio(t.found_real_ends, t.true_real_ends), min_end_recall);
  ASSERT_GT(t.line_n, 500);
  ASSERT_GT(t.end_n, 300);
  EXPECT_LE(t.line_nees / t.line_n, 2.4);
  EXPECT_LE(t.end_nees / t.end_n, 1.2);
  EXPECT_LE(std::abs(t.end_bias / t.end_n), 0.01);
}

TEST(LaserLines, CleanFloor) {
  const Tally t = run_scenes(false, 300, 1);
  print("clean", t);
  expect_bounds(t, 0.97, 0.75);
}

TEST(LaserLines, ClutteredFloor) {
  const Tally t = run_scenes(true, 300, 2);
  print("clutter", t);
  expect_bounds(t, 0.95, 0.65);
}

// range_sigma_from_data: the range noise measured on the segments (the
// median of the last 400 segments' residuals, turned back along the beams)
// is the noise the scans were made with, within 10 %, for lasers quieter and
// noisier than the configured 1 cm; a quieter one keeps the configured σ (the
// floor): the same segments as without the option. A noisier laser's scans
// cut into clusters with the measured σ (the breakpoint detector's 3σ term)
// lose no precision worth counting (≤ 1 point) and no recall; the README
// ("The laser's range noise, measured") has the 1080-beam laser, where
// the gain is large.
TEST(LaserLines, RangeNoiseIsMeasuredOnTheSegments) {
  for (const double sigma : {0.005, 0.01, 0.02, 0.03}) {
    RangeNoiseTracker noise;
    const Tally measured = run_scenes(false, 150, 3, sigma, &noise);
    const Tally configured = run_scenes(false, 150, 3, sigma);
    const std::optional<double> median = noise.median();
    ASSERT_TRUE(median.has_value()) << sigma;
    std::cout << "range noise " << sigma << " m: measured " << *median << " m on " << noise.samples().size()
              << " segments; recall " << ratio(configured.found_pieces, configured.true_pieces) << " configured, "
              << ratio(measured.found_pieces, measured.true_pieces) << " measured; precision "
              << ratio(configured.correct_segments, configured.segments) << " / "
              << ratio(measured.correct_segments, measured.segments) << "\n";
    EXPECT_NEAR(*median / sigma, 1.0, 0.1) << sigma;
    EXPECT_GT(noise.samples().size(), RangeNoiseTracker::kWindow * 9 / 10);
    if (sigma < intel_config().range_sigma) {
      EXPECT_EQ(measured.segments, configured.segments);
      EXPECT_EQ(measured.found_pieces, configured.found_pieces);
      EXPECT_EQ(measured.correct_real, configured.correct_real);
    } else {
      EXPECT_GE(ratio(measured.found_pieces, measured.true_pieces),
                ratio(configured.found_pieces, configured.true_pieces));
      EXPECT_GE(ratio(measured.correct_segments, measured.segments),
                ratio(configured.correct_segments, configured.segments) - 0.01);
    }
  }
}

TEST(LaserLines, RangeNoiseTrackerKeepsTheLatestWindowAndNeedsEnoughSegments) {
  RangeNoiseTracker noise;
  EXPECT_FALSE(noise.median().has_value());
  EXPECT_EQ(noise.sigma(0.01), 0.01);
  // A straight wall 2 m ahead seen with exact ranges: no residual at all.
  Segment clean;
  clean.rho = 2.0;
  clean.alpha = 0.0;
  clean.inliers.resize(2, 30);
  for (int i = 0; i < 30; ++i) clean.inliers.col(i) << 2.0, -1.0 + i / 15.0;
  ASSERT_TRUE(range_noise_of_segment(clean, 1.4).has_value());
  EXPECT_NEAR(*range_noise_of_segment(clean, 1.4), 0.0, 1e-12);
  // Offsets of ±e along x are range errors of e / cos(incidence) along each beam.
  Segment noisy = clean;
  for (int i = 0; i < 30; ++i) noisy.inliers(0, i) += (i % 2 == 0 ? 0.02 : -0.02);
  double expected = 0.0;
  for (int i = 0; i < 30; ++i) {
    const Vec2 q = noisy.inliers.col(i);
    expected += std::pow(0.02 * q.norm() / q.x(), 2);
  }
  EXPECT_NEAR(*range_noise_of_segment(noisy, 1.4), std::sqrt(expected / 28), 1e-12);
  Segment short_one = clean;
  short_one.inliers.conservativeResize(2, 19);
  EXPECT_FALSE(range_noise_of_segment(short_one, 1.4).has_value());
  for (std::size_t k = 0; k + 1 < RangeNoiseTracker::kMinSamples; ++k) noise.add({noisy}, 1.4);
  EXPECT_FALSE(noise.median().has_value());
  noise.add({noisy}, 1.4);
  EXPECT_GT(noise.sigma(0.01), 0.02);
  // The window keeps the latest: once kWindow clean segments followed, the noisy ones are gone.
  for (std::size_t k = 0; k < RangeNoiseTracker::kWindow; ++k) noise.add({clean}, 1.4);
  EXPECT_EQ(noise.samples().size(), RangeNoiseTracker::kWindow);
  EXPECT_NEAR(*noise.median(), 0.0, 1e-12);
  EXPECT_EQ(noise.sigma(0.01), 0.01);
}

}  // namespace
