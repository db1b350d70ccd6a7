#pragma once
/// @file Value conversion shared by all kernels: round to nearest (ties up) and saturate for
/// integer targets; NaN becomes 0 in integer targets and stays NaN in float targets.
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>

#include "sonoslice/backend/HostDevice.h"

namespace sonoslice {
namespace backend {
inline namespace SONOSLICE_KERNEL_ISA {

/// a + t·(b − a): the one lerp every interpolation formula is built from (scalar lanes; the
/// AVX2 lanes overload it).
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F lerp(F a, F b, F t) {
  return a + t * (b - a);
}

/// a + b·c rounded as two operations, never fused: every backend then computes the same pixel
/// coordinates and makes the same inside/outside decision (nvcc fuses by default).
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F add_product(F a, F b, F c) {
#if defined(__CUDA_ARCH__)
  if constexpr (std::is_same<F, float>::value)
    return __fadd_rn(a, __fmul_rn(b, c));
  else
    return __dadd_rn(a, __dmul_rn(b, c));
#else
  return a + b * c;
#endif
}

template <typename T, typename V>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T saturate_cast(V v) {
  if constexpr (std::is_floating_point<T>::value) {
    return static_cast<T>(v);
  } else {
    if (!(v == v)) return T(0);
    constexpr V lo = V(std::numeric_limits<T>::lowest());
    constexpr V hi = V(std::numeric_limits<T>::max());
    const V r = std::floor(v + V(0.5));
    // Compare before converting: float(INT32_MAX) rounds up, so clamp at hi with >=.
    if (r <= lo) return std::numeric_limits<T>::lowest();
    if (r >= hi) return std::numeric_limits<T>::max();
    return static_cast<T>(r);
  }
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace backend
}  // namespace sonoslice
