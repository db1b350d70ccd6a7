#pragma once
// Internal: a 2D frame's clip (FrameClip, sonoslice/compound/FrameClip.h) as the runs of pixels
// the kernels take.
#include <cstdint>
#include <vector>

#include "CompoundTypes.h"

namespace sonoslice {
namespace compound_impl {

/// The runs of a frame's mask rows (H×W, 1: inserted); InputError for a row with more than
/// kMaxSpans runs.
std::vector<RowSpans> spans_from_mask(const std::vector<uint8_t>& mask, int width, int height);

}  // namespace compound_impl
}  // namespace sonoslice
