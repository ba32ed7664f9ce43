// Tests of the M-space EKF (sdk/src/ekf_filter.cpp) against the dense
// textbook Kalman filter: x⁺ = x + K(z − Hx), P⁺ = (I − KH)P, computed here
// with full matrices and no knowledge of the filter's storage.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "mspace/ekf_filter.hpp"

namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using mspace::LinearizedObservation;
using mspace::StateAugmentation;
using mspace::ekf::EkfFilter;

constexpr double kTol = 1e-10;

double max_abs_diff(const MatrixXd& a, const MatrixXd& b) {
  EXPECT_EQ(a.rows(), b.rows());
  EXPECT_EQ(a.cols(), b.cols());
  if (a.rows() != b.rows() || a.cols() != b.cols()) return 1e300;
  return (a - b).cwiseAbs().maxCoeff();
}

/// The local Jacobian J (rows × idx.size()) written into the columns idx of a rows × n matrix.
MatrixXd scatter(const MatrixXd& J, const std::vector<int>& idx, int n) {
  MatrixXd H = MatrixXd::Zero(J.rows(), n);
  for (std::size_t c = 0; c < idx.size(); ++c) H.col(idx[c]) += J.col(static_cast<int>(c));
  return H;
}

/// Dense textbook Kalman filter over the whole state (mean x, covariance P).
struct DenseKalman {
  VectorXd x;
  MatrixXd P;

  /// Robot block k × k moves by F; the rest stays: P ← Fa P Faᵀ + Qa.
  void predict(const MatrixXd& F, const MatrixXd& Q) {
    const auto n = static_cast<int>(P.rows());
    const auto k = static_cast<int>(F.rows());
    MatrixXd Fa = MatrixXd::Identity(n, n);
    Fa.topLeftCorner(k, k) = F;
    MatrixXd Qa = MatrixXd::Zero(n, n);
    Qa.topLeftCorner(k, k) = Q;
    P = Fa * P * Fa.transpose() + Qa;
  }

  /// New rows y = G x + w with G = scatter(J, idx): P ← [I; G] P [I; G]ᵀ + diag(0, C_new).
  void augment(const std::vector<int>& idx, const MatrixXd& J, const MatrixXd& C_new,
               const VectorXd& mean_new) {
    const auto n = static_cast<int>(P.rows());
    const auto added = static_cast<int>(J.rows());
    MatrixXd A(n + added, n);
    A << MatrixXd::Identity(n, n), scatter(J, idx, n);
    MatrixXd Cw = MatrixXd::Zero(n + added, n + added);
    Cw.bottomRightCorner(added, added) = C_new;
    P = A * P * A.transpose() + Cw;
    x.conservativeResize(n + added);
    x.tail(added) = mean_new;
  }

  /// z = H x + v, v ~ N(0, R). Returns the state change K(z − Hx).
  VectorXd update(const MatrixXd& H, const MatrixXd& R, const VectorXd& z) {
    const MatrixXd S = H * P * H.transpose() + R;
    const MatrixXd K = P * H.transpose() * S.inverse();
    const VectorXd change = K * (z - H * x);
    x += change;
    const auto n = static_cast<int>(P.rows());
    P = (MatrixXd::Identity(n, n) - K * H) * P;
    return change;
  }
};

MatrixXd random_matrix(int rows, int cols, std::mt19937& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  MatrixXd m(rows, cols);
  for (int c = 0; c < cols; ++c) {
    for (int r = 0; r < rows; ++r) m(r, c) = normal(rng);
  }
  return m;
}

/// A well-conditioned symmetric positive definite matrix with eigenvalues ≳ `floor`.
MatrixXd random_spd(int n, std::mt19937& rng, double floor) {
  const MatrixXd a = random_matrix(n, n, rng);
  return a * a.transpose() / n + floor * MatrixXd::Identity(n, n);
}

/// Expects `call` to throw E with exactly `message`.
template <class E>
void expect_throw_message(const std::function<void()>& call, const std::string& message) {
  try {
    call();
    ADD_FAILURE() << "no exception; expected: " << message;
  } catch (const E& e) {
    EXPECT_EQ(std::string(e.what()), message);
  }
}

/// A filter with robot dimension 3 and features of 2, 3 and 1 rows appended with
/// random Jacobians, and the same covariance built with the dense formula.
/// With `U_r`, the filter is observability-constrained with robot directions U_r.
struct RandomState {
  EkfFilter filter;
  DenseKalman dense;

