#pragma once
/// @file Physical geometry of a voxel grid (docs/conventions.md §1).
#include <array>
#include <cstdint>
#include <string>

#include "sonoslice/geometry/Math.h"

namespace sonoslice {

/// A voxel grid in the world frame (LPS by default, as ITK defines it). Voxel index
/// c = (i, j, k), i fastest in memory, has its centre at origin + direction · diag(spacing) · c.
struct VolumeGrid {
  std::array<int64_t, 3> dims{{0, 0, 0}};  ///< voxels along i, j, k
  Vec3 spacing_mm{{1.0, 1.0, 1.0}};        ///< voxel size along i, j, k (mm)
  Vec3 origin_mm{{0.0, 0.0, 0.0}};         ///< world position of voxel (0,0,0)'s centre (mm)
  Mat3 direction = Mat3::identity();       ///< index axes as columns (unit vectors)

  int64_t voxel_count() const { return dims[0] * dims[1] * dims[2]; }

  /// Throws InputError naming `what` when dims/spacing/direction/origin are not usable:
  /// non-positive sizes or spacings, non-finite values, a singular direction matrix.
  void validate(const std::string& what) const;

  /// World position (mm) of the continuous index c.
  Vec3 index_to_world(const Vec3& c) const;

  /// The affine world → continuous index: c = world_to_index_linear() · p +
  /// world_to_index_offset().
  Mat3 world_to_index_linear() const;
  Vec3 world_to_index_offset() const;
  Vec3 world_to_index(const Vec3& p) const;
};

}  // namespace sonoslice
