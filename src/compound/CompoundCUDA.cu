// The CUDA backend of the compounding kernels: CompoundDriverCUDA.cuh (over the shared
// CompoundImpl.h) compiled by nvcc with the CUDA parallel_for. Buffers and streams are host code
// (CompounderCUDA.cpp).
#define SONOSLICE_KERNEL_ISA cuda
#include <cstdint>

#include "../backend/ParallelForCUDA.cuh"
#include "CompoundBackends.h"
#include "CompoundDriverCUDA.cuh"
#include "FinishImpl.h"

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

namespace {
// One thread per voxel, x fastest: neighbouring threads read neighbouring accumulators.
template <typename T>
struct FinishVoxels {
  FinishInput in;
  T* out;
  __device__ void operator()(int64_t i) const {
    const int64_t nx = in.g.nx, ny = in.g.ny;
    const int x = int(i % nx), y = int((i / nx) % ny), z = int(i / (nx * ny));
    out[i] = finished_voxel<T>(in, x, y, z);
  }
};
}  // namespace

void compound_cuda_finish(const FinishInput& in, PixelType type, void* out, void* stream) {
  const int64_t n = int64_t(in.g.nx) * in.g.ny * in.g.nz;
  visit_pixel_type(type, [&](auto zero) {
    using T = decltype(zero);
    backend::parallel_for(n, FinishVoxels<T>{in, static_cast<T*>(out)}, stream);
  });
}

void compound_cuda_clear(const AccumulatorView& grid, Mode mode, void* stream) {
  const int64_t n = int64_t(grid.nx) * grid.ny * grid.nz;
  backend::parallel_for(n, ClearAccumulators{grid, empty_value(mode)}, stream);
}

}  // namespace compound_impl
}  // namespace sonoslice
