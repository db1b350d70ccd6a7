#pragma once
/// @file Surface meshes: legacy .vtk (ASCII and binary POLYDATA, read by sonoslice), .vtp, .stl,
/// .obj, .ply (read by VTK). Polygons are triangulated and coincident points merged; coordinates
/// are world mm. Files are checked before VTK works on them: counts against the file's size,
/// point ids against the point count, finite coordinates.
#include <string>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/surface/Mesh.h"

namespace sonoslice {

/// Reads a mesh; `frame` says which world frame its coordinates are in (RAS meshes are turned
/// into LPS). FileError for a missing, unreadable, truncated or corrupt file (a count the file
/// cannot hold, a cell naming a point that does not exist), InputError for a non-finite
/// coordinate or a mesh without triangles. Attribute data (normals, scalars) is not read.
TriangleMesh read_mesh(const std::string& path, WorldFrame frame = WorldFrame::LPS);

/// Writes a mesh (format by extension, as read_mesh), atomically.
void write_mesh(const std::string& path, const TriangleMesh& mesh);

/// True when this build reads meshes (VTK was found).
bool built_with_vtk();

}  // namespace sonoslice
