#include "chi2.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace mspace::kernel {
namespace {

// Regularised lower incomplete gamma P(a, x): power series for x < a + 1,
// Lentz continued fraction for Q = 1 − P otherwise (Abramowitz & Stegun 6.5).
double regularized_gamma_p(double a, double x) {
  if (x <= 0.0) return 0.0;
  const double log_prefactor = a * std::log(x) - x - std::lgamma(a);
  if (x < a + 1.0) {
    double term = 1.0 / a;
    double sum = term;
    for (int n = 1; n < 1000; ++n) {
      term *= x / (a + n);
      sum += term;
      if (std::abs(term) < std::abs(sum) * 1e-16) break;
    }
    return sum * std::exp(log_prefactor);
  }
  const double tiny = 1e-300;
  double b = x + 1.0 - a;
  double c = 1.0 / tiny;
  double d = 1.0 / b;
  double h = d;
  for (int i = 1; i < 1000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < 1e-16) break;
  }
  return 1.0 - std::exp(log_prefactor) * h;
}

}  // namespace

double chi2_cdf(double x, int dof) {
  if (dof <= 0) throw std::invalid_argument("chi2_cdf: degrees of freedom must be positive");
  return regularized_gamma_p(0.5 * dof, 0.5 * x);
}

double chi2_quantile(double p, int dof) {
  if (!(p > 0.0 && p < 1.0))
    throw std::invalid_argument("chi2_quantile: probability must be in (0, 1), got " + std::to_string(p));
  if (dof <= 0) throw std::invalid_argument("chi2_quantile: degrees of freedom must be positive");
  // Bisection on the monotone CDF, bracketed generously; 200 halvings reach
  // machine precision for any realistic dof.
  double lo = 0.0;
  double hi = dof + 20.0 * std::sqrt(2.0 * dof) + 100.0;
  while (chi2_cdf(hi, dof) < p) hi *= 2.0;
  for (int i = 0; i < 200 && hi - lo > 1e-12 * hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    (chi2_cdf(mid, dof) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace mspace::kernel
