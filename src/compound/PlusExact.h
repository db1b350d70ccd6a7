#pragma once
// Internal: PLUS-exact compounding (CompoundSettings::plus_exact), the Compounder's CPU path that
// reproduces PLUS's insertion arithmetic (PlusExactImpl.h; docs/compounding.md §4b).
#include <cstdint>

#include "CompoundTypes.h"
#include "PlusExactImpl.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

/// Pixel (x, y) of frame f lands at continuous voxel index m·(x, y, 0, 1).
struct PixelToIndex {
  double m[3][4];
};

struct PlusExactBatch {
  const void* pixels = nullptr;  ///< count frames of height × width, x fastest
  PixelType type = PixelType::UInt8;
  int width = 0, height = 0;
  int64_t count = 0;
  const PixelToIndex* matrices = nullptr;  ///< one per frame
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
