// dense_product.cpp — C ← C + α A Bᵀ (see dense_product.hpp).
//
// The AVX2/FMA kernel. A is copied into panels of kRows rows and B into panels
// of kCols rows, each stored l-major (the kRows or kCols values of one column
// l side by side), so that the inner loop reads both with unit stride. For
// every block of C (on or below the diagonal for the lower triangle) the
// kernel keeps the kRows × kCols block of A Bᵀ in eight 4-wide registers: per
// l, two loads of A, four broadcasts of B and eight fused multiply–adds. Only
// the function with the intrinsics carries the target attribute: whatever it
// calls that is not inlined is compiled for the baseline processor, so no AVX
// instruction can reach code that runs without the check.
//
// A large product is split by column panels of C over the helper threads of
// Helpers below (see "Threads" in dense_product.hpp): the panels are packed
// once by the caller, and each thread runs the same block loop over its own
// contiguous range of column panels. A block of C is the same sum in the same
// order whichever thread computes it, so the split changes no bit.
#include "mspace/dense_product.hpp"

#include <Eigen/Core>
#include <algorithm>
#include <condition_variable>
#include <cstdint>
#include <cstdlib>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#if defined(__unix__)
#include <pthread.h>
#define MSPACE_DENSE_PRODUCT_FORK_SAFE 1
#endif

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define MSPACE_DENSE_PRODUCT_AVX2 1
#endif

namespace mspace {

namespace {

using Eigen::Index;

constexpr int kMaxThreads = 64;
/// Products with fewer multiply–adds than this run on the calling thread:
/// waking a helper and waiting for it costs tens of microseconds.
constexpr double kThreadedWork = 2.0e6;

int default_threads() {
  if (const char* env = std::getenv("MSPACE_THREADS")) {
    char* end = nullptr;
    const long n = std::strtol(env, &end, 10);
    if (end != env && *end == '\0' && n >= 1 && n <= kMaxThreads) return static_cast<int>(n);
  }
  // One thread unless asked: the second core saves 2 % on Victoria Park (docs/performance.md, fifth pass), and
  // users who run several jobs at once (one per core) must not get twice as many busy threads as cores.
  return 1;
}

int& threads_setting() {
  static int threads = default_threads();
  return threads;
}

/// Helper threads, started when first needed and kept waiting between jobs.
/// run(parts, job) calls job(0) on the caller and job(1) … job(parts − 1) on
/// helpers, and returns when all have returned. One job at a time: a caller
/// that finds another job running (two filters on two threads) runs all parts
/// itself, with the same results.
class Helpers {
 public:
  static Helpers& instance() { return *current(); }

  void run(int parts, const std::function<void(int)>& job) {
    std::unique_lock<std::mutex> busy(busy_, std::try_to_lock);
    if (!busy.owns_lock() || parts <= 1) {
      for (int p = 0; p < parts; ++p) job(p);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      while (static_cast<int>(threads_.size()) < parts - 1) {
        const int part = static_cast<int>(threads_.size()) + 1;
        threads_.emplace_back([this, part, seen = generation_] { serve(part, seen); });
        threads_.back().detach();
      }
      job_ = &job;
      parts_ = parts;
      pending_ = parts - 1;
      ++generation_;
    }
    start_.notify_all();
    job(0);
    std::unique_lock<std::mutex> lock(mutex_);
    done_.wait(lock, [this] { return pending_ == 0; });
    job_ = nullptr;
  }

 private:
  /// Helper `part` (≥ 1): runs its part of every job after generation `seen`.
  void serve(int part, std::uint64_t seen) {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      start_.wait(lock, [&] { return generation_ != seen; });
      seen = generation_;
      if (part >= parts_) continue;  // a job of fewer parts
      const std::function<void(int)>* job = job_;
      lock.unlock();
      (*job)(part);
      lock.lock();
      if (--pending_ == 0) done_.notify_one();
    }
  }

