// Meshes through VTK, fan-slicer surface configurations, and the real fan-slicer meshes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/surface/SurfaceConfig.h"
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

// ---- broken mesh files: an error naming the file, never a crash --------------------

std::string mesh_error(const std::string& path) {
  try {
    read_mesh(path);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// Big-endian bytes of a value, as legacy VTK binary files store them.
template <typename T>
std::string big_endian(T value) {
  std::string b(sizeof(T), '\0');
  std::memcpy(&b[0], &value, sizeof(T));
  std::reverse(b.begin(), b.end());
  return b;
}

// The tetrahedron as a binary legacy file, version 3.0 (counted cell lists) or 5.1 (offsets and
// connectivity), with `ids` as its triangles' point ids.
std::string binary_legacy_tet(bool version5, const std::vector<int>& ids) {
  const TriangleMesh tet = tetrahedron();
  std::string b = std::string("# vtk DataFile Version ") + (version5 ? "5.1" : "3.0") +
                  "\ntet\nBINARY\nDATASET POLYDATA\nPOINTS 4 float\n";
  for (const Vec3& v : tet.vertices)
    for (double x : v) b += big_endian(float(x));
  const size_t n = ids.size() / 3;
  if (version5) {
    b += "\nPOLYGONS " + std::to_string(n + 1) + " " + std::to_string(ids.size()) +
         "\nOFFSETS vtktypeint64\n";
    for (size_t k = 0; k <= n; ++k) b += big_endian(int64_t(3 * k));
    b += "\nCONNECTIVITY vtktypeint64\n";
    for (int id : ids) b += big_endian(int64_t(id));
  } else {
    b += "\nPOLYGONS " + std::to_string(n) + " " + std::to_string(4 * n) + "\n";
    for (size_t k = 0; k < n; ++k) {
      b += big_endian(int32_t(3));
      for (size_t j = 0; j < 3; ++j) b += big_endian(int32_t(ids[3 * k + j]));
    }
  }
  return b + "\n";
}

const std::vector<int> kTetIds = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};

// A bad-input probe found this: `head -c 308216 liver.vtk` crashed VTK's reader (SIGSEGV).
TEST(MeshFile, TruncatedBinaryLegacyVtkIsAnError) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir dir;
  std::ifstream in(test::data_dir() + "/fanslicer/liver.vtk", std::ios::binary);
  const std::string liver((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(liver.size(), 484247u);  // POINT_DATA starts there
  write_bytes(dir.file("cut.vtk"), liver.substr(0, 308216));
  const std::string e = mesh_error(dir.file("cut.vtk"));
  EXPECT_NE(e.find(dir.file("cut.vtk")), std::string::npos) << e;
  EXPECT_NE(e.find("POLYGONS announces 88000 values"), std::string::npos) << e;
  EXPECT_THROW(read_mesh(dir.file("cut.vtk")), FileError);
  // Cut anywhere in the header, the points or the polygons: an error, never a crash.
  for (size_t n = 0; n < 484247; n += 4999) {
    write_bytes(dir.file("cut.vtk"), liver.substr(0, n));
    EXPECT_THROW(read_mesh(dir.file("cut.vtk")), Error) << n << " bytes";
  }
}

// A bad-input probe found this: a polygon naming point 99999 of 3 crashed VTK's clean-up; point 100
// read outside VTK's arrays (valgrind), with results that changed from run to run.
TEST(MeshFile, LegacyVtkIndexOutOfRangeIsAnError) {
  test::TempDir dir;
  for (const char* index : {"99999", "100", "3", "-1"}) {
    write_bytes(dir.file("bad.vtk"),
                std::string("# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\n") +
                    "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 " + index + "\n");
    const std::string e = mesh_error(dir.file("bad.vtk"));
    EXPECT_NE(e.find("uses point " + std::string(index) + ", but the file has 3 points"),
              std::string::npos)
        << e;
    EXPECT_NE(e.find(dir.file("bad.vtk")), std::string::npos) << e;
  }
  // The same in binary files, both cell layouts.
  for (bool version5 : {false, true}) {
    std::vector<int> ids = kTetIds;
    write_bytes(dir.file("tet.vtk"), binary_legacy_tet(version5, ids));
    EXPECT_EQ(read_mesh(dir.file("tet.vtk")).triangles.size(), 4u);
    ids[7] = 99999;
    write_bytes(dir.file("tet.vtk"), binary_legacy_tet(version5, ids));
    EXPECT_NE(mesh_error(dir.file("tet.vtk")).find("cell 2 uses point 99999"), std::string::npos)
        << mesh_error(dir.file("tet.vtk"));
  }
}

TEST(MeshFile, LegacyVtkCountsAndCoordinatesAreChecked) {
  test::TempDir dir;
  const std::string head = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\n";
  auto error_for = [&](const std::string& body) {
    write_bytes(dir.file("m.vtk"), head + body);
    return mesh_error(dir.file("m.vtk"));
  };
  // A cell list longer than its announced size, one that does not fill it, a count past the end.
  EXPECT_NE(error_for("POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 3\n3 0 1 2\n")
                .find("runs past the announced size"),
            std::string::npos);
  EXPECT_NE(error_for("POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 5\n3 0 1 2 2\n")
                .find("fill 4 of the announced size"),
            std::string::npos);
  EXPECT_NE(error_for("POINTS 40000 float\n0 0 0\n").find("truncated"), std::string::npos);
  // Coordinates: finite numbers only.
  EXPECT_NE(error_for("POINTS 3 float\n0 0 0 1 nan 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n")
                .find("point 1 has a non-finite coordinate"),
            std::string::npos);
  EXPECT_NE(error_for("POINTS 3 float\n0 0 0 1 x 0 0 1 0\n").find("'x' is not a number"),
            std::string::npos);
  EXPECT_NE(error_for("POINTS 3 float\n0 0 0 1 0 0 0 1 0\nSPHERES 1\n").find("'spheres'"),
            std::string::npos);
  // Version 5 ASCII, with field data before the points, metadata after them and attributes
  // after the cells (which are not read): all accepted.
  EXPECT_EQ(error_for("FIELD FieldData 1\nTimeValue 1 1 double\n0.5\n"
                      "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nMETADATA\nINFORMATION 0\n\n"
                      "POLYGONS 1 4\n3 0 1 2\nPOINT_DATA 3\nSCALARS s float\nbroken"),
            "");
  write_bytes(dir.file("v5.vtk"),
              "# vtk DataFile Version 5.1\nt\nASCII\nDATASET POLYDATA\nPOINTS 4 float\n"
              "0 0 0 10 0 0 0 10 0 0 0 10\nPOLYGONS 5 12\nOFFSETS vtktypeint64\n0 3 6 9 12\n"
              "CONNECTIVITY vtktypeint64\n0 2 1 0 1 3 0 3 2 1 2 3\n");
  EXPECT_TRUE(mesh_topology(read_mesh(dir.file("v5.vtk"))).closed());
  write_bytes(dir.file("v5.vtk"),
              "# vtk DataFile Version 5.1\nt\nASCII\nDATASET POLYDATA\nPOINTS 4 float\n"
              "0 0 0 10 0 0 0 10 0 0 0 10\nPOLYGONS 3 6\nOFFSETS vtktypeint64\n0 6 3\n"
              "CONNECTIVITY vtktypeint64\n0 2 1 0 1 3\n");
  EXPECT_NE(mesh_error(dir.file("v5.vtk")).find("offsets must run from 0 to"), std::string::npos);
}

// A bad-input probe found this: a binary STL whose header claims 4.29e9 triangles was read as far
// as it went, without a word.
TEST(MeshFile, BinaryStlTriangleCountMustFitTheFile) {
  test::TempDir dir;
  write_mesh(dir.file("tet.stl"), tetrahedron());
  std::string stl;
  {
    std::ifstream in(dir.file("tet.stl"), std::ios::binary);
    stl.assign((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  }
  ASSERT_EQ(stl.size(), 84u + 50 * 4);
  for (uint32_t claimed : {uint32_t(4294967295u), uint32_t(5)}) {
    std::string bad = stl;
    std::memcpy(&bad[80], &claimed, 4);  // little-endian, as STL stores it
    write_bytes(dir.file("bad.stl"), bad);
    const std::string e = mesh_error(dir.file("bad.stl"));
    EXPECT_NE(e.find("announces " + std::to_string(claimed) + " triangles"), std::string::npos)
        << e;
    EXPECT_NE(e.find(dir.file("bad.stl")), std::string::npos) << e;
  }
  write_bytes(dir.file("cut.stl"), stl.substr(0, 200));
  EXPECT_THROW(read_mesh(dir.file("cut.stl")), FileError);
}

// A bad-input probe found this: garbage named .obj became "no triangles", faces naming vertices
// that do not exist were dropped and "nan" coordinates were read.
TEST(MeshFile, ObjGarbageAndBadIndicesAreRefused) {
  test::TempDir dir;
  auto error_for = [&](const std::string& text) {
    write_bytes(dir.file("m.obj"), text);
    return mesh_error(dir.file("m.obj"));
  };
  EXPECT_NE(error_for("hello world\nthis is not an obj\n").find("not an OBJ mesh"),
            std::string::npos);
  EXPECT_NE(error_for(std::string("\x89PNG\r\n\x1a\n\0\0\0", 11)).find("not an OBJ mesh"),
            std::string::npos);
  const std::string v = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  EXPECT_NE(error_for(v + "f 1 2 99\n").find("a face uses vertex 99, but the file has 3"),
            std::string::npos);
  EXPECT_NE(error_for(v + "f 1 2 -7\n").find("vertex -7 counts back past the 3"),
            std::string::npos);
  EXPECT_NE(error_for(v + "f 1 2 0\n").find("'0' is not a vertex index"), std::string::npos);
  EXPECT_NE(error_for("v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n").find("line 2: a vertex is not"),
            std::string::npos);
  EXPECT_NE(error_for(v).find("no face ('f') lines"), std::string::npos);
  // "v/" and "v//" (an empty last index): vtkOBJReader read index 0, before its array
  // (SIGSEGV, found by fuzz_mesh_obj).
  for (const char* face : {"f 1 2/ 3\n", "f 1 2// 3\n", "f 1 2/1/1/1 3\n"})
    EXPECT_NE(error_for(v + "vt 0 0\nvn 0 0 1\n" + face).find("is not a face vertex"),
              std::string::npos)
        << face;
  // Good files still read: negative (relative) indices, v/vt/vn triples, v//vn.
  EXPECT_EQ(error_for(v + "vt 0 0\nf -3/1 -2/1 -1/1\n"), "");
  EXPECT_EQ(error_for(v + "vn 0 0 1\nf 1//1 2//1 3//1\n"), "");
}

// PLY is parsed by sonoslice (vtkPLYReader read on after a file without y and z: SIGSEGV). The
// tetrahedron in the three encodings, with properties and elements sonoslice reads past.
std::string ply_tet(const std::string& format, const std::string& list_name = "vertex_indices") {
  const TriangleMesh tet = tetrahedron();
  std::string b = "ply\r\nformat " + format +
                  " 1.0\ncomment made by hand\nelement vertex 4\nproperty double x\n"
                  "property float y\nproperty float z\nproperty uchar red\n"
                  "element face 4\nproperty list uchar int " +
                  list_name +
                  "\nproperty short flags\nelement edge 1\nproperty list int uint ends\n"
                  "end_header\n";
  const bool big = format == "binary_big_endian";
  const auto raw = [&](auto value) {
    std::string bytes(sizeof(value), '\0');
    std::memcpy(&bytes[0], &value, sizeof(value));
    if (big) std::reverse(bytes.begin(), bytes.end());
    return bytes;
  };
  for (const Vec3& v : tet.vertices)
    b += format == "ascii"
             ? std::to_string(v[0]) + " " + std::to_string(v[1]) + " " + std::to_string(v[2]) +
                   " 200\n"
             : raw(double(v[0])) + raw(float(v[1])) + raw(float(v[2])) + raw(uint8_t(200));
  for (const auto& t : tet.triangles)
    b += format == "ascii" ? "3 " + std::to_string(t[0]) + " " + std::to_string(t[1]) + " " +
                                 std::to_string(t[2]) + " -1\n"
                           : raw(uint8_t(3)) + raw(int32_t(t[0])) + raw(int32_t(t[1])) +
                                 raw(int32_t(t[2])) + raw(int16_t(-1));
  b += format == "ascii" ? "2 0 1\n" : raw(int32_t(2)) + raw(uint32_t(0)) + raw(uint32_t(1));
  return b;
}

TEST(MeshFile, PlyEncodingsReadAlike) {
  test::TempDir dir;
  for (const char* format : {"ascii", "binary_little_endian", "binary_big_endian"})
    for (const char* list : {"vertex_indices", "vertex_index"}) {
      write_bytes(dir.file("m.ply"), ply_tet(format, list));
      const TriangleMesh m = read_mesh(dir.file("m.ply"));
      EXPECT_EQ(m.triangles.size(), 4u) << format;
      EXPECT_EQ(m.vertices.size(), 4u) << format;
      EXPECT_TRUE(mesh_topology(m).closed()) << format;
      EXPECT_NEAR(std::fabs(mesh_volume(m)), 1000.0 / 6.0, 1e-9) << format << " " << list;
    }
}

TEST(MeshFile, PlyGarbageTruncationAndBadIndicesAreRefused) {
  test::TempDir dir;
  auto error_for = [&](const std::string& bytes) {
    write_bytes(dir.file("m.ply"), bytes);
    return mesh_error(dir.file("m.ply"));
  };
  const std::string ascii = ply_tet("ascii"), binary = ply_tet("binary_little_endian");
  const std::string head = "ply\nformat ascii 1.0\nelement vertex 3\n";
  // A vertex element with x alone: VTK 9.1's reader crashed (use after free).
  EXPECT_NE(error_for(head + "property float x\nend_header\n1 2\n")
                .find("cannot read mesh '" + dir.file("m.ply") +
                      "': the vertex element has no scalar property 'y'"),
            std::string::npos);
  EXPECT_NE(error_for("garbage\n1 2 3\n").find("not a PLY mesh (its first line is not 'ply')"),
            std::string::npos);
  EXPECT_NE(error_for("ply\nformat ascii 1.0\n").find("no end_header"), std::string::npos);
  EXPECT_NE(error_for("ply\nelement vertex 0\nend_header\n").find("no format line"),
            std::string::npos);
  EXPECT_NE(error_for(head + "property quad x\nend_header\n").find("unknown type 'quad'"),
            std::string::npos);
  // Cut anywhere in the body: one line that says so, for both encodings.
  for (const std::string& whole : {ascii, binary})
    for (size_t cut : {size_t(2), size_t(7), size_t(20)}) {
      const std::string e = error_for(whole.substr(0, whole.size() - cut));
      EXPECT_NE(e.find("truncated"), std::string::npos) << cut << ": " << e;
    }
  // A count the file cannot hold is refused before anything of its size is allocated.
  std::string huge = binary;
  huge.replace(huge.find("element vertex 4"), 16, "element vertex 2000000000");
  EXPECT_NE(error_for(huge).find("truncated: 2000000000 vertex records need at least"),
            std::string::npos);
  std::string bad = ascii;
  bad.replace(bad.find("3 0 2 1 -1"), 10, "3 0 2 9 -1");
  EXPECT_NE(error_for(bad).find("face 0 uses vertex 9, but the file has 4"), std::string::npos);
  bad = ascii;
  bad.replace(bad.find("3 0 2 1 -1"), 10, "3 0 2 x -1");
  EXPECT_NE(error_for(bad).find("face 0: 'x' is not an integer"), std::string::npos);
  bad = ascii;
  bad.replace(bad.find("10.000000 0.000000 0.000000"), 27, "10.000000 nan 0.000000");
  EXPECT_NE(error_for(bad).find("vertex 1: 'nan' is not a number"), std::string::npos);
  EXPECT_NE(error_for(ascii + "7\n").find("more values after the last element ('7')"),
            std::string::npos);
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
  // A bad-input probe found this: a colour that is not a number escaped as the JSON library's own
  // exception ("[json.exception.type_error.302] type must be number"), without the file.
  std::ifstream in(d + "/models_binary_LUS_config.json");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto error_for = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    t.replace(t.find(from), from.size(), to);
    std::ofstream(dir.file("cfg.json")) << t;
    try {
      read_fanslicer_models(dir.file("cfg.json"), d);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  std::string e = error_for("[0, 200, 0]", "[\"green\", 200, 0]");
  EXPECT_NE(e.find("cfg.json': colour of 'hepatic veins' must be [r, g, b]"), std::string::npos)
      << e;
  e = error_for("[0, 1, 1, 1]", "[0, \"yes\", 1, 1]");
  EXPECT_NE(e.find("cfg.json': \"simulation_models\"[1] must be 0 or 1"), std::string::npos) << e;
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
