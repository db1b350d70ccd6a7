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

/// pair[0] += a and pair[1] += b, each atomically: one vector atomic on sm_90 and later
/// (atomicAdd on a float2 in global memory; `pair` must be 8-byte aligned), two float atomics on
/// older GPUs. The two halves are not updated as one transaction before sm_90; nothing here
/// needs them to be (every update is a sum, read only after the kernels finish).
__device__ __forceinline__ void atomic_add_pair(float* pair, float a, float b) {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  atomicAdd(reinterpret_cast<float2*>(pair), make_float2(a, b));
#else
  atomicAdd(pair, a);
  atomicAdd(pair + 1, b);
#endif
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace backend
}  // namespace sonoslice