  /// The process's helpers, never destroyed (their threads wait until the
  /// process ends). A child made by fork() has none of its parent's threads
  /// and may have copied a mutex while it was held: it starts afresh.
  static Helpers*& current() {
    static Helpers* helpers = [] {
#ifdef MSPACE_DENSE_PRODUCT_FORK_SAFE
      pthread_atfork(nullptr, nullptr, [] { current() = new Helpers; });
#endif
      return new Helpers;
    }();
    return helpers;
  }

  std::mutex busy_;   ///< held by the caller of run() for the whole job
  std::mutex mutex_;  ///< guards what follows
  std::condition_variable start_, done_;
  std::vector<std::thread> threads_;  ///< detached; kept for their count
  const std::function<void(int)>* job_ = nullptr;
  std::uint64_t generation_ = 0;
  int parts_ = 0;
  int pending_ = 0;  ///< helpers of the current job not yet done
};

#ifdef MSPACE_DENSE_PRODUCT_AVX2
constexpr Index kRows = 8;  // rows of C per block (two 4-wide registers)
constexpr Index kCols = 4;  // columns of C per block

/// Rows [first, first + width) of M as `width`-wide groups, one per column l
/// of M, zero past its last row: out[l * width + r] = M(first + r, l).
void pack_panel(const Eigen::Ref<const Eigen::MatrixXd>& M, Index first, Index width, double* out) {
  const Index valid = std::min(width, M.rows() - first);
  if (valid == width) {
    for (Index l = 0; l < M.cols(); ++l) {
      const double* column = M.data() + l * M.outerStride() + first;
      double* group = out + l * width;
      for (Index r = 0; r < width; ++r) group[r] = column[r];
    }
    return;
  }
  // The last, partial panel: one select per entry rather than a copy and a
  // fill, which the compiler turns into a memset call per column (a call of
  // a few bytes for each of the k columns of every product: 2 % of the
  // Victoria Park run's instructions).
  for (Index l = 0; l < M.cols(); ++l) {
    const double* column = M.data() + l * M.outerStride() + first;
    double* group = out + l * width;
    for (Index r = 0; r < width; ++r) group[r] = r < valid ? column[r] : 0.0;
  }
}

/// The kRows × kCols block Σ_l a_l b_lᵀ of the packed panels a and b (k
/// columns each) into block[c * kRows + r].
__attribute__((target("avx2,fma"))) void block_product_avx2(const double* a, const double* b, Index k,
                                                             double* block) {
  __m256d c0_lo = _mm256_setzero_pd(), c0_hi = _mm256_setzero_pd();
  __m256d c1_lo = _mm256_setzero_pd(), c1_hi = _mm256_setzero_pd();
  __m256d c2_lo = _mm256_setzero_pd(), c2_hi = _mm256_setzero_pd();
  __m256d c3_lo = _mm256_setzero_pd(), c3_hi = _mm256_setzero_pd();
  for (Index l = 0; l < k; ++l) {
    const __m256d a_lo = _mm256_loadu_pd(a + l * kRows);
    const __m256d a_hi = _mm256_loadu_pd(a + l * kRows + 4);
    const double* bl = b + l * kCols;
    __m256d bc = _mm256_broadcast_sd(bl);
    c0_lo = _mm256_fmadd_pd(a_lo, bc, c0_lo);
    c0_hi = _mm256_fmadd_pd(a_hi, bc, c0_hi);
    bc = _mm256_broadcast_sd(bl + 1);
    c1_lo = _mm256_fmadd_pd(a_lo, bc, c1_lo);
    c1_hi = _mm256_fmadd_pd(a_hi, bc, c1_hi);
    bc = _mm256_broadcast_sd(bl + 2);
    c2_lo = _mm256_fmadd_pd(a_lo, bc, c2_lo);
    c2_hi = _mm256_fmadd_pd(a_hi, bc, c2_hi);
    bc = _mm256_broadcast_sd(bl + 3);
    c3_lo = _mm256_fmadd_pd(a_lo, bc, c3_lo);
    c3_hi = _mm256_fmadd_pd(a_hi, bc, c3_hi);
  }
  _mm256_storeu_pd(block, c0_lo);
  _mm256_storeu_pd(block + 4, c0_hi);
  _mm256_storeu_pd(block + 8, c1_lo);
  _mm256_storeu_pd(block + 12, c1_hi);
  _mm256_storeu_pd(block + 16, c2_lo);
  _mm256_storeu_pd(block + 20, c2_hi);
  _mm256_storeu_pd(block + 24, c3_lo);
  _mm256_storeu_pd(block + 28, c3_hi);
}

void add_product_avx2(Eigen::Ref<Eigen::MatrixXd> C, double alpha, const Eigen::Ref<const Eigen::MatrixXd>& A,
                      const Eigen::Ref<const Eigen::MatrixXd>& B, bool lower) {
  const Index rows = C.rows(), cols = C.cols(), k = A.cols();
  const Index row_panels = (rows + kRows - 1) / kRows, col_panels = (cols + kCols - 1) / kCols;
  // Kept between calls: a filter asks for similar sizes again and again.
  // They only grow: resize() after a smaller product would zero-fill the
  // entries in between, which every product overwrites anyway (a memset of
  // up to megabytes per call, 2 % of the Victoria Park run's instructions).
  thread_local std::vector<double> packed_a, packed_b;
  const auto at_least = [](std::vector<double>& v, Index n) {
    if (v.size() < static_cast<std::size_t>(n)) v.resize(static_cast<std::size_t>(n));
  };
  at_least(packed_a, row_panels * kRows * k);
  at_least(packed_b, col_panels * kCols * k);
  for (Index p = 0; p < row_panels; ++p) pack_panel(A, p * kRows, kRows, packed_a.data() + p * kRows * k);
  for (Index q = 0; q < col_panels; ++q) pack_panel(B, q * kCols, kCols, packed_b.data() + q * kCols * k);

  const double* a_panels = packed_a.data();
  const double* b_panels = packed_b.data();
  // Column panels [q_begin, q_end) of C: every block of them, whole.
  const auto panels = [&](Index q_begin, Index q_end) {
    double block[kRows * kCols];
    for (Index q = q_begin; q < q_end; ++q) {
      const Index j0 = q * kCols, block_cols = std::min(kCols, cols - j0);
      for (Index p = lower ? j0 / kRows : 0; p < row_panels; ++p) {
        const Index i0 = p * kRows, block_rows = std::min(kRows, rows - i0);
        block_product_avx2(a_panels + p * kRows * k, b_panels + q * kCols * k, k, block);
        for (Index c = 0; c < block_cols; ++c) {
          const Index j = j0 + c;
          double* column = C.data() + j * C.outerStride() + i0;
          const double* sums = block + c * kRows;
          for (Index r = lower ? std::max<Index>(0, j - i0) : 0; r < block_rows; ++r) column[r] += alpha * sums[r];
        }
      }
    }
  };

  const double work = static_cast<double>(rows) * static_cast<double>(cols) * static_cast<double>(k) * (lower ? 0.5 : 1.0);
  const int parts = static_cast<int>(std::min<Index>(product_threads(), col_panels));
  if (parts <= 1 || work < kThreadedWork) {
    panels(0, col_panels);
    return;
  }
  // Contiguous ranges of column panels with about equal numbers of blocks
  // (on the lower triangle a panel further right has fewer blocks).
  const auto blocks_in = [&](Index q) { return row_panels - (lower ? (q * kCols) / kRows : 0); };
  Index total = 0;
  for (Index q = 0; q < col_panels; ++q) total += blocks_in(q);
  std::vector<Index> first(static_cast<std::size_t>(parts) + 1, col_panels);
  first[0] = 0;
  Index q = 0, done = 0;
  for (int part = 1; part < parts; ++part) {
    const Index target = total * part / parts;
    while (q < col_panels && done + blocks_in(q) <= target) done += blocks_in(q++);
    first[static_cast<std::size_t>(part)] = q;
  }
  Helpers::instance().run(parts, [&](int part) {
    panels(first[static_cast<std::size_t>(part)], first[static_cast<std::size_t>(part) + 1]);
  });
}

/// y[j] = α A(:, j) · x for the columns of A: four columns at a time, each
/// with a 4-wide partial sum over rows [0, 4⌊m/4⌋), then the rest of the rows.
__attribute__((target("avx2,fma"))) void transposed_product_avx2(double* y, double alpha, const double* A,
                                                                  Index stride, Index m, Index n, const double* x) {
  const Index m4 = m - m % 4;
  // α (the four partial sums, then the rows past m4).
  const auto total = [&](const double* partial, const double* column) {
    double s = (partial[0] + partial[1]) + (partial[2] + partial[3]);
    for (Index i = m4; i < m; ++i) s += column[i] * x[i];
    return alpha * s;
  };
  alignas(32) double p0[4], p1[4], p2[4], p3[4];
  Index j = 0;
  for (; j + 4 <= n; j += 4) {
    const double* c0 = A + j * stride;
    const double* c1 = c0 + stride;
    const double* c2 = c1 + stride;
    const double* c3 = c2 + stride;
    __m256d s0 = _mm256_setzero_pd(), s1 = _mm256_setzero_pd(), s2 = _mm256_setzero_pd(), s3 = _mm256_setzero_pd();
    for (Index i = 0; i < m4; i += 4) {
      const __m256d xi = _mm256_loadu_pd(x + i);
      s0 = _mm256_fmadd_pd(_mm256_loadu_pd(c0 + i), xi, s0);
      s1 = _mm256_fmadd_pd(_mm256_loadu_pd(c1 + i), xi, s1);
      s2 = _mm256_fmadd_pd(_mm256_loadu_pd(c2 + i), xi, s2);
      s3 = _mm256_fmadd_pd(_mm256_loadu_pd(c3 + i), xi, s3);
    }
    _mm256_store_pd(p0, s0);
    _mm256_store_pd(p1, s1);
    _mm256_store_pd(p2, s2);
    _mm256_store_pd(p3, s3);
    y[j] = total(p0, c0);
    y[j + 1] = total(p1, c1);
    y[j + 2] = total(p2, c2);
    y[j + 3] = total(p3, c3);
  }
  for (; j < n; ++j) {
    const double* c = A + j * stride;
    __m256d s0 = _mm256_setzero_pd();
    for (Index i = 0; i < m4; i += 4) s0 = _mm256_fmadd_pd(_mm256_loadu_pd(c + i), _mm256_loadu_pd(x + i), s0);
    _mm256_store_pd(p0, s0);
    y[j] = total(p0, c);
  }
}

/// X ← X U⁻¹ column by column (see solve_upper_on_right), rows four at a time.
__attribute__((target("avx2,fma"))) void solve_upper_on_right_avx2(double* X, Index x_stride, Index n, Index m,
                                                                    const double* U, Index u_stride) {
  const Index n4 = n - n % 4;
  for (Index j = 0; j < m; ++j) {
    double* xj = X + j * x_stride;
    for (Index i = 0; i < j; ++i) {
      const double u = U[i + j * u_stride];
      const double* xi = X + i * x_stride;
      const __m256d uv = _mm256_set1_pd(u);
      for (Index r = 0; r < n4; r += 4)
        _mm256_storeu_pd(xj + r, _mm256_fnmadd_pd(uv, _mm256_loadu_pd(xi + r), _mm256_loadu_pd(xj + r)));
      for (Index r = n4; r < n; ++r) xj[r] -= u * xi[r];
    }
    const double d = U[j + j * u_stride];
    const __m256d dv = _mm256_set1_pd(d);
    for (Index r = 0; r < n4; r += 4) _mm256_storeu_pd(xj + r, _mm256_div_pd(_mm256_loadu_pd(xj + r), dv));
    for (Index r = n4; r < n; ++r) xj[r] /= d;
  }
}
#endif

bool cpu_has_avx2_fma() {
#ifdef MSPACE_DENSE_PRODUCT_AVX2
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
  return false;
#endif
}

std::string size_text(Index rows, Index cols) { return std::to_string(rows) + " x " + std::to_string(cols); }

}  // namespace

