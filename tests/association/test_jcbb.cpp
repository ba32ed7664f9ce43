// Joint compatibility branch and bound (Neira & Tardós 2001) on hand-built
// readings: 2-D point features observed relative to a 2-D robot position,
//   z = f − x + v,  η = z − (f̂ − x̂),  J_state = (−I  I)  over (x, f),
// so that every pairing of one reading shares the robot's uncertainty.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "association.hpp"
#include "chi2.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;

/// A state of a robot position (rows 0, 1) and n features (rows 2+2j, 3+2j).
struct World {
  Eigen::MatrixXd P;
  double meas_sigma = 0.05;

  World(int features, double robot_sigma, double feature_sigma) {
    P = Eigen::MatrixXd::Identity(2 + 2 * features, 2 + 2 * features) * feature_sigma * feature_sigma;
    P.topLeftCorner(2, 2) = Eigen::Matrix2d::Identity() * robot_sigma * robot_sigma;
  }

  MarginalFn marginal() const {
    return [this](const std::vector<int>& idx) {
      Eigen::MatrixXd m(static_cast<Eigen::Index>(idx.size()), static_cast<Eigen::Index>(idx.size()));
      for (std::size_t i = 0; i < idx.size(); ++i)
        for (std::size_t j = 0; j < idx.size(); ++j)
          m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = P(idx[i], idx[j]);
      return m;
    };
  }

  /// Measurement `m` (innovation η against feature `f`) as a gated candidate.
  Candidate candidate(int m, int f, const Eigen::Vector2d& eta) const {
    Candidate c;
    c.measurement = m;
    c.feature = f;
    c.innovation.eta = eta;
    c.innovation.J_eta_o = Eigen::Matrix2d::Identity();
    c.innovation.J_eta_v = Eigen::Matrix2d::Identity();
    c.C_eta = Eigen::Matrix2d::Identity() * meas_sigma * meas_sigma;
    c.J_state.resize(2, 4);
    c.J_state << -Eigen::Matrix2d::Identity(), Eigen::Matrix2d::Identity();
    c.idx = {0, 1, 2 + 2 * f, 3 + 2 * f};
    c.d2 = eta.dot(individual_S(c).ldlt().solve(eta));
    return c;
  }

  Eigen::MatrixXd individual_S(const Candidate& c) const {
    return c.J_state * marginal()(c.idx) * c.J_state.transpose() + c.C_eta;
  }

  /// Joint D² of a set of candidates, from the full stacked S (no increments).
  double joint_d2(const std::vector<Candidate>& cands, const std::vector<int>& chosen) const {
    const Eigen::Index n = 2 * static_cast<Eigen::Index>(chosen.size());
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, P.cols());
    Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n, n);
    Eigen::VectorXd nu(n);
    for (std::size_t i = 0; i < chosen.size(); ++i) {
      const Candidate& c = cands[chosen[i]];
      const auto r = 2 * static_cast<Eigen::Index>(i);
      for (std::size_t j = 0; j < c.idx.size(); ++j) J.block(r, c.idx[j], 2, 1) += c.J_state.col(static_cast<Eigen::Index>(j));
      C.block(r, r, 2, 2) = c.C_eta;
      nu.segment(r, 2) = c.innovation.eta;
    }
    const Eigen::MatrixXd S = J * P * J.transpose() + C;
    return nu.dot(S.ldlt().solve(nu));
  }
};

std::vector<std::pair<int, int>> pairs(const std::vector<Candidate>& cands, const std::vector<int>& chosen) {
  std::vector<std::pair<int, int>> out;
  for (int c : chosen) out.emplace_back(cands[c].measurement, cands[c].feature);
  std::sort(out.begin(), out.end());
  return out;
}

