// Surfaces: voxelisation and exact plane cuts against analytic meshes, tie cases, overlaps, open
// meshes, and the real fan-slicer meshes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/surface/SurfaceSlicer.h"
#include "sonoslice/surface/Voxelize.h"

namespace sonoslice {
namespace {

// A UV sphere with `rings` latitude bands and `segments` longitudes, outward-facing.
TriangleMesh sphere(const Vec3& c, double r, int rings = 64, int segments = 128) {
  TriangleMesh m;
  m.name = "sphere";
  m.vertices.push_back(c + Vec3{0, 0, r});
  for (int i = 1; i < rings; ++i) {
    const double th = kPi * i / rings;
    for (int j = 0; j < segments; ++j) {
      const double ph = 2 * kPi * j / segments;
      m.vertices.push_back(c + Vec3{r * std::sin(th) * std::cos(ph),
                                    r * std::sin(th) * std::sin(ph), r * std::cos(th)});
    }
  }
  m.vertices.push_back(c + Vec3{0, 0, -r});
  const int south = int(m.vertices.size()) - 1;
  auto ring = [&](int i, int j) { return 1 + (i - 1) * segments + (j % segments); };
  for (int j = 0; j < segments; ++j) m.triangles.push_back({0, ring(1, j), ring(1, j + 1)});
  for (int i = 1; i < rings - 1; ++i)
    for (int j = 0; j < segments; ++j) {
      m.triangles.push_back({ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
      m.triangles.push_back({ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
    }
  for (int j = 0; j < segments; ++j)
    m.triangles.push_back({south, ring(rings - 1, j + 1), ring(rings - 1, j)});
  return m;
}

// A torus around the z axis: major radius R, minor radius r.
TriangleMesh torus(const Vec3& c, double R, double r, int n = 96, int m = 48) {
  TriangleMesh t;
  t.name = "torus";
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < m; ++j) {
      const double u = 2 * kPi * i / n, v = 2 * kPi * j / m;
      t.vertices.push_back(c + Vec3{(R + r * std::cos(v)) * std::cos(u),
                                    (R + r * std::cos(v)) * std::sin(u), r * std::sin(v)});
    }
  auto at = [&](int i, int j) { return (i % n) * m + (j % m); };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < m; ++j) {
      t.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      t.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  return t;
}

// An axis-aligned box, each face split into `k`×`k` squares of two triangles (so that many
// vertices and diagonals fall exactly on grid lines), outward-facing.
TriangleMesh box(const Vec3& lo, const Vec3& hi, int k = 4) {
  TriangleMesh m;
  m.name = "box";
  auto face = [&](int axis, bool upper) {
    const int a = (axis + 1) % 3, b = (axis + 2) % 3;
    const int base = int(m.vertices.size());
    for (int i = 0; i <= k; ++i)
      for (int j = 0; j <= k; ++j) {
        Vec3 p;
        p[axis] = upper ? hi[axis] : lo[axis];
        p[a] = lo[a] + (hi[a] - lo[a]) * i / k;
        p[b] = lo[b] + (hi[b] - lo[b]) * j / k;
        m.vertices.push_back(p);
      }
    for (int i = 0; i < k; ++i)
      for (int j = 0; j < k; ++j) {
        const int v00 = base + i * (k + 1) + j, v10 = v00 + (k + 1), v01 = v00 + 1, v11 = v10 + 1;
        if (upper) {
          m.triangles.push_back({v00, v10, v11});
          m.triangles.push_back({v00, v11, v01});
        } else {
          m.triangles.push_back({v00, v11, v10});
          m.triangles.push_back({v00, v01, v11});
        }
      }
  };
  for (int axis = 0; axis < 3; ++axis) {
    face(axis, false);
    face(axis, true);
  }
  // Merge the duplicated edge vertices so the box is closed (shared edges share vertices).
  std::map<std::array<double, 3>, int32_t> index;
  std::vector<Vec3> unique;
  std::vector<int32_t> remap(m.vertices.size());
  for (size_t i = 0; i < m.vertices.size(); ++i) {
    auto it = index.find(m.vertices[i]);
    if (it == index.end()) {
      it = index.emplace(m.vertices[i], int32_t(unique.size())).first;
      unique.push_back(m.vertices[i]);
    }
    remap[i] = it->second;
  }
  for (auto& t : m.triangles)
    for (auto& v : t) v = remap[size_t(v)];
  m.vertices = unique;
  return m;
}

int64_t count(const Volume& v, int label) {
  int64_t n = 0;
  for (int64_t i = 0; i < v.grid().voxel_count(); ++i) n += v.data_as<uint8_t>()[i] == label;
  return n;
}

double mesh_volume(const TriangleMesh& m) {  // divergence theorem
  double v = 0;
  for (const auto& t : m.triangles)
    v += dot(m.vertices[size_t(t[0])], cross(m.vertices[size_t(t[1])], m.vertices[size_t(t[2])])) /
         6.0;
  return v;
}

VolumeGrid unit_grid(int64_t n, double spacing = 1.0, Vec3 origin = {0, 0, 0}) {
  VolumeGrid g;
  g.dims = {n, n, n};
  g.spacing_mm = {spacing, spacing, spacing};
  g.origin_mm = origin;
  return g;
}

TEST(Mesh, TopologyOfClosedAndOpenMeshes) {
  EXPECT_TRUE(mesh_topology(sphere({0, 0, 0}, 5)).closed());
  EXPECT_TRUE(mesh_topology(torus({0, 0, 0}, 10, 3)).closed());
  EXPECT_TRUE(mesh_topology(box({0, 0, 0}, {1, 1, 1})).closed());
  TriangleMesh open = sphere({0, 0, 0}, 5);
  open.triangles.resize(open.triangles.size() / 2);
  const MeshTopology t = mesh_topology(open);
  EXPECT_FALSE(t.closed());
  EXPECT_GT(t.boundary_edges, 0);
}

// Faces exactly on voxel boundaries (half-integers in index space): no ties, exact count.
TEST(Voxelize, CubeOnVoxelBoundariesIsExact) {
  const Volume v = voxelize({box({2.5, 3.5, 4.5}, {12.5, 9.5, 8.5})}, unit_grid(16));
  EXPECT_EQ(count(v, 1), 10 * 6 * 4);
  // And the box's voxels are exactly where they should be.
  const auto& d = v.grid().dims;
  for (int64_t k = 0; k < d[2]; ++k)
    for (int64_t j = 0; j < d[1]; ++j)
      for (int64_t i = 0; i < d[0]; ++i) {
        const bool inside = i >= 3 && i <= 12 && j >= 4 && j <= 9 && k >= 5 && k <= 8;
        ASSERT_EQ(v.data_as<uint8_t>()[(k * d[1] + j) * d[0] + i], inside ? 1 : 0)
            << i << " " << j << " " << k;
      }
}

// Faces, edges and vertices exactly through voxel centres and rays: every ray meets vertices and
// diagonals. Half-open [lo, hi) on every axis, no streaks.
TEST(Voxelize, RaysThroughVerticesAndEdgesDoNotStreak) {
  for (int k : {1, 2, 5}) {
    const Volume v = voxelize({box({2, 3, 4}, {12, 9, 8}, k)}, unit_grid(16));
    EXPECT_EQ(count(v, 1), 10 * 6 * 4) << "face split " << k;
    const auto& d = v.grid().dims;
    for (int64_t z = 0; z < d[2]; ++z)
      for (int64_t y = 0; y < d[1]; ++y)
        for (int64_t x = 0; x < d[0]; ++x) {
          const bool inside = x >= 2 && x < 12 && y >= 3 && y < 9 && z >= 4 && z < 8;
          ASSERT_EQ(v.data_as<uint8_t>()[(z * d[1] + y) * d[0] + x], inside ? 1 : 0)
              << x << " " << y << " " << z;
        }
  }
  // A rotated cube (45° about z) whose vertices sit on ray lines.
  TriangleMesh diamond = box({-4, -4, 2}, {4, 4, 9});
  const Pose r = test::make_pose(test::rotation({0, 0, 1}, 45), {10, 10, 0});
  diamond.transform(r);
  const Volume v = voxelize({diamond}, unit_grid(24));
  EXPECT_NEAR(double(count(v, 1)), mesh_volume(diamond), 0.05 * mesh_volume(diamond));
}

// An independent oracle: parity of a ray in an arbitrary direction (Möller–Trumbore), voxel by
// voxel. Slow, so only for small meshes; its own ties (rays through edges) are rare and random.
bool brute_force_inside(const TriangleMesh& m, const Vec3& p) {
  const Vec3 d = normalized(Vec3{0.3127, 0.7213, 0.5411});
  int n = 0;
  for (const auto& t : m.triangles) {
    const Vec3 a = m.vertices[size_t(t[0])], e1 = m.vertices[size_t(t[1])] - a,
               e2 = m.vertices[size_t(t[2])] - a;
    const Vec3 h = cross(d, e2);
    const double det = dot(e1, h);
    if (std::fabs(det) < 1e-14) continue;
    const Vec3 s = p - a;
    const double u = dot(s, h) / det;
    if (u < 0 || u > 1) continue;
    const Vec3 q = cross(s, e1);
    const double v = dot(d, q) / det;
    if (v < 0 || u + v > 1) continue;
    n += dot(e2, q) / det > 0;
  }
  return n % 2 == 1;
}

void expect_matches_brute_force(const TriangleMesh& m, const VolumeGrid& g) {
  const Volume v = voxelize({m}, g);
  int64_t mismatches = 0, inside = 0;
  const auto& d = g.dims;
  for (int64_t k = 0; k < d[2]; ++k)
    for (int64_t j = 0; j < d[1]; ++j)
      for (int64_t i = 0; i < d[0]; ++i) {
        const bool got = v.data_as<uint8_t>()[(k * d[1] + j) * d[0] + i] == 1;
        mismatches +=
            got != brute_force_inside(m, g.index_to_world({double(i), double(j), double(k)}));
        inside += got;
      }
  EXPECT_GT(inside, 1000);
  EXPECT_LE(mismatches, inside / 1000) << m.name;  // only exact-boundary voxels may differ
  EXPECT_NEAR(double(inside) * g.spacing_mm[0] * g.spacing_mm[1] * g.spacing_mm[2], mesh_volume(m),
              0.05 * mesh_volume(m));
}

TEST(Voxelize, SphereAndTorusMatchAnIndependentOracle) {
  expect_matches_brute_force(sphere({10.3, 9.7, 10.1}, 7.0, 24, 48), unit_grid(41, 0.5));
  const TriangleMesh t = torus({12.5, 12.5, 12.5}, 7, 2.5, 48, 24);
  expect_matches_brute_force(t, unit_grid(51, 0.5));
  // The hole of the torus stays empty.
  const Volume vt = voxelize({t}, unit_grid(51, 0.5));
  EXPECT_EQ(vt.data_as<uint8_t>()[(25 * 51 + 25) * 51 + 25], 0);
  // Larger: the sphere's voxel volume converges to the mesh volume.
  const TriangleMesh s = sphere({20.3, 19.7, 20.1}, 12.0);
  EXPECT_NEAR(double(count(voxelize({s}, unit_grid(81, 0.5)), 1)) * 0.125, mesh_volume(s),
              0.005 * mesh_volume(s));
}

TEST(Voxelize, ObliqueReferenceGrid) {
  // The same sphere on a rotated, anisotropic grid keeps its volume.
  const TriangleMesh s = sphere({0, 0, 0}, 10.0);
  VolumeGrid g = test::oblique_grid({40, 40, 40});
  g.spacing_mm = {0.7, 0.8, 0.9};
  g.origin_mm = g.direction * Vec3{-14, -16, -18};
  const Volume v = voxelize({s}, g);
  EXPECT_NEAR(double(count(v, 1)) * 0.7 * 0.8 * 0.9, mesh_volume(s), 0.015 * mesh_volume(s));
}

TEST(Voxelize, OverlapsLaterWinsAndGridAround) {
  const TriangleMesh a = box({0, 0, 0}, {10, 10, 10}), b = box({5, 5, 5}, {15, 15, 15});
  const VolumeGrid g = voxel_grid_around({a, b}, 1.0, 2.0);
  EXPECT_EQ(g.origin_mm, (Vec3{-2, -2, -2}));
  EXPECT_EQ(g.dims, (std::array<int64_t, 3>{19, 19, 19}));  // ceil((15 - 0 + 4) / 1)
  const Volume v = voxelize({a, b}, g);
  EXPECT_EQ(count(v, 2), 10 * 10 * 10);
  EXPECT_EQ(count(v, 1), 1000 - 125);  // the overlap belongs to the later mesh
  const Volume w = voxelize({a, b}, g, {7, 300});
  EXPECT_EQ(w.pixel_type(), PixelType::UInt16);
  const uint16_t* labels = w.data_as<uint16_t>();
  EXPECT_EQ(std::count(labels, labels + w.grid().voxel_count(), uint16_t(300)), 1000);
  EXPECT_EQ(std::count(labels, labels + w.grid().voxel_count(), uint16_t(7)), 1000 - 125);
  EXPECT_THROW(voxel_grid_around({a}, 0.0, 1.0), InputError);
  EXPECT_THROW(voxel_grid_around({a}, 1e-4, 1.0), ResourceError);
}

std::vector<std::string> g_warnings;
void capture(const std::string& m) {
  g_warnings.push_back(m);
}

TEST(Voxelize, OpenMeshWarnsAndIsBestEffort) {
  TriangleMesh s = sphere({20, 20, 20}, 10.0);
  s.name = "open sphere";
  // Cut a small cap out: a hole at the north pole.
  std::vector<std::array<int32_t, 3>> kept;
  for (const auto& t : s.triangles)
    if (t[0] != 0) kept.push_back(t);
  s.triangles = kept;
  g_warnings.clear();
  set_warning_handler(&capture);
  const Volume v = voxelize({s}, unit_grid(41));
  set_warning_handler(nullptr);
  ASSERT_EQ(g_warnings.size(), 1u);
  EXPECT_NE(g_warnings[0].find("open sphere"), std::string::npos);
  const double expected = 4.0 / 3.0 * kPi * 1000;
  EXPECT_NEAR(double(count(v, 1)), expected, 0.03 * expected);  // no streaks through the hole
}

// The exact cut of a sphere at distance d from its centre is a disc of radius sqrt(R² - d²).
TEST(ExactCut, SphereCutIsADiscOfKnownRadius) {
  const double R = 20;
  const TriangleMesh s = sphere({3, -4, 50}, R, 128, 256);
  for (double d : {0.0, 7.5, 15.0}) {
    const Pose pose = test::make_pose(Mat3::identity(), {3, -4, 50 + d});  // plane z = 50 + d
    const auto polys = cut_polygons(s, pose);
    ASSERT_EQ(polys.size(), 1u) << "d = " << d;
    EXPECT_TRUE(polys[0].closed);
    const double expected = kPi * (R * R - d * d);
    // A polygon inscribed in the true circle: area within the tessellation error.
    EXPECT_NEAR(std::fabs(polys[0].area()), expected, 0.002 * expected) << "d = " << d;
  }
  // The filled image: the pixels inside the disc, to within one ring of pixels.
  ProbeGeometry probe;
  probe.type = ProbeType::Linear;
  probe.image.width = probe.image.height = 200;
  probe.image.spacing_mm[0] = probe.image.spacing_mm[1] = 0.25;
  probe.image.origin_mm[0] = probe.image.origin_mm[1] = -24.875;
  SurfaceSlicer slicer({s}, probe);
  const Pose pose = test::make_pose(Mat3::identity(), {3, -4, 57.5});
  std::vector<uint8_t> img(200 * 200);
  slicer.slice(&pose, 1, img.data());
  const double r = std::sqrt(R * R - 7.5 * 7.5);
  int64_t inside = 0, wrong = 0;
  for (int v = 0; v < 200; ++v)
    for (int u = 0; u < 200; ++u) {
      const double x = -24.875 + u * 0.25, y = -24.875 + v * 0.25;
      const double rho = std::hypot(x, y);
      const bool label = img[size_t(v) * 200 + u] == 1;
      inside += label;
      if (std::fabs(rho - r) > 0.25 && label != (rho < r)) ++wrong;  // beyond one pixel ring
    }
  EXPECT_EQ(wrong, 0);
  EXPECT_NEAR(double(inside) * 0.0625, kPi * r * r, 0.01 * kPi * r * r);
}

TEST(ExactCut, TorusHasTwoLoopsAndAHole) {
  const TriangleMesh t = torus({0, 0, 0}, 14, 5, 192, 96);
  // The plane y = 0 (pose x̂ = world x, ŷ = world z) cuts two discs of radius 5.
  Mat3 r;
  r.m[0][0] = 1;
  r.m[0][1] = 0;
  r.m[1][0] = 0;
  r.m[1][1] = 0;
  r.m[2][0] = 0;
  r.m[2][1] = 1;
  r.m[0][2] = 0;
  r.m[1][2] = -1;
  r.m[2][2] = 0;
  const Pose pose = test::make_pose(r, {0, 0, 0});
  const auto polys = cut_polygons(t, pose);
  ASSERT_EQ(polys.size(), 2u);
  for (const auto& p : polys) EXPECT_NEAR(std::fabs(p.area()), kPi * 25, 0.01 * kPi * 25);
  // A horizontal plane through the torus' middle cuts an annulus: two loops, even-odd fill.
  const auto ring = cut_polygons(t, test::make_pose(Mat3::identity(), {0, 0, 0.3}));
  ASSERT_EQ(ring.size(), 2u);
  ProbeGeometry probe;
  probe.type = ProbeType::Linear;
  probe.image.width = probe.image.height = 180;
  probe.image.spacing_mm[0] = probe.image.spacing_mm[1] = 0.25;
  probe.image.set_default_origin();
  probe.image.origin_mm[1] = -22.375;
  SurfaceSlicer slicer({t}, probe);
  std::vector<uint8_t> img(180 * 180);
  const Pose flat = test::make_pose(Mat3::identity(), {0, 0, 0.3});
  slicer.slice(&flat, 1, img.data());
  EXPECT_EQ(img[size_t(90) * 180 + 90], 0);  // the hole in the middle
  int64_t inside = 0;
  for (uint8_t p : img) inside += p;
  const double a = std::fabs(ring[0].area()) - std::fabs(ring[1].area());
  EXPECT_NEAR(double(inside) * 0.0625, std::fabs(a), 0.01 * std::fabs(a));
}

TEST(ExactCut, VoxelisedSlicingAgreesWithExactOnASphere) {
  const TriangleMesh s = sphere({0, 0, 0}, 15, 96, 192);
  const Volume labels = voxelize({s}, voxel_grid_around({s}, 0.25, 1.0));
  const ProbeGeometry probe = test::curvilinear_probe(10, 40, 70, 160, 160, 0.25);
  const auto poses = test::random_poses(20, {0, -20, 0}, 4, 3);
  SliceSettings settings;
  settings.interpolation = Interpolation::Nearest;
  settings.output_type = PixelType::UInt8;
  const auto voxel = Slicer(labels, probe, settings).slice<uint8_t>(poses);
  std::vector<uint8_t> exact(voxel.size());
  SurfaceSlicer({s}, probe).slice(poses.data(), poses.size(), exact.data());
  int64_t both = 0, a = 0, b = 0;
  for (size_t i = 0; i < voxel.size(); ++i) {
    a += voxel[i] == 1;
    b += exact[i] == 1;
    both += voxel[i] == 1 && exact[i] == 1;
  }
  ASSERT_GT(a, 1000);
  EXPECT_GE(2.0 * double(both) / double(a + b), 0.98);
}

TEST(ExactCut, LaterMeshesPaintOverEarlierOnesAndRespectTheMask) {
  const ProbeGeometry probe = test::curvilinear_probe(5, 30, 60, 100, 100, 0.4);
  const TriangleMesh big = box({-50, -50, -50}, {50, 50, 50}), small = sphere({0, 20, 0}, 5);
  SurfaceSlicer slicer({big, small}, probe, {3, 9});
  const Pose pose = Pose::identity();
  std::vector<uint8_t> img(100 * 100);
  slicer.slice(&pose, 1, img.data());
  const auto mask = probe.mask();
  int nine = 0;
  for (size_t i = 0; i < img.size(); ++i) {
    if (!mask[i]) {
      ASSERT_EQ(img[i], 0);
      continue;
    }
    ASSERT_TRUE(img[i] == 3 || img[i] == 9);
    nine += img[i] == 9;
  }
  EXPECT_NEAR(nine * 0.16, kPi * 25, 0.05 * kPi * 25);
}

}  // namespace
}  // namespace sonoslice