  explicit RandomState(unsigned seed, const MatrixXd* U_r = nullptr) : filter(4, U_r != nullptr) {
    std::mt19937 rng(seed);
    const MatrixXd P_rr = random_spd(3, rng, 0.5);
    filter.reset(P_rr);
    if (U_r) filter.set_unobservable(*U_r);
    dense.x = VectorXd::Zero(3);
    dense.P = P_rr;
    add({0, 2}, random_matrix(2, 2, rng), random_spd(2, rng, 0.2));
    add({4, 1, 3}, random_matrix(3, 3, rng), random_spd(3, rng, 0.2));
    add({}, MatrixXd(1, 0), random_spd(1, rng, 0.2));
  }

  void add(const std::vector<int>& idx, const MatrixXd& J, const MatrixXd& C_new) {
    const int first = filter.augment(StateAugmentation{idx, J, C_new});
    EXPECT_EQ(first, static_cast<int>(dense.P.rows()));
    dense.augment(idx, J, C_new, VectorXd::Zero(J.rows()));
  }
};

// ---------------------------------------------------------------------------
// A linear-Gaussian problem solved in closed form.

// Robot (position p, velocity v) on a line, constant-velocity motion, three
// landmarks at 1-D positions added as they are first seen. Landmark sightings
// measure l − p, a speedometer measures v. Because everything is linear the
// EKF must reproduce the Kalman filter exactly.
TEST(EkfLinear, MatchesDenseKalmanFilterOverSeveralCycles) {
  const double dt = 0.5;
  MatrixXd F(2, 2);
  F << 1, dt, 0, 1;
  MatrixXd Q(2, 2);
  Q << 0.01, 0.002, 0.002, 0.04;
  const VectorXd u = (VectorXd(2) << 0.05, 0.0).finished();  // known control offset
  MatrixXd P0(2, 2);
  P0 << 0.2, 0.01, 0.01, 0.3;

  EkfFilter ekf(2);
  ekf.reset(P0);
  VectorXd x_ekf = (VectorXd(2) << 0.0, 1.0).finished();  // the caller's estimate
  DenseKalman ref{x_ekf, P0};

  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.1);
  const std::vector<double> landmark_truth = {2.0, 3.5, 5.0};
  const double sight_var = 0.05;
  const double speed_var = 0.02;
  double true_p = 0.1;
  double true_v = 0.9;
  std::vector<int> landmark_row;  // state row of each landmark once added

  for (int step = 0; step < 8; ++step) {
    // Predict (eqs. 25–27): the caller moves the mean, the filter the covariance.
    true_p += true_v * dt;
    x_ekf.head(2) = F * x_ekf.head(2) + u;
    ekf.predict(F, Q);
    ref.x.head(2) = F * ref.x.head(2) + u;
    ref.predict(F, Q);

    // Add a landmark on steps 0, 1 and 3: l = p + z, so δl = δp + w.
    if (step == 0 || step == 1 || step == 3) {
      const auto which = landmark_row.size();
      const double z = landmark_truth[which] - true_p + noise(rng);
      const MatrixXd J = MatrixXd::Ones(1, 1);
      const MatrixXd C = MatrixXd::Constant(1, 1, sight_var);
      const VectorXd mean = VectorXd::Constant(1, x_ekf(0) + z);
      landmark_row.push_back(ekf.augment(StateAugmentation{{0}, J, C}));
      x_ekf.conservativeResize(x_ekf.size() + 1);
      x_ekf.tail(1) = mean;
      ref.augment({0}, J, C, mean);
    }

    // One update with every landmark sighting plus the speedometer.
    std::vector<LinearizedObservation> obs;
    MatrixXd H(0, ref.x.size());
    std::vector<double> z_all;
    std::vector<double> var_all;
    for (std::size_t i = 0; i < landmark_row.size(); ++i) {
      const int row = landmark_row[i];
      const double z = landmark_truth[i] - true_p + noise(rng);
      // Indices deliberately in descending order for the last landmark.
      const bool reversed = i + 1 == landmark_row.size();
      LinearizedObservation o;
      o.idx = reversed ? std::vector<int>{row, 0} : std::vector<int>{0, row};
      o.J = reversed ? MatrixXd{{1.0, -1.0}} : MatrixXd{{-1.0, 1.0}};
      o.eta = VectorXd::Constant(1, x_ekf(row) - x_ekf(0) - z);  // η = h(x) − z
      o.C_eta = MatrixXd::Constant(1, 1, sight_var);
      obs.push_back(o);
      z_all.push_back(z);
      var_all.push_back(sight_var);
    }
    const double speed = true_v + noise(rng);
    obs.push_back({VectorXd::Constant(1, x_ekf(1) - speed),
                   MatrixXd::Constant(1, 1, speed_var),
                   {1},
                   MatrixXd::Ones(1, 1)});
    z_all.push_back(speed);
    var_all.push_back(speed_var);
    for (const auto& o : obs) {
      H.conservativeResize(H.rows() + 1, Eigen::NoChange);
      H.bottomRows(1) = scatter(o.J, o.idx, static_cast<int>(ref.x.size()));
    }
    const VectorXd z = Eigen::Map<const VectorXd>(z_all.data(), static_cast<int>(z_all.size()));
    const MatrixXd R =
        Eigen::Map<const VectorXd>(var_all.data(), static_cast<int>(var_all.size())).asDiagonal();

    const VectorXd dx = ekf.update(obs);  // eq. 31
    x_ekf += dx;
    const VectorXd change = ref.update(H, R, z);

    EXPECT_LT(max_abs_diff(dx, change), kTol) << "step " << step;
    EXPECT_LT(max_abs_diff(x_ekf, ref.x), kTol) << "step " << step;
    EXPECT_LT(max_abs_diff(ekf.covariance(), ref.P), kTol) << "step " << step;
  }
  EXPECT_EQ(ekf.dim(), 5);
  // The landmark estimates end near the truth (a sanity check of the set-up).
  for (std::size_t i = 0; i < landmark_row.size(); ++i) {
    EXPECT_NEAR(x_ekf(landmark_row[i]), landmark_truth[i], 0.3);
  }
}

