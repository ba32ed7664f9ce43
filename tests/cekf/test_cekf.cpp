// Tests of the compressed EKF (sdk/src/cekf_filter.cpp): driven side by
// side with the full EKF of plugins/ekf through random sequences of predict,
// update, augment, remove, marginal and cross, it must give the same δx and
// the same covariance to round-off at every step — across activations of
// passive rows and global updates — and reject bad input exactly as the EKF
// does (with "cekf" in the messages). The same holds with the
// observability-constrained option on in both filters; off, the option changes
// nothing, bit for bit. On whole runs of issue 13's range-bearing scenario
// (tests/bench/range_bearing_scenario.hpp) at a slow and a fast robot, the
// final state of the ekf and the cekf (with and without its churn fallback)
// agree to 1e-9, and the fallback engages only for the fast robot.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <functional>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "mspace/cekf_filter.hpp"
#include "../bench/range_bearing_scenario.hpp"
#include "mspace/ekf_filter.hpp"

namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;
using mspace::LinearizedObservation;
using mspace::StateAugmentation;
using mspace::cekf::CekfFilter;
using mspace::ekf::EkfFilter;

constexpr double kRelTol = 1e-9;
constexpr int kRobotDim = 3;

/// max |a − b| / max |b| (b the reference; 0 when both are empty).
double relative_error(const MatrixXd& a, const MatrixXd& b) {
  EXPECT_EQ(a.rows(), b.rows());
  EXPECT_EQ(a.cols(), b.cols());
  if (a.rows() != b.rows() || a.cols() != b.cols()) return 1e300;
  if (b.size() == 0) return 0.0;
  return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
}

MatrixXd random_matrix(int rows, int cols, std::mt19937& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  return MatrixXd::NullaryExpr(rows, cols, [&] { return normal(rng); });
}

/// Symmetric positive definite with eigenvalues ≥ floor.
MatrixXd random_spd(int n, double floor, std::mt19937& rng) {
  const MatrixXd a = random_matrix(n, n, rng);
  return a * a.transpose() / std::max(n, 1) + floor * MatrixXd::Identity(n, n);
}

int uniform_int(int lo, int hi, std::mt19937& rng) { return std::uniform_int_distribution<int>(lo, hi)(rng); }

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

/// Global planar motion of a robot (x, y, θ) at (x, y): translation along x,
/// along y, rotation about the origin (the kernel's U_r for a planar robot).
MatrixXd global_motion(double x, double y) { return MatrixXd{{1, 0, -y}, {0, 1, x}, {0, 0, 1}}; }

/// The observability-constrained option of both filters, and whether they are
/// given the robot's unobservable directions after reset (as the kernel does).
enum class Constraint {
  Off,                 ///< option off, no directions
  OffGivenDirections,  ///< option off, set_unobservable() called (ignored)
  OnWithoutDirections, ///< option on, set_unobservable() never called
  On,                  ///< option on with global_motion(0.7, −1.2)
};

bool option_on(Constraint c) { return c == Constraint::OnWithoutDirections || c == Constraint::On; }

/// The EKF and the CEKF fed the same calls; every result is compared.
/// `features` lists the state rows of each feature (renumbered on removal).
struct Twin {
  EkfFilter ekf;
  CekfFilter cekf;
  std::vector<std::vector<int>> features;
  std::mt19937 rng;
  double worst = 0.0;     ///< largest relative difference seen
  int passive_steps = 0;     ///< steps that started with at least one passive row
  int all_active_steps = 0;  ///< steps that started with every row active after churn
  VectorXd last_dx;          ///< the CEKF's δx of the latest update

  Twin(int max_active, int keep_steps, unsigned seed, Constraint constraint = Constraint::Off,
       bool churn_fallback = true)
      : ekf(64, option_on(constraint)),
        cekf(max_active, keep_steps, option_on(constraint), churn_fallback),
        rng(seed) {
    const MatrixXd P_rr = random_spd(kRobotDim, 0.5, rng);
    ekf.reset(P_rr);
    cekf.reset(P_rr);
    if (constraint == Constraint::OffGivenDirections || constraint == Constraint::On) {
      ekf.set_unobservable(global_motion(0.7, -1.2));
      cekf.set_unobservable(global_motion(0.7, -1.2));
    }
  }

  void record(double error) {
    worst = std::max(worst, error);
    EXPECT_LE(error, kRelTol);
  }

  void compare_covariance() { record(relative_error(cekf.covariance(), ekf.covariance())); }

  void predict() {
    const MatrixXd F = MatrixXd::Identity(kRobotDim, kRobotDim) + 0.1 * random_matrix(kRobotDim, kRobotDim, rng);
    const MatrixXd Q = random_spd(kRobotDim, 0.01, rng) * 0.05;
    ekf.predict(F, Q);
    cekf.predict(F, Q);
  }

