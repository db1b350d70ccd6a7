// Host side of the CUDA compounding backend: the accumulators resident on the GPU and the
// buffers frames travel through. The kernels are CompoundDriverCUDA.cuh compiled by nvcc
// (CompoundCUDA.cu).
#include <string>

#include "../backend/CudaChecks.h"
#include "../backend/CudaRuntime.h"
#include "CompoundBackends.h"

namespace sonoslice {
namespace compound_impl {

struct CudaCompounding::State {
  int device = 0;
  std::string name;
  long process = 0;      // the process that made it: CUDA state does not survive fork()
  AccumulatorView grid;  // device pointers
  Mode mode = Mode::Mean;
  cuda::DeviceBuffer cells, stamp, samples, lines, spans;
  std::unique_ptr<cuda::Stream> stream;
};

CudaCompounding::CudaCompounding(int device, int nx, int ny, int nz, Mode mode)
    : state_(std::make_unique<State>()) {
  State& st = *state_;
  cuda::use_device(device);
  st.device = device;
  st.name = "cuda:" + std::to_string(device);
  st.process = cuda::current_process();
  st.mode = mode;
  st.stream = std::make_unique<cuda::Stream>();
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
  cuda::check_not_forked(st.process, st.name + " compounder");
  cuda::use_device(st.device);
  void* s = st.stream->get();
  const size_t sample_bytes = size_t(host.frames) * host.rows * host.width * pixel_size(host.type);
  const size_t line_bytes = size_t(host.frames) * host.rows * sizeof(RowLine);
  const size_t span_bytes = size_t(host.rows) * sizeof(RowSpans);
  // The previous batch's kernels read these buffers: wait before overwriting them.
  st.stream->synchronize(st.name + ": compounding");
  st.samples.reserve(sample_bytes, st.name + ": frame buffer");
  st.lines.reserve(line_bytes, st.name + ": row geometry");
  st.spans.reserve(span_bytes, st.name + ": clip spans");
  cuda::copy_to_device(st.samples.data(), host.samples, sample_bytes, s,
                       st.name + ": uploading frames");
  cuda::copy_to_device(st.lines.data(), host.lines, line_bytes, s,
                       st.name + ": uploading row geometry");
  cuda::copy_to_device(st.spans.data(), host.spans, span_bytes, s,
                       st.name + ": uploading clip spans");
  FrameBatch b = host;
  b.samples = st.samples.data();
  b.lines = static_cast<const RowLine*>(st.lines.data());
  b.spans = static_cast<const RowSpans*>(st.spans.data());
  compound_cuda_launch(st.grid, b, st.mode, linear, s);
}

void CudaCompounding::download(Accumulator* cells, int32_t* stamp) {
  State& st = *state_;
  cuda::check_not_forked(st.process, st.name + " compounder");
  cuda::use_device(st.device);
  const size_t voxels = size_t(st.grid.nx) * st.grid.ny * st.grid.nz;
  cuda::copy_to_host(cells, st.cells.data(), voxels * sizeof(Accumulator), st.stream->get(),
                     st.name + ": downloading the accumulators");
  if (stamp && st.grid.stamp)
    cuda::copy_to_host(stamp, st.stamp.data(), voxels * sizeof(int32_t), st.stream->get(),
                       st.name + ": downloading the stamps");
  st.stream->synchronize(st.name + ": downloading the accumulators");
}

}  // namespace compound_impl
}  // namespace sonoslice
