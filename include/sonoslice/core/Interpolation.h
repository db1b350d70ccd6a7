#pragma once
/// @file How a value is read between voxels: the one interpolation enum of the library, shared by
/// slicing (sampling a volume, docs/conventions.md §5) and compounding (splatting a sample into a
/// grid, docs/conventions.md §7).
#include <string>

namespace sonoslice {

enum class Interpolation {
  Linear,  ///< trilinear: the 8 voxels around the point, weighted by distance
  Nearest  ///< the voxel floor(c + 0.5)
};

/// "linear" or "nearest".
const char* to_string(Interpolation interpolation);
/// "linear"/"trilinear" or "nearest"/"nearest_neighbor"/"nn", any case (PLUS spells them in
/// capitals). InputError naming `what` and the accepted names otherwise.
Interpolation parse_interpolation(const std::string& name,
                                  const std::string& what = "interpolation");

}  // namespace sonoslice
