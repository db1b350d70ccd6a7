// The CPU backend of the simulation kernel for any x86-64 (or other) CPU: SimulateDriverCPU.h
// built with the default flags. SimulateCPUAvx2.cpp is the same source for AVX2 + FMA.
#include "SimulateBackends.h"
#include "SimulateDriverCPU.h"

namespace sonoslice {
namespace simulate_impl {
void simulate_cpu_generic(const ImageModel& base, const IndexMap* maps, size_t count, uint8_t* out,
                          size_t image_bytes) {
  simulate_images(base, maps, count, out, image_bytes);
}
}  // namespace simulate_impl
}  // namespace sonoslice
