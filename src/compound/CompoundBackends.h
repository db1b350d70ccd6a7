#pragma once
// Internal: the entry points of the compounding backends, called by Compounder.cpp.
#include <memory>
#include <vector>

#include "CompoundTypes.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

struct FinishInput;  // FinishImpl.h

/// CPU: `slabs` owner-computes tasks along `axis` over voxel indices [lo, hi), with the
/// instruction set cpu_kernel_isa() names.
void compound_cpu(const AccumulatorView& grid, const FrameBatch& batch, Mode mode, bool linear,
                  int axis, int lo, int hi, int slabs);
void compound_cpu_generic(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                          bool linear, int axis, int lo, int hi, int slabs);
void compound_cpu_avx2(const AccumulatorView& grid, const FrameBatch& batch, Mode mode, bool linear,
                       int axis, int lo, int hi, int slabs);

#ifdef SONOSLICE_HAVE_CUDA
/// CUDA: the batch's pointers and the grid's are device pointers.
void compound_cuda_launch(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                          bool linear, void* stream);
/// CUDA: sets every accumulator to its empty state (value 0, or -inf for max; stamp -1).
void compound_cuda_clear(const AccumulatorView& grid, Mode mode, void* stream);
/// CUDA: the finished volume (FinishImpl.h, one thread per voxel) into `out`, device memory of
/// voxel_count values of `type`; `in` points at device memory.
void compound_cuda_finish(const FinishInput& in, PixelType type, void* out, void* stream);

/// The accumulators on a GPU and the buffers frames travel through (CompounderCUDA.cpp).
class CudaCompounding {
 public:
  CudaCompounding(int device, int nx, int ny, int nz, Mode mode);
  ~CudaCompounding();
  /// Uploads the batch (host pointers) and queues its kernels.
  void add(const FrameBatch& host_batch, bool linear);
  /// Copies the accumulators (and stamps, latest mode) to host memory.
  void download(Accumulator* cells, int32_t* stamp);
  /// Finishes the volume on the GPU (values, hole filling with `kernels`) and copies only the
  /// result, voxel_count values of `type`, into `host_out`.
  void finish(const std::vector<HoleFillingKernel>& kernels, PixelType type, void* host_out);

 private:
  struct State;
  std::unique_ptr<State> state_;
};
#endif

}  // namespace compound_impl
}  // namespace sonoslice
