#pragma once
// Internal: turning accumulators into a volume (the combined value per voxel, holes filled). The
// per-voxel code every backend runs is FinishImpl.h; this is the host side.
#include <memory>
#include <vector>

#include "CompoundTypes.h"
#include "FinishImpl.h"
#include "sonoslice/compound/CompoundSettings.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

/// The hole-filling elements ready for the kernels: PLUS's kernels computed with PLUS's float
/// arithmetic. `elements[k].kernel` points into `kernels[k]` (host memory; the CUDA backend
/// uploads them and points its copies at the device ones).
struct FillSetup {
  std::vector<FillElement> elements;
  std::vector<std::vector<float>> kernels;
};
FillSetup setup_fill_elements(const std::vector<HoleFillingKernel>& kernels);

/// Writes every voxel of `out` (type `out_type`, x fastest): the compounded value where samples
/// arrived (rounded and saturated), the first hole-filling element that can fill the voxel
/// elsewhere (when `kernels` is not empty), 0 otherwise. Parallel over z, deterministic.
void finish_volume(const AccumulatorView& grid, Mode mode,
                   const std::vector<HoleFillingKernel>& kernels, PixelType out_type, void* out);

}  // namespace compound_impl
}  // namespace sonoslice
