// Host side of the CUDA compounding backend: the accumulators resident on the GPU and the
// buffers frames travel through. The kernels are CompoundDriverCUDA.cuh compiled by nvcc
// (CompoundCUDA.cu).
#include <algorithm>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "../backend/CudaChecks.h"
#include "../backend/CudaRuntime.h"
#include "../backend/ParallelFor.h"
#include "CompoundBackends.h"
#include "Finish.h"

namespace sonoslice {
namespace compound_impl {

struct CudaCompounding::State : cuda::Owner {
  explicit State(int device) : cuda::Owner(device) {}
  AccumulatorView grid;  // device pointers
  Mode mode = Mode::Mean;
  cuda::DeviceBuffer cells, stamp;
  // Batches alternate between two slots: while the GPU splats one, the host copies the next into
  // the other slot's page-locked staging buffer and the copy stream uploads it.
  struct Slot {
    cuda::DeviceBuffer samples, lines, spans;
    cuda::PinnedBuffer staging;         // samples | lines | spans, packed
    std::unique_ptr<cuda::Event> done;  // the slot's kernels have run (its buffers are free)
    bool used = false;
  } slots[2];
  int next_slot = 0;
  std::unique_ptr<cuda::Stream> stream;  // the kernels, in batch order (latest mode needs it)
  std::unique_ptr<cuda::Stream> copies;  // the uploads
  std::unique_ptr<cuda::Event> uploaded;
  cuda::PinnedBuffer download_staging[2];  // volumes and accumulators on their way to the host
};

CudaCompounding::CudaCompounding(int device, int nx, int ny, int nz, Mode mode)
    : state_(std::make_unique<State>(device)) {
  State& st = *state_;
  st.mode = mode;
  st.stream = std::make_unique<cuda::Stream>();
  st.copies = std::make_unique<cuda::Stream>();
  st.uploaded = std::make_unique<cuda::Event>();
  for (auto& slot : st.slots) slot.done = std::make_unique<cuda::Event>();
  const size_t voxels = size_t(nx) * size_t(ny) * size_t(nz);
  st.cells.reserve(voxels * sizeof(Accumulator),
                   st.name + ": the accumulators (" + std::to_string((voxels * 8) >> 20) + " MiB)");
  if (mode == Mode::Latest)
    st.stamp.reserve(voxels * sizeof(int32_t), st.name + ": the latest-frame stamps");
  st.grid.nx = nx;
  st.grid.ny = ny;
  st.grid.nz = nz;
  st.grid.cells = static_cast<Accumulator*>(st.cells.data());
  st.grid.stamp = mode == Mode::Latest ? static_cast<int32_t*>(st.stamp.data()) : nullptr;
  compound_cuda_clear(st.grid, mode, st.stream->get());
}

CudaCompounding::~CudaCompounding() = default;

void CudaCompounding::add(const FrameBatch& host, bool linear) {
  State& st = *state_;
  st.enter("compounder");
  void* s = st.stream->get();
  const size_t sample_bytes = size_t(host.frames) * host.rows * host.width * pixel_size(host.type);
  const size_t line_bytes = size_t(host.frames) * host.rows * sizeof(RowLine);
  const size_t span_bytes = size_t(host.rows) * sizeof(RowSpans);
  State::Slot& slot = st.slots[st.next_slot];
  st.next_slot ^= 1;
  // The batch before the previous one used this slot: wait for its kernels (the other slot's
  // batch may still be running: that is the overlap).
  if (slot.used) slot.done->synchronize(st.name + ": compounding");
  slot.samples.reserve(sample_bytes, st.name + ": frame buffer");
  slot.lines.reserve(line_bytes, st.name + ": row geometry");
  slot.spans.reserve(span_bytes, st.name + ": clip spans");
  slot.staging.reserve(sample_bytes + line_bytes + span_bytes, st.name + ": pinned frame buffer");
  auto* staged = static_cast<char*>(slot.staging.data());
  backend::parallel_memcpy(staged, host.samples, sample_bytes);  // the frames, on every thread
  std::memcpy(staged + sample_bytes, host.lines, line_bytes);
  std::memcpy(staged + sample_bytes + line_bytes, host.spans, span_bytes);
  void* c = st.copies->get();
  cuda::copy_to_device(slot.samples.data(), staged, sample_bytes, c,
                       st.name + ": uploading frames");
  cuda::copy_to_device(slot.lines.data(), staged + sample_bytes, line_bytes, c,
                       st.name + ": uploading row geometry");
  cuda::copy_to_device(slot.spans.data(), staged + sample_bytes + line_bytes, span_bytes, c,
                       st.name + ": uploading clip spans");
  st.uploaded->record(c, st.name + ": uploading frames");
  st.uploaded->make_wait(s, st.name + ": uploading frames");
  FrameBatch b = host;
  b.samples = slot.samples.data();
  b.lines = static_cast<const RowLine*>(slot.lines.data());
  b.spans = static_cast<const RowSpans*>(slot.spans.data());
  compound_cuda_launch(st.grid, b, st.mode, linear, s);
  slot.done->record(s, st.name + ": compounding");
  slot.used = true;
}

void CudaCompounding::download(Accumulator* cells, int32_t* stamp) {
  State& st = *state_;
  st.enter("compounder");
  const size_t voxels = size_t(st.grid.nx) * st.grid.ny * st.grid.nz;
  cuda::download(cells, st.cells.data(), voxels * sizeof(Accumulator), st.stream->get(),
                 st.download_staging, st.name + ": downloading the accumulators");
  if (stamp && st.grid.stamp)
    cuda::download(stamp, st.stamp.data(), voxels * sizeof(int32_t), st.stream->get(),
                   st.download_staging, st.name + ": downloading the stamps");
}

void CudaCompounding::finish(const std::vector<HoleFillingKernel>& kernels, PixelType type,
                             void* host_out) {
  State& st = *state_;
  st.enter("compounder");
  void* s = st.stream->get();
  // The elements and their kernels (PLUS's float weights, set up on the host) on the GPU.
  FillSetup setup = setup_fill_elements(kernels);
  std::vector<std::unique_ptr<cuda::DeviceBuffer>> kernel_buffers;
  for (size_t k = 0; k < setup.elements.size(); ++k) {
    if (setup.kernels[k].empty()) continue;
    const size_t bytes = setup.kernels[k].size() * sizeof(float);
    kernel_buffers.push_back(std::make_unique<cuda::DeviceBuffer>());
    kernel_buffers.back()->reserve(bytes, st.name + ": hole-filling kernel");
    cuda::copy_to_device(kernel_buffers.back()->data(), setup.kernels[k].data(), bytes, s,
                         st.name + ": uploading a hole-filling kernel");
    setup.elements[k].kernel = static_cast<const float*>(kernel_buffers.back()->data());
  }
  cuda::DeviceBuffer elements, out;
  const size_t element_bytes = std::max<size_t>(1, setup.elements.size() * sizeof(FillElement));
  elements.reserve(element_bytes, st.name + ": hole-filling elements");
  if (!setup.elements.empty())
    cuda::copy_to_device(elements.data(), setup.elements.data(),
                         setup.elements.size() * sizeof(FillElement), s,
                         st.name + ": uploading the hole-filling elements");
  const size_t voxels = size_t(st.grid.nx) * st.grid.ny * st.grid.nz;
  const size_t bytes = voxels * pixel_size(type);
  out.reserve(std::max<size_t>(bytes, 1),
              st.name + ": the finished volume (" + std::to_string(bytes >> 20) + " MiB)");
  FinishInput in;
  in.g = st.grid;
  in.mode = st.mode;
  in.elements = static_cast<const FillElement*>(elements.data());
  in.element_count = int(setup.elements.size());
  compound_cuda_finish(in, type, out.data(), s);
  // download() waits: the uploads above read host memory that goes when this returns, and the
  // buffers go too.
  cuda::download(host_out, out.data(), bytes, s, st.download_staging,
                 st.name + ": downloading the volume");
}

}  // namespace compound_impl
}  // namespace sonoslice
