#include "sonoslice/surface/Mesh.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <unordered_map>

#include "sonoslice/core/Error.h"

namespace sonoslice {

std::array<Vec3, 2> TriangleMesh::bounds() const {
  if (vertices.empty()) throw InputError("mesh '" + name + "': no vertices");
  Vec3 lo = vertices.front(), hi = vertices.front();
  for (const Vec3& v : vertices)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], v[a]);
      hi[a] = std::max(hi[a], v[a]);
    }
  return {lo, hi};
}

void TriangleMesh::transform(const Mat4& m) {
  for (Vec3& v : vertices) v = m.transform_point(v);
}

void TriangleMesh::validate() const {
  if (triangles.empty()) throw InputError("mesh '" + name + "': no triangles");
  for (const Vec3& v : vertices)
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2]))
      throw InputError("mesh '" + name + "': a vertex is not finite");
  const int64_t n = int64_t(vertices.size());
  for (size_t t = 0; t < triangles.size(); ++t)
    for (int32_t i : triangles[t])
      if (i < 0 || i >= n)
        throw InputError("mesh '" + name + "': triangle " + std::to_string(t) + " uses vertex " +
                         std::to_string(i) + " of " + std::to_string(n));
}

std::string MeshTopology::describe() const {
  std::ostringstream s;
  if (closed()) {
    s << "closed";
  } else {
    s << boundary_edges << " boundary edge" << (boundary_edges == 1 ? "" : "s") << " (open)";
    if (nonmanifold_edges) s << ", " << nonmanifold_edges << " non-manifold edges";
  }
  return s.str();
}

MeshTopology mesh_topology(const TriangleMesh& mesh) {
  MeshTopology topo;
  std::unordered_map<uint64_t, int> uses;
  uses.reserve(mesh.triangles.size() * 2);
  for (const auto& t : mesh.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      ++topo.degenerate_triangles;
      continue;
    }
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = uint32_t(t[e]), b = uint32_t(t[(e + 1) % 3]);
      ++uses[(uint64_t(std::min(a, b)) << 32) | std::max(a, b)];
    }
  }
  topo.edges = int64_t(uses.size());
  for (const auto& kv : uses) {
    if (kv.second == 1) ++topo.boundary_edges;
    if (kv.second > 2) ++topo.nonmanifold_edges;
  }
  return topo;
}

}  // namespace sonoslice
