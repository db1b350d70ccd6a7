// Mesh voxelisation by scanline ray parity in the grid's index space.
//
// Every triangle is projected along the ray axis onto the plane of ray origins (integer grid
// coordinates); each ray whose origin falls inside the projection records where it crosses the
// triangle. Sorted crossings give [entry, exit) runs of voxel centres. Rays through an edge or a
// vertex of the projection are decided by a symbolic perturbation of the ray origin (shifted by
// (ε, ε²)), evaluated with each edge in a canonical vertex order: two triangles sharing an edge
// then take complementary decisions, so every crossing of the surface is counted exactly once.
// (Only the decision needs to be exact; where a ray crosses is interpolated.)
#include "sonoslice/surface/Voxelize.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "../backend/ParallelFor.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

struct P2 {
  double u, v;
};

// Sign of orient2d(a, b, q) with q perturbed by (ε, ε²): the exact value when non-zero, else
// the sign of the perturbation's effect (a "top-left" rule, the same for every triangle).
inline int edge_sign(const P2& a, const P2& b, const P2& q) {
  const double e = (b.u - a.u) * (q.v - a.v) - (b.v - a.v) * (q.u - a.u);
  if (e > 0) return 1;
  if (e < 0) return -1;
  // d/dε of orient2d(a, b, q + ε(1, ε)) = -(b.v - a.v) + ε (b.u - a.u)
  if (b.v != a.v) return a.v > b.v ? 1 : -1;
  if (b.u != a.u) return b.u > a.u ? 1 : -1;
  return 0;  // a degenerate edge: its triangle is skipped
}

struct Crossing {
  int32_t ray;  // index along the second axis within the slice
  double t;     // continuous index along the ray axis
};

