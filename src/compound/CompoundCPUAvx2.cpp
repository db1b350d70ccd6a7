// The CPU backend of the compounding kernels for CPUs with AVX2: the same CompoundDriverCPU.h
// built with -mavx2 -mfma (eight samples' voxels at a time, the eight corner sums of a linear
// splat in one register). Chosen at run time (Compounder.cpp); it gives the same bits as the
// generic build.
#define SONOSLICE_KERNEL_ISA avx2
#include "CompoundBackends.h"
#include "CompoundDriverCPU.h"
#include "FinishImpl.h"

namespace sonoslice {
namespace compound_impl {
void compound_cpu_avx2(const AccumulatorView& grid, const FrameBatch& batch, Mode mode, bool linear,
                       int axis, int lo, int hi, int slabs) {
  dispatch_compound_cpu(grid, batch, mode, linear, axis, lo, hi, slabs);
}
void finish_values_avx2(const FinishInput& in, PixelType type, int64_t begin, int64_t end,
                        void* out) {
  finished_values(in, type, begin, end, out);
}
}  // namespace compound_impl
}  // namespace sonoslice
