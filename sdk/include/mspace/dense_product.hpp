// mspace/dense_product.hpp — C ← C + α A Bᵀ, in full or on the lower triangle
// of a square C: the products that dominate a covariance filter on a large
// map. The EKF's eq. 32 on the whole covariance is C − W Wᵀ (A = B = W, lower
// triangle); the compressed EKF's global update is P⁰_BB − Gᵀ Ψ G (lower
// triangle) with Ψ G and Φ G before it (full).
//
// Two kernels compute it, the same sums in a different order (results agree
// to round-off): Eigen's product, and on x86-64 processors with AVX2 and FMA
// (checked at run time) a packed 8 × 4 register-blocked kernel, 2–3 times
// faster on these sizes because Eigen as built here (no -march flag) uses SSE2.
//
// Threads. A large product on the AVX2/FMA kernel is split by columns of C
// over up to product_threads() threads (the caller and helpers kept waiting
// between products). Every column of C is computed whole by exactly one
// thread, by the same block kernel over the same packed panels in the same
// order, so the result is the same bit for bit whatever the number of
// threads. Small products (below about two million multiply–adds, where
// waking a helper costs more than it saves) and Eigen's kernel run on the
// calling thread alone.
#pragma once

#include <Eigen/Core>

namespace mspace {

enum class ProductKernel {
  automatic,  ///< avx2_fma when the processor has it, else eigen
  eigen,      ///< Eigen's products (any processor)
  avx2_fma,   ///< the packed AVX2/FMA kernel (throws where unavailable)
};

/// Which entries of C a product writes.
enum class ProductPart {
  full,   ///< all of C
  lower,  ///< i ≥ j only (C square, A Bᵀ meant to be symmetric); the rest is neither read nor written
};

/// Whether this build and this processor can run ProductKernel::avx2_fma.
bool avx2_fma_available();

/// y[j] = α Σ_i A[i, j] x[i] for every column j of A (y ← α Aᵀ x, y of size
/// A.cols(), x of size A.rows()): one dot product per column, the shape of
/// the compressed EKF's δx_B = −Gᵀ (V w) over every passive slot. Same
/// kernels as add_product (the AVX2/FMA one: four columns at a time, 4-wide
/// partial sums); on one thread. Throws std::invalid_argument on mismatched
/// sizes or an unavailable kernel.
void transposed_product(Eigen::Ref<Eigen::VectorXd> y, double alpha, const Eigen::Ref<const Eigen::MatrixXd>& A,
                        const Eigen::Ref<const Eigen::VectorXd>& x, ProductKernel kernel = ProductKernel::automatic);

/// X ← X U⁻¹ for an upper triangular U (m × m, only its upper triangle and
/// diagonal are read; X n × m): column j of the result is (x_j − Σ_{i<j}
/// U(i, j) x_i) / U(j, j), the Kalman update's W L⁻ᵀ with U = Lᵀ. The AVX2/FMA
/// kernel runs down the rows four at a time; Eigen's triangular solve
/// otherwise. Throws std::invalid_argument on mismatched sizes or an
/// unavailable kernel.
void solve_upper_on_right(Eigen::Ref<Eigen::MatrixXd> X, const Eigen::Ref<const Eigen::MatrixXd>& U,
                          ProductKernel kernel = ProductKernel::automatic);

/// Most threads the AVX2/FMA kernel uses for one large product, the caller
/// included. Default: the environment variable MSPACE_THREADS when it is a
/// number from 1 to 64, else the processor's hardware threads, at most 4.
int product_threads();
/// Sets product_threads() (clamped to [1, 64]); results do not change, only
/// the time they take. Not to be called while a product runs.
void set_product_threads(int threads);

/// C[i, j] += α Σ_l A[i, l] B[j, l] over `part` (C is A.rows() × B.rows(), A
/// and B have the same number of columns). Throws std::invalid_argument on
/// mismatched sizes or an unavailable kernel.
void add_product(Eigen::Ref<Eigen::MatrixXd> C, double alpha, const Eigen::Ref<const Eigen::MatrixXd>& A,
                 const Eigen::Ref<const Eigen::MatrixXd>& B, ProductPart part = ProductPart::full,
                 ProductKernel kernel = ProductKernel::automatic);

}  // namespace mspace
