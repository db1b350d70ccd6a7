#pragma once
/// @file Atomic updates the CUDA kernels need beyond CUDA's own (atomicAdd on floats is built in).
/// Only .cu files include this.
#include <cuda_runtime.h>

#include "sonoslice/backend/HostDevice.h"

namespace sonoslice {
namespace backend {
inline namespace SONOSLICE_KERNEL_ISA {

/// *address = max(*address, value), atomically, for floats other than NaN.
__device__ __forceinline__ void atomic_max_float(float* address, float value) {
  // Floats order like sign-magnitude integers: positive values as ints, negative ones reversed.
  if (value >= 0.f)
    atomicMax(reinterpret_cast<int*>(address), __float_as_int(value));
  else
    atomicMin(reinterpret_cast<unsigned int*>(address), __float_as_uint(value));
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace backend
}  // namespace sonoslice
