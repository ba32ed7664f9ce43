// mspace/estimator_support.hpp — input checks and observation stacking shared
// by the estimator plugins (ekf, cekf).
//
// Every check throws std::invalid_argument with a message that starts with the
// caller's `context` (e.g. "ekf update: observation 2") and names the matrix
// and the row, e.g. "ekf update: observation 2: J row 1 is not finite".
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "mspace/estimator.hpp"

namespace mspace::estimator_support {

/// "rows x cols".
std::string size_text(Eigen::Index rows, Eigen::Index cols);

/// Throws naming the first row of `m` that holds a NaN or an infinity:
/// "<context>: <name> row <r> is not finite".
void require_finite(const Eigen::Ref<const Eigen::MatrixXd>& m, const std::string& context, const char* name);

/// Throws unless `m` is rows × cols: "<context>: <name> is 2 x 3, expected 3 x 3".
void require_size(const Eigen::MatrixXd& m, Eigen::Index rows, Eigen::Index cols, const std::string& context,
                  const char* name);

/// Throws unless every index lies in [0, n) and, with `distinct`, none appears twice.
void require_indices(const std::vector<int>& idx, int n, const std::string& context, bool distinct);

/// P_rr of a reset: square and finite.
void validate_reset(const Eigen::MatrixXd& P_rr, const std::string& context);

/// Sizes, indices (in [0, n), distinct) and finiteness of one observation.
void validate_observation(const LinearizedObservation& o, int n, const std::string& context);

/// Sizes, indices (in [0, n), repeats allowed) and finiteness of an augmentation.
void validate_augmentation(const StateAugmentation& aug, int n, const std::string& context);

/// J_rr and Q of a robot prediction: both k × k and finite.
void validate_prediction(const Eigen::MatrixXd& J_rr, const Eigen::MatrixXd& Q, int k, const std::string& context);

/// Indices of a removal: in [0, n), distinct, none of them a robot row (< k).
void validate_removal(const std::vector<int>& idx, int n, int k, const std::string& context);

/// All observations of one step as one measurement over the union I of their
/// state indices: η = J_I δx[I] + noise with block-diagonal C_eta.
struct StackedObservation {
  std::vector<int> union_idx;  ///< I, sorted ascending
  Eigen::VectorXd eta;         ///< m
  Eigen::MatrixXd J;           ///< m × |I|
  Eigen::MatrixXd C_eta;       ///< m × m
};

/// Validates every observation (context "<context>: observation <i>") against a
/// state of dimension n, then stacks them. No observations give m = 0.
StackedObservation stack_observations(const std::vector<LinearizedObservation>& obs, int n, const std::string& context);

}  // namespace mspace::estimator_support
