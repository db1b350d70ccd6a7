#pragma once
// Internal: the memory a reconstruction needs (and the advice when it does not fit), the checks
// of the poses frames are placed with, and the size and dimension texts of their messages.
#include <array>
#include <cstdint>
#include <string>

#include "sonoslice/compound/CompoundSettings.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

/// "1.5 GiB" from 1 GiB up, "12 MiB" below.
std::string format_bytes(uint64_t bytes);
/// "512x512x300".
std::string format_dims(const std::array<int64_t, 3>& d);

/// Accumulator bytes per voxel: value and weight, plus the frame stamp in latest mode.
uint64_t accumulator_bytes_per_voxel(const CompoundSettings& s);

/// ResourceError, before anything is allocated, when the accumulators plus an `output_type`
/// result on `grid` need more than `max_memory_bytes` (0: the memory available), naming the size
/// and a spacing that fits.
void check_fits_in_memory(const VolumeGrid& grid, const CompoundSettings& settings,
                          PixelType output_type, uint64_t max_memory_bytes);

/// InputError naming `what` for a pose with a non-finite element, a last row other than 0 0 0 1,
/// or axes that collapse the frame: the first `axes` columns (2: an image's pixel x and y; 3: a
/// probe's x, y and z) zero or linearly dependent.
void check_matrix(const Mat4& m, const std::string& what, int axes = 3);

}  // namespace compound_impl
}  // namespace sonoslice
