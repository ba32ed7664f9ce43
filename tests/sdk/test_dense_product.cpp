// C ← C + α A Bᵀ (mspace/dense_product.hpp): both kernels against a plain
// triple loop, in full and on the lower triangle, on sizes that are and are
// not multiples of the AVX2 kernel's 8 × 4 blocks, on blocks of larger
// matrices (outer stride ≠ rows), and the entries they must leave alone.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <cstring>
#include <random>
#include <stdexcept>
#include <thread>
#include <vector>

#include <sys/wait.h>
#include <unistd.h>

#include "mspace/dense_product.hpp"

namespace {

using mspace::add_product;
using mspace::ProductKernel;
using mspace::ProductPart;

Eigen::MatrixXd random_matrix(Eigen::Index rows, Eigen::Index cols, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::MatrixXd m(rows, cols);
  for (Eigen::Index j = 0; j < cols; ++j)
    for (Eigen::Index i = 0; i < rows; ++i) m(i, j) = u(rng);
  return m;
}

/// The reference: the sum in the plain order.
double entry(const Eigen::MatrixXd& A, const Eigen::MatrixXd& B, Eigen::Index i, Eigen::Index j) {
  double s = 0.0;
  for (Eigen::Index l = 0; l < A.cols(); ++l) s += A(i, l) * B(j, l);
  return s;
}

std::vector<ProductKernel> kernels() {
  std::vector<ProductKernel> out{ProductKernel::eigen, ProductKernel::automatic};
  if (mspace::avx2_fma_available()) out.push_back(ProductKernel::avx2_fma);
  return out;
}

struct Sizes {
  Eigen::Index m, n, k;
};

class DenseProduct : public ::testing::TestWithParam<Sizes> {};

TEST_P(DenseProduct, FullAndLowerAgreeWithTheSumsOnABlockOfALargerMatrix) {
  const Sizes s = GetParam();
  std::mt19937 rng(static_cast<unsigned>(s.m * 1000 + s.n * 10 + s.k));
  const Eigen::MatrixXd A = random_matrix(s.m, s.k, rng), B = random_matrix(s.n, s.k, rng);
  const Eigen::MatrixXd start = random_matrix(s.m + 3, s.n + 2, rng);  // C is its block at (1, 2)
  for (const ProductKernel kernel : kernels()) {
    for (const ProductPart part : {ProductPart::full, ProductPart::lower}) {
      if (part == ProductPart::lower && s.m != s.n) continue;
      SCOPED_TRACE(::testing::Message() << "kernel " << static_cast<int>(kernel) << ", part "
                                        << static_cast<int>(part));
      Eigen::MatrixXd store = start;
      add_product(store.block(1, 2, s.m, s.n), -0.5, A, B, part, kernel);
      for (Eigen::Index j = 0; j < store.cols(); ++j) {
        for (Eigen::Index i = 0; i < store.rows(); ++i) {
          const Eigen::Index bi = i - 1, bj = j - 2;
          const bool inside = bi >= 0 && bi < s.m && bj >= 0 && bj < s.n;
          if (!inside || (part == ProductPart::lower && bi < bj)) {
            ASSERT_EQ(store(i, j), start(i, j)) << "entry (" << i << ", " << j << ") must stay";
          } else {
            const double expected = start(i, j) - 0.5 * entry(A, B, bi, bj);
            ASSERT_NEAR(store(i, j), expected, 1e-13 * (1.0 + static_cast<double>(s.k)))
                << "entry (" << bi << ", " << bj << ")";
          }
        }
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Sizes, DenseProduct,
                         ::testing::Values(Sizes{1, 1, 1}, Sizes{8, 8, 4}, Sizes{7, 7, 3}, Sizes{13, 13, 17},
                                           Sizes{33, 33, 90}, Sizes{101, 101, 6}, Sizes{5, 19, 9},
                                           Sizes{21, 4, 1}, Sizes{64, 96, 33}));

// y = α Aᵀ x (transposed_product): every kernel against plain sums, on
// row counts that are and are not multiples of 4, column counts that are and
// are not multiples of 4, and a block of a larger matrix.
TEST(DenseTransposedProduct, AgreesWithTheSumsOnABlockOfALargerMatrix) {
  std::mt19937 rng(5);
  for (const Sizes s : {Sizes{1, 1, 0}, Sizes{3, 5, 0}, Sizes{4, 4, 0}, Sizes{96, 1301, 0}, Sizes{97, 13, 0},
                        Sizes{8, 0, 0}, Sizes{0, 6, 0}}) {
    const Eigen::MatrixXd store = random_matrix(s.m + 3, s.n + 2, rng);
    const Eigen::VectorXd x = random_matrix(s.m, 1, rng);
    for (const ProductKernel kernel : kernels()) {
      SCOPED_TRACE(::testing::Message() << s.m << " x " << s.n << ", kernel " << static_cast<int>(kernel));
      Eigen::VectorXd y = Eigen::VectorXd::Constant(s.n, 7.0);
      mspace::transposed_product(y, -0.5, store.block(2, 1, s.m, s.n), x, kernel);
      for (Eigen::Index j = 0; j < s.n; ++j) {
        double expected = 0.0;
        for (Eigen::Index i = 0; i < s.m; ++i) expected += store(2 + i, 1 + j) * x[i];
        ASSERT_NEAR(y[j], -0.5 * expected, 1e-13 * (1.0 + static_cast<double>(s.m))) << "entry " << j;
      }
    }
  }
  Eigen::VectorXd y(3);
  EXPECT_THROW(mspace::transposed_product(y, 1.0, Eigen::MatrixXd::Zero(2, 4), Eigen::VectorXd::Zero(2)),
               std::invalid_argument);
  EXPECT_THROW(mspace::transposed_product(y, 1.0, Eigen::MatrixXd::Zero(2, 3), Eigen::VectorXd::Zero(3)),
               std::invalid_argument);
}

// X ← X U⁻¹ (solve_upper_on_right): every kernel against Eigen's solve, on
// row counts that are and are not multiples of 4, on a block of a larger X,
// with U's lower triangle full of values that must not be read.
TEST(DenseUpperSolve, AgreesWithEigensSolveOnABlockOfALargerMatrix) {
  std::mt19937 rng(9);
  for (const Sizes s : {Sizes{1, 1, 0}, Sizes{5, 3, 0}, Sizes{96, 20, 0}, Sizes{97, 7, 0}, Sizes{0, 4, 0},
                        Sizes{9, 0, 0}}) {
    Eigen::MatrixXd U = random_matrix(s.n, s.n, rng);
    for (Eigen::Index j = 0; j < s.n; ++j) U(j, j) = 2.0 + std::abs(U(j, j));  // well conditioned
    const Eigen::MatrixXd start = random_matrix(s.m + 2, s.n + 1, rng);
    Eigen::MatrixXd expected = start.block(1, 1, s.m, s.n);
    if (s.n > 0) U.triangularView<Eigen::Upper>().solveInPlace<Eigen::OnTheRight>(expected);
    for (const ProductKernel kernel : kernels()) {
      SCOPED_TRACE(::testing::Message() << s.m << " x " << s.n << ", kernel " << static_cast<int>(kernel));
      Eigen::MatrixXd X = start;
      mspace::solve_upper_on_right(X.block(1, 1, s.m, s.n), U, kernel);
      for (Eigen::Index j = 0; j < X.cols(); ++j)
        for (Eigen::Index i = 0; i < X.rows(); ++i) {
          const bool inside = i >= 1 && i <= s.m && j >= 1 && j <= s.n;
          if (!inside) {
            ASSERT_EQ(X(i, j), start(i, j)) << "entry (" << i << ", " << j << ") must stay";
          } else {
            ASSERT_NEAR(X(i, j), expected(i - 1, j - 1), 1e-12 * (1.0 + std::abs(expected(i - 1, j - 1))));
          }
        }
    }
  }
  Eigen::MatrixXd X(3, 2);
  EXPECT_THROW(mspace::solve_upper_on_right(X, Eigen::MatrixXd::Identity(3, 3)), std::invalid_argument);
}

/// Restores product_threads() when a test ends.
class ThreadSetting {
 public:
  ThreadSetting() : saved_(mspace::product_threads()) {}
  ~ThreadSetting() { mspace::set_product_threads(saved_); }
  ThreadSetting(const ThreadSetting&) = delete;
  ThreadSetting& operator=(const ThreadSetting&) = delete;

 private:
  int saved_;
};

bool same_bits(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() &&
         std::memcmp(a.data(), b.data(), static_cast<std::size_t>(a.size()) * sizeof(double)) == 0;
}

// Large products are split by columns over helper threads: every entry must
// come out the same bit for bit with 1, 2, 3 and 4 threads, in full and on
// the lower triangle, on sizes that are not multiples of the blocks and on a
// block of a larger matrix (the shapes of a global update of the cekf:
// P⁰_BB − Gᵀ Ψ G with n ≈ 1300, k ≈ 90, and Φ G).
TEST(DenseProductThreads, ResultsAreTheSameBitForBitWhateverTheThreadCount) {
  if (!mspace::avx2_fma_available()) GTEST_SKIP() << "no AVX2/FMA: large products run on one thread";
  ThreadSetting restore;
  std::mt19937 rng(11);
  struct Case {
    Eigen::Index m, n, k;
    ProductPart part;
  };
  for (const Case c : {Case{1301, 1301, 91, ProductPart::lower}, Case{517, 517, 64, ProductPart::lower},
                       Case{96, 1301, 93, ProductPart::full}, Case{1301, 90, 90, ProductPart::full}}) {
    SCOPED_TRACE(::testing::Message() << c.m << " x " << c.n << ", k " << c.k);
    const Eigen::MatrixXd A = random_matrix(c.m, c.k, rng), B = random_matrix(c.n, c.k, rng);
    const Eigen::MatrixXd start = random_matrix(c.m + 2, c.n + 1, rng);
    mspace::set_product_threads(1);
    Eigen::MatrixXd one = start;
    add_product(one.block(1, 1, c.m, c.n), -1.0, A, B, c.part);
    for (int threads : {2, 3, 4}) {
      mspace::set_product_threads(threads);
      ASSERT_EQ(mspace::product_threads(), threads);
      Eigen::MatrixXd many = start;
      add_product(many.block(1, 1, c.m, c.n), -1.0, A, B, c.part);
      EXPECT_TRUE(same_bits(one, many)) << threads << " threads: max difference " << (one - many).cwiseAbs().maxCoeff();
    }
  }
}

// Two callers at once (two filters on two threads): the second runs its
// product on its own thread; both results are exact.
TEST(DenseProductThreads, ConcurrentCallersGetTheSameResults) {
  if (!mspace::avx2_fma_available()) GTEST_SKIP() << "no AVX2/FMA: large products run on one thread";
  ThreadSetting restore;
  std::mt19937 rng(12);
  const Eigen::MatrixXd A = random_matrix(700, 80, rng), B = random_matrix(700, 80, rng);
  mspace::set_product_threads(1);
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(700, 700);
  add_product(expected, 1.0, A, B, ProductPart::lower);
  mspace::set_product_threads(2);
  std::vector<Eigen::MatrixXd> results(4, Eigen::MatrixXd::Zero(700, 700));
  std::vector<std::thread> callers;
  for (std::size_t i = 0; i < results.size(); ++i)
    callers.emplace_back([&, i] {
      for (int repeat = 0; repeat < 5; ++repeat) {
        results[i].setZero();
        add_product(results[i], 1.0, A, B, ProductPart::lower);
      }
    });
  for (std::thread& t : callers) t.join();
  for (const Eigen::MatrixXd& r : results) EXPECT_TRUE(same_bits(expected, r));
}

// A child made by fork() after the helpers started (a test that runs a
// filter in a child process) has none of the parent's threads: its large
// products must still finish, with the same bits.
TEST(DenseProductThreads, AForkedChildComputesWithoutItsParentsHelpers) {
  if (!mspace::avx2_fma_available()) GTEST_SKIP() << "no AVX2/FMA: large products run on one thread";
  ThreadSetting restore;
  std::mt19937 rng(13);
  const Eigen::MatrixXd A = random_matrix(600, 64, rng), B = random_matrix(600, 64, rng);
  mspace::set_product_threads(2);
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(600, 600);
  add_product(expected, 1.0, A, B, ProductPart::lower);  // the helpers are running now
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    Eigen::MatrixXd C = Eigen::MatrixXd::Zero(600, 600);
    add_product(C, 1.0, A, B, ProductPart::lower);
    _exit(same_bits(C, expected) ? 0 : 1);
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

TEST(DenseProductThreads, TheSettingIsClamped) {
  ThreadSetting restore;
  mspace::set_product_threads(0);
  EXPECT_EQ(mspace::product_threads(), 1);
  mspace::set_product_threads(1000);
  EXPECT_EQ(mspace::product_threads(), 64);
}

TEST(DenseProductInput, NoColumnsChangeNothingAndMismatchedSizesAreErrors) {
  std::mt19937 rng(7);
  Eigen::MatrixXd C = random_matrix(5, 5, rng);
  const Eigen::MatrixXd before = C;
  for (const ProductKernel kernel : kernels()) {
    add_product(C, 1.0, Eigen::MatrixXd(5, 0), Eigen::MatrixXd(5, 0), ProductPart::lower, kernel);
    EXPECT_EQ(C, before);
  }
  try {
    add_product(C, 1.0, Eigen::MatrixXd::Zero(5, 2), Eigen::MatrixXd::Zero(4, 2));
    FAIL() << "mismatched sizes accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("C is 5 x 5, A 5 x 2, B 4 x 2"), std::string::npos) << e.what();
  }
  Eigen::MatrixXd tall = Eigen::MatrixXd::Zero(6, 5);
  EXPECT_THROW(add_product(tall, 1.0, Eigen::MatrixXd::Zero(6, 2), Eigen::MatrixXd::Zero(5, 2), ProductPart::lower),
               std::invalid_argument);
  if (!mspace::avx2_fma_available()) {
    EXPECT_THROW(add_product(C, 1.0, Eigen::MatrixXd::Zero(5, 2), Eigen::MatrixXd::Zero(5, 2), ProductPart::full,
                             ProductKernel::avx2_fma),
                 std::invalid_argument);
  }
}

}  // namespace