// ---------------------------------------------------------------------------
// Augment, remove, marginal, cross, capacity.

TEST(EkfAugment, CrossCovariancesMatchDenseFormula) {
  RandomState s(11);  // every add() also checks the returned first index
  EXPECT_EQ(s.filter.dim(), 9);
  EXPECT_EQ(s.filter.robot_dim(), 3);
  EXPECT_LT(max_abs_diff(s.filter.covariance(), s.dense.P), kTol);
  // The 1-row feature with no dependencies is uncorrelated with everything before it.
  EXPECT_EQ(s.filter.cross({8}, {0, 1, 2, 3, 4, 5, 6, 7}).cwiseAbs().maxCoeff(), 0.0);
}

TEST(EkfAugment, ZeroRowsIsANoOp) {
  RandomState s(12);
  const MatrixXd before = s.filter.covariance();
  EXPECT_EQ(s.filter.augment(StateAugmentation{{0}, MatrixXd(0, 1), MatrixXd(0, 0)}), 9);
  EXPECT_EQ(s.filter.dim(), 9);
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), before), 0.0);
}

TEST(EkfRemove, KeepsTheRestIntact) {
  RandomState s(13);
  s.filter.remove({6, 3, 7});
  const std::vector<int> keep = {0, 1, 2, 4, 5, 8};
  EXPECT_EQ(s.filter.dim(), 6);
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), s.dense.P(keep, keep)), 0.0);

  // The compacted storage keeps working: append and update again.
  DenseKalman dense{VectorXd::Zero(6), s.dense.P(keep, keep)};
  std::mt19937 rng(5);
  const MatrixXd J = random_matrix(2, 2, rng);
  const MatrixXd C = random_spd(2, rng, 0.3);
  EXPECT_EQ(s.filter.augment(StateAugmentation{{5, 1}, J, C}), 6);
  dense.augment({5, 1}, J, C, VectorXd::Zero(2));
  EXPECT_LT(max_abs_diff(s.filter.covariance(), dense.P), kTol);
}

TEST(EkfRemove, RejectsRobotRowsAndBadIndices) {
  RandomState s(14);
  const MatrixXd before = s.filter.covariance();
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.remove({4, 1});
      },
      "ekf remove: index 1 is a robot pose coordinate (robot dimension 3)");
  expect_throw_message<std::invalid_argument>([&] { s.filter.remove({9}); },
                                              "ekf remove: index 9 is out of range [0, 9)");
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.remove({5, 5});
      },
      "ekf remove: index 5 appears more than once");
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), before), 0.0);
}

