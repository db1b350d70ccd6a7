#pragma once
// Internal: PLUS-exact compounding (CompoundSettings::plus_exact), the Compounder's CPU path that
// reproduces PLUS's insertion arithmetic (PlusExactImpl.h; docs/compounding.md §4b).
#include <cstdint>

#include "CompoundTypes.h"
#include "PlusExactImpl.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

struct PlusExactBatch {
  const void* pixels = nullptr;  ///< count frames of height × width, x fastest
  PixelType type = PixelType::UInt8;
  int width = 0, height = 0;
  int64_t count = 0;
  /// One per frame: pixel (x, y) lands at continuous voxel index A·(x, y, 0) + a.
  const IndexMap* matrices = nullptr;
  plus_exact::PixelFilter filter;
  bool linear = true;
  Mode mode = Mode::Mean;
  PlusOptimization optimization = PlusOptimization::Full;
};

/// Whether PLUS-exact compounding takes frames of this type.
bool plus_exact_frame_type(PixelType type);

/// Inserts the batch into `g` (value: the voxel in the frames' type, weight: PLUS's buffer / 256).
void plus_exact_insert(const AccumulatorView& g, const PlusExactBatch& b);

}  // namespace compound_impl
}  // namespace sonoslice