// The parity runs of one mesh along `axis`, delivered row by row to `fill(k, j, i0, i1)` for
// voxel index ranges [i0, i1) along the axis (k: third axis, j: second axis).
template <typename Fill>
void cast_rays(const std::vector<Vec3>& c, const std::vector<std::array<int32_t, 3>>& tris,
               int axis, const std::array<int64_t, 3>& dims, const Fill& fill) {
  const int a = axis, b = (axis + 1) % 3, k_axis = (axis + 2) % 3;
  const int64_t na = dims[size_t(a)], nb = dims[size_t(b)], nk = dims[size_t(k_axis)];
  // Bucket triangles by the slices (integer k) their projection spans.
  std::vector<std::vector<int32_t>> buckets(static_cast<size_t>(nk));
  for (size_t t = 0; t < tris.size(); ++t) {
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (int32_t vi : tris[t]) {
      lo = std::min(lo, c[size_t(vi)][size_t(k_axis)]);
      hi = std::max(hi, c[size_t(vi)][size_t(k_axis)]);
    }
    const int64_t k0 = std::max<int64_t>(0, int64_t(std::ceil(lo)));
    const int64_t k1 = std::min<int64_t>(nk - 1, int64_t(std::floor(hi)));
    for (int64_t k = k0; k <= k1; ++k) buckets[size_t(k)].push_back(int32_t(t));
  }
  backend::parallel_for(nk, [&](int64_t k) {
    const std::vector<int32_t>& bucket = buckets[size_t(k)];
    if (bucket.empty()) return;
    std::vector<Crossing> hits;
    for (int32_t t : bucket) {
      const auto& tri = tris[size_t(t)];
      const P2 p[3] = {{c[size_t(tri[0])][size_t(b)], c[size_t(tri[0])][size_t(k_axis)]},
                       {c[size_t(tri[1])][size_t(b)], c[size_t(tri[1])][size_t(k_axis)]},
                       {c[size_t(tri[2])][size_t(b)], c[size_t(tri[2])][size_t(k_axis)]}};
      const double area =
          (p[1].u - p[0].u) * (p[2].v - p[0].v) - (p[1].v - p[0].v) * (p[2].u - p[0].u);
      if (area == 0) continue;  // parallel to the rays: its neighbours carry the crossing
      const int orientation = area > 0 ? 1 : -1;
      const double ulo = std::min({p[0].u, p[1].u, p[2].u}),
                   uhi = std::max({p[0].u, p[1].u, p[2].u});
      const int64_t j0 = std::max<int64_t>(0, int64_t(std::ceil(ulo)));
      const int64_t j1 = std::min<int64_t>(nb - 1, int64_t(std::floor(uhi)));
      for (int64_t j = j0; j <= j1; ++j) {
        const P2 q{double(j), double(k)};
        bool inside = true;
        double w[3];
        for (int e = 0; e < 3 && inside; ++e) {
          // Edge opposite vertex e, taken in a canonical (lexicographic) order so that the two
          // triangles sharing it compute the same number, duplicated vertices or not.
          const P2* pa = &p[(e + 1) % 3];
          const P2* pb = &p[(e + 2) % 3];
          int flip = 1;
          if (pa->u > pb->u || (pa->u == pb->u && pa->v > pb->v)) {
            std::swap(pa, pb);
            flip = -1;
          }
          const int s = edge_sign(*pa, *pb, q) * flip;
          inside = s * orientation > 0;
          w[e] = std::fabs((pb->u - pa->u) * (q.v - pa->v) - (pb->v - pa->v) * (q.u - pa->u));
        }
        if (!inside) continue;
        const double sum = w[0] + w[1] + w[2];
        const double ta = c[size_t(tri[0])][size_t(a)], tb = c[size_t(tri[1])][size_t(a)],
                     tc = c[size_t(tri[2])][size_t(a)];
        double t_hit = sum > 0 ? (w[0] * ta + w[1] * tb + w[2] * tc) / sum : ta;
        // Rounding must not carry the crossing outside the triangle: a face at x = 12 exactly
        // crosses at 12, not at 12 + 1 ulp (which would add a voxel).
        t_hit = std::min(std::max(t_hit, std::min({ta, tb, tc})), std::max({ta, tb, tc}));
        hits.push_back({int32_t(j), t_hit});
      }
    }
    std::sort(hits.begin(), hits.end(), [](const Crossing& x, const Crossing& y) {
      return x.ray != y.ray ? x.ray < y.ray : x.t < y.t;
    });
    for (size_t s = 0; s < hits.size();) {
      size_t e = s;
      while (e < hits.size() && hits[e].ray == hits[s].ray) ++e;
      // Voxel i is inside when an odd number of crossings lie at or before it: [entry, exit).
      for (size_t m = s; m + 1 < e; m += 2) {
        const int64_t i0 = std::max<int64_t>(0, int64_t(std::ceil(hits[m].t)));
        const int64_t i1 = std::min<int64_t>(na, int64_t(std::ceil(hits[m + 1].t)));
        if (i1 > i0) fill(k, int64_t(hits[s].ray), i0, i1);
      }
      s = e;
    }
  });
}

template <typename T>
void paint_mesh(const TriangleMesh& mesh, const std::vector<Vec3>& c, const VolumeGrid& grid,
                T label, T* labels) {
  const auto& d = grid.dims;
  const int64_t sy = d[0], sz = d[0] * d[1];
  const MeshTopology topo = mesh_topology(mesh);
  if (topo.closed()) {
    // Rays along i: runs are contiguous in memory.
    cast_rays(c, mesh.triangles, 0, d, [&](int64_t k, int64_t j, int64_t i0, int64_t i1) {
      std::fill(labels + k * sz + j * sy + i0, labels + k * sz + j * sy + i1, label);
    });
    return;
  }
  warn("mesh '" + mesh.name + "' is not closed (" + topo.describe() +
       "): voxelised best-effort, by a majority of rays along the three axes");
  std::vector<uint8_t> votes(size_t(grid.voxel_count()), 0);
  const int64_t stride[3] = {1, sy, sz};
  for (int axis = 0; axis < 3; ++axis) {
    const int b = (axis + 1) % 3, k_axis = (axis + 2) % 3;
    cast_rays(c, mesh.triangles, axis, d, [&](int64_t k, int64_t j, int64_t i0, int64_t i1) {
      uint8_t* base = votes.data() + k * stride[k_axis] + j * stride[b];
      for (int64_t i = i0; i < i1; ++i) base[i * stride[axis]] += 1;
    });
  }
  for (size_t i = 0; i < votes.size(); ++i)
    if (votes[i] >= 2) labels[i] = label;
}

}  // namespace