TEST(EkfMarginal, MarginalAndCrossAgreeWithTheFullMatrix) {
  RandomState s(15);
  const MatrixXd& P = s.dense.P;
  const std::vector<int> idx = {7, 0, 4, 2};
  EXPECT_LT(max_abs_diff(s.filter.marginal(idx), P(idx, idx)), kTol);
  const std::vector<int> rows = {8, 1, 5};
  const std::vector<int> cols = {0, 6, 3, 8};
  EXPECT_LT(max_abs_diff(s.filter.cross(rows, cols), P(rows, cols)), kTol);
  EXPECT_LT(max_abs_diff(s.filter.cross(cols, rows), P(cols, rows)), kTol);
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.marginal({0, 10});
      },
      "ekf cross: rows: index 10 is out of range [0, 9)");
}

TEST(EkfStorage, CapacityDoublesAndKeepsValues) {
  std::mt19937 rng(16);
  EkfFilter f(2);
  const MatrixXd P_rr = random_spd(1, rng, 0.5);
  f.reset(P_rr);
  DenseKalman dense{VectorXd::Zero(1), P_rr};
  EXPECT_EQ(f.capacity(), 2);
  std::vector<int> capacities;
  for (int i = 0; i < 20; ++i) {
    const std::vector<int> idx = {0, i};
    const MatrixXd J = random_matrix(1, i == 0 ? 1 : 2, rng);
    const std::vector<int> used = i == 0 ? std::vector<int>{0} : idx;
    const MatrixXd C = random_spd(1, rng, 0.2);
    f.augment(StateAugmentation{used, J, C});
    dense.augment(used, J, C, VectorXd::Zero(1));
    capacities.push_back(f.capacity());
  }
  EXPECT_EQ(f.dim(), 21);
  EXPECT_EQ(capacities.front(), 2);
  EXPECT_EQ(capacities[2], 4);    // dim 4
  EXPECT_EQ(capacities[4], 8);    // dim 6
  EXPECT_EQ(capacities[8], 16);   // dim 10
  EXPECT_EQ(capacities[16], 32);  // dim 18
  EXPECT_EQ(f.capacity(), 32);
  EXPECT_LT(max_abs_diff(f.covariance(), dense.P), kTol);

  f.reserve(100);
  EXPECT_EQ(f.capacity(), 100);
  EXPECT_EQ(max_abs_diff(f.covariance(), dense.P), 0.0);
  f.reserve(50);  // never shrinks
  EXPECT_EQ(f.capacity(), 100);
}

// ---------------------------------------------------------------------------
// Predict (eqs. 26–27).

TEST(EkfPredict, MatchesEquations26And27OnARandomState) {
  RandomState s(17);
  std::mt19937 rng(3);
  const MatrixXd J_rr = random_matrix(3, 3, rng);
  const MatrixXd Q = random_spd(3, rng, 0.1);
  const MatrixXd P = s.filter.covariance();
  s.filter.predict(J_rr, Q);

  const MatrixXd C = s.filter.covariance();
  // eq. 26
  EXPECT_LT(
      max_abs_diff(C.topLeftCorner(3, 3), J_rr * P.topLeftCorner(3, 3) * J_rr.transpose() + Q),
      kTol);
  // eq. 27 (and its transpose)
  EXPECT_LT(max_abs_diff(C.topRightCorner(3, 6), J_rr * P.topRightCorner(3, 6)), kTol);
  EXPECT_LT(max_abs_diff(C.bottomLeftCorner(6, 3), P.bottomLeftCorner(6, 3) * J_rr.transpose()),
            kTol);
  // The M-space block does not change.
  EXPECT_EQ(max_abs_diff(C.bottomRightCorner(6, 6), P.bottomRightCorner(6, 6)), 0.0);
}

// ---------------------------------------------------------------------------
// A random larger problem (N = 300) against the dense textbook update.