  /// A feature of 1–3 rows from the robot, sometimes also from another
  /// feature (possibly repeating an index), sometimes from nothing.
  void augment() {
    const int added = uniform_int(1, 3);
    StateAugmentation aug;
    const int kind = uniform_int(0, 5);
    if (kind > 0) aug.idx = {0, 1, 2};
    if (kind >= 4 && !features.empty()) {
      const auto& other = features[static_cast<std::size_t>(uniform_int(0, static_cast<int>(features.size()) - 1))];
      aug.idx.insert(aug.idx.end(), other.begin(), other.end());
      if (kind == 5) aug.idx.push_back(other.front());  // a repeated index adds its columns
    }
    aug.J = random_matrix(added, static_cast<int>(aug.idx.size()), rng);
    aug.C_new = random_spd(added, 0.2, rng);
    const int first_ekf = ekf.augment(aug);
    const int first_cekf = cekf.augment(aug);
    EXPECT_EQ(first_cekf, first_ekf);
    std::vector<int> rows(static_cast<std::size_t>(added));
    for (int r = 0; r < added; ++r) rows[static_cast<std::size_t>(r)] = first_ekf + r;
    features.push_back(rows);
  }

  int uniform_int(int lo, int hi) { return ::uniform_int(lo, hi, rng); }

  /// 1–5 observations of distinct random features, most of them with the robot.
  void update() {
    if (features.empty()) return;
    std::vector<int> order(features.size());
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), rng);
    const int count = std::min(uniform_int(1, 5), static_cast<int>(features.size()));
    std::vector<LinearizedObservation> obs;
    for (int i = 0; i < count; ++i) {
      LinearizedObservation o;
      if (uniform_int(0, 4) > 0) o.idx = {0, 1, 2};
      const auto& f = features[static_cast<std::size_t>(order[static_cast<std::size_t>(i)])];
      o.idx.insert(o.idx.end(), f.begin(), f.end());
      const int m = uniform_int(1, 3);
      o.J = random_matrix(m, static_cast<int>(o.idx.size()), rng);
      o.eta = random_matrix(m, 1, rng);
      o.C_eta = random_spd(m, 0.1, rng);
      obs.push_back(o);
    }
    last_dx = cekf.update(obs);
    record(relative_error(last_dx, ekf.update(obs)));
  }

  /// Drops a random feature; the rows after it shift down.
  void remove() {
    if (features.empty()) return;
    const auto pick = static_cast<std::size_t>(uniform_int(0, static_cast<int>(features.size()) - 1));
    const std::vector<int> rows = features[pick];
    ekf.remove(rows);
    cekf.remove(rows);
    features.erase(features.begin() + static_cast<std::ptrdiff_t>(pick));
    for (auto& f : features) {
      for (int& i : f) i -= static_cast<int>(std::count_if(rows.begin(), rows.end(), [i](int r) { return r < i; }));
    }
  }

  std::vector<int> random_indices() {
    std::vector<int> idx;
    const int count = uniform_int(1, 8);
    for (int i = 0; i < count; ++i) idx.push_back(uniform_int(0, ekf.dim() - 1));
    return idx;
  }

  void query() {
    const std::vector<int> idx = random_indices(), other = random_indices();
    record(relative_error(cekf.marginal(idx), ekf.marginal(idx)));
    record(relative_error(cekf.cross(idx, other), ekf.cross(idx, other)));
    if (!features.empty()) {  // the kernel's gating query: robot and one feature
      std::vector<int> gate = {0, 1, 2};
      const auto& f = features[static_cast<std::size_t>(uniform_int(0, static_cast<int>(features.size()) - 1))];
      gate.insert(gate.end(), f.begin(), f.end());
      record(relative_error(cekf.marginal(gate), ekf.marginal(gate)));
    }
  }

  bool any_passive() const {
    for (int i = 0; i < cekf.dim(); ++i) {
      if (!cekf.is_active(i)) return true;
    }
    return false;
  }

  /// One random operation; the map grows towards `target_dim` rows.
  void step(int target_dim) {
    if (any_passive()) ++passive_steps;
    if (cekf.all_active()) ++all_active_steps;
    const int op = uniform_int(0, 99);
    if (op < 25) {
      predict();
    } else if (op < 60) {
      update();
    } else if (op < 60 + (ekf.dim() < target_dim ? 25 : 5)) {
      augment();
    } else if (op < 92) {
      query();
    } else if (op < 97) {
      remove();
    } else {
      cekf.flush();
    }
    EXPECT_EQ(cekf.dim(), ekf.dim());
    // U is carried by the same shared code in both: equal bit for bit.
    EXPECT_TRUE(cekf.unobservable() == ekf.unobservable());
    compare_covariance();
  }
};