bool avx2_fma_available() {
  static const bool available = cpu_has_avx2_fma();
  return available;
}

int product_threads() { return threads_setting(); }

void set_product_threads(int threads) { threads_setting() = std::clamp(threads, 1, kMaxThreads); }

void add_product(Eigen::Ref<Eigen::MatrixXd> C, double alpha, const Eigen::Ref<const Eigen::MatrixXd>& A,
                 const Eigen::Ref<const Eigen::MatrixXd>& B, ProductPart part, ProductKernel kernel) {
  const bool lower = part == ProductPart::lower;
  if (C.rows() != A.rows() || C.cols() != B.rows() || A.cols() != B.cols() || (lower && C.rows() != C.cols())) {
    throw std::invalid_argument("add_product: C is " + size_text(C.rows(), C.cols()) + ", A " +
                                size_text(A.rows(), A.cols()) + ", B " + size_text(B.rows(), B.cols()) +
                                " (expected C m x n, A m x k, B n x k" + (lower ? ", m = n for the lower triangle)" : ")"));
  }
  if (kernel == ProductKernel::avx2_fma && !avx2_fma_available()) {
    throw std::invalid_argument("add_product: the AVX2/FMA kernel is not available on this processor");
  }
  if (C.size() == 0 || A.cols() == 0) return;
#ifdef MSPACE_DENSE_PRODUCT_AVX2
  if (kernel != ProductKernel::eigen && avx2_fma_available()) {
    add_product_avx2(C, alpha, A, B, lower);
    return;
  }
#endif
  if (lower) {
    C.triangularView<Eigen::Lower>() += alpha * A * B.transpose();
  } else {
    C.noalias() += alpha * A * B.transpose();
  }
}

