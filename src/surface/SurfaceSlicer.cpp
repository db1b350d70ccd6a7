// Exact plane cuts of triangle meshes, filled into label images.
//
// Vertices are classified by their side of the image plane, a vertex exactly on the plane
// counting as the positive side (a symbolic perturbation): every triangle then has either no
// crossing or one segment, and neighbours agree on the crossing point of their shared edge
// (computed from the edge's two vertices in a fixed order). Filling the segments row by row
// with the even-odd rule is filling the closed cut polygons, without having to build them.
#include "sonoslice/surface/SurfaceSlicer.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <unordered_map>

#include "../backend/ParallelFor.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

// ---- the image plane of one pose
// -----------------------------------------------------------------
struct Plane {
  Vec3 origin, x_axis, y_axis, normal;
  double inv_gram[2][2];  // (x, y) of a point on the plane = inv_gram · (x̂·d, ŷ·d), d = p - origin

  explicit Plane(const Pose& pose) {
    origin = pose.column3(3);
    x_axis = pose.column3(0);
    y_axis = pose.column3(1);
    normal = cross(x_axis, y_axis);
    const double a = dot(x_axis, x_axis), b = dot(x_axis, y_axis), c = dot(y_axis, y_axis);
    const double det = a * c - b * b;
    inv_gram[0][0] = c / det;
    inv_gram[0][1] = -b / det;
    inv_gram[1][0] = -b / det;
    inv_gram[1][1] = a / det;
  }
  double side(const Vec3& p) const { return dot(normal, p - origin); }
  std::array<double, 2> in_plane(const Vec3& p) const {
    const Vec3 d = p - origin;
    const double px = dot(x_axis, d), py = dot(y_axis, d);
    return {inv_gram[0][0] * px + inv_gram[0][1] * py, inv_gram[1][0] * px + inv_gram[1][1] * py};
  }
};

// The segment a triangle contributes, as the two edges it crosses (vertex pairs) and points.
struct Segment {
  int32_t edge[2][2];
  Vec3 p[2];
};

// Classification: true = positive side (a vertex on the plane counts as positive).
inline bool positive(double s) {
  return s >= 0;
}

inline bool cut_triangle(const std::vector<Vec3>& v, const std::array<int32_t, 3>& tri,
                         const double s[3], Segment* seg) {
  const bool pos[3] = {positive(s[0]), positive(s[1]), positive(s[2])};
  if (pos[0] == pos[1] && pos[1] == pos[2]) return false;
  int n = 0;
  for (int e = 0; e < 3; ++e) {
    const int i = e, j = (e + 1) % 3;
    if (pos[i] == pos[j]) continue;
    int32_t a = tri[size_t(i)], b = tri[size_t(j)];
    double sa = s[i], sb = s[j];
    if (a > b) {
      std::swap(a, b);
      std::swap(sa, sb);
    }
    const double t = sa / (sa - sb);  // sa and sb differ in sign (or sa = 0)
    const Vec3& va = v[size_t(a)];
    const Vec3& vb = v[size_t(b)];
    seg->edge[n][0] = a;
    seg->edge[n][1] = b;
    seg->p[n] = {va[0] + t * (vb[0] - va[0]), va[1] + t * (vb[1] - va[1]),
                 va[2] + t * (vb[2] - va[2])};
    ++n;
  }
  return n == 2;
}

// ---- bounding-volume hierarchy over one mesh's triangles --------------------------------------
struct Node {
  Vec3 lo, hi;
  int32_t first,
      count;  // leaf: triangles order[first, first + count); inner: children first, first + 1
  bool leaf() const { return count > 0; }
};

class Bvh {
 public:
  void build(const TriangleMesh& mesh) {
    const size_t n = mesh.triangles.size();
    order_.resize(n);
    std::iota(order_.begin(), order_.end(), 0);
    centre_.resize(n);
    tri_lo_.resize(n);
    tri_hi_.resize(n);
    for (size_t t = 0; t < n; ++t) {
      Vec3 lo = mesh.vertices[size_t(mesh.triangles[t][0])], hi = lo;
      for (int32_t vi : mesh.triangles[t])
        for (int a = 0; a < 3; ++a) {
          lo[a] = std::min(lo[a], mesh.vertices[size_t(vi)][a]);
          hi[a] = std::max(hi[a], mesh.vertices[size_t(vi)][a]);
        }
      tri_lo_[t] = lo;
      tri_hi_[t] = hi;
      centre_[t] = 0.5 * (lo + hi);
    }
    nodes_.clear();
    nodes_.reserve(2 * n / kLeaf + 2);
    nodes_.push_back({});
    split(0, 0, int32_t(n));
  }

