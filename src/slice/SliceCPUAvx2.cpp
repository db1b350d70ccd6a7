// The CPU backend of the slicing kernel for CPUs with AVX2 and FMA: the same SliceImpl.h, built
// with -mavx2 -mfma, which adds the eight-lane fast path. Chosen at run time (Slicer.cpp).
#define SONOSLICE_KERNEL_ISA avx2
#include "SliceBackends.h"
#include "SliceImpl.h"

namespace sonoslice {
namespace slice_impl {
void slice_cpu_avx2(const SliceLaunch& launch) {
  dispatch_slice(launch);
}
}  // namespace slice_impl
}  // namespace sonoslice
