#pragma once
/// @file Surface meshes through VTK: legacy .vtk (ASCII and binary POLYDATA), .vtp, .stl, .obj,
/// .ply. Polygons are triangulated and coincident points merged; coordinates are world mm.
#include <string>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/surface/Mesh.h"

namespace sonoslice {

/// Reads a mesh; `frame` says which world frame its coordinates are in (RAS meshes are turned
/// into LPS). FileError for a missing, unreadable or corrupt file, InputError for one without
/// triangles.
TriangleMesh read_mesh(const std::string& path, WorldFrame frame = WorldFrame::LPS);

/// Writes a mesh (format by extension, as read_mesh), atomically.
void write_mesh(const std::string& path, const TriangleMesh& mesh);

/// True when this build reads meshes (VTK was found).
bool built_with_vtk();

}  // namespace sonoslice