  // visit(triangle) for the triangles of leaves whose boxes pass `keep(lo, hi)`.
  template <typename Keep, typename Visit>
  void query(const Keep& keep, const Visit& visit) const {
    if (nodes_.empty()) return;
    int32_t stack[128];
    int top = 0;
    stack[top++] = 0;
    while (top) {
      const Node& node = nodes_[size_t(stack[--top])];
      if (!keep(node.lo, node.hi)) continue;
      if (node.leaf()) {
        for (int32_t i = node.first; i < node.first + node.count; ++i) visit(order_[size_t(i)]);
      } else if (top + 2 <= 128) {
        stack[top++] = node.first;
        stack[top++] = node.first + 1;
      }
    }
  }

 private:
  static constexpr int32_t kLeaf = 4;

  void split(size_t index, int32_t first, int32_t count) {
    Vec3 lo = tri_lo_[size_t(order_[size_t(first)])], hi = tri_hi_[size_t(order_[size_t(first)])];
    Vec3 clo = centre_[size_t(order_[size_t(first)])], chi = clo;
    for (int32_t i = first; i < first + count; ++i) {
      const int32_t t = order_[size_t(i)];
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], tri_lo_[size_t(t)][a]);
        hi[a] = std::max(hi[a], tri_hi_[size_t(t)][a]);
        clo[a] = std::min(clo[a], centre_[size_t(t)][a]);
        chi[a] = std::max(chi[a], centre_[size_t(t)][a]);
      }
    }
    nodes_[index].lo = lo;
    nodes_[index].hi = hi;
    if (count <= kLeaf) {
      nodes_[index].first = first;
      nodes_[index].count = count;
      return;
    }
    int axis = 0;
    for (int a = 1; a < 3; ++a)
      if (chi[a] - clo[a] > chi[axis] - clo[axis]) axis = a;
    const int32_t half = count / 2;
    std::nth_element(
        order_.begin() + first, order_.begin() + first + half, order_.begin() + first + count,
        [&](int32_t x, int32_t y) { return centre_[size_t(x)][axis] < centre_[size_t(y)][axis]; });
    const size_t left = nodes_.size();
    nodes_.push_back({});
    nodes_.push_back({});
    nodes_[index].first = int32_t(left);
    nodes_[index].count = 0;
    split(left, first, half);
    split(left + 1, first + half, count - half);
  }

  std::vector<Node> nodes_;
  std::vector<int32_t> order_;
  std::vector<Vec3> centre_, tri_lo_, tri_hi_;
};

}  // namespace

double CutPolygon::area() const {
  double a = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    const auto& p = points[i];
    const auto& q = points[(i + 1) % points.size()];
    a += p[0] * q[1] - q[0] * p[1];
  }
  return 0.5 * a;
}

