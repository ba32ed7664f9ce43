// range_bearing_scenario.hpp — the planar range–bearing SLAM scenario of
// issue 13 (500 / 1000 / 2000 landmarks, 1000 steps, 1–10 m per step), as a
// log generated up front and a small EKF-SLAM driver that runs any
// mspace::Estimator on it. Used by tests/bench/bench_cekf.cpp (time) and
// tests/cekf/test_cekf.cpp (the ekf and the cekf give the same final state).
//
// The world. N point landmarks, uniform in a square of side sqrt(N / density)
// centred on the origin (density 0.02 per m² by default, so the robot meets
// landmarks at the same rate whatever N). The robot starts at the origin and
// drives `steps` steps of `speed` metres: each step it turns by a random
// angle (σ 10°), then drives straight; a step that would leave the square
// (minus a margin) turns towards the centre instead. A 360° sensor of range
// `max_range` reports (range, bearing) of every landmark in range, with the
// landmark's identity (true association: the scenario times the estimator,
// not the association). Odometry is the true increment plus Gaussian noise.
//
// The driver (run_estimator) is plain EKF-SLAM with planar points at M-space
// dimension 2 (state 3 + 2N, robot first): predict with the odometry
// (eqs. 25–27), one update with every re-observed landmark of the step
// (eqs. 28–32, η = h(x̂) − z), then one augmentation per new landmark
// (initialised from its first reading). It keeps the mean; the estimator
// keeps the covariance. Identical input and identical filters give identical
// results: the ekf and the cekf differ only by round-off.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <vector>

#include "mspace/estimator.hpp"

namespace mspace::bench {

struct RangeBearingSettings {
  int landmarks = 1000;
  int steps = 1000;
  double speed = 1.0;        ///< m per step
  double density = 0.02;     ///< landmarks per m²
  double max_range = 8.0;    ///< m (360° field of view)
  double range_sigma = 0.1;  ///< m
  double bearing_sigma = 0.5 * std::numbers::pi / 180.0;
  double turn_sigma = 10.0 * std::numbers::pi / 180.0;  ///< per step
  double odometry_sigma_per_m = 0.01;                    ///< along and across, m per m
  double heading_sigma_per_m = 0.1 * std::numbers::pi / 180.0;
  double heading_sigma_per_rad = 0.01;
  std::uint64_t seed = 1;
};

/// One reading: landmark `id` at (range, bearing) from the robot pose.
struct RangeBearingReading {
  int id;
  double range, bearing;
};

struct RangeBearingLog {
  RangeBearingSettings settings;
  Eigen::Matrix2Xd landmarks;
  /// odometry[k]: noisy increment (dx, dy, dθ) in the robot frame from pose k to pose k + 1.
  std::vector<Eigen::Vector3d> odometry;
  /// readings[k]: what the sensor saw at pose k + 1 (after odometry[k]).
  std::vector<std::vector<RangeBearingReading>> readings;
};

inline double wrap(double a) { return std::remainder(a, 2.0 * std::numbers::pi); }

/// p ⊕ u for planar poses (x, y, θ).
inline Eigen::Vector3d compose(const Eigen::Vector3d& p, const Eigen::Vector3d& u) {
  const double c = std::cos(p.z()), s = std::sin(p.z());
  return {p.x() + c * u.x() - s * u.y(), p.y() + s * u.x() + c * u.y(), wrap(p.z() + u.z())};
}

/// Odometry noise covariance (diagonal, in the increment's frame) of an increment.
inline Eigen::Matrix3d odometry_covariance(const RangeBearingSettings& s, const Eigen::Vector3d& u) {
  const double d = u.head<2>().norm();
  const double sxy = s.odometry_sigma_per_m * d + 1e-3;
  const double sth = s.heading_sigma_per_m * d + s.heading_sigma_per_rad * std::abs(u.z()) + 1e-4;
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, sth * sth).asDiagonal();
}