// Two features 1 m apart, both measured; the robot is 0.8 m further along x
// than it believes (σ = 1 m), so both measurements are offset by −0.8 m.
// Measurement 1 (of feature 1) lands 0.2 m from feature 0: nearest neighbour
// takes that pair first and then gives measurement 0 to feature 1. JCBB sees
// that the right pairs share one offset (the robot's), the wrong ones would
// need the two measurements to move apart by 2 m with 5 cm noise.
TEST(Jcbb, PairsRightWhereNearestNeighbourPairsWrong) {
  const World w(2, 1.0, 0.01);
  const Eigen::Vector2d f0(0.0, 0.0), f1(1.0, 0.0), offset(-0.8, 0.0);
  const Eigen::Vector2d z0 = f0 + offset, z1 = f1 + offset;  // relative to the believed robot at 0
  std::vector<Candidate> cands;
  const double gate = chi2_quantile(0.99, 2);
  for (int m = 0; m < 2; ++m)
    for (int f = 0; f < 2; ++f) {
      const Candidate c = w.candidate(m, f, (m == 0 ? z0 : z1) - (f == 0 ? f0 : f1));
      ASSERT_LE(c.d2, gate) << "every pair is individually compatible";
      cands.push_back(c);
    }

  std::vector<Candidate> greedy = cands;
  const std::vector<int> nn = nearest_neighbour(greedy, 2, 2);
  EXPECT_EQ(pairs(greedy, nn), (std::vector<std::pair<int, int>>{{0, 1}, {1, 0}})) << "greedy pairs wrongly";

  const JcbbResult jc = joint_compatibility(cands, w.marginal(), {0.99, 1000});
  ASSERT_FALSE(jc.bounded);
  EXPECT_EQ(pairs(cands, jc.chosen), (std::vector<std::pair<int, int>>{{0, 0}, {1, 1}}));
  // The incremental D² is the batch one, and the right pairs are jointly as
  // good as either alone (their common offset is the robot's).
  EXPECT_NEAR(jc.d2, w.joint_d2(cands, jc.chosen), 1e-9);
  EXPECT_LT(jc.d2, 1.0);
  EXPECT_GT(w.joint_d2(cands, {1, 2}), 100.0) << "the greedy pairs are jointly incompatible";
}

// Each measurement has one candidate and passes its gate alone, but the two
// innovations point in opposite directions: one robot offset cannot explain
// both. JCBB keeps one pairing; nearest neighbour would use both.
TEST(Jcbb, RejectsAJointlyIncompatibleSetOfIndividuallyCompatiblePairs) {
  const World w(2, 1.0, 0.01);
  std::vector<Candidate> cands = {w.candidate(0, 0, {0.8, 0.0}), w.candidate(1, 1, {-0.8, 0.0})};
  const double gate = chi2_quantile(0.99, 2);
  for (const Candidate& c : cands) ASSERT_LE(c.d2, gate);
  EXPECT_GT(w.joint_d2(cands, {0, 1}), chi2_quantile(0.99, 4));

  std::vector<Candidate> greedy = cands;
  EXPECT_EQ(nearest_neighbour(greedy, 2, 2).size(), 2u);
  const JcbbResult jc = joint_compatibility(cands, w.marginal(), {0.99, 1000});
  ASSERT_FALSE(jc.bounded);
  ASSERT_EQ(jc.chosen.size(), 1u);
  EXPECT_NEAR(jc.d2, cands[jc.chosen[0]].d2, 1e-9);

  // With a small robot uncertainty the same innovations would fail their own
  // gates; with a large one and the same sign they are jointly compatible.
  std::vector<Candidate> same = {w.candidate(0, 0, {0.8, 0.0}), w.candidate(1, 1, {0.8, 0.05})};
  const JcbbResult both = joint_compatibility(same, w.marginal(), {0.99, 1000});
  EXPECT_EQ(both.chosen.size(), 2u);
}

// A candidate whose J_state does not match its state indices is refused.
TEST(Jcbb, RefusesACandidateWithoutItsStateIndices) {
  const World w(1, 1.0, 0.01);
  std::vector<Candidate> cands = {w.candidate(0, 0, {0.1, 0.0})};
  cands[0].idx.clear();
  EXPECT_THROW(joint_compatibility(cands, w.marginal(), {0.99, 1000}), std::invalid_argument);
}

