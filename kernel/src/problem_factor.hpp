// problem_factor.hpp — one factor of the nonlinear problem (problem.hpp):
// private to problem.cpp (recording, linearising) and problem_state.cpp
// (checkpoints), which both read every field.
#pragma once

#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "mspace/feature.hpp"
#include "mspace/measurement.hpp"
#include "problem.hpp"

namespace mspace::kernel {

/// feature_id of a factor on no feature (a pose relation; ids start at 1).
inline constexpr int kNoFeature = -1;

struct Problem::Factor {
  FactorKind kind = FactorKind::Linear;
  bool live = false;    ///< observation: re-linearised in full (else its last linearisation)
  bool robust = false;  ///< an observation (live or frozen)
  // observation (and coincidence: feature_id and other_id, sigma)
  int feature_id = 0;
  int other_id = 0;
  double sigma = 0.0;
  std::shared_ptr<Feature> feature;
  int type = 0;
  Measurement m;
  int sensor = 0;
  int node = 0;
  std::vector<int> rows;  ///< the feature's state_idx when recorded
  int dim = 0;            ///< the feature's M-space dimension when recorded
  // motion (and a pose relation: from, to, its value in m.v, covariance in m.C_v)
  int from = 0, to = 0;
  std::vector<OdometryIncrement> odometry;
  std::vector<std::size_t> odometry_records;  ///< trajectory index of each increment
  // The linearisation r = eta + J (x ⊟ x_lin): linear factors always, live
  // observations their newest one (kept for freezing). Columns: k per node
  // in lin_nodes, then one per estimator row in lin_rows.
  Eigen::VectorXd eta;
  Eigen::MatrixXd J, C;
  std::vector<int> lin_nodes;
  std::vector<Pose6> node_base;
  std::vector<int> lin_rows;
  Eigen::VectorXd row_base;
  // A frozen observation kept in its sensor's frame (Problem::freeze_in_frame):
  // r = eta + G (x_o − x_o_base), x_o the feature's coordinates seen from the
  // sensor at its pose node now, G = J_f B_old J_of⁻¹ from the freezing. Its
  // lin_nodes and lin_rows are empty: it reads the node and the feature's rows.
  bool in_frame = false;
  Eigen::VectorXd x_o_base;
  Eigen::MatrixXd G;
};

}  // namespace mspace::kernel
