// The CUDA backend of the slicing kernel: SliceImpl.h compiled by nvcc with the CUDA
// parallel_for. Only the kernels live here; buffers and streams are host code (SlicerCUDA.cpp).
#define SONOSLICE_KERNEL_ISA cuda
#include "SliceBackends.h"
#include "SliceImpl.h"

namespace sonoslice {
namespace slice_impl {
void slice_cuda_launch(const SliceLaunch& launch) {
  dispatch_slice(launch);
}
}  // namespace slice_impl
}  // namespace sonoslice