// ---------------------------------------------------------------------------
// Random sequences against the EKF.

struct SequenceCase {
  int max_active;
  int keep_steps;
  int target_dim;
  int steps;
  unsigned seed;
  bool churn_fallback;  ///< on: both forms (compressed, all active) must have been used
};

/// The sequence exercised what its case is about: global updates, passive rows
/// and, with the churn fallback, stretches with every row active.
void expect_both_forms_used(const SequenceCase& c, const Twin& twin) {
  EXPECT_GT(twin.cekf.global_updates(), 0);
  if (!c.churn_fallback) {
    EXPECT_GT(twin.passive_steps, c.steps / 4);
    EXPECT_EQ(twin.all_active_steps, 0);
    EXPECT_EQ(twin.cekf.fallbacks(), 0);
    return;
  }
  EXPECT_GT(twin.passive_steps, c.steps / 10);
  EXPECT_GT(twin.all_active_steps, c.steps / 10);
  EXPECT_GT(twin.cekf.fallbacks(), 1);  // so it also went back to the compressed form
}

class CekfSequence : public ::testing::TestWithParam<SequenceCase> {};

TEST_P(CekfSequence, AgreesWithTheEkfAtEveryStep) {
  const SequenceCase c = GetParam();
  Twin twin(c.max_active, c.keep_steps, c.seed, Constraint::Off, c.churn_fallback);
  for (int s = 0; s < c.steps; ++s) {
    twin.step(c.target_dim);
    if (HasFailure()) FAIL() << "first disagreement at step " << s;
  }
  EXPECT_LE(twin.worst, kRelTol);
  expect_both_forms_used(c, twin);
}

TEST_P(CekfSequence, ObservabilityConstrainedAgreesWithTheConstrainedEkfAtEveryStep) {
  const SequenceCase c = GetParam();
  Twin twin(c.max_active, c.keep_steps, c.seed, Constraint::On, c.churn_fallback);
  for (int s = 0; s < c.steps; ++s) {
    twin.step(c.target_dim);
    if (HasFailure()) FAIL() << "first disagreement at step " << s;
  }
  EXPECT_LE(twin.worst, kRelTol);
  expect_both_forms_used(c, twin);
  // The directions were carried over every row: 3 of them, the robot rows
  // moved by the predictions (no longer the initial global motion).
  ASSERT_EQ(twin.cekf.unobservable().rows(), twin.cekf.dim());
  ASSERT_EQ(twin.cekf.unobservable().cols(), 3);
  EXPECT_GT((twin.cekf.unobservable().topRows(kRobotDim) - global_motion(0.7, -1.2)).cwiseAbs().maxCoeff(), 0.1);
}

// The compressed form alone (churn fallback off), then with the fallback
// (random updates touch random rows: the active set churns).
INSTANTIATE_TEST_SUITE_P(
    Sizes, CekfSequence,
    ::testing::Values(SequenceCase{1, 0, 40, 400, 1, false},      // a global update after every call
                      SequenceCase{12, 2, 60, 600, 2, false},     // small active part, many activations
                      SequenceCase{24, 5, 150, 800, 3, false},    //
                      SequenceCase{40, 1000, 300, 900, 4, false},  // keep everything recent (capped at 20)
                      SequenceCase{1000, 3, 200, 600, 5, false},  // global updates by flush() only
                      SequenceCase{12, 2, 60, 600, 6, true},      //
                      SequenceCase{24, 5, 150, 800, 7, true}));

// ---------------------------------------------------------------------------
// The compressed form itself.

/// A state of `features` 3-row features, all made passive by a global update
/// that keeps only the robot active.
struct PassiveMap {
  EkfFilter ekf;
  CekfFilter cekf{1000, 0};
  std::mt19937 rng{77};

  explicit PassiveMap(int features) {
    const MatrixXd P_rr = random_spd(kRobotDim, 0.5, rng);
    ekf.reset(P_rr);
    cekf.reset(P_rr);
    for (int f = 0; f < features; ++f) {
      const StateAugmentation aug{{0, 1, 2}, random_matrix(3, 3, rng), random_spd(3, 0.2, rng)};
      ekf.augment(aug);
      cekf.augment(aug);
    }
    cekf.flush();
  }

  /// An m-row observation of the rows idx with a random Jacobian, η = eta·1, C = c·I.
  LinearizedObservation observation(std::vector<int> idx, int m, double eta, double c) {
    LinearizedObservation o;
    o.J = random_matrix(m, static_cast<int>(idx.size()), rng);
    o.idx = std::move(idx);
    o.eta = VectorXd::Constant(m, eta);
    o.C_eta = c * MatrixXd::Identity(m, m);
    return o;
  }
};