inline RangeBearingLog make_range_bearing_log(const RangeBearingSettings& s) {
  RangeBearingLog log;
  log.settings = s;
  std::mt19937_64 rng(s.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> unit(-0.5, 0.5);
  const double side = std::sqrt(s.landmarks / s.density);
  log.landmarks = Eigen::Matrix2Xd::NullaryExpr(2, s.landmarks, [&] { return side * unit(rng); });

  const double bound = 0.5 * side - s.max_range;  // the robot stays inside ±bound
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();
  for (int k = 0; k < s.steps; ++k) {
    // Turn, then drive straight: the increment in the robot frame.
    double turn = s.turn_sigma * normal(rng);
    const auto ahead = [&](double t) {
      const double h = pose.z() + t;
      return Eigen::Vector2d(pose.x() + s.speed * std::cos(h), pose.y() + s.speed * std::sin(h));
    };
    if (ahead(turn).cwiseAbs().maxCoeff() > bound) turn = wrap(std::atan2(-pose.y(), -pose.x()) - pose.z());
    const Eigen::Vector3d u(s.speed * std::cos(turn), s.speed * std::sin(turn), turn);
    pose = compose(pose, u);

    const Eigen::Vector3d sigma = odometry_covariance(s, u).diagonal().cwiseSqrt();
    log.odometry.emplace_back(u + Eigen::Vector3d(sigma.x() * normal(rng), sigma.y() * normal(rng),
                                                  sigma.z() * normal(rng)));
    std::vector<RangeBearingReading> seen;
    for (int id = 0; id < s.landmarks; ++id) {
      const Eigen::Vector2d d = log.landmarks.col(id) - pose.head<2>();
      const double r = d.norm();
      if (r > s.max_range) continue;
      seen.push_back({id, r + s.range_sigma * normal(rng),
                      wrap(std::atan2(d.y(), d.x()) - pose.z() + s.bearing_sigma * normal(rng))});
    }
    log.readings.push_back(std::move(seen));
  }
  return log;
}

struct RangeBearingResult {
  Eigen::VectorXd mean;  ///< robot (x, y, θ), then each mapped landmark (x, y) in order of first sight
  int updates = 0;       ///< update() calls with observations
  int rows = 0;          ///< measurement rows in them
};

/// Runs `filter` over the whole log (see the file comment) and returns the final mean.
inline RangeBearingResult run_estimator(Estimator& filter, const RangeBearingLog& log) {
  const RangeBearingSettings& s = log.settings;
  const Eigen::Matrix2d R =
      Eigen::Vector2d(s.range_sigma * s.range_sigma, s.bearing_sigma * s.bearing_sigma).asDiagonal();
  filter.reset(1e-6 * Eigen::Matrix3d::Identity());
  RangeBearingResult out;
  std::vector<double> mean = {0.0, 0.0, 0.0};
  std::vector<int> row_of(static_cast<std::size_t>(s.landmarks), -1);  // first state row of each landmark

  for (std::size_t k = 0; k < log.odometry.size(); ++k) {
    // Predict (eqs. 25–27): x_r ← x_r ⊕ u, J_rr = ∂(x ⊕ u)/∂x, Q = J_u C_u J_uᵀ.
    const Eigen::Vector3d& u = log.odometry[k];
    const double c = std::cos(mean[2]), sn = std::sin(mean[2]);
    Eigen::Matrix3d J_rr = Eigen::Matrix3d::Identity();
    J_rr(0, 2) = -sn * u.x() - c * u.y();
    J_rr(1, 2) = c * u.x() - sn * u.y();
    Eigen::Matrix3d J_u = Eigen::Matrix3d::Identity();
    J_u.topLeftCorner<2, 2>() << c, -sn, sn, c;
    filter.predict(J_rr, J_u * odometry_covariance(s, u) * J_u.transpose());
    const Eigen::Vector3d moved = compose({mean[0], mean[1], mean[2]}, u);
    for (int i = 0; i < 3; ++i) mean[static_cast<std::size_t>(i)] = moved[i];

    // Update (eqs. 28–32) with every landmark already in the map.
    std::vector<LinearizedObservation> obs;
    std::vector<const RangeBearingReading*> fresh;
    for (const RangeBearingReading& z : log.readings[k]) {
      const int row = row_of[static_cast<std::size_t>(z.id)];
      if (row < 0) {
        fresh.push_back(&z);
        continue;
      }
      const double dx = mean[static_cast<std::size_t>(row)] - mean[0];
      const double dy = mean[static_cast<std::size_t>(row) + 1] - mean[1];
      const double q = dx * dx + dy * dy, r = std::sqrt(q);
      LinearizedObservation o;
      o.idx = {0, 1, 2, row, row + 1};
      o.eta = Eigen::Vector2d(r - z.range, wrap(std::atan2(dy, dx) - mean[2] - z.bearing));
      o.J.resize(2, 5);
      o.J << -dx / r, -dy / r, 0, dx / r, dy / r,  //
          dy / q, -dx / q, -1, -dy / q, dx / q;
      o.C_eta = R;
      obs.push_back(std::move(o));
    }
    if (!obs.empty()) {
      const Eigen::VectorXd dx = filter.update(obs);
      for (std::size_t i = 0; i < mean.size(); ++i) mean[i] += dx[static_cast<Eigen::Index>(i)];
      mean[2] = wrap(mean[2]);
      ++out.updates;
      out.rows += 2 * static_cast<int>(obs.size());
    }

    // New landmarks: l = p + r (cos(θ + b), sin(θ + b)), from the robot and the reading.
    for (const RangeBearingReading* z : fresh) {
      const double a = mean[2] + z->bearing, ca = std::cos(a), sa = std::sin(a);
      StateAugmentation aug;
      aug.idx = {0, 1, 2};
      aug.J.resize(2, 3);
      aug.J << 1, 0, -z->range * sa, 0, 1, z->range * ca;
      Eigen::Matrix2d J_z;
      J_z << ca, -z->range * sa, sa, z->range * ca;
      aug.C_new = J_z * R * J_z.transpose();
      row_of[static_cast<std::size_t>(z->id)] = filter.augment(aug);
      mean.push_back(mean[0] + z->range * ca);
      mean.push_back(mean[1] + z->range * sa);
    }
  }
  out.mean = Eigen::Map<const Eigen::VectorXd>(mean.data(), static_cast<Eigen::Index>(mean.size()));
  return out;
}

}  // namespace mspace::bench
