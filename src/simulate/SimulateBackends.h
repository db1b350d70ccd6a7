#pragma once
/// @file How the simulation dispatch layer (Simulator.cpp) reaches the simulation kernel
/// (SimulateImpl.h, driven by SimulateDriverCPU.h) in each of its builds: one entry point per CPU
/// instruction set (SimulateCPU.cpp, SimulateCPUAvx2.cpp), chosen by CpuIsa, and, in CUDA
/// builds, the kernel stages (SimulateCUDA.cu) with the host code that drives them
/// (SimulatorCUDA.cpp). The same wiring as every kernel folder (SliceBackends.h,
/// CompoundBackends.h; docs/architecture.md).
#include <cstddef>
#include <cstdint>
#include <memory>

#include "SimulateImpl.h"
#include "sonoslice/backend/Device.h"

namespace sonoslice {
namespace simulate_impl {

/// `count` images, pose n's probe → index map maps[n], into out (image n at n·image_bytes).
void simulate_cpu_generic(const ImageModel& base, const IndexMap* maps, size_t count, uint8_t* out,
                          size_t image_bytes);
void simulate_cpu_avx2(const ImageModel& base, const IndexMap* maps, size_t count, uint8_t* out,
                       size_t image_bytes);
inline void simulate_cpu(CpuIsa isa, const ImageModel& base, const IndexMap* maps, size_t count,
                         uint8_t* out, size_t image_bytes) {
  switch (isa) {
    case CpuIsa::Avx2:
      return simulate_cpu_avx2(base, maps, count, out, image_bytes);
    case CpuIsa::Generic:
      return simulate_cpu_generic(base, maps, count, out, image_bytes);
  }
}

#ifdef SONOSLICE_HAVE_CUDA
/// A batch of images on the GPU: every pointer is device memory; image n's part of each buffer
/// starts at n times its per-image size.
struct CudaBatch {
  const ImageModel* models = nullptr;  // per image: the base model with its pose set
  int64_t count = 0;
  int beams = 0, samples = 0, knots_per_image = 0;
  int64_t pixels = 0;
  size_t image_bytes = 0;
  bool tgc_auto = true;
  float* echo = nullptr;               // 2 × beams × samples (complex)
  float* echo_filtered = nullptr;      // 2 × beams × samples
  float* specular = nullptr;           // beams × samples
  float* specular_filtered = nullptr;  // beams × samples
  float* loss = nullptr;               // beams × samples
  float* tmp = nullptr;                // beams × 2 × samples (the axial filter's copy)
  float* select = nullptr;             // knots × beams (the medians' working copies)
  float* knots = nullptr;              // knots
  float* level = nullptr;              // samples
  uint8_t* out = nullptr;              // image_bytes
  SONOSLICE_HOST_DEVICE int64_t beam_samples() const { return int64_t(beams) * samples; }
};
/// Every stage for the batch, on `stream` (SimulateCUDA.cu).
void simulate_cuda_launch(const CudaBatch& batch, void* stream);

struct Model;
struct CudaSimulateState;
/// Uploads the model's volume and tables to cuda:`device`, once.
std::shared_ptr<CudaSimulateState> cuda_prepare(const Model& model, int device);
/// `count` images, pose n's map maps[n], into host memory `out` (image n at n·image_bytes), in
/// batches that fit the GPU's memory.
void cuda_simulate(CudaSimulateState& state, const IndexMap* maps, size_t count, uint8_t* out,
                   size_t image_bytes);
#endif  // SONOSLICE_HAVE_CUDA

}  // namespace simulate_impl
}  // namespace sonoslice
