#pragma once
/// @file The one seeded random-number generator of the library: splitmix64 (Steele, Lea and
/// Flood 2014; public-domain constants). Tiny state, a pure function of the seed, and
/// counter-friendly (mix64 of any 64-bit key is itself a good random number), which is what
/// deterministic simulation noise, multi-start draws and per-seed pose sampling need: results
/// that depend on the seed alone, never on threads or call order.
#include <cmath>
#include <cstdint>

namespace sonoslice {

/// splitmix64's increment (2^64 / φ, odd): successive states, or counters scaled by it, are
/// well spread before mixing.
constexpr uint64_t kGoldenGamma = 0x9E3779B97F4A7C15ull;

/// splitmix64's finaliser: a bijection of 64-bit values with good avalanche.
constexpr uint64_t mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// splitmix64: the stream of 64-bit values of a seed, and uniforms built from their top 53 bits.
class SplitMix64 {
 public:
  explicit SplitMix64(uint64_t seed) : state_(seed) {}

  uint64_t next() { return mix64(state_ += kGoldenGamma); }
  /// Uniform in [0, 1).
  double uniform() { return double(next() >> 11) * 0x1p-53; }
  /// Uniform in (0, 1]: safe under a logarithm.
  double uniform_nonzero() { return (double(next() >> 11) + 1.0) * 0x1p-53; }
  /// Standard normal, one of Box–Muller's pair.
  double normal() {
    const double u = 1.0 - uniform(), v = uniform();
    return std::sqrt(-2 * std::log(u)) * std::cos(6.283185307179586 * v);
  }

 private:
  uint64_t state_;
};

}  // namespace sonoslice