TEST(CekfPartition, GlobalUpdateKeepsOnlyTheRobotWhenNothingWasTouched) {
  PassiveMap map(5);
  EXPECT_EQ(map.cekf.active_dim(), kRobotDim);
  EXPECT_EQ(map.cekf.basis_dim(), kRobotDim);
  for (int i = kRobotDim; i < map.cekf.dim(); ++i) EXPECT_FALSE(map.cekf.is_active(i)) << i;
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
}

TEST(CekfPartition, UpdateOfPassiveFeatureActivatesItAndMovesTheOthersExactly) {
  PassiveMap map(6);
  // Observe feature 2 (rows 9..11) relative to the robot.
  LinearizedObservation o;
  o.idx = {0, 1, 2, 9, 10, 11};
  o.J = random_matrix(3, 6, map.rng);
  o.eta = VectorXd::Constant(3, 0.3);
  o.C_eta = 0.05 * MatrixXd::Identity(3, 3);
  const VectorXd dx_cekf = map.cekf.update({o});
  const VectorXd dx_ekf = map.ekf.update({o});
  EXPECT_LE(relative_error(dx_cekf, dx_ekf), kRelTol);
  // The observed feature joined A (with one basis row per activated row);
  // the others stayed passive yet moved, through their correlation with the robot.
  EXPECT_EQ(map.cekf.active_dim(), kRobotDim + 3);
  EXPECT_EQ(map.cekf.basis_dim(), kRobotDim + 3);
  for (int i : {9, 10, 11}) EXPECT_TRUE(map.cekf.is_active(i));
  EXPECT_FALSE(map.cekf.is_active(3));
  EXPECT_GT(std::abs(dx_cekf[3]), 1e-6);
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
}

// assign() (the smoother re-sets the running covariance after an
// optimisation): the whole covariance is replaced, the partition is a global
// update's, and later updates agree with the EKF given the same covariance.
TEST(CekfPartition, AssignReplacesTheCovarianceAndLaterUpdatesAgreeWithTheEkf) {
  PassiveMap map(6);
  // Make one feature active and the basis non-trivial, then assign.
  LinearizedObservation o = map.observation({0, 1, 2, 6, 7, 8}, 3, 0.2, 0.05);
  map.ekf.update({o});
  map.cekf.update({o});
  const MatrixXd C = random_spd(map.ekf.dim(), 0.3, map.rng);
  map.ekf.assign(C);
  map.cekf.assign(C);
  EXPECT_LE(relative_error(map.cekf.covariance(), C), kRelTol);
  EXPECT_EQ(map.cekf.active_dim(), kRobotDim) << "keep_steps 0: only the robot stays active, as after a global update";
  EXPECT_FALSE(map.cekf.is_active(6));
  // An update of a passive feature after assign: the same δx and covariance as the EKF's.
  o.idx = {0, 1, 2, 12, 13, 14};
  o.J = random_matrix(3, 6, map.rng);
  const VectorXd dx_cekf = map.cekf.update({o});
  const VectorXd dx_ekf = map.ekf.update({o});
  EXPECT_LE(relative_error(dx_cekf, dx_ekf), kRelTol);
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
  MatrixXd wrong = C;
  wrong(3, 3) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(map.cekf.assign(wrong), std::invalid_argument);
  EXPECT_THROW(map.cekf.assign(MatrixXd::Identity(3, 3)), std::invalid_argument);
}

TEST(CekfPartition, AugmentationFromPassiveRowsActivatesThem) {
  PassiveMap map(4);
  const StateAugmentation aug{{0, 6, 7}, random_matrix(2, 3, map.rng), random_spd(2, 0.2, map.rng)};
  EXPECT_EQ(map.cekf.augment(aug), map.ekf.augment(aug));
  EXPECT_TRUE(map.cekf.is_active(6));
  EXPECT_TRUE(map.cekf.is_active(7));
  EXPECT_FALSE(map.cekf.is_active(8));
  EXPECT_TRUE(map.cekf.is_active(map.cekf.dim() - 1));
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
}

TEST(CekfPartition, QueriesOfPassiveRowsChangeNothing) {
  PassiveMap map(5);
  const int active = map.cekf.active_dim(), basis = map.cekf.basis_dim();
  const std::vector<int> gate = {0, 1, 2, 6, 7, 8};
  EXPECT_LE(relative_error(map.cekf.marginal(gate), map.ekf.marginal(gate)), kRelTol);
  EXPECT_LE(relative_error(map.cekf.cross({4, 0}, {12, 13, 1}), map.ekf.cross({4, 0}, {12, 13, 1})), kRelTol);
  EXPECT_EQ(map.cekf.active_dim(), active);
  EXPECT_EQ(map.cekf.basis_dim(), basis);
  EXPECT_FALSE(map.cekf.is_active(6));
}