// Tentative candidates (features not in the estimator) take no part.
TEST(Jcbb, IgnoresTentativeCandidates) {
  const World w(2, 1.0, 0.01);
  std::vector<Candidate> cands = {w.candidate(0, 0, {0.1, 0.0}), w.candidate(1, 1, {0.1, 0.0})};
  cands[1].tentative = true;
  const JcbbResult jc = joint_compatibility(cands, w.marginal(), {0.99, 1000});
  EXPECT_EQ(pairs(cands, jc.chosen), (std::vector<std::pair<int, int>>{{0, 0}}));
  cands[0].tentative = true;
  const JcbbResult none = joint_compatibility(cands, w.marginal(), {0.99, 1000});
  EXPECT_TRUE(none.chosen.empty());
  EXPECT_EQ(none.nodes, 0);
}

/// Calls visit(h) for every leaf h of the interpretation tree over the
/// non-tentative candidates (each measurement paired with one of its
/// candidates or with nothing, each feature used once) whose every prefix is
/// jointly compatible (D² grows with pairings, but so does the threshold).
template <class Visit>
void for_each_hypothesis(const World& w, const std::vector<Candidate>& cands, int measurements, double p,
                         Visit&& visit) {
  std::vector<int> current;
  std::vector<bool> used(64, false);
  const auto recurse = [&](auto&& self, int m) -> void {
    if (m == measurements) {
      visit(current);
      return;
    }
    for (std::size_t c = 0; c < cands.size(); ++c) {
      if (cands[c].measurement != m || used[cands[c].feature] || cands[c].tentative) continue;
      current.push_back(static_cast<int>(c));
      if (w.joint_d2(cands, current) <= chi2_quantile(p, 2 * static_cast<int>(current.size()))) {
        used[cands[c].feature] = true;
        self(self, m + 1);
        used[cands[c].feature] = false;
      }
      current.pop_back();
    }
    self(self, m + 1);
  };
  recurse(recurse, 0);
}

/// The best hypothesis by exhaustive enumeration of the interpretation tree:
/// most pairings, then smallest joint D², jointly compatible throughout.
std::vector<int> brute_force(const World& w, const std::vector<Candidate>& cands, int measurements, double p,
                             std::int64_t& leaves) {
  std::vector<int> best;
  int best_pairings = -1;
  double best_d2 = std::numeric_limits<double>::infinity();
  leaves = 0;
  for_each_hypothesis(w, cands, measurements, p, [&](const std::vector<int>& h) {
    ++leaves;
    const double d2 = h.empty() ? 0.0 : w.joint_d2(cands, h);
    const int n = static_cast<int>(h.size());
    if (n > best_pairings || (n == best_pairings && d2 < best_d2)) {
      best = h;
      best_pairings = n;
      best_d2 = d2;
    }
  });
  return best;
}

/// A random reading: nf features in a 3 m square, measurement m of feature m
/// under one robot offset with 5 cm noise, the last measurement clutter
/// somewhere; the candidates that pass the individual gate.
std::vector<Candidate> random_reading(const World& w, int nf, int nm, std::mt19937& rng) {
  std::uniform_real_distribution<double> uni(-1.5, 1.5);
  std::normal_distribution<double> noise(0.0, 0.05);
  const double gate = chi2_quantile(0.99, 2);
  std::vector<Eigen::Vector2d> f(static_cast<std::size_t>(nf));
  for (Eigen::Vector2d& p : f) p = {uni(rng), uni(rng)};
  const Eigen::Vector2d offset(uni(rng) * 0.4, uni(rng) * 0.4);
  std::vector<Candidate> cands;
  for (int m = 0; m < nm; ++m) {
    const Eigen::Vector2d z = m < nf - 1 ? Eigen::Vector2d(f[static_cast<std::size_t>(m)] + offset +
                                                           Eigen::Vector2d(noise(rng), noise(rng)))
                                         : Eigen::Vector2d(uni(rng), uni(rng));
    for (int j = 0; j < nf; ++j) {
      const Candidate c = w.candidate(m, j, z - f[static_cast<std::size_t>(j)]);
      if (c.d2 <= gate) cands.push_back(c);
    }
  }
  return cands;
}

