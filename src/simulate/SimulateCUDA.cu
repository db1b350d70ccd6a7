// The CUDA backend of the simulation kernel: SimulateDriverCUDA.cuh (over the shared
// SimulateImpl.h) compiled by nvcc with the CUDA parallel_for. Buffers and streams are host code
// (SimulatorCUDA.cpp).
#define SONOSLICE_KERNEL_ISA cuda
#include "SimulateBackends.h"
#include "SimulateDriverCUDA.cuh"

namespace sonoslice {
namespace simulate_impl {
void simulate_cuda_launch(const CudaBatch& batch, void* stream) {
  simulate_batch(batch, stream);
}
}  // namespace simulate_impl
}  // namespace sonoslice
