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
#include "mspace/dense_product.hpp"

#include <Eigen/Core>
#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define MSPACE_DENSE_PRODUCT_AVX2 1
#endif

namespace mspace {

namespace {

using Eigen::Index;

#ifdef MSPACE_DENSE_PRODUCT_AVX2
constexpr Index kRows = 8;  // rows of C per block (two 4-wide registers)
constexpr Index kCols = 4;  // columns of C per block

/// Rows [first, first + width) of M as `width`-wide groups, one per column l
/// of M, zero past its last row: out[l * width + r] = M(first + r, l).
void pack_panel(const Eigen::Ref<const Eigen::MatrixXd>& M, Index first, Index width, double* out) {
  const Index valid = std::min(width, M.rows() - first);
  for (Index l = 0; l < M.cols(); ++l) {
    const double* column = M.data() + l * M.outerStride() + first;
    double* group = out + l * width;
    for (Index r = 0; r < valid; ++r) group[r] = column[r];
    for (Index r = valid; r < width; ++r) group[r] = 0.0;
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
  thread_local std::vector<double> packed_a, packed_b;
  packed_a.resize(static_cast<std::size_t>(row_panels * kRows * k));
  packed_b.resize(static_cast<std::size_t>(col_panels * kCols * k));
  for (Index p = 0; p < row_panels; ++p) pack_panel(A, p * kRows, kRows, packed_a.data() + p * kRows * k);
  for (Index q = 0; q < col_panels; ++q) pack_panel(B, q * kCols, kCols, packed_b.data() + q * kCols * k);

  double block[kRows * kCols];
  for (Index q = 0; q < col_panels; ++q) {
    const Index j0 = q * kCols, block_cols = std::min(kCols, cols - j0);
    for (Index p = lower ? j0 / kRows : 0; p < row_panels; ++p) {
      const Index i0 = p * kRows, block_rows = std::min(kRows, rows - i0);
      block_product_avx2(packed_a.data() + p * kRows * k, packed_b.data() + q * kCols * k, k, block);
      for (Index c = 0; c < block_cols; ++c) {
        const Index j = j0 + c;
        double* column = C.data() + j * C.outerStride() + i0;
        const double* sums = block + c * kRows;
        for (Index r = lower ? std::max<Index>(0, j - i0) : 0; r < block_rows; ++r) column[r] += alpha * sums[r];
      }
    }
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

}  // namespace mspace
