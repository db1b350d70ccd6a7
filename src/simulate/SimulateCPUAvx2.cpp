// The CPU backend of the simulation kernel for CPUs with AVX2 and FMA: the same
// SimulateDriverCPU.h, built with -mavx2 -mfma (fused multiply-adds throughout: the speckle's
// trilinear sums and polynomials are a third shorter). Chosen at run time (Simulator.cpp).
#define SONOSLICE_KERNEL_ISA avx2
#include "SimulateBackends.h"
#include "SimulateDriverCPU.h"

namespace sonoslice {
namespace simulate_impl {
void simulate_cpu_avx2(const ImageModel& base, const IndexMap* maps, size_t count, uint8_t* out,
                       size_t image_bytes) {
  simulate_images(base, maps, count, out, image_bytes);
}
}  // namespace simulate_impl
}  // namespace sonoslice