TEST(EkfUpdate, RandomLargeProblemMatchesDenseFormula) {
  constexpr int kRobot = 3;
  constexpr int kFeatures = 99;
  std::mt19937 rng(2024);
  std::uniform_int_distribution<int> pick(0, kFeatures - 1);

  EkfFilter ekf;
  ekf.reset(random_spd(kRobot, rng, 0.5));
  for (int f = 0; f < kFeatures; ++f) {
    // Each feature initialised from the robot pose, so all rows are correlated.
    ekf.augment(StateAugmentation{{0, 1, 2}, random_matrix(3, 3, rng), random_spd(3, rng, 0.3)});
  }
  ASSERT_EQ(ekf.dim(), 300);
  DenseKalman ref{VectorXd::Zero(300), ekf.covariance()};

  for (int step = 0; step < 4; ++step) {
    const MatrixXd J_rr = MatrixXd::Identity(3, 3) + 0.1 * random_matrix(3, 3, rng);
    const MatrixXd Q = random_spd(3, rng, 0.05);
    ekf.predict(J_rr, Q);
    ref.predict(J_rr, Q);

    // Ten 3-row observations, each of the robot and one feature.
    std::vector<LinearizedObservation> obs;
    MatrixXd H = MatrixXd::Zero(30, 300);
    MatrixXd R = MatrixXd::Zero(30, 30);
    VectorXd eta(30);
    for (int i = 0; i < 10; ++i) {
      const int first = kRobot + 3 * pick(rng);
      LinearizedObservation o;
      o.idx = {0, 1, 2, first, first + 1, first + 2};
      o.J = random_matrix(3, 6, rng);
      o.C_eta = random_spd(3, rng, 0.1);
      o.eta = random_matrix(3, 1, rng);
      H.middleRows(3 * i, 3) = scatter(o.J, o.idx, 300);
      R.block(3 * i, 3 * i, 3, 3) = o.C_eta;
      eta.segment(3 * i, 3) = o.eta;
      obs.push_back(o);
    }
    // With x = 0 and z = −η the textbook change K(z − Hx) is −Kη (eq. 31).
    ref.x.setZero();
    const VectorXd expected = ref.update(H, R, -eta);
    const VectorXd dx = ekf.update(obs);
    EXPECT_LT(max_abs_diff(dx, expected), kTol) << "step " << step;
    EXPECT_LT(max_abs_diff(ekf.covariance(), ref.P), kTol) << "step " << step;
  }
}

TEST(EkfUpdate, NoObservationsChangesNothing) {
  RandomState s(18);
  const MatrixXd before = s.filter.covariance();
  const VectorXd dx = s.filter.update({});
  EXPECT_EQ(dx.size(), 9);
  EXPECT_EQ(dx.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), before), 0.0);
}

// ---------------------------------------------------------------------------
// Input checks: every message names the call, the matrix and the row.

LinearizedObservation good_observation() {
  LinearizedObservation o;
  o.idx = {0, 4};
  o.J = MatrixXd{{1.0, -1.0}, {0.5, 2.0}};
  o.eta = VectorXd::Constant(2, 0.1);
  o.C_eta = 0.2 * MatrixXd::Identity(2, 2);
  return o;
}

TEST(EkfInput, NonFiniteInputsAreRejectedNamingMatrixAndRow) {
  RandomState s(19);
  const MatrixXd before = s.filter.covariance();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();

  auto update_with = [&](const std::function<void(LinearizedObservation&)>& spoil) {
    return [&s, spoil] {
      std::vector<LinearizedObservation> obs = {good_observation(), good_observation()};
      spoil(obs[1]);
      s.filter.update(obs);
    };
  };
  expect_throw_message<std::invalid_argument>(
      update_with([&](LinearizedObservation& o) { o.eta(1) = nan; }),
      "ekf update: observation 1: eta row 1 is not finite");
  expect_throw_message<std::invalid_argument>(
      update_with([&](LinearizedObservation& o) { o.J(0, 1) = inf; }),
      "ekf update: observation 1: J row 0 is not finite");
  expect_throw_message<std::invalid_argument>(
      update_with([&](LinearizedObservation& o) { o.C_eta(1, 0) = -inf; }),
      "ekf update: observation 1: C_eta row 1 is not finite");

  MatrixXd bad = MatrixXd::Identity(3, 3);
  bad(2, 0) = nan;
  expect_throw_message<std::invalid_argument>(
      [&] { s.filter.predict(MatrixXd::Identity(3, 3), bad); },
      "ekf predict: Q row 2 is not finite");
  expect_throw_message<std::invalid_argument>(
      [&] { s.filter.predict(bad, MatrixXd::Identity(3, 3)); },
      "ekf predict: J_rr row 2 is not finite");

  const MatrixXd J_aug{{1.0, nan}};
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.augment(StateAugmentation{{0, 1}, J_aug, MatrixXd::Ones(1, 1)});
      },
      "ekf augment: J row 0 is not finite");
  const MatrixXd C_aug{{1.0, 0.0}, {inf, 1.0}};
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.augment(StateAugmentation{{0}, MatrixXd::Ones(2, 1), C_aug});
      },
      "ekf augment: C_new row 1 is not finite");

  EXPECT_EQ(s.filter.dim(), 9);
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), before), 0.0);

  EkfFilter fresh;
  expect_throw_message<std::invalid_argument>([&] { fresh.reset(bad); },
                                              "ekf reset: P_rr row 2 is not finite");
}

