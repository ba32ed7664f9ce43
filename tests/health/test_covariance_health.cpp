// The covariance health checks (kernel/src/covariance_health.hpp): figures of
// known matrices, the touched-block check and its single warning, and the
// checkpoint round trip of what was found.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <map>

#include <Eigen/QR>

#include "covariance_health.hpp"

namespace mspace::kernel {
namespace {

TEST(CovarianceHealth, FiguresOfKnownMatrices) {
  Eigen::MatrixXd C(2, 2);
  C << 2, 1, 1, 2;  // eigenvalues 1 and 3
  CovarianceFigures f = covariance_figures(C);
  EXPECT_NEAR(f.min_eigenvalue, 1.0, 1e-14);
  EXPECT_NEAR(f.max_eigenvalue, 3.0, 1e-14);
  EXPECT_EQ(f.asymmetry, 0.0);
  C << 2, 1.5, 0.5, 2;  // symmetric part as above, |C − Cᵀ| = 1, max|C| = 2
  f = covariance_figures(C);
  EXPECT_NEAR(f.min_eigenvalue, 1.0, 1e-14);
  EXPECT_NEAR(f.asymmetry, 0.5, 1e-15);
}

// Beyond 300 rows a positive definite covariance gets a Cholesky factor and
// power / inverse iteration instead of every eigenvalue: the smallest comes out
// exact when it is well separated, the largest close (from below).
TEST(CovarianceHealth, LargeMatricesGetTheirExtremeEigenvaluesByIteration) {
  const int n = 400;
  std::srand(7);
  const Eigen::MatrixXd Q = Eigen::HouseholderQR<Eigen::MatrixXd>(Eigen::MatrixXd::Random(n, n)).householderQ();
  const Eigen::VectorXd lambda = Eigen::VectorXd::LinSpaced(n, 0.01, 10.0);
  const Eigen::MatrixXd C = Q * lambda.asDiagonal() * Q.transpose();
  const CovarianceFigures f = covariance_figures(C);
  EXPECT_NEAR(f.min_eigenvalue, 0.01, 1e-9);
  EXPECT_LE(f.max_eigenvalue, 10.0 + 1e-9);
  EXPECT_GT(f.max_eigenvalue, 9.5);
  // Not positive definite: exact, whatever the size.
  Eigen::VectorXd shifted = lambda;
  shifted[0] = -0.5;
  const CovarianceFigures g = covariance_figures(Q * shifted.asDiagonal() * Q.transpose());
  EXPECT_NEAR(g.min_eigenvalue, -0.5, 1e-9);
  EXPECT_NEAR(g.max_eigenvalue, 10.0, 1e-9);
}

TEST(CovarianceHealth, BlockThatIsNotPositiveDefiniteIsCountedAndWarnedOnce) {
  CovarianceHealth health(0);
  EXPECT_FALSE(health.full_check_due(100));  // 0: whole covariance only at the end
  Eigen::MatrixXd good(2, 2);
  good << 1, 0.5, 0.5, 1;
  EXPECT_EQ(health.check_block(good, 3), "");
  Eigen::MatrixXd bad(2, 2);
  bad << 1, 2, 2, 1;  // eigenvalues −1 and 3
  const std::string warning = health.check_block(bad, 7);
  EXPECT_NE(warning.find("step 7: "), std::string::npos) << warning;
  EXPECT_NE(warning.find("not positive definite"), std::string::npos) << warning;
  EXPECT_NE(warning.find("smallest eigenvalue -1"), std::string::npos) << warning;
  EXPECT_EQ(health.check_block(bad, 9), "");  // counted, not warned again
  EXPECT_EQ(health.report().block_checks, 3);
  EXPECT_EQ(health.report().blocks_not_pd, 2);
  EXPECT_EQ(health.report().first_not_pd_step, 7);
}

TEST(CovarianceHealth, WholeChecksKeepTheSmallestEigenvalue) {
  CovarianceHealth health(10);
  EXPECT_TRUE(health.full_check_due(20));
  EXPECT_FALSE(health.full_check_due(25));
  EXPECT_TRUE(std::isnan(health.report().min_eigenvalue));
  health.record_full({0.5, 4.0, 0.0}, 10);
  health.record_full({0.25, 1.0, 1e-12}, 20);
  health.record_full({2.0, 8.0, 0.0}, 30);
  EXPECT_EQ(health.report().full_checks, 3);
  EXPECT_EQ(health.report().min_eigenvalue, 0.25);
  EXPECT_EQ(health.report().min_relative_eigenvalue, 0.25);
  EXPECT_EQ(health.report().min_eigenvalue_step, 20);
  EXPECT_EQ(health.report().max_asymmetry, 1e-12);
}

/// A StateWriter/StateReader over a map, for the round trip.
class MapState final : public StateWriter, public StateReader {
 public:
  void put(const std::string& name, const Eigen::MatrixXd& value) override { m_[name] = value; }
  void put_bytes(const std::string& name, const std::string& bytes) override { b_[name] = bytes; }
  bool has(const std::string& name) const override { return m_.count(name) != 0 || b_.count(name) != 0; }
  const Eigen::MatrixXd& get(const std::string& name) const override { return m_.at(name); }
  const std::string& get_bytes(const std::string& name) const override { return b_.at(name); }

 private:
  std::map<std::string, Eigen::MatrixXd> m_;
  std::map<std::string, std::string> b_;
};

TEST(CovarianceHealth, CheckpointRoundTrip) {
  CovarianceHealth health(10);
  Eigen::MatrixXd bad(2, 2);
  bad << 1, 2, 2, 1;
  health.check_block(bad, 4);
  health.record_full({0.125, 2.0, 0.0}, 10);
  MapState state;
  health.save(state, "h_");
  CovarianceHealth restored(10);
  restored.restore(state, "h_");
  const CovarianceHealthReport &a = health.report(), &b = restored.report();
  EXPECT_EQ(b.block_checks, a.block_checks);
  EXPECT_EQ(b.blocks_not_pd, a.blocks_not_pd);
  EXPECT_EQ(b.first_not_pd_step, a.first_not_pd_step);
  EXPECT_EQ(b.full_checks, a.full_checks);
  EXPECT_EQ(b.min_eigenvalue, a.min_eigenvalue);
  EXPECT_EQ(b.min_relative_eigenvalue, a.min_relative_eigenvalue);
  EXPECT_EQ(b.min_eigenvalue_step, a.min_eigenvalue_step);
  // Before any whole check the smallest eigenvalue stays unknown.
  CovarianceHealth fresh(10), fresh_restored(10);
  MapState empty_state;
  fresh.save(empty_state, "h_");
  fresh_restored.restore(empty_state, "h_");
  EXPECT_TRUE(std::isnan(fresh_restored.report().min_eigenvalue));
}

}  // namespace
}  // namespace mspace::kernel