VolumeGrid voxel_grid_around(const std::vector<TriangleMesh>& meshes, double spacing_mm,
                             double margin_mm) {
  if (!(spacing_mm > 0) || !std::isfinite(spacing_mm))
    throw ParameterError("spacing_mm", std::to_string(spacing_mm) + ": must be > 0 mm");
  if (!(margin_mm >= 0) || !std::isfinite(margin_mm))
    throw ParameterError("margin_mm", std::to_string(margin_mm) + ": must be >= 0 mm");
  if (meshes.empty()) throw InputError("voxelize: no meshes");
  Vec3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  for (const TriangleMesh& m : meshes) {
    const auto b = m.bounds();
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], b[0][a]);
      hi[a] = std::max(hi[a], b[1][a]);
    }
  }
  VolumeGrid g;
  for (int a = 0; a < 3; ++a) {
    const double first = std::floor(lo[a]) - margin_mm;
    const double last = std::ceil(hi[a]) + margin_mm;
    g.origin_mm[a] = first;
    g.spacing_mm[a] = spacing_mm;
    g.dims[a] = std::max<int64_t>(1, int64_t(std::ceil((last - first) / spacing_mm - 1e-9)));
  }
  const double voxels = double(g.dims[0]) * double(g.dims[1]) * double(g.dims[2]);
  if (voxels > 8e9) {
    std::ostringstream s;
    s << "voxelize: a " << g.dims[0] << "x" << g.dims[1] << "x" << g.dims[2] << " grid at "
      << spacing_mm << " mm is too large; use a coarser spacing";
    throw ResourceError(s.str());
  }
  return g;
}

Volume voxelize(const std::vector<TriangleMesh>& meshes, const VolumeGrid& grid,
                const std::vector<uint16_t>& labels) {
  grid.validate("voxel grid");
  if (!labels.empty() && labels.size() != meshes.size())
    throw InputError("voxelize: " + std::to_string(labels.size()) + " labels for " +
                     std::to_string(meshes.size()) + " meshes");
  uint16_t max_label = 0;
  for (size_t k = 0; k < meshes.size(); ++k)
    max_label = std::max<uint16_t>(max_label, labels.empty() ? uint16_t(k + 1) : labels[k]);
  const PixelType type = max_label > 255 ? PixelType::UInt16 : PixelType::UInt8;
  Volume out = Volume::allocate(type, grid);
  const Mat3 w2i = grid.world_to_index_linear();
  for (size_t k = 0; k < meshes.size(); ++k) {
    const TriangleMesh& mesh = meshes[k];
    mesh.validate();
    // Into index space: voxel centres at integer coordinates, rays along the first index axis.
    std::vector<Vec3> c(mesh.vertices.size());
    for (size_t v = 0; v < c.size(); ++v) c[v] = w2i * (mesh.vertices[v] - grid.origin_mm);
    const uint16_t label = labels.empty() ? uint16_t(k + 1) : labels[k];
    if (type == PixelType::UInt8)
      paint_mesh<uint8_t>(mesh, c, grid, uint8_t(label), out.data_as<uint8_t>());
    else
      paint_mesh<uint16_t>(mesh, c, grid, label, out.data_as<uint16_t>());
  }
  return out;
}

}  // namespace sonoslice