TEST(EkfInput, SizesAndIndicesAreChecked) {
  RandomState s(20);
  const MatrixXd before = s.filter.covariance();
  auto update_one = [&s](const LinearizedObservation& o) {
    return [&s, o] { s.filter.update({o}); };
  };

  LinearizedObservation o = good_observation();
  o.idx = {0, 4, 5};
  expect_throw_message<std::invalid_argument>(
      update_one(o), "ekf update: observation 0: J has 2 columns but idx has 3 indices");
  o = good_observation();
  o.eta = VectorXd::Zero(3);
  expect_throw_message<std::invalid_argument>(
      update_one(o), "ekf update: observation 0: eta has 3 rows but J has 2");
  o = good_observation();
  o.C_eta = MatrixXd::Identity(3, 3);
  expect_throw_message<std::invalid_argument>(
      update_one(o), "ekf update: observation 0: C_eta is 3 x 3, expected 2 x 2");
  o = good_observation();
  o.idx = {0, 9};
  expect_throw_message<std::invalid_argument>(
      update_one(o), "ekf update: observation 0: index 9 is out of range [0, 9)");
  o = good_observation();
  o.idx = {4, 4};
  expect_throw_message<std::invalid_argument>(
      update_one(o), "ekf update: observation 0: index 4 appears more than once");

  expect_throw_message<std::invalid_argument>(
      [&] { s.filter.predict(MatrixXd::Identity(2, 2), MatrixXd::Identity(3, 3)); },
      "ekf predict: J_rr is 2 x 2, expected 3 x 3");
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.augment(StateAugmentation{{0, 1}, MatrixXd::Ones(1, 1), MatrixXd::Ones(1, 1)});
      },
      "ekf augment: J is 1 x 1, expected 1 x 2");
  expect_throw_message<std::invalid_argument>(
      [&] {
        s.filter.augment(StateAugmentation{{0}, MatrixXd::Ones(1, 1), MatrixXd::Ones(1, 2)});
      },
      "ekf augment: C_new is 1 x 2, expected 1 x 1");
  expect_throw_message<std::invalid_argument>([] { EkfFilter bad_capacity(0); },
                                              "ekf: initial_capacity must be at least 1, got 0");
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), before), 0.0);
}

TEST(EkfUpdate, InnovationCovarianceNotPositiveDefiniteIsAnError) {
  RandomState s(21);
  const MatrixXd before = s.filter.covariance();
  LinearizedObservation o = good_observation();
  o.C_eta = -100.0 * MatrixXd::Identity(2, 2);
  expect_throw_message<std::runtime_error>([&] { s.filter.update({o}); },
                                           "ekf update: S (2 x 2) is not positive definite");
  EXPECT_EQ(max_abs_diff(s.filter.covariance(), before), 0.0);
}

// ---------------------------------------------------------------------------
// Observability-constrained mode (Huang, Mourikis & Roumeliotis, IJRR 2010).

/// Global planar motion of a robot (x, y, θ) at (x, y): translation along x,
/// along y, rotation about the origin.
MatrixXd global_motion(double x, double y) { return MatrixXd{{1, 0, -y}, {0, 1, x}, {0, 0, 1}}; }

/// The Jacobian of a planar odometry step that moves the robot by (dx, dy) in
/// the map: ∂(x', y')/∂θ = (−dy, dx), everything else the identity.
MatrixXd odometry_jacobian(double dx, double dy) { return MatrixXd{{1, 0, -dy}, {0, 1, dx}, {0, 0, 1}}; }