// Random clusters of features measured under a shared robot offset, with
// clutter: JCBB finds the hypothesis exhaustive search finds, visiting fewer
// nodes than the interpretation tree has leaves.
TEST(Jcbb, MatchesExhaustiveSearchOnRandomReadings) {
  std::mt19937 rng(7);
  int checked = 0;
  std::int64_t nodes = 0, leaves_total = 0;
  for (int trial = 0; trial < 60; ++trial) {
    const int nf = 5, nm = 5;
    const World w(nf, 0.5, 0.02);
    const std::vector<Candidate> cands = random_reading(w, nf, nm, rng);
    std::int64_t leaves = 0;
    const std::vector<int> expected = brute_force(w, cands, nm, 0.99, leaves);
    const JcbbResult jc = joint_compatibility(cands, w.marginal(), {0.99, 1000000});
    ASSERT_FALSE(jc.bounded);
    EXPECT_EQ(pairs(cands, jc.chosen), pairs(cands, expected)) << "trial " << trial;
    if (!expected.empty()) {
      EXPECT_NEAR(jc.d2, w.joint_d2(cands, expected), 1e-6 * (1.0 + jc.d2));
    }
    nodes += jc.nodes;
    leaves_total += leaves;
    ++checked;
  }
  EXPECT_EQ(checked, 60);
  EXPECT_LT(nodes, leaves_total) << "branch and bound prunes the tree";
}

// A reading where every measurement is compatible with every feature (a
// tight cluster under a large robot uncertainty): the tree has (n+1)!-like
// size. The node bound stops the search, says so, and returns nothing (the
// associator then uses nearest neighbour); with a generous bound it completes.
TEST(Jcbb, StopsAtTheNodeBound) {
  const int n = 7;
  World w(n, 2.0, 0.3);
  w.meas_sigma = 0.3;
  std::vector<Candidate> cands;
  for (int m = 0; m < n; ++m)
    for (int f = 0; f < n; ++f) cands.push_back(w.candidate(m, f, {0.01 * (m - f), 0.02 * (f + m)}));

  const JcbbResult small = joint_compatibility(cands, w.marginal(), {0.99, 50});
  EXPECT_TRUE(small.bounded);
  EXPECT_TRUE(small.chosen.empty());
  EXPECT_LE(small.nodes, 51);

  const JcbbResult full = joint_compatibility(cands, w.marginal(), {0.99, 10000000});
  EXPECT_FALSE(full.bounded);
  EXPECT_EQ(full.chosen.size(), static_cast<std::size_t>(n)) << "all pairings are jointly compatible";
  EXPECT_GT(full.nodes, 50);
}

// ---- Rivals (association.refuse_ambiguous) ----------------------------------

/// Every hypothesis the interpretation tree holds with the most pairings.
std::vector<std::vector<int>> all_largest(const World& w, const std::vector<Candidate>& cands, int measurements,
                                          double p) {
  std::vector<std::vector<int>> out;
  std::size_t most = 0;
  for_each_hypothesis(w, cands, measurements, p, [&](const std::vector<int>& h) {
    if (h.size() > most) {
      most = h.size();
      out.clear();
    }
    if (h.size() == most) out.push_back(h);
  });
  return out;
}

/// The pairings of `best` that some hypothesis of `largest` leaves out.
std::vector<int> expected_disputed(const std::vector<int>& best, const std::vector<std::vector<int>>& largest) {
  std::vector<int> out;
  for (int c : best)
    for (const std::vector<int>& h : largest)
      if (std::find(h.begin(), h.end(), c) == h.end()) {
        out.push_back(c);
        break;
      }
  std::sort(out.begin(), out.end());
  return out;
}

