#pragma once
/// @file How the compounding dispatch layer (Compounder.cpp) reaches the compounding kernels
/// (CompoundImpl.h, driven by CompoundDriverCPU.h and CompoundDriverCUDA.cuh) in each of their
/// builds: one entry point per CPU instruction set (CompoundCPU.cpp, CompoundCPUAvx2.cpp) chosen
/// by CpuIsa, and, in CUDA builds, the kernels (CompoundCUDA.cu) with the host code that drives
/// them (CompounderCUDA.cpp). The same wiring as every kernel folder (SliceBackends.h,
/// SimulateBackends.h; docs/architecture.md).
#include <memory>
#include <vector>

#include "CompoundTypes.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

struct FinishInput;  // FinishImpl.h

/// CPU: `slabs` owner-computes tasks along `axis` over voxel indices [lo, hi), with the kernels
/// built for each instruction set.
void compound_cpu_generic(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                          bool linear, int axis, int lo, int hi, int slabs);
void compound_cpu_avx2(const AccumulatorView& grid, const FrameBatch& batch, Mode mode, bool linear,
                       int axis, int lo, int hi, int slabs);
inline void compound_cpu(CpuIsa isa, const AccumulatorView& grid, const FrameBatch& batch,
                         Mode mode, bool linear, int axis, int lo, int hi, int slabs) {
  switch (isa) {
    case CpuIsa::Avx2:
      return compound_cpu_avx2(grid, batch, mode, linear, axis, lo, hi, slabs);
    case CpuIsa::Generic:
      return compound_cpu_generic(grid, batch, mode, linear, axis, lo, hi, slabs);
  }
}

/// CPU: the finished values without hole filling of voxels [begin, end) into `out` (the whole
/// grid's voxel_count values of `type`), with the code built for each instruction set.
void finish_values_generic(const FinishInput& in, PixelType type, int64_t begin, int64_t end,
                           void* out);
void finish_values_avx2(const FinishInput& in, PixelType type, int64_t begin, int64_t end,
                        void* out);
inline void finish_values_cpu(CpuIsa isa, const FinishInput& in, PixelType type, int64_t begin,
                              int64_t end, void* out) {
  if (isa == CpuIsa::Avx2) return finish_values_avx2(in, type, begin, end, out);
  finish_values_generic(in, type, begin, end, out);
}

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
