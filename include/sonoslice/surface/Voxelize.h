#pragma once
/// @file Surface meshes → one label volume.
#include <cstdint>
#include <vector>

#include "sonoslice/surface/Mesh.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// A grid (identity direction, isotropic `spacing_mm`) around the meshes' bounds plus `margin_mm`
/// on every side, laid out as fan-slicer does: the first voxel centre at floor(min) - margin and
/// ceil((ceil(max) - floor(min) + 2·margin) / spacing) voxels per axis.
VolumeGrid voxel_grid_around(const std::vector<TriangleMesh>& meshes, double spacing_mm,
                             double margin_mm);

/// Voxelises `meshes` into one label volume on `grid` (any geometry: oblique directions and
/// anisotropic spacings included). Mesh k gets label labels[k] (default k + 1); where meshes
/// overlap the later one wins. The result is uint8, or uint16 when a label exceeds 255.
///
/// A voxel is inside a closed mesh when its centre is (docs/conventions.md §1, no half-voxel
/// shift): rays along the grid's first axis through the voxel centres count crossings, with a
/// consistent tie-break (a symbolic perturbation) for rays through vertices or along edges, so
/// surfaces that pass exactly through voxel centres give half-open [entry, exit) runs and never
/// streaks. An open or non-manifold mesh is voxelised by a majority vote of rays along all three
/// axes, with one warning naming it.
Volume voxelize(const std::vector<TriangleMesh>& meshes, const VolumeGrid& grid,
                const std::vector<uint16_t>& labels = {});

}  // namespace sonoslice