TEST(EkfObservabilityConstrained, DirectionsFollowPredictAugmentAndRemove) {
  EkfFilter f(4, true);
  f.reset(MatrixXd::Identity(3, 3));
  f.set_unobservable(global_motion(1.0, 2.0));
  EXPECT_EQ(max_abs_diff(f.unobservable(), global_motion(1.0, 2.0)), 0.0);

  // (1, 2) → (1.3, 2.5): U_r ← J_rr U_r is the global motion at the new pose.
  f.predict(odometry_jacobian(0.3, 0.5), 0.01 * MatrixXd::Identity(3, 3));
  EXPECT_LT(max_abs_diff(f.unobservable(), global_motion(1.3, 2.5)), kTol);

  // A point p = (x − θ, y + 2θ): rows J U[0..2] = (1, 0, −2.5 − 1), (0, 1, 1.3 + 2).
  f.augment(StateAugmentation{{0, 1, 2}, MatrixXd{{1, 0, -1}, {0, 1, 2}}, 0.1 * MatrixXd::Identity(2, 2)});
  // One row 2·δx[4] − δx[3]: 2·(0, 1, 3.3) − (1, 0, −3.5) = (−1, 2, 10.1).
  f.augment(StateAugmentation{{4, 3}, MatrixXd{{2, -1}}, MatrixXd::Constant(1, 1, 0.1)});
  // One row that depends on nothing: no motion.
  f.augment(StateAugmentation{{}, MatrixXd(1, 0), MatrixXd::Constant(1, 1, 0.1)});
  // (1.3, 2.5) → (1.1, 2.5): only the robot rows move.
  f.predict(odometry_jacobian(-0.2, 0.0), 0.01 * MatrixXd::Identity(3, 3));
  const MatrixXd before_remove{{1, 0, -2.5}, {0, 1, 1.1}, {0, 0, 1},   {1, 0, -3.5},
                               {0, 1, 3.3},  {-1, 2, 10.1}, {0, 0, 0}};
  EXPECT_LT(max_abs_diff(f.unobservable(), before_remove), kTol);

  f.remove({5, 3});
  const MatrixXd after_remove{{1, 0, -2.5}, {0, 1, 1.1}, {0, 0, 1}, {0, 1, 3.3}, {0, 0, 0}};
  EXPECT_LT(max_abs_diff(f.unobservable(), after_remove), kTol);
  EXPECT_EQ(f.dim(), 5);
}

// After a re-linearisation the kernel gives every row (Estimator::
// set_unobservable, SDK 6.1): U is replaced as a whole; k rows still set the
// robot's rows only; any other row count is refused.
TEST(EkfObservabilityConstrained, EveryRowMayBeGivenAfterARelinearisation) {
  EkfFilter f(4, true);
  f.reset(MatrixXd::Identity(3, 3));
  f.set_unobservable(global_motion(1.0, 2.0));
  f.augment(StateAugmentation{{0, 1, 2}, MatrixXd{{1, 0, -1}, {0, 1, 2}}, 0.1 * MatrixXd::Identity(2, 2)});
  MatrixXd every(5, 3);
  every << global_motion(4.0, -1.0), MatrixXd{{1, 0, 0.5}, {0, 1, 7.0}};
  f.set_unobservable(every);
  EXPECT_EQ(max_abs_diff(f.unobservable(), every), 0.0);
  f.set_unobservable(global_motion(0.0, 0.0));  // the robot's rows only
  EXPECT_EQ(max_abs_diff(f.unobservable().bottomRows(2), every.bottomRows(2)), 0.0);
  EXPECT_EQ(max_abs_diff(f.unobservable().topRows(3), global_motion(0.0, 0.0)), 0.0);
  expect_throw_message<std::invalid_argument>([&] { f.set_unobservable(MatrixXd::Ones(4, 3)); },
                                              "ekf set_unobservable: U_r is 4 x 3, expected 3 x 3");
  MatrixXd bad = every;
  bad(4, 1) = std::nan("");
  expect_throw_message<std::invalid_argument>([&] { f.set_unobservable(bad); },
                                              "ekf set_unobservable: U row 4 is not finite");
}

/// An observation of two rows over `idx` with the given Jacobian.
LinearizedObservation observation(const std::vector<int>& idx, const MatrixXd& J) {
  return LinearizedObservation{VectorXd{{0.3, -0.2}}, MatrixXd{{0.05, 0.01}, {0.01, 0.04}}, idx, J};
}

