#pragma once
// Internal: the entry points of the compounding backends, called by Compounder.cpp.
#include <memory>

#include "CompoundTypes.h"

namespace sonoslice {
namespace compound_impl {

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

/// The accumulators on a GPU and the buffers frames travel through (CompounderCUDA.cpp).
class CudaCompounding {
 public:
  CudaCompounding(int device, int nx, int ny, int nz, Mode mode);
  ~CudaCompounding();
  /// Uploads the batch (host pointers) and queues its kernels.
  void add(const FrameBatch& host_batch, bool linear);
  /// Copies the accumulators (and stamps, latest mode) to host memory.
  void download(Accumulator* cells, int32_t* stamp);

 private:
  struct State;
  std::unique_ptr<State> state_;
};
#endif

}  // namespace compound_impl
}  // namespace sonoslice