TEST(CekfPartition, RepeatedGatingQueriesStayExactAcrossUpdates) {
  // The memo of passive quadratic forms is kept up to date by update().
  PassiveMap map(8);
  const std::vector<int> gate = {0, 1, 2, 15, 16, 17};
  for (int step = 0; step < 6; ++step) {
    EXPECT_LE(relative_error(map.cekf.marginal(gate), map.ekf.marginal(gate)), kRelTol) << step;
    LinearizedObservation o;
    o.idx = {0, 1, 2, 3 + 3 * (step % 4), 4 + 3 * (step % 4)};
    o.J = random_matrix(2, 5, map.rng);
    o.eta = VectorXd::Constant(2, 0.2);
    o.C_eta = 0.1 * MatrixXd::Identity(2, 2);
    EXPECT_LE(relative_error(map.cekf.update({o}), map.ekf.update({o})), kRelTol) << step;
  }
  EXPECT_FALSE(map.cekf.is_active(15));
}

TEST(CekfPartition, GlobalUpdateKeepsRecentlyTouchedRowsActive) {
  CekfFilter cekf(1000, 2);
  std::mt19937 rng(5);
  cekf.reset(random_spd(kRobotDim, 0.5, rng));
  for (int f = 0; f < 4; ++f)
    cekf.augment(StateAugmentation{{0, 1, 2}, random_matrix(2, 3, rng), random_spd(2, 0.2, rng)});
  const auto observe = [&](std::vector<int> idx) {
    LinearizedObservation o;
    o.idx = std::move(idx);
    o.J = random_matrix(1, static_cast<int>(o.idx.size()), rng);
    o.eta = VectorXd::Constant(1, 0.1);
    o.C_eta = 0.1 * MatrixXd::Identity(1, 1);
    cekf.update({o});
  };
  observe({0, 3, 4});  // three updates ago: forgotten with keep_steps = 2
  observe({0, 5, 6});
  observe({0, 7, 8});
  cekf.flush();
  EXPECT_FALSE(cekf.is_active(3));
  EXPECT_TRUE(cekf.is_active(5));
  EXPECT_TRUE(cekf.is_active(8));
  EXPECT_FALSE(cekf.is_active(9));  // augmented before the updates, never touched since
  EXPECT_EQ(cekf.active_dim(), kRobotDim + 4);
}

TEST(CekfPartition, RemovalOfActiveAndPassiveRowsThenGlobalUpdate) {
  PassiveMap map(6);
  const LinearizedObservation o = map.observation({0, 1, 2, 6, 7, 8}, 2, 0.1, 0.1);
  map.cekf.update({o});
  map.ekf.update({o});
  const std::vector<int> rows = {7, 12, 13, 14};  // one active row, one passive feature
  map.cekf.remove(rows);
  map.ekf.remove(rows);
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
  map.cekf.flush();  // drops the slots of the removed rows
  EXPECT_EQ(map.cekf.dim(), map.ekf.dim());
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
  map.cekf.predict(MatrixXd::Identity(3, 3), 0.01 * MatrixXd::Identity(3, 3));
  map.ekf.predict(MatrixXd::Identity(3, 3), 0.01 * MatrixXd::Identity(3, 3));
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
}

