// Meshes through VTK, fan-slicer surface configurations, and the real fan-slicer meshes.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <random>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/SurfaceConfig.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/surface/SurfaceSlicer.h"
#include "sonoslice/surface/Voxelize.h"

namespace sonoslice {
namespace {

namespace fs = std::filesystem;

TriangleMesh tetrahedron() {
  TriangleMesh m;
  m.name = "tet";
  m.vertices = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

double mesh_volume(const TriangleMesh& m) {
  double v = 0;
  for (const auto& t : m.triangles)
    v += dot(m.vertices[size_t(t[0])], cross(m.vertices[size_t(t[1])], m.vertices[size_t(t[2])])) /
         6.0;
  return v;
}

class MeshFormats : public ::testing::TestWithParam<std::string> {};

TEST_P(MeshFormats, RoundTrip) {
  test::TempDir dir;
  const std::string path = dir.file("tet" + GetParam());
  write_mesh(path, tetrahedron());
  const TriangleMesh back = read_mesh(path);
  EXPECT_EQ(back.triangles.size(), 4u);
  EXPECT_EQ(back.vertices.size(), 4u);  // STL's per-triangle vertices are merged again
  EXPECT_TRUE(mesh_topology(back).closed());
  EXPECT_NEAR(std::fabs(mesh_volume(back)), 1000.0 / 6.0, 1e-3);
  // RAS meshes come in as LPS: x and y negated.
  const TriangleMesh ras = read_mesh(path, WorldFrame::RAS);
  const auto b = ras.bounds();
  EXPECT_NEAR(b[0][0], -10, 1e-5);
  EXPECT_NEAR(b[1][1], 0, 1e-5);
  EXPECT_NEAR(b[1][2], 10, 1e-5);
}

INSTANTIATE_TEST_SUITE_P(Formats, MeshFormats,
                         ::testing::Values(".vtk", ".vtp", ".stl", ".obj", ".ply"),
                         [](const auto& info) { return info.param.substr(1); });

TEST(MeshFile, LegacyAsciiPolygonsAreTriangulated) {
  test::TempDir dir;
  // A unit cube as six quads in ASCII legacy VTK.
  std::ofstream(dir.file("cube.vtk"))
      << "# vtk DataFile Version 3.0\ncube\nASCII\nDATASET POLYDATA\n"
         "POINTS 8 float\n0 0 0 1 0 0 1 1 0 0 1 0 0 0 1 1 0 1 1 1 1 0 1 1\n"
         "POLYGONS 6 30\n4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 2 3 7 6\n4 1 2 6 5\n4 0 4 7 3\n";
  const TriangleMesh cube = read_mesh(dir.file("cube.vtk"));
  EXPECT_EQ(cube.triangles.size(), 12u);
  EXPECT_TRUE(mesh_topology(cube).closed());
  EXPECT_NEAR(mesh_volume(cube), 1.0, 1e-6);
}

TEST(MeshFile, BadFilesNameTheFile) {
  test::TempDir dir;
  auto error_of = [](const std::string& p) {
    try {
      read_mesh(p);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error_of(dir.file("none.vtk")).find("no such file"), std::string::npos);
  std::ofstream(dir.file("junk.vtk")) << "not a vtk file at all\n";
  EXPECT_NE(error_of(dir.file("junk.vtk")).find("junk.vtk"), std::string::npos);
  std::ofstream(dir.file("junk.stl")) << "solid nonsense\n facet normal what\n";
  EXPECT_NE(error_of(dir.file("junk.stl")).find("junk.stl"), std::string::npos);
  std::ofstream(dir.file("m.xyz")) << "1 2 3\n";
  EXPECT_NE(error_of(dir.file("m.xyz")).find("unknown format"), std::string::npos);
}

TEST(SurfaceConfig, FanSlicerModelsWithSpacesInNames) {
  SONOSLICE_REQUIRE_DATA();
  const std::string d = test::data_dir() + "/fanslicer";
  const auto models = read_fanslicer_models(d + "/models_binary_LUS_config.json", d);
  // simulation_models [0, 1, 1, 1]: the liver is off; the k-th enabled model is label k.
  ASSERT_EQ(models.size(), 3u);
  EXPECT_EQ(models[0].name, "hepatic veins");
  EXPECT_EQ(models[0].path, d + "/hepatic veins.vtk");
  EXPECT_EQ(models[0].label, 1);
  EXPECT_EQ(models[1].name, "portal vein");
  EXPECT_EQ(models[2].label, 3);
  EXPECT_EQ(models[0].color, (std::array<uint8_t, 3>{0, 200, 0}));
  test::TempDir dir;
  EXPECT_THROW(read_fanslicer_models(d + "/models_binary_LUS_config.json", dir.path().string()),
               FileError);
  EXPECT_THROW(read_fanslicer_models(d + "/models_intensity_LUS_config.json", d), InputError);
}

// The real meshes: closed, volumes preserved by voxelisation, and voxel vs exact label images
// agreeing (Dice) on fans through the liver.
TEST(RealMeshes, VoxelisedAndExactModesAgree) {
  SONOSLICE_REQUIRE_DATA();
  const std::string d = test::data_dir() + "/fanslicer/";
  std::vector<TriangleMesh> meshes;
  for (const char* name : {"liver", "hepatic veins", "portal vein", "arteries"}) {
    meshes.push_back(read_mesh(d + name + ".vtk"));
    EXPECT_TRUE(mesh_topology(meshes.back()).closed()) << name;
  }
  const Volume liver = voxelize({meshes[0]}, voxel_grid_around({meshes[0]}, 1.0, 0.0));
  int64_t liver_voxels = 0;
  for (int64_t i = 0; i < liver.grid().voxel_count(); ++i)
    liver_voxels += liver.data_as<uint8_t>()[i];
  EXPECT_NEAR(double(liver_voxels), mesh_volume(meshes[0]), 0.01 * mesh_volume(meshes[0]));

  // 100 poses through the liver: random voxel centres inside it, random orientations.
  std::mt19937 rng(17);
  std::vector<Pose> poses;
  const auto& g = liver.grid();
  std::uniform_int_distribution<int64_t> pick(0, g.voxel_count() - 1);
  while (poses.size() < 100) {
    const int64_t i = pick(rng);
    if (!liver.data_as<uint8_t>()[i]) continue;
    const Vec3 c{double(i % g.dims[0]), double((i / g.dims[0]) % g.dims[1]),
                 double(i / (g.dims[0] * g.dims[1]))};
    const auto one = test::random_poses(1, g.index_to_world(c), 0.0, uint32_t(rng()));
    poses.push_back(one[0]);
  }
  const ProbeGeometry probe = workload_w1_fan_probe();
  const Volume labels = voxelize(meshes, voxel_grid_around(meshes, 0.25, 0.5));
  SliceSettings s;
  s.interpolation = Interpolation::Nearest;
  s.output_type = PixelType::UInt8;
  const auto voxel = Slicer(labels, probe, s).slice<uint8_t>(poses);
  std::vector<uint8_t> exact(voxel.size());
  SurfaceSlicer(meshes, probe).slice(poses.data(), poses.size(), exact.data());
  for (int label = 1; label <= 4; ++label) {
    int64_t a = 0, b = 0, both = 0;
    for (size_t i = 0; i < voxel.size(); ++i) {
      a += voxel[i] == label;
      b += exact[i] == label;
      both += voxel[i] == label && exact[i] == label;
    }
    const double dice = 2.0 * double(both) / double(a + b);
    std::printf("[ dice ] %s: %.4f (%lld voxel-mode pixels, %lld exact-mode pixels)\n",
                meshes[size_t(label - 1)].name.c_str(), dice, static_cast<long long>(a),
                static_cast<long long>(b));
    EXPECT_GT(b, 1000);
    EXPECT_GE(dice, 0.97) << meshes[size_t(label - 1)].name;
  }
}

}  // namespace
}  // namespace sonoslice
