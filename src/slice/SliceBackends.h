#pragma once
/// @file How the slicing dispatch layer (Slicer.cpp) reaches the slicing kernel (SliceImpl.h) in
/// each of its builds: one entry point per CPU instruction set (SliceCPU.cpp, SliceCPUAvx2.cpp)
/// chosen by CpuIsa, and, in CUDA builds, the kernel (SliceCUDA.cu) with the host code that
/// drives it (SlicerCUDA.cpp). Every kernel folder wires its backends the same way
/// (CompoundBackends.h, SimulateBackends.h; docs/architecture.md).
#include <memory>
#include <vector>

#include "SliceTypes.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/slice/Slicer.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {
namespace slice_impl {

/// CPU: the kernel built for each instruction set.
void slice_cpu_generic(const SliceLaunch& launch);
void slice_cpu_avx2(const SliceLaunch& launch);
inline void slice_cpu(CpuIsa isa, const SliceLaunch& launch) {
  switch (isa) {
    case CpuIsa::Avx2:
      return slice_cpu_avx2(launch);
    case CpuIsa::Generic:
      return slice_cpu_generic(launch);
  }
}

#ifdef SONOSLICE_HAVE_CUDA
/// CUDA: the kernel, on the launch's stream; every pointer in `launch` is device memory.
void slice_cuda_launch(const SliceLaunch& launch);

struct CudaSliceState;

/// Uploads the volume (native pixel type) and the mask to cuda:`device`, once.
std::shared_ptr<CudaSliceState> cuda_prepare(const Volume& volume, const std::vector<uint8_t>& mask,
                                             int device);

/// `launch` carries everything but the device pointers, which the state provides. `device_out`
/// is checked to be memory of the state's GPU; `stream` says where the work goes (Slicer.h).
void cuda_slice_into_device(CudaSliceState& state, SliceLaunch launch,
                            const std::vector<PixelToIndex>& affines, void* device_out,
                            CudaStream stream);
/// Into a new device buffer of its own (freed, stream-ordered, when the last owner goes), on the
/// state's stream; returns the buffer's owner and the stream used.
std::shared_ptr<void> cuda_slice_to_new_buffer(const std::shared_ptr<CudaSliceState>& state,
                                               SliceLaunch launch,
                                               const std::vector<PixelToIndex>& affines,
                                               void** stream);
/// Into host memory, in chunks, copies overlapping the next chunk's kernel.
void cuda_slice_to_host(CudaSliceState& state, SliceLaunch launch,
                        const std::vector<PixelToIndex>& affines, void* host_out);
/// Waits for `stream` on cuda:`device`.
void cuda_synchronize(void* stream, int device);
/// Synchronous device → host copy of `bytes` on `stream`.
void cuda_copy_to_host(void* host_out, const void* device_data, size_t bytes, void* stream,
                       int device);

#endif  // SONOSLICE_HAVE_CUDA

}  // namespace slice_impl
}  // namespace sonoslice