TEST(CekfPartition, NoObservationsAndEmptyAugmentationChangeNothing) {
  PassiveMap map(3);
  const MatrixXd before = map.cekf.covariance();
  EXPECT_EQ(map.cekf.update({}).size(), map.cekf.dim());
  EXPECT_EQ(map.cekf.update({}).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(map.cekf.augment(StateAugmentation{{4}, MatrixXd(0, 1), MatrixXd(0, 0)}), map.cekf.dim());
  EXPECT_EQ(relative_error(map.cekf.covariance(), before), 0.0);
  EXPECT_FALSE(map.cekf.is_active(4));
}

// ---------------------------------------------------------------------------
// Input checks: the EKF's messages with "cekf".

LinearizedObservation good_observation() {
  LinearizedObservation o;
  o.idx = {0, 4};
  o.J = MatrixXd{{1.0, -1.0}, {0.5, 2.0}};
  o.eta = VectorXd::Constant(2, 0.1);
  o.C_eta = 0.2 * MatrixXd::Identity(2, 2);
  return o;
}

TEST(CekfInput, NonFiniteInputsAreRejectedNamingMatrixAndRow) {
  PassiveMap map(3);
  CekfFilter& f = map.cekf;
  const MatrixXd before = f.covariance();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  auto update_with = [&f](const std::function<void(LinearizedObservation&)>& spoil) {
    return [&f, spoil] {
      std::vector<LinearizedObservation> obs = {good_observation(), good_observation(), good_observation()};
      spoil(obs[2]);
      f.update(obs);
    };
  };
  expect_throw_message<std::invalid_argument>(update_with([&](LinearizedObservation& o) { o.eta(1) = nan; }),
                                              "cekf update: observation 2: eta row 1 is not finite");
  expect_throw_message<std::invalid_argument>(update_with([&](LinearizedObservation& o) { o.J(1, 0) = inf; }),
                                              "cekf update: observation 2: J row 1 is not finite");
  expect_throw_message<std::invalid_argument>(update_with([&](LinearizedObservation& o) { o.C_eta(0, 1) = nan; }),
                                              "cekf update: observation 2: C_eta row 0 is not finite");
  MatrixXd bad = MatrixXd::Identity(3, 3);
  bad(1, 2) = nan;
  expect_throw_message<std::invalid_argument>([&] { f.predict(MatrixXd::Identity(3, 3), bad); },
                                              "cekf predict: Q row 1 is not finite");
  expect_throw_message<std::invalid_argument>([&] { f.predict(bad, MatrixXd::Identity(3, 3)); },
                                              "cekf predict: J_rr row 1 is not finite");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.augment(StateAugmentation{{0, 5}, MatrixXd{{1.0, inf}}, MatrixXd::Ones(1, 1)});
      },
      "cekf augment: J row 0 is not finite");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.augment(StateAugmentation{{0}, MatrixXd::Ones(2, 1), MatrixXd{{1.0, 0.0}, {nan, 1.0}}});
      },
      "cekf augment: C_new row 1 is not finite");
  EXPECT_EQ(f.dim(), 12);
  EXPECT_EQ(relative_error(f.covariance(), before), 0.0);
  EXPECT_FALSE(f.is_active(5));  // nothing was activated either

  CekfFilter fresh;
  expect_throw_message<std::invalid_argument>([&] { fresh.reset(bad); }, "cekf reset: P_rr row 1 is not finite");
}

TEST(CekfInput, SizesAndIndicesAreChecked) {
  PassiveMap map(2);
  CekfFilter& f = map.cekf;
  const MatrixXd before = f.covariance();
  auto update_one = [&f](const LinearizedObservation& o) { return [&f, o] { f.update({o}); }; };
  LinearizedObservation o = good_observation();
  o.idx = {0, 4, 5};
  expect_throw_message<std::invalid_argument>(update_one(o),
                                              "cekf update: observation 0: J has 2 columns but idx has 3 indices");
  o = good_observation();
  o.eta = VectorXd::Zero(3);
  expect_throw_message<std::invalid_argument>(update_one(o), "cekf update: observation 0: eta has 3 rows but J has 2");
  o = good_observation();
  o.C_eta = MatrixXd::Identity(3, 3);
  expect_throw_message<std::invalid_argument>(update_one(o),
                                              "cekf update: observation 0: C_eta is 3 x 3, expected 2 x 2");
  o = good_observation();
  o.idx = {0, 9};
  expect_throw_message<std::invalid_argument>(update_one(o),
                                              "cekf update: observation 0: index 9 is out of range [0, 9)");
  o = good_observation();
  o.idx = {4, 4};
  expect_throw_message<std::invalid_argument>(update_one(o),
                                              "cekf update: observation 0: index 4 appears more than once");
  expect_throw_message<std::invalid_argument>([&] { f.predict(MatrixXd::Identity(2, 2), MatrixXd::Identity(3, 3)); },
                                              "cekf predict: J_rr is 2 x 2, expected 3 x 3");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.augment(StateAugmentation{{0, 1}, MatrixXd::Ones(1, 1), MatrixXd::Ones(1, 1)});
      },
      "cekf augment: J is 1 x 1, expected 1 x 2");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.augment(StateAugmentation{{0}, MatrixXd::Ones(1, 1), MatrixXd::Ones(1, 2)});
      },
      "cekf augment: C_new is 1 x 2, expected 1 x 1");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.augment(StateAugmentation{{9}, MatrixXd::Ones(1, 1), MatrixXd::Ones(1, 1)});
      },
      "cekf augment: index 9 is out of range [0, 9)");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.remove({4, 1});
      },
      "cekf remove: index 1 is a robot pose coordinate (robot dimension 3)");
  expect_throw_message<std::invalid_argument>([&] { f.remove({5, 5}); }, "cekf remove: index 5 appears more than once");
  expect_throw_message<std::invalid_argument>([&] { f.remove({-1}); }, "cekf remove: index -1 is out of range [0, 9)");
  expect_throw_message<std::invalid_argument>(
      [&] {
        f.marginal({0, 9});
      },
      "cekf cross: rows: index 9 is out of range [0, 9)");
  expect_throw_message<std::invalid_argument>([&] { f.cross({0}, {-2}); },
                                              "cekf cross: cols: index -2 is out of range [0, 9)");
  expect_throw_message<std::invalid_argument>([] { CekfFilter bad(0, 4); },
                                              "cekf: max_active must be at least 1, got 0");
  expect_throw_message<std::invalid_argument>([] { CekfFilter bad(8, -1); },
                                              "cekf: keep_steps must be at least 0, got -1");
  EXPECT_EQ(f.dim(), 9);
  EXPECT_EQ(relative_error(f.covariance(), before), 0.0);
}