void transposed_product(Eigen::Ref<Eigen::VectorXd> y, double alpha, const Eigen::Ref<const Eigen::MatrixXd>& A,
                        const Eigen::Ref<const Eigen::VectorXd>& x, ProductKernel kernel) {
  if (y.size() != A.cols() || x.size() != A.rows()) {
    throw std::invalid_argument("transposed_product: y has " + std::to_string(y.size()) + " entries, A is " +
                                size_text(A.rows(), A.cols()) + ", x has " + std::to_string(x.size()) +
                                " (expected y n, A m x n, x m)");
  }
  if (kernel == ProductKernel::avx2_fma && !avx2_fma_available()) {
    throw std::invalid_argument("transposed_product: the AVX2/FMA kernel is not available on this processor");
  }
  if (y.size() == 0) return;
#ifdef MSPACE_DENSE_PRODUCT_AVX2
  if (kernel != ProductKernel::eigen && avx2_fma_available()) {
    // (Both vectors have unit stride: Eigen::Ref's default for vectors.)
    transposed_product_avx2(y.data(), alpha, A.data(), A.outerStride(), A.rows(), A.cols(), x.data());
    return;
  }
#endif
  y.noalias() = alpha * (A.transpose() * x);
}

void solve_upper_on_right(Eigen::Ref<Eigen::MatrixXd> X, const Eigen::Ref<const Eigen::MatrixXd>& U,
                          ProductKernel kernel) {
  if (U.rows() != U.cols() || X.cols() != U.rows()) {
    throw std::invalid_argument("solve_upper_on_right: X is " + size_text(X.rows(), X.cols()) + ", U " +
                                size_text(U.rows(), U.cols()) + " (expected X n x m, U m x m)");
  }
  if (kernel == ProductKernel::avx2_fma && !avx2_fma_available()) {
    throw std::invalid_argument("solve_upper_on_right: the AVX2/FMA kernel is not available on this processor");
  }
  if (X.size() == 0) return;
#ifdef MSPACE_DENSE_PRODUCT_AVX2
  if (kernel != ProductKernel::eigen && avx2_fma_available()) {
    solve_upper_on_right_avx2(X.data(), X.outerStride(), X.rows(), X.cols(), U.data(), U.outerStride());
    return;
  }
#endif
  U.triangularView<Eigen::Upper>().solveInPlace<Eigen::OnTheRight>(X);
}

}  // namespace mspace
