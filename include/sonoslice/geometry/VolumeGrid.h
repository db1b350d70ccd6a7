#pragma once
/// @file Physical geometry of a voxel grid (docs/conventions.md §1).
#include <array>
#include <cstdint>
#include <string>

#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {

/// An affine map into a grid's continuous voxel index (docs/conventions.md §5), c = A·p + a,
/// from the coordinates p of a frame placed in the world: probe mm for slicing, simulation and
/// registration, a PLUS frame's pixels or a beam frame's probe mm for compounding. Plain arrays,
/// so kernels on every backend take it as it is. Built only by VolumeGrid::index_map.
struct IndexMap {
  double A[3][3];
  double a[3];

  /// c = A·(x, y, z) + a.
  SONOSLICE_HOST_DEVICE void apply(double x, double y, double z, double c[3]) const {
    for (int i = 0; i < 3; ++i) c[i] = A[i][0] * x + A[i][1] * y + A[i][2] * z + a[i];
  }
  Vec3 operator()(const Vec3& p) const {
    Vec3 c;
    apply(p[0], p[1], p[2], c.data());
    return c;
  }
  /// A·d: how far c moves when p moves by d.
  Vec3 direction(const Vec3& d) const {
    Vec3 c;
    for (int i = 0; i < 3; ++i) c[size_t(i)] = A[i][0] * d[0] + A[i][1] * d[1] + A[i][2] * d[2];
    return c;
  }
};

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

  /// The map from a frame's coordinates to this grid's continuous index: world_to_index ∘
  /// frame_to_world. The one place a frame-to-index affine is built.
  IndexMap index_map(const Mat4& frame_to_world) const;
};

}  // namespace sonoslice
