// Host side of the CUDA slicing backend: the resident volume, buffers, streams and the chunked,
// overlapped copy-back. The kernel is SliceImpl.h compiled by nvcc (SliceCUDA.cu).
#include <algorithm>
#include <cstring>
#include <memory>

#include "../backend/CudaChecks.h"
#include "../backend/CudaRuntime.h"
#include "../backend/ParallelFor.h"
#include "SliceBackends.h"

namespace sonoslice {
namespace slice_impl {

struct CudaSliceState : cuda::Owner {
  explicit CudaSliceState(int device) : cuda::Owner(device) {}
  cuda::DeviceBuffer volume, mask;
  cuda::DeviceBuffer out[2];      // chunks on their way to host memory (grow with the batch)
  cuda::PinnedBuffer staging[2];  // page-locked landing zones for device → host copies
  std::unique_ptr<cuda::Stream> streams[2];
  // Orders the slicer's stream after the caller's and back (CudaStream::own_then_join).
  std::unique_ptr<cuda::Event> caller_done, slicing_done;
  void enter() const { cuda::Owner::enter("slicer"); }
};

namespace {

size_t image_bytes(const SliceLaunch& l) {
  return size_t(l.width) * size_t(l.height) * pixel_size(l.output_type);
}

// Uploads the affines on `stream` into stream-ordered scratch memory, queues the kernel, and
// releases the scratch behind it: nothing waits, and the host vector may go right away
// (a copy from pageable memory returns once the data has been staged).
void queue_slice(const CudaSliceState& st, SliceLaunch l, const PixelToIndex* affines, size_t count,
                 void* device_out, void* stream) {
  const size_t bytes = count * sizeof(PixelToIndex);
  void* poses = cuda::malloc_async(bytes, stream, st.name + ": pose buffer");
  cuda::copy_to_device(poses, affines, bytes, stream, st.name + ": uploading poses");
  l.volume = st.volume.data();
  l.mask = static_cast<const uint8_t*>(st.mask.data());
  l.poses = static_cast<const PixelToIndex*>(poses);
  l.count = int64_t(count);
  l.out = device_out;
  l.stream = stream;
  slice_cuda_launch(l);
  cuda::free_async(poses, stream);
}

}  // namespace

std::shared_ptr<CudaSliceState> cuda_prepare(const Volume& volume, const std::vector<uint8_t>& mask,
                                             int device) {
  auto st = std::make_shared<CudaSliceState>(device);
  for (auto& s : st->streams) s = std::make_unique<cuda::Stream>();
  st->caller_done = std::make_unique<cuda::Event>();
  st->slicing_done = std::make_unique<cuda::Event>();
  const size_t bytes = volume.byte_size();
  // The volume keeps its pixel type on the GPU: an int16 CT costs 2 bytes per voxel there too.
  st->volume.reserve(bytes, st->name + ": the volume (" + std::to_string(bytes >> 20) + " MiB, " +
                                to_string(volume.pixel_type()) + ")");
  cuda::copy_to_device(st->volume.data(), volume.data(), bytes, st->streams[0]->get(),
                       st->name + ": uploading the volume");
  st->mask.reserve(mask.size(), st->name + ": the probe mask");
  cuda::copy_to_device(st->mask.data(), mask.data(), mask.size(), st->streams[0]->get(),
                       st->name + ": uploading the probe mask");
  st->streams[0]->synchronize(st->name + ": uploading the volume");
  return st;
}

void cuda_slice_into_device(CudaSliceState& st, SliceLaunch l,
                            const std::vector<PixelToIndex>& affines, void* device_out,
                            CudaStream stream) {
  st.enter();
  cuda::check_device_pointer(device_out, st.device, "out");
  if (!stream.slicer_stream) {
    // The caller's stream, the legacy default one (null) included: torch, CuPy and the caller's
    // own kernels are ordered with the slicing by the stream itself.
    queue_slice(st, l, affines.data(), affines.size(), device_out, stream.handle);
    return;
  }
  void* own = st.streams[0]->get();
  st.caller_done->record(stream.handle, st.name + ": ordering after the caller's stream");
  st.caller_done->make_wait(own, st.name + ": ordering after the caller's stream");
  queue_slice(st, l, affines.data(), affines.size(), device_out, own);
  st.slicing_done->record(own, st.name + ": ordering the caller's stream after the slicing");
  st.slicing_done->make_wait(stream.handle, st.name + ": ordering the caller's stream");
}

std::shared_ptr<void> cuda_slice_to_new_buffer(const std::shared_ptr<CudaSliceState>& state,
                                               SliceLaunch l,
                                               const std::vector<PixelToIndex>& affines,
                                               void** stream) {
  CudaSliceState& st = *state;
  st.enter();
  const size_t bytes = std::max<size_t>(affines.size() * image_bytes(l), 1);
  *stream = st.streams[0]->get();
  size_t free_bytes = 0, total = 0;
  cuda::memory_info(&free_bytes, &total);
  if (bytes > free_bytes)
    throw ResourceError(st.name + ": " + std::to_string(affines.size()) + " output images need " +
                        std::to_string(bytes >> 20) + " MiB of GPU memory, " +
                        std::to_string(free_bytes >> 20) + " MiB free");
  void* data = cuda::malloc_async(bytes, *stream,
                                  st.name + ": " + std::to_string(affines.size()) +
                                      " output images (" + std::to_string(bytes >> 20) + " MiB)");
  // Freed on the stream that wrote it, after everything queued there; the deleter holds the
  // state, so the stream outlives the buffer.
  std::shared_ptr<void> owner(data,
                              [state](void* p) { cuda::free_async(p, state->streams[0]->get()); });
  queue_slice(st, l, affines.data(), affines.size(), data, *stream);
  return owner;
}

void cuda_slice_to_host(CudaSliceState& st, SliceLaunch l, const std::vector<PixelToIndex>& affines,
                        void* host_out) {
  st.enter();
  const size_t ib = image_bytes(l), count = affines.size();
  // Page-locked output (a pinned torch tensor, cudaHostAlloc): each chunk's copy lands in the
  // caller's memory directly. Pageable output goes through our pinned staging buffers.
  const bool direct = cuda::is_page_locked(host_out, count * ib);
  // Chunks small enough for any batch size to stream through (GPU memory is never asked for the
  // whole output) and large enough to keep the GPU busy.
  size_t free_bytes = 0, total = 0;
  cuda::memory_info(&free_bytes, &total);
  const size_t budget = std::clamp<size_t>(free_bytes / 8, size_t(16) << 20, size_t(256) << 20);
  const size_t chunk = std::max<size_t>(1, std::min(count, budget / std::max<size_t>(ib, 1)));
  for (int s = 0; s < 2; ++s) {
    st.out[s].reserve(chunk * ib, st.name + ": output chunk");
    if (!direct) st.staging[s].reserve(chunk * ib, st.name + ": pinned staging buffer");
  }
  struct Pending {
    size_t first = 0, n = 0;
  } pending[2];
  // From the pinned staging buffer into the caller's memory on every CPU thread: one thread's
  // memcpy moves about 10 GB/s, a third of what the device → host copy delivers.
  auto drain = [&](int s) {
    if (!pending[s].n) return;
    st.streams[s]->synchronize(st.name + ": slicing");
    if (!direct)
      backend::parallel_memcpy(static_cast<char*>(host_out) + pending[s].first * ib,
                               st.staging[s].data(), pending[s].n * ib);
    pending[s].n = 0;
  };
  // Two streams alternate: while one chunk's images travel to the host (and are copied into the
  // caller's memory), the other chunk's kernel runs. Direct copies need no host wait until the
  // end: each stream orders its next kernel after its last copy out of the same chunk buffer.
  int s = 0;
  for (size_t first = 0; first < count; first += chunk, s ^= 1) {
    if (!direct) drain(s);
    const size_t n = std::min(chunk, count - first);
    void* stream = st.streams[s]->get();
    queue_slice(st, l, affines.data() + first, n, st.out[s].data(), stream);
    void* to = direct ? static_cast<char*>(host_out) + first * ib : st.staging[s].data();
    cuda::copy_to_host(to, st.out[s].data(), n * ib, stream,
                       st.name + ": copying images to the host");
    pending[s] = {first, n};
  }
  drain(s);
  drain(s ^ 1);
}

void cuda_synchronize(void* stream, int device) {
  cuda::use_device(device);
  cuda::synchronize(stream, "cuda:" + std::to_string(device) + ": slicing");
}

void cuda_copy_to_host(void* host_out, const void* device_data, size_t bytes, void* stream,
                       int device) {
  cuda::use_device(device);
  const std::string what = "cuda:" + std::to_string(device) + ": copying images to the host";
  cuda::copy_to_host(host_out, device_data, bytes, stream, what);
  cuda::synchronize(stream, what);
}

}  // namespace slice_impl
}  // namespace sonoslice