std::vector<CutPolygon> cut_polygons(const TriangleMesh& mesh, const Pose& pose) {
  mesh.validate();
  const Plane plane(pose);
  std::vector<Segment> segments;
  for (const auto& tri : mesh.triangles) {
    const double s[3] = {plane.side(mesh.vertices[size_t(tri[0])]),
                         plane.side(mesh.vertices[size_t(tri[1])]),
                         plane.side(mesh.vertices[size_t(tri[2])])};
    Segment seg;
    if (cut_triangle(mesh.vertices, tri, s, &seg)) segments.push_back(seg);
  }
  // Each crossed edge is an endpoint of two segments in a closed mesh: chain them.
  auto key = [](const int32_t e[2]) { return (uint64_t(uint32_t(e[0])) << 32) | uint32_t(e[1]); };
  std::unordered_multimap<uint64_t, size_t> by_edge;
  for (size_t i = 0; i < segments.size(); ++i)
    for (int k = 0; k < 2; ++k) by_edge.emplace(key(segments[i].edge[k]), i);
  std::vector<bool> used(segments.size(), false);
  std::vector<CutPolygon> polygons;
  for (size_t start = 0; start < segments.size(); ++start) {
    if (used[start]) continue;
    CutPolygon poly;
    size_t current = start;
    int enter = 0;  // the end of `current` we arrived at
    used[start] = true;
    poly.points.push_back(plane.in_plane(segments[start].p[0]));
    while (true) {
      const int leave = 1 - enter;
      const Segment& seg = segments[current];
      const uint64_t k = key(seg.edge[leave]);
      size_t next = SIZE_MAX;
      auto range = by_edge.equal_range(k);
      for (auto it = range.first; it != range.second; ++it)
        if (it->second != current && !used[it->second]) next = it->second;
      if (next == SIZE_MAX) {
        // Back at the start (closed), or at a hole of an open mesh.
        bool back_home = false;
        for (auto it = range.first; it != range.second; ++it)
          back_home |= it->second == start && current != start;
        if (!back_home) {
          poly.points.push_back(plane.in_plane(seg.p[leave]));
          poly.closed = false;
        }
        break;
      }
      poly.points.push_back(plane.in_plane(seg.p[leave]));
      used[next] = true;
      enter = key(segments[next].edge[0]) == k ? 0 : 1;
      current = next;
    }
    polygons.push_back(std::move(poly));
  }
  return polygons;
}

// ---- the slicer --------------------------------------------------------------------------------
struct SurfaceSlicer::Impl {
  std::vector<TriangleMesh> meshes;
  std::vector<uint16_t> labels;
  std::vector<Bvh> trees;
};

SurfaceSlicer::SurfaceSlicer(std::vector<TriangleMesh> meshes, ProbeGeometry probe,
                             std::vector<uint16_t> labels, PixelType output_type)
    : impl_(std::make_unique<Impl>()), probe_(probe), output_type_(output_type) {
  probe_.validate("probe");
  if (output_type != PixelType::UInt8 && output_type != PixelType::UInt16)
    throw InputError("surface slicing: labels are uint8 or uint16");
  if (meshes.empty()) throw InputError("surface slicing: no meshes");
  if (!labels.empty() && labels.size() != meshes.size())
    throw InputError("surface slicing: " + std::to_string(labels.size()) + " labels for " +
                     std::to_string(meshes.size()) + " meshes");
  for (size_t k = 0; k < meshes.size(); ++k) {
    meshes[k].validate();
    if (labels.empty()) impl_->labels.push_back(uint16_t(k + 1));
    const MeshTopology topo = mesh_topology(meshes[k]);
    if (!topo.closed())
      warn("mesh '" + meshes[k].name + "' is not closed (" + topo.describe() +
           "): its cuts have open ends, filled best-effort");
  }
  if (!labels.empty()) impl_->labels = std::move(labels);
  for (uint16_t l : impl_->labels)
    if (output_type == PixelType::UInt8 && l > 255)
      throw InputError("surface slicing: label " + std::to_string(l) + " needs uint16 output");
  impl_->meshes = std::move(meshes);
  impl_->trees.resize(impl_->meshes.size());
  for (size_t k = 0; k < impl_->meshes.size(); ++k) impl_->trees[k].build(impl_->meshes[k]);
  mask_ = probe_.mask();
}

SurfaceSlicer::~SurfaceSlicer() = default;
SurfaceSlicer::SurfaceSlicer(SurfaceSlicer&&) noexcept = default;

