#pragma once
/// @file The CUDA side of the parallel_for choke point (see ParallelFor.h): the same functors,
/// launched as grid-stride kernels on a stream. Only .cu files include this.
#include <cuda_runtime.h>

#include <cstdint>
#include <string>

#include "CudaChecks.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace backend {
inline namespace SONOSLICE_KERNEL_ISA {

namespace detail {
inline void check_launch(const char* what, void* stream) {
  cudaError_t err = cudaGetLastError();
  if (err != cudaSuccess)
    throw Error(std::string("cuda: launching ") + what + " failed: " + cudaGetErrorString(err));
  // SONOSLICE_CUDA_DEBUG=1: wait for the kernel, so that a fault is reported at its launch.
  if (::sonoslice::cuda::debug_sync_enabled()) {
    err = cudaStreamSynchronize(static_cast<cudaStream_t>(stream));
    if (err != cudaSuccess)
      throw Error(std::string("cuda: ") + what +
                  " failed (SONOSLICE_CUDA_DEBUG): " + cudaGetErrorString(err));
  }
}

template <typename F>
__global__ void for_kernel(int64_t n, F f) {
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < n;
       i += int64_t(blockDim.x) * gridDim.x)
    f(i);
}

// A warp takes 2^shift rows at once as a tile: 32 >> shift lanes per row, each lane taking
// columns col, col + (32 >> shift), ... of its row, so that every lane computes its row's start
// (row()) once and a warp's loads touch a compact patch of the image (neighbouring voxels) rather
// than a long line through the volume, while its stores stay whole 32-byte sectors. Warps stride
// over the row groups, so any batch size fits the grid.
template <typename F>
__global__ void rows_kernel(int64_t rows, int width, int shift, F f) {
  const int lane = int(threadIdx.x);
  const int step = 32 >> shift;
  const int col = lane & (step - 1);
  const int sub = lane >> (5 - shift);
  for (int64_t group = int64_t(blockIdx.x) * blockDim.y + threadIdx.y; (group << shift) < rows;
       group += int64_t(gridDim.x) * blockDim.y) {
    const int64_t r = (group << shift) + sub;
    if (r >= rows) continue;
    const auto state = f.row(r);
    for (int u = col; u < width; u += step) f.pixel(state, u);
  }
}
}  // namespace detail

/// f(i) for i in [0, n) on the current device, on `stream` (cudaStream_t; null: default).
template <typename F>
void parallel_for(int64_t n, const F& f, void* stream = nullptr) {
  if (n <= 0) return;
  const int block = 256;
  const int64_t blocks = (n + block - 1) / block;
  detail::for_kernel<<<unsigned(blocks < 65535 * 16 ? blocks : 65535 * 16), block, 0,
                       static_cast<cudaStream_t>(stream)>>>(n, f);
  detail::check_launch("parallel_for", stream);
}

namespace detail {
// F::kCudaRowsPerWarp, or 1 where F does not say.
template <typename F, typename = void>
struct rows_per_warp {
  static constexpr int value = 1;
};
template <typename F>
struct rows_per_warp<F, decltype(void(F::kCudaRowsPerWarp))> {
  static constexpr int value = F::kCudaRowsPerWarp;
};
}  // namespace detail

/// The rows × width index space of ParallelFor.h: eight warps per block, each taking a tile of
/// rows at once: F::kCudaRowsPerWarp of them where the functor says (the shape measured fastest
/// for it), else one; SONOSLICE_CUDA_ROW_TILE overrides both (CudaChecks.h).
template <typename F>
void parallel_for_rows(int64_t rows, int width, const F& f, void* stream = nullptr) {
  if (rows <= 0 || width <= 0) return;
  const int shift = ::sonoslice::cuda::row_tile_shift(detail::rows_per_warp<F>::value);
  const dim3 block(32, 8);
  const int64_t groups = (rows + (int64_t(1) << shift) - 1) >> shift;
  const int64_t row_blocks = (groups + block.y - 1) / block.y;
  constexpr int64_t kMaxBlocks = int64_t(1) << 20;  // then warps take several tiles each
  const dim3 grid(unsigned(row_blocks < kMaxBlocks ? row_blocks : kMaxBlocks));
  detail::rows_kernel<<<grid, block, 0, static_cast<cudaStream_t>(stream)>>>(rows, width, shift, f);
  detail::check_launch("parallel_for_rows", stream);
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace backend
}  // namespace sonoslice
