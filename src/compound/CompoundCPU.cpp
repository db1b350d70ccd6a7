// The CPU backend of the compounding kernels for any x86-64 (or other) CPU: CompoundDriverCPU.h
// with the thread pool's parallel_for and scalar code.
#include "CompoundBackends.h"
#include "CompoundDriverCPU.h"
#include "FinishImpl.h"

namespace sonoslice {
namespace compound_impl {
void compound_cpu_generic(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                          bool linear, int axis, int lo, int hi, int slabs) {
  dispatch_compound_cpu(grid, batch, mode, linear, axis, lo, hi, slabs);
}
void finish_values_generic(const FinishInput& in, PixelType type, int64_t begin, int64_t end,
                           void* out) {
  finished_values(in, type, begin, end, out);
}
}  // namespace compound_impl
}  // namespace sonoslice