namespace {

struct RowHit {
  int32_t row;
  double x;
};

template <typename T>
void slice_one(const std::vector<TriangleMesh>& meshes, const std::vector<Bvh>& trees,
               const std::vector<uint16_t>& labels, const ProbeGeometry& probe, const uint8_t* mask,
               const Pose& pose, T* out, std::vector<RowHit>& hits) {
  const ImageGrid& im = probe.image;
  const int W = im.width, H = im.height;
  std::fill(out, out + size_t(W) * size_t(H), T(0));
  const Plane plane(pose);
  // Triangles matter when they cross the plane within the band of the image's rows. Left and
  // right of the image they still count: the even-odd rule needs every crossing along a row.
  const Vec3 y_of = plane.inv_gram[1][0] * plane.x_axis + plane.inv_gram[1][1] * plane.y_axis;
  const double band_lo = im.origin_mm[1] - im.spacing_mm[1],
               band_hi = im.origin_mm[1] + H * im.spacing_mm[1];
  auto reach = [](const Vec3& n, const Vec3& e) {
    return std::fabs(n[0]) * e[0] + std::fabs(n[1]) * e[1] + std::fabs(n[2]) * e[2];
  };
  auto keep = [&](const Vec3& blo, const Vec3& bhi) {
    const Vec3 c = 0.5 * (blo + bhi), e = 0.5 * (bhi - blo);
    if (std::fabs(plane.side(c)) > reach(plane.normal, e) * (1 + 1e-12) + 1e-12) return false;
    const double y = dot(y_of, c - plane.origin), r = reach(y_of, e);
    return y + r >= band_lo && y - r <= band_hi;
  };
  const double inv_sx = 1.0 / im.spacing_mm[0], inv_sy = 1.0 / im.spacing_mm[1];
  for (size_t k = 0; k < meshes.size(); ++k) {
    const TriangleMesh& mesh = meshes[k];
    hits.clear();
    trees[k].query(keep, [&](int32_t t) {
      const auto& tri = mesh.triangles[size_t(t)];
      const double s[3] = {plane.side(mesh.vertices[size_t(tri[0])]),
                           plane.side(mesh.vertices[size_t(tri[1])]),
                           plane.side(mesh.vertices[size_t(tri[2])])};
      Segment seg;
      if (!cut_triangle(mesh.vertices, tri, s, &seg)) return;
      // In pixel units: row v's centres sit at fv = v.
      std::array<double, 2> a = plane.in_plane(seg.p[0]), b = plane.in_plane(seg.p[1]);
      const double au = (a[0] - im.origin_mm[0]) * inv_sx, av = (a[1] - im.origin_mm[1]) * inv_sy;
      const double bu = (b[0] - im.origin_mm[0]) * inv_sx, bv = (b[1] - im.origin_mm[1]) * inv_sy;
      if (av == bv) return;  // along a row: no row centre crosses it (half-open rule)
      // Rows v with min <= v < max cross the segment.
      const double vmin = std::min(av, bv), vmax = std::max(av, bv);
      const int64_t v0 = std::max<int64_t>(0, int64_t(std::ceil(vmin)));
      const int64_t v1 = std::min<int64_t>(H, int64_t(std::ceil(vmax)));
      for (int64_t v = v0; v < v1; ++v)
        hits.push_back({int32_t(v), au + (double(v) - av) * (bu - au) / (bv - av)});
    });
    if (hits.empty()) continue;
    std::sort(hits.begin(), hits.end(), [](const RowHit& x, const RowHit& y) {
      return x.row != y.row ? x.row < y.row : x.x < y.x;
    });
    const T label = T(labels[k]);
    for (size_t s = 0; s < hits.size();) {
      size_t e = s;
      while (e < hits.size() && hits[e].row == hits[s].row) ++e;
      const size_t row = size_t(hits[s].row) * size_t(W);
      for (size_t m = s; m + 1 < e; m += 2) {
        const int64_t u0 = std::max<int64_t>(0, int64_t(std::ceil(hits[m].x)));
        const int64_t u1 = std::min<int64_t>(W, int64_t(std::ceil(hits[m + 1].x)));
        for (int64_t u = u0; u < u1; ++u)
          if (mask[row + size_t(u)]) out[row + size_t(u)] = label;
      }
      s = e;
    }
  }
}

}  // namespace

void SurfaceSlicer::slice(const Pose* poses, size_t count, void* out, size_t first_index) const {
  if (count == 0) return;
  validate_poses(poses, count, "poses", first_index, /*warn_non_orthonormal=*/false);
  const size_t pixels = size_t(probe_.image.pixel_count());
  backend::parallel_for(int64_t(count), [&](int64_t n) {
    thread_local std::vector<RowHit> hits;
    if (output_type_ == PixelType::UInt8)
      slice_one(impl_->meshes, impl_->trees, impl_->labels, probe_, mask_.data(), poses[n],
                static_cast<uint8_t*>(out) + size_t(n) * pixels, hits);
    else
      slice_one(impl_->meshes, impl_->trees, impl_->labels, probe_, mask_.data(), poses[n],
                static_cast<uint16_t*>(out) + size_t(n) * pixels, hits);
  });
}

}  // namespace sonoslice
