#pragma once
/// @file Exact label images from surface meshes: each image plane cuts the meshes' triangles and
/// the cross-sections are filled, with no voxelisation at all (resolution independent).
#include <cstdint>
#include <memory>
#include <vector>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/surface/Mesh.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

/// A closed loop of a plane cut, in probe coordinates (x, y) mm of the image plane.
struct CutPolygon {
  std::vector<std::array<double, 2>> points;
  bool closed = true;  ///< false where the mesh is open and the loop ends at a hole
  /// Signed area (mm², positive counter-clockwise in (x, y)).
  double area() const;
};

/// Cuts `mesh` with the plane z = 0 of `pose` (probe → world) and assembles the cut segments
/// into polygons (consecutive triangles share the crossing point of their common edge, so the
/// loops of a closed mesh close exactly).
std::vector<CutPolygon> cut_polygons(const TriangleMesh& mesh, const Pose& pose);

/// Label images by exact plane cuts. Mesh k paints label labels[k] (default k + 1) where the
/// image plane cuts through its inside (even-odd rule over the cut polygons, pixel centres on a
/// boundary counted half-open as in voxelisation); later meshes paint over earlier ones; pixels
/// outside the probe shape and outside every mesh are 0. A bounding-volume hierarchy per mesh
/// keeps each pose to the triangles near its image.
///
/// CPU only: the work per image is a tree walk, a variable number of segments and a sort per
/// row, which maps poorly to a GPU's lockstep threads; voxelised label volumes slice on CUDA.
class SurfaceSlicer {
 public:
  SurfaceSlicer(std::vector<TriangleMesh> meshes, ProbeGeometry probe,
                std::vector<uint16_t> labels = {}, PixelType output_type = PixelType::UInt8);
  ~SurfaceSlicer();
  SurfaceSlicer(SurfaceSlicer&&) noexcept;

  int width() const { return probe_.image.width; }
  int height() const { return probe_.image.height; }
  const std::vector<uint8_t>& mask() const { return mask_; }
  PixelType output_type() const { return output_type_; }

  /// Slices `count` poses into `out`, a C-order (count, H, W) array of output_type().
  void slice(const Pose* poses, size_t count, void* out, size_t first_index = 0) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  ProbeGeometry probe_;
  std::vector<uint8_t> mask_;
  PixelType output_type_;
};

}  // namespace sonoslice
