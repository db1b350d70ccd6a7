// The CUDA backend of the compounding kernels: CompoundDriverCUDA.cuh (over the shared
// CompoundImpl.h) compiled by nvcc with the CUDA parallel_for. Buffers and streams are host code
// (CompounderCUDA.cpp).
#define SONOSLICE_KERNEL_ISA cuda
#include <cstdint>

#include "../backend/ParallelForCUDA.cuh"
#include "CompoundBackends.h"
#include "CompoundDriverCUDA.cuh"

namespace sonoslice {
namespace compound_impl {

void compound_cuda_launch(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                          bool linear, void* stream) {
  dispatch_compound_cuda(grid, batch, mode, linear, stream);
}

namespace {
struct ClearAccumulators {
  AccumulatorView grid;
  float empty;
  __device__ void operator()(int64_t i) const {
    grid.cells[i].value = empty;
    grid.cells[i].weight = 0.f;
    if (grid.stamp) grid.stamp[i] = -1;
  }
};
}  // namespace

void compound_cuda_clear(const AccumulatorView& grid, Mode mode, void* stream) {
  const int64_t n = int64_t(grid.nx) * grid.ny * grid.nz;
  backend::parallel_for(n, ClearAccumulators{grid, empty_value(mode)}, stream);
}

}  // namespace compound_impl
}  // namespace sonoslice
