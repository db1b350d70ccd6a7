#pragma once
/// @file How the simulation dispatch layer (Simulator.cpp) reaches the simulation kernel
/// (SimulateImpl.h, driven by SimulateDriverCPU.h) in each of its builds: one entry point per CPU
/// instruction set (SimulateCPU.cpp, SimulateCPUAvx2.cpp), chosen by CpuIsa. The same wiring as
/// every kernel folder (SliceBackends.h, CompoundBackends.h; docs/architecture.md).
#include <cstddef>
#include <cstdint>

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

}  // namespace simulate_impl
}  // namespace sonoslice