// A row of posts 1 m apart seen under a lateral uncertainty of 1.5 m: the
// two measured posts fit posts (0, 1) and, shifted by one spacing, posts
// (1, 2) — both jointly compatible with two pairings. Plain JCBB takes the
// one of smaller D²; with rivals both pairings are disputed.
TEST(JcbbRivals, ARepeatedStructureUnderALargeUncertaintyDisputesEveryPairing) {
  const World w(3, 1.5, 0.01);
  const std::vector<Eigen::Vector2d> f = {{0.0, 0.0}, {1.0, 0.0}, {2.0, 0.0}};
  const Eigen::Vector2d offset(0.45, 0.0);  // the truth: posts 0 and 1, seen 0.45 m further on
  std::vector<Candidate> cands;
  for (int m = 0; m < 2; ++m)
    for (int j = 0; j < 3; ++j) {
      const Candidate c = w.candidate(m, j, f[m] + offset - f[j]);
      if (c.d2 <= chi2_quantile(0.99, 2)) cands.push_back(c);
    }
  const JcbbResult plain = joint_compatibility(cands, w.marginal(), {0.99, 1000});
  ASSERT_EQ(plain.chosen.size(), 2u);
  EXPECT_TRUE(plain.disputed.empty()) << "rivals are looked for only when asked";
  EXPECT_EQ(plain.rival_nodes, 0);

  JcbbOptions options{0.99, 1000};
  options.find_rivals = true;
  const JcbbResult jc = joint_compatibility(cands, w.marginal(), options);
  EXPECT_EQ(pairs(cands, jc.chosen), pairs(cands, plain.chosen)) << "the best hypothesis is the same";
  EXPECT_FALSE(jc.rivals_bounded);
  std::vector<int> chosen = jc.chosen;
  std::sort(chosen.begin(), chosen.end());
  EXPECT_EQ(jc.disputed, chosen) << "the shifted hypothesis contradicts both pairings";
  EXPECT_GT(jc.rival_nodes, 0);

  // The same reading with the robot known to 5 cm: the shift is out of every
  // gate and nothing is disputed.
  const World sure(3, 0.05, 0.01);
  std::vector<Candidate> near;
  for (int m = 0; m < 2; ++m)
    for (int j = 0; j < 3; ++j) {
      const Candidate c = sure.candidate(m, j, f[m] + Eigen::Vector2d(0.03, 0.0) - f[j]);
      if (c.d2 <= chi2_quantile(0.99, 2)) near.push_back(c);
    }
  const JcbbResult certain = joint_compatibility(near, sure.marginal(), options);
  EXPECT_EQ(certain.chosen.size(), 2u);
  EXPECT_TRUE(certain.disputed.empty());
}

// Three posts well apart and a fourth 4 cm from the third (a feature mapped
// twice): the third measurement fits either copy, so its pairing is
// disputed; the two others are not, whatever the third does.
TEST(JcbbRivals, OnlyThePairingARivalChangesIsDisputed) {
  const World w(4, 0.1, 0.01);
  const std::vector<Eigen::Vector2d> f = {{0.0, 0.0}, {3.0, 0.0}, {0.0, 3.0}, {0.04, 3.0}};
  const Eigen::Vector2d offset(0.02, -0.03);
  std::vector<Candidate> cands;
  for (int m = 0; m < 3; ++m)
    for (int j = 0; j < 4; ++j) {
      const Candidate c = w.candidate(m, j, f[m] + offset - f[j]);
      if (c.d2 <= chi2_quantile(0.99, 2)) cands.push_back(c);
    }
  JcbbOptions options{0.99, 1000};
  options.find_rivals = true;
  const JcbbResult jc = joint_compatibility(cands, w.marginal(), options);
  ASSERT_EQ(jc.chosen.size(), 3u);
  ASSERT_EQ(jc.disputed.size(), 1u);
  EXPECT_EQ(cands[jc.disputed[0]].measurement, 2);
}

// The reading where JCBB corrects nearest neighbour: the crossed pairs are
// jointly incompatible, so the right hypothesis has no rival.
TEST(JcbbRivals, AJointlyIncompatibleAlternativeIsNoRival) {
  const World w(2, 1.0, 0.01);
  const Eigen::Vector2d f0(0.0, 0.0), f1(1.0, 0.0), offset(-0.8, 0.0);
  std::vector<Candidate> cands;
  for (int m = 0; m < 2; ++m)
    for (int j = 0; j < 2; ++j) cands.push_back(w.candidate(m, j, (m == 0 ? f0 : f1) + offset - (j == 0 ? f0 : f1)));
  JcbbOptions options{0.99, 1000};
  options.find_rivals = true;
  const JcbbResult jc = joint_compatibility(cands, w.marginal(), options);
  EXPECT_EQ(pairs(cands, jc.chosen), (std::vector<std::pair<int, int>>{{0, 0}, {1, 1}}));
  EXPECT_TRUE(jc.disputed.empty());
}

