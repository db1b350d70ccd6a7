#pragma once
/// @file Triangle meshes of segmented anatomy (liver, vessels, tumours), in world millimetres in
/// the same frame as volumes (docs/conventions.md §1).
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "sonoslice/geometry/Math.h"

namespace sonoslice {

struct TriangleMesh {
  std::string name;                               ///< for messages (usually the file name)
  std::vector<Vec3> vertices;                     ///< mm
  std::vector<std::array<int32_t, 3>> triangles;  ///< vertex indices

  /// Axis-aligned bounds {min, max} (mm); InputError for an empty mesh.
  std::array<Vec3, 2> bounds() const;
  /// Applies a 4×4 transform to every vertex.
  void transform(const Mat4& m);
  /// Throws InputError naming the mesh for out-of-range indices or non-finite vertices.
  void validate() const;
};

/// How closed a mesh is: every edge shared by exactly two triangles (closed, manifold), some by
/// one (boundary: an open mesh), some by three or more (non-manifold).
struct MeshTopology {
  int64_t edges = 0;
  int64_t boundary_edges = 0;
  int64_t nonmanifold_edges = 0;
  int64_t degenerate_triangles = 0;  ///< triangles with a repeated vertex
  bool closed() const { return boundary_edges == 0 && nonmanifold_edges == 0; }
  std::string describe() const;
};
MeshTopology mesh_topology(const TriangleMesh& mesh);

}  // namespace sonoslice