TEST(CekfInput, InnovationCovarianceNotPositiveDefiniteIsAnError) {
  PassiveMap map(2);
  const MatrixXd before = map.cekf.covariance();
  LinearizedObservation o = good_observation();
  o.C_eta = -100.0 * MatrixXd::Identity(2, 2);
  expect_throw_message<std::runtime_error>([&] { map.cekf.update({o}); },
                                           "cekf update: S (2 x 2) is not positive definite");
  // Row 4 may have been activated, which changes the representation only.
  EXPECT_LE(relative_error(map.cekf.covariance(), before), 1e-14);
  EXPECT_LE(relative_error(map.cekf.covariance(), map.ekf.covariance()), kRelTol);
}

// ---------------------------------------------------------------------------
// Observability-constrained mode (Huang, Mourikis & Roumeliotis, IJRR 2010).

TEST(CekfObservabilityConstrained, OffOrWithoutDirectionsIsThePlainFilterBitForBit) {
  // Lockstep random sequences (same seed, same calls) across global updates.
  Twin plain(12, 2, 9), off(12, 2, 9, Constraint::OffGivenDirections);
  Twin without(12, 2, 9, Constraint::OnWithoutDirections), on(12, 2, 9, Constraint::On);
  for (int s = 0; s < 300; ++s) {
    for (Twin* t : {&plain, &off, &without, &on}) t->step(50);
    ASSERT_TRUE(off.last_dx == plain.last_dx) << s;
    ASSERT_TRUE(without.last_dx == plain.last_dx) << s;
  }
  EXPECT_TRUE(off.cekf.covariance() == plain.cekf.covariance());
  EXPECT_TRUE(without.cekf.covariance() == plain.cekf.covariance());
  EXPECT_GT(plain.cekf.global_updates(), 0);
  EXPECT_FALSE(off.cekf.observability_constrained());
  EXPECT_EQ(off.cekf.unobservable().size(), 0);
  EXPECT_TRUE(without.cekf.observability_constrained());
  EXPECT_EQ(without.cekf.unobservable().rows(), without.cekf.dim());
  EXPECT_EQ(without.cekf.unobservable().cols(), 0);
  // With directions the option does change the estimate.
  EXPECT_GT(relative_error(on.cekf.covariance(), plain.cekf.covariance()), 1e-3);
}

/// A constrained (or plain) CEKF with five 3-row features, all passive.
CekfFilter passive_map_with_directions(bool constrained) {
  CekfFilter cekf(1000, 0, constrained);
  std::mt19937 rng(41);
  cekf.reset(random_spd(kRobotDim, 0.5, rng));
  cekf.set_unobservable(global_motion(0.7, -1.2));
  for (int f = 0; f < 5; ++f)
    cekf.augment(StateAugmentation{{0, 1, 2}, random_matrix(3, 3, rng), random_spd(3, 0.2, rng)});
  cekf.flush();
  return cekf;
}