// Random readings (clusters, clutter, uncertainty large enough for shifted
// fits): the disputed pairings are exactly those of the best hypothesis that
// some other largest jointly compatible hypothesis leaves out.
TEST(JcbbRivals, MatchExhaustiveEnumerationOnRandomReadings) {
  std::mt19937 rng(11);
  int with_disputes = 0, without = 0;
  for (int trial = 0; trial < 80; ++trial) {
    const int nf = 5, nm = 5;
    const World w(nf, trial % 2 == 0 ? 0.8 : 0.2, 0.02);
    const std::vector<Candidate> cands = random_reading(w, nf, nm, rng);
    JcbbOptions options{0.99, 1000000};
    options.find_rivals = true;
    const JcbbResult jc = joint_compatibility(cands, w.marginal(), options);
    ASSERT_FALSE(jc.bounded);
    ASSERT_FALSE(jc.rivals_bounded);
    const std::vector<std::vector<int>> largest = all_largest(w, cands, nm, 0.99);
    EXPECT_EQ(jc.disputed, expected_disputed(jc.chosen, largest)) << "trial " << trial;
    (jc.disputed.empty() ? without : with_disputes) += 1;
  }
  EXPECT_GT(with_disputes, 5) << "the trials exercise rivals";
  EXPECT_GT(without, 5);
}

// A rival search that runs out of nodes cannot vouch for any pairing: all
// are reported disputed.
TEST(JcbbRivals, ABoundedRivalSearchDisputesEverything) {
  const int n = 6;
  World w(n, 2.0, 0.3);
  w.meas_sigma = 0.3;
  std::vector<Candidate> cands;
  for (int m = 0; m < n; ++m)
    for (int f = 0; f < n; ++f) cands.push_back(w.candidate(m, f, {0.01 * (m - f), 0.02 * (f + m)}));
  JcbbOptions options{0.99, 10000000};
  options.find_rivals = true;
  const JcbbResult full = joint_compatibility(cands, w.marginal(), options);
  ASSERT_FALSE(full.bounded);
  EXPECT_FALSE(full.rivals_bounded);
  EXPECT_EQ(full.disputed.size(), static_cast<std::size_t>(n)) << "every permutation fits: all disputed";
  options.max_rival_nodes = 3;
  const JcbbResult cut = joint_compatibility(cands, w.marginal(), options);
  ASSERT_FALSE(cut.bounded);
  EXPECT_TRUE(cut.rivals_bounded);
  EXPECT_EQ(cut.disputed.size(), static_cast<std::size_t>(n));
}

// ---- Re-entries (association.reentry_joint_test) ---------------------------

TEST(Reentry, WideningAddsVarianceAtTheRobotRowsOnly) {
  const World w(2, 0.1, 0.2);
  Eigen::Matrix2d extra;
  extra << 0.5, 0.2, 0.2, 0.7;
  const MarginalFn wide = widen_robot(w.marginal(), {0, 1}, extra);
  const std::vector<int> rows = {4, 1, 2, 0};  // the robot's rows anywhere among the asked ones
  const Eigen::MatrixXd before = w.marginal()(rows), after = wide(rows);
  Eigen::MatrixXd expected = before;
  expected(1, 1) += 0.7;
  expected(3, 3) += 0.5;
  expected(1, 3) += 0.2;
  expected(3, 1) += 0.2;
  EXPECT_TRUE(after.isApprox(expected)) << after;
  EXPECT_TRUE(widen_robot(w.marginal(), {0, 1}, extra)({2, 3}).isApprox(w.marginal()({2, 3}))) << "no robot row asked";
  EXPECT_THROW(widen_robot(w.marginal(), {0, 1}, Eigen::Matrix3d::Identity()), std::invalid_argument);
}

