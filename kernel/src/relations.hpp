// relations.hpp — the relations metric of Kümmerle et al. 2009, "On measuring
// the accuracy of SLAM algorithms" (Autonomous Robots 27(4)).
//
// A relation (t1, t2, δ) states the reference relative pose δ of the robot at
// time t2 seen from its pose at time t1. An estimated trajectory is scored by
// comparing its own relative pose pose(t1)⁻¹ ⊕ pose(t2) with δ: the error
// ε = δ⁻¹ ⊕ (pose(t1)⁻¹ ⊕ pose(t2)) is split into a translational part |ε_xyz|
// (m) and a rotational part (the angle of ε's rotation, reported in degrees),
// and the statistics of both over all relations are reported, plain and
// squared. Relations whose time stamps do not both lie within a tolerance of
// a trajectory pose are not scored, only counted.
#pragma once

#include <cstddef>
#include <filesystem>
#include <vector>

#include "evaluation.hpp"
#include "mspace/pose.hpp"

namespace mspace::kernel {

struct Relation {
  double t1 = 0.0;
  double t2 = 0.0;
  Pose6 delta;  ///< pose at t2 in the frame of the pose at t1 (m, rad)
};

/// Reads a relations file: one relation per line, `t1 t2 x y z roll pitch yaw`
/// (m and rad); empty lines and lines starting with '#' are skipped. Throws
/// std::runtime_error "file:line: problem" for a malformed line or a file
/// that cannot be opened.
std::vector<Relation> read_relations(const std::filesystem::path& file);

/// Mean and (population) standard deviation.
struct MeanStd {
  double mean = 0.0;
  double std = 0.0;
};

struct RelationErrors {
  std::size_t total = 0;    ///< relations given
  std::size_t matched = 0;  ///< relations with both time stamps on the trajectory
  MeanStd translation;      ///< |ε_xyz| (m)
  MeanStd translation_sq;   ///< |ε_xyz|² (m²)
  MeanStd rotation_deg;     ///< rotation angle of ε (deg)
  MeanStd rotation_sq_deg;  ///< its square (deg²)
};

/// Scores `trajectory` (sorted by time or not) against `relations`, pairing
/// each time stamp with the trajectory pose closest in time if it lies within
/// `max_dt` seconds.
RelationErrors evaluate_relations(const std::vector<StampedPose>& trajectory,
                                  const std::vector<Relation>& relations, double max_dt);

}  // namespace mspace::kernel
