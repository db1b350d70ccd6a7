#pragma once
// Internal, CUDA builds only: the Slicer's GPU state and the host code that drives the kernel
// (SlicerCUDA.cpp; the kernel itself is SliceCUDA.cu).
#include <memory>
#include <vector>

#include "SliceTypes.h"
#include "sonoslice/slice/Slicer.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {
namespace slice_impl {

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

}  // namespace slice_impl
}  // namespace sonoslice