/// The candidates of measurements of `seen` posts, displaced by `offset` from
/// where the estimate puts them, that pass the 99 % gate of `w`.
std::vector<Candidate> gated(const World& w, const std::vector<Eigen::Vector2d>& posts, const std::vector<int>& seen,
                             const Eigen::Vector2d& offset) {
  std::vector<Candidate> out;
  for (std::size_t m = 0; m < seen.size(); ++m)
    for (std::size_t j = 0; j < posts.size(); ++j) {
      const Candidate c = w.candidate(static_cast<int>(m), static_cast<int>(j),
                                      posts[static_cast<std::size_t>(seen[m])] + offset - posts[j]);
      if (c.d2 <= chi2_quantile(0.99, 2)) out.push_back(c);
    }
  return out;
}

// A row of posts 1 m apart, revisited after a drift of 0.95 m along it that
// the filter's 5 cm does not hold: its gate admits only the posts one
// further on (a wrong re-entry, which plain JCBB makes). Widened by a drift
// of 0.6 m, the true and the shifted hypotheses both fit: not confirmed.
TEST(Reentry, AShiftAlongARepeatedStructureIsNotConfirmed) {
  const World filter(3, 0.05, 0.01);
  const std::vector<Eigen::Vector2d> posts = {{0.0, 0.0}, {1.0, 0.0}, {2.0, 0.0}};
  const Eigen::Vector2d drift(-0.95, 0.0);  // the robot sees posts 1 and 2 where the estimate puts 0 and 1
  const std::vector<Candidate> narrow = gated(filter, posts, {1, 2}, drift);
  const JcbbResult chosen = joint_compatibility(narrow, filter.marginal(), {0.99, 1000});
  ASSERT_EQ(pairs(narrow, chosen.chosen), (std::vector<std::pair<int, int>>{{0, 0}, {1, 1}}))
      << "the filter's gate makes the wrong pairings";

  World wide = filter;
  wide.P.topLeftCorner(2, 2) += Eigen::Matrix2d::Identity() * 0.36;
  const std::vector<Candidate> candidates = gated(wide, posts, {1, 2}, drift);
  const ReentryVerdict v = confirm_reentries(candidates, {{0, 0}, {1, 1}},
                                             widen_robot(filter.marginal(), {0, 1}, Eigen::Matrix2d::Identity() * 0.36),
                                             {0.99, 1000});
  EXPECT_EQ(v.confirmed, (std::vector<bool>{false, false}));
  EXPECT_FALSE(v.search.rivals_bounded);
  EXPECT_EQ(v.search.disputed.size(), 2u) << "a rival hypothesis pairs both measurements otherwise";
}

// Three posts no shift maps onto each other, revisited with a 0.3 m drift:
// the filter (0.2 m) pairs them rightly, and widened by 0.6 m the only
// hypothesis with three pairings is the same — confirmed. A pairing the
// widened best does not make is not confirmed either.
TEST(Reentry, AnUnambiguousRevisitIsConfirmed) {
  const World filter(3, 0.2, 0.01);
  const std::vector<Eigen::Vector2d> posts = {{0.0, 0.0}, {1.0, 0.0}, {3.0, 2.0}};
  const Eigen::Vector2d drift(0.3, -0.1);
  const MarginalFn widened = widen_robot(filter.marginal(), {0, 1}, Eigen::Matrix2d::Identity() * 0.36);
  World wide = filter;
  wide.P.topLeftCorner(2, 2) += Eigen::Matrix2d::Identity() * 0.36;
  const std::vector<Candidate> candidates = gated(wide, posts, {0, 1, 2}, drift);
  ASSERT_GT(candidates.size(), 3u) << "the widened gate admits shifted pairs too";
  const ReentryVerdict v = confirm_reentries(candidates, {{0, 0}, {1, 1}, {2, 2}, {0, 1}}, widened, {0.99, 1000});
  EXPECT_EQ(v.confirmed, (std::vector<bool>{true, true, true, false}));
  EXPECT_TRUE(v.search.disputed.empty());
}

}  // namespace
