// sim_random.hpp — random numbers that are identical on every machine.
//
// std::mt19937_64 is fully specified by the C++ standard, but the standard
// distributions (normal, uniform, poisson, std::shuffle) are not: their
// algorithms differ between standard libraries. So the simulator draws raw
// 64-bit words from the engine and turns them into samples here.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

namespace mspace::sim_world {

class SimRandom {
 public:
  /// An independent stream per (seed, stream) pair, so e.g. changing the
  /// detection probability does not change the odometry noise.
  SimRandom(std::uint64_t seed, std::uint64_t stream)
      : engine_(splitmix64(seed ^ splitmix64(stream))) {}

  /// Uniform in [0, 1) with 53 random bits.
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  /// Uniform in [lo, hi).
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }

  /// Standard normal N(0, 1), Marsaglia's polar form of the Box–Muller method
  /// (two samples per accepted pair; the second is kept for the next call).
  double normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    double u = 0.0, v = 0.0, s = 0.0;
    do {
      u = uniform(-1.0, 1.0);
      v = uniform(-1.0, 1.0);
      s = u * u + v * v;
    } while (s >= 1.0 || s == 0.0);
    const double factor = std::sqrt(-2.0 * std::log(s) / s);
    spare_ = v * factor;
    has_spare_ = true;
    return u * factor;
  }

  /// Poisson with mean `mean` (Knuth's product of uniforms; fine for small means).
  int poisson(double mean) {
    const double limit = std::exp(-mean);
    int count = 0;
    for (double product = uniform(); product > limit; product *= uniform()) ++count;
    return count;
  }

  /// Uniform integer in [0, n), n > 0, without modulo bias.
  std::uint64_t index(std::uint64_t n) {
    const std::uint64_t threshold = (0 - n) % n;  // 2^64 mod n
    for (;;) {
      const std::uint64_t r = engine_();
      if (r >= threshold) return r % n;
    }
  }

  /// Fisher–Yates shuffle of the rows of a matrix.
  template <class Matrix>
  void shuffle_rows(Matrix& m) {
    for (auto i = m.rows() - 1; i > 0; --i) {
      const auto j = static_cast<decltype(i)>(index(static_cast<std::uint64_t>(i) + 1));
      if (j != i) m.row(i).swap(m.row(j));
    }
  }

 /// The whole generator state as text: the engine's standard text form
  /// (std::mt19937_64's operator<<, exact and portable) and the spare normal
  /// sample as its IEEE-754 bits. set_state(state()) continues the same stream.
  std::string state() const {
    std::ostringstream os;
    std::uint64_t spare_bits = 0;
    static_assert(sizeof spare_bits == sizeof spare_);
    std::memcpy(&spare_bits, &spare_, sizeof spare_);
    os << engine_ << ' ' << (has_spare_ ? 1 : 0) << ' ' << spare_bits;
    return os.str();
  }
  /// Throws std::invalid_argument for text state() did not write.
  void set_state(const std::string& text) {
    std::istringstream is(text);
    std::mt19937_64 engine;
    int has_spare = 0;
    std::uint64_t spare_bits = 0;
    if (!(is >> engine >> has_spare >> spare_bits) || (has_spare != 0 && has_spare != 1) || !(is >> std::ws).eof())
      throw std::invalid_argument("not a random generator state");
    engine_ = engine;
    has_spare_ = has_spare == 1;
    std::memcpy(&spare_, &spare_bits, sizeof spare_);
  }

 private:
  static std::uint64_t splitmix64(std::uint64_t x) {
    x += 0x9E3779B97F4A7C15ULL;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
  }

  std::mt19937_64 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

}  // namespace mspace::sim_world
