// The CPU backend of the compounding kernels for any x86-64 (or other) CPU: CompoundDriverCPU.h
// with the thread pool's parallel_for and scalar code.
#include "CompoundBackends.h"
#include "CompoundDriverCPU.h"

namespace sonoslice {
namespace compound_impl {
void compound_cpu_generic(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                          bool linear, int axis, int lo, int hi, int slabs) {
  dispatch_compound_cpu(grid, batch, mode, linear, axis, lo, hi, slabs);
}
}  // namespace compound_impl
}  // namespace sonoslice