TEST(EkfObservabilityConstrained, JacobianAlongTheDirectionsChangesNothing) {
  const MatrixXd U_r = global_motion(0.7, -1.2);
  RandomState constrained(31, &U_r);
  RandomState plain(31);
  const std::vector<int> idx = {0, 1, 2, 4, 6};
  // Every row of J is a combination of the rows of U[idx]ᵀ: J lies in the
  // unobservable directions.
  const MatrixXd Ui = constrained.filter.unobservable()(idx, Eigen::all);
  const MatrixXd J = MatrixXd{{1.0, -2.0, 0.5}, {0.3, 0.0, 4.0}} * Ui.transpose();

  const MatrixXd before = constrained.filter.covariance();
  const VectorXd dx = constrained.filter.update({observation(idx, J)});
  EXPECT_LT(dx.cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(max_abs_diff(constrained.filter.covariance(), before), 1e-12);

  // The plain filter takes it as real information.
  const VectorXd dx_plain = plain.filter.update({observation(idx, J)});
  EXPECT_GT(dx_plain.cwiseAbs().maxCoeff(), 1e-2);
  EXPECT_GT(max_abs_diff(plain.filter.covariance(), before), 1e-2);
}

TEST(EkfObservabilityConstrained, UpdateUsesTheProjectedJacobianAndAddsNoInformationAlongU) {
  const MatrixXd U_r = global_motion(2.0, 0.5);
  RandomState constrained(32, &U_r);
  RandomState plain(32);
  std::mt19937 rng(33);
  const std::vector<int> idx = {0, 1, 2, 4, 6};
  const MatrixXd J = random_matrix(2, 5, rng);
  const MatrixXd U = constrained.filter.unobservable();
  ASSERT_EQ(U.rows(), 9);
  const MatrixXd Ui = U(idx, Eigen::all);  // 5 × 3, full column rank
  const MatrixXd J_projected = J * (MatrixXd::Identity(5, 5) - Ui * (Ui.transpose() * Ui).inverse() * Ui.transpose());

  const MatrixXd info_before = constrained.filter.covariance().inverse();
  const VectorXd dx = constrained.filter.update({observation(idx, J)});
  const VectorXd dx_plain = plain.filter.update({observation(idx, J_projected)});
  EXPECT_LT(max_abs_diff(dx, dx_plain), kTol);
  EXPECT_LT(max_abs_diff(constrained.filter.covariance(), plain.filter.covariance()), kTol);

  // The information gained, C⁺⁻¹ − C⁻¹ = Hᵀ C_η⁻¹ H, is zero along U.
  const MatrixXd gained = constrained.filter.covariance().inverse() - info_before;
  EXPECT_GT(gained.cwiseAbs().maxCoeff(), 1.0);
  EXPECT_LT((U.transpose() * gained * U).cwiseAbs().maxCoeff(), 1e-9);
}

/// Predict, augment, update and remove on `f`; returns the update's δx.
VectorXd exercise(EkfFilter& f) {
  f.reset(MatrixXd{{0.3, 0.02, 0.0}, {0.02, 0.2, 0.01}, {0.0, 0.01, 0.1}});
  f.predict(odometry_jacobian(0.4, -0.1), 0.01 * MatrixXd::Identity(3, 3));
  f.augment(StateAugmentation{{0, 2}, MatrixXd{{1, 0.5}, {0.2, 1}}, 0.1 * MatrixXd::Identity(2, 2)});
  f.augment(StateAugmentation{{1}, MatrixXd{{1}}, MatrixXd::Constant(1, 1, 0.2)});
  const VectorXd dx = f.update({observation({0, 3, 5}, MatrixXd{{1, -1, 0.5}, {0.2, 0.3, -1}})});
  f.remove({4});
  return dx;
}

TEST(EkfObservabilityConstrained, OffOrWithoutDirectionsIsThePlainFilterBitForBit) {
  EkfFilter plain(4), off(4, false), without(4, true);
  const VectorXd dx_plain = exercise(plain);
  off.set_unobservable(global_motion(1.0, 1.0));  // ignored when off
  EXPECT_TRUE(exercise(off) == dx_plain);
  EXPECT_TRUE(exercise(without) == dx_plain);
  EXPECT_TRUE(off.covariance() == plain.covariance());
  EXPECT_TRUE(without.covariance() == plain.covariance());
  EXPECT_EQ(off.unobservable().size(), 0);
  EXPECT_FALSE(off.observability_constrained());
  EXPECT_TRUE(without.observability_constrained());
  EXPECT_EQ(without.unobservable().rows(), 5);
  EXPECT_EQ(without.unobservable().cols(), 0);
}

TEST(EkfObservabilityConstrained, DirectionsAreChecked) {
  EkfFilter f(4, true);
  f.reset(MatrixXd::Identity(3, 3));
  expect_throw_message<std::invalid_argument>([&] { f.set_unobservable(MatrixXd::Ones(2, 3)); },
                                              "ekf set_unobservable: U_r is 2 x 3, expected 3 x 3");
  MatrixXd bad = global_motion(0.0, 0.0);
  bad(1, 2) = std::numeric_limits<double>::quiet_NaN();
  expect_throw_message<std::invalid_argument>([&] { f.set_unobservable(bad); },
                                              "ekf set_unobservable: U_r row 1 is not finite");
  EXPECT_EQ(f.unobservable().cols(), 0);
}

}  // namespace
