#pragma once
// Internal: turning accumulators into a volume (the combined value per voxel, holes filled).
#include <vector>

#include "CompoundTypes.h"
#include "sonoslice/compound/Compounder.h"

namespace sonoslice {
namespace compound_impl {

/// Writes every voxel of `out` (type `out_type`, x fastest): the compounded value where samples
/// arrived (rounded and saturated), the first hole-filling element that can fill the voxel
/// elsewhere (when `kernels` is not empty), 0 otherwise. Parallel over z, deterministic.
void finish_volume(const AccumulatorView& grid, Mode mode,
                   const std::vector<HoleFillingKernel>& kernels, PixelType out_type, void* out);

}  // namespace compound_impl
}  // namespace sonoslice