TEST(CekfObservabilityConstrained, JacobianAlongTheDirectionsOfPassiveRowsChangesNothing) {
  CekfFilter cekf = passive_map_with_directions(true);
  CekfFilter plain = passive_map_with_directions(false);
  const std::vector<int> idx = {0, 1, 2, 9, 10, 11};
  ASSERT_FALSE(cekf.is_active(9));
  // Every row of J a combination of the columns of U[idx]: J lies in the
  // unobservable directions, so the projected J is zero (to round-off).
  const MatrixXd Ui = cekf.unobservable()(idx, Eigen::all);
  LinearizedObservation o;
  o.idx = idx;
  o.J = MatrixXd{{1.0, -2.0, 0.5}, {0.3, 0.0, 4.0}} * Ui.transpose();
  o.eta = VectorXd{{0.3, -0.2}};
  o.C_eta = MatrixXd{{0.05, 0.01}, {0.01, 0.04}};
  const MatrixXd before = cekf.covariance();
  ASSERT_EQ(relative_error(before, plain.covariance()), 0.0);
  const VectorXd dx = cekf.update({o});
  const VectorXd dx_plain = plain.update({o});
  // The plain filter takes it as real information.
  EXPECT_GT(dx_plain.cwiseAbs().maxCoeff(), 1e-2);
  EXPECT_GT((plain.covariance() - before).cwiseAbs().maxCoeff(), 1e-2);
  // The constrained one moves by round-off only: the projected J is ε‖J‖,
  // so δx is at most about ε‖J‖ ‖C‖ ‖C_η⁻¹ η‖ (and δC far less).
  const double scale = o.J.cwiseAbs().maxCoeff() * before.cwiseAbs().maxCoeff() *
                       o.C_eta.inverse().cwiseAbs().rowwise().sum().maxCoeff() * o.eta.cwiseAbs().maxCoeff();
  EXPECT_LT(dx.cwiseAbs().maxCoeff(), 1e-13 * scale);
  EXPECT_LT((cekf.covariance() - before).cwiseAbs().maxCoeff(), 1e-13 * scale);
  EXPECT_TRUE(cekf.is_active(9));  // activated all the same
}

TEST(CekfObservabilityConstrained, DirectionsAreChecked) {
  CekfFilter f(8, 2, true);
  f.reset(MatrixXd::Identity(3, 3));
  expect_throw_message<std::invalid_argument>([&] { f.set_unobservable(MatrixXd::Ones(2, 3)); },
                                              "cekf set_unobservable: U_r is 2 x 3, expected 3 x 3");
  MatrixXd bad = global_motion(0.0, 0.0);
  bad(1, 2) = std::numeric_limits<double>::quiet_NaN();
  expect_throw_message<std::invalid_argument>([&] { f.set_unobservable(bad); },
                                              "cekf set_unobservable: U_r row 1 is not finite");
  EXPECT_EQ(f.unobservable().cols(), 0);
  f.set_unobservable(global_motion(1.0, 2.0));
  LinearizedObservation o = good_observation();
  o.idx = {0, 3};
  expect_throw_message<std::invalid_argument>([&] { f.update({o}); },
                                              "cekf update: observation 0: index 3 is out of range [0, 3)");
}

// ---------------------------------------------------------------------------
// Whole runs of the range-bearing scenario (issue 13), ekf against cekf.

struct ScenarioCase {
  double speed;     ///< m per step
  bool fast_robot;  ///< expected to make the cekf fall back to EKF updates
};

class CekfRangeBearing : public ::testing::TestWithParam<ScenarioCase> {};

TEST_P(CekfRangeBearing, FinalStateIsTheEkfsWithAndWithoutTheChurnFallback) {
  using namespace mspace::bench;
  RangeBearingSettings settings;
  settings.landmarks = 400;
  settings.steps = 400;
  settings.speed = GetParam().speed;
  const RangeBearingLog log = make_range_bearing_log(settings);

  EkfFilter ekf;
  const RangeBearingResult reference = run_estimator(ekf, log);
  ASSERT_GT(reference.rows, 1000);  // a real run: many updates, a map of many landmarks
  ASSERT_GT(ekf.dim(), 3 + 2 * 100);
  const MatrixXd C = ekf.covariance();

  for (const bool fallback : {true, false}) {
    SCOPED_TRACE(fallback ? "churn fallback on" : "churn fallback off");
    // max_active 24: many global updates, as on a larger map with the default.
    CekfFilter cekf(24, CekfFilter::kDefaultKeepSteps, false, fallback);
    const RangeBearingResult result = run_estimator(cekf, log);
    ASSERT_EQ(result.mean.size(), reference.mean.size());
    EXPECT_LE((result.mean - reference.mean).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LE(relative_error(cekf.covariance(), C), kRelTol);
    if (!fallback) {
      EXPECT_GT(cekf.global_updates(), 10);
      EXPECT_EQ(cekf.fallbacks(), 0);
    } else if (GetParam().fast_robot) {
      // Every update brings new rows: the filter ends with every row active.
      EXPECT_GT(cekf.fallbacks(), 0);
      EXPECT_TRUE(cekf.all_active());
    } else {
      // Updates revisit the same rows: compressed (at most one fallback, while
      // the first landmarks were being added with few updates).
      EXPECT_LE(cekf.fallbacks(), 1);
      EXPECT_FALSE(cekf.all_active());
      EXPECT_GT(cekf.global_updates(), 10);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Speeds, CekfRangeBearing,
                         ::testing::Values(ScenarioCase{1.0, false}, ScenarioCase{10.0, true}),
                         [](const auto& info) { return info.param.fast_robot ? "Fast" : "Slow"; });

}  // namespace
