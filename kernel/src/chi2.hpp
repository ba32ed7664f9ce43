// chi2.hpp — χ² distribution helpers for gating and consistency bands.
#pragma once

namespace mspace::kernel {

/// P(X ≤ x) for X ~ χ²(dof).
double chi2_cdf(double x, int dof);
/// The x with chi2_cdf(x, dof) = p, for 0 < p < 1.
double chi2_quantile(double p, int dof);

}  // namespace mspace::kernel
