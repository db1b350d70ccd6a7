// Pose files in every format docs/conventions.md §2 lists, and their errors.
#include <gtest/gtest.h>

#include <fstream>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PoseFile.h"

namespace sonoslice {
namespace {

std::vector<Pose> two_poses() {
  return {test::make_pose(test::rotation({0, 1, 0}, 20), {1.5, -2, 30}),
          test::make_pose(test::rotation({1, 1, 1}, -75), {-10, 5, 0.25})};
}

void expect_same(const std::vector<Pose>& a, const std::vector<Pose>& b, double tol = 1e-12) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t n = 0; n < a.size(); ++n)
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) EXPECT_NEAR(a[n].m[r][c], b[n].m[r][c], tol) << n << r << c;
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

std::string pose_file_error(const std::string& path) {
  try {
    read_poses(path);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(PoseFile, NpyStackFloat64AndFloat32) {
  test::TempDir dir;
  const auto poses = two_poses();
  write_poses_npy(dir.file("p.npy"), poses);
  expect_same(read_poses(dir.file("p.npy")), poses);
  std::vector<float> f;
  for (const Pose& p : poses)
    for (int i = 0; i < 16; ++i) f.push_back(float(p.m[i / 4][i % 4]));
  write_npy(dir.file("f.npy"), PixelType::Float32, {2, 4, 4}, f.data());
  expect_same(read_poses(dir.file("f.npy")), poses, 1e-6);
}

TEST(PoseFile, FanSlicerStrip) {
  test::TempDir dir;
  const auto poses = two_poses();
  std::vector<double> strip(4 * 8);  // (4, 4N), pose n = columns 4n..4n+3
  for (int n = 0; n < 2; ++n)
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) strip[size_t(r) * 8 + 4 * n + c] = poses[size_t(n)].m[r][c];
  write_npy(dir.file("strip.npy"), PixelType::Float64, {4, 8}, strip.data());
  expect_same(read_poses(dir.file("strip.npy")), poses);
}

TEST(PoseFile, TextFormats) {
  test::TempDir dir;
  const auto poses = two_poses();
  write_poses_text(dir.file("p.txt"), poses);
  expect_same(read_poses(dir.file("p.txt")), poses);
  // 12 numbers (3x4), commas, tabs, comments, blank lines.
  std::string csv = "# a comment\n\n";
  for (const Pose& p : poses) {
    for (int i = 0; i < 12; ++i)
      csv += std::to_string(p.m[i / 4][i % 4]) + (i % 3 == 0 ? ",\t" : ", ");
    csv += "  # trailing comment\n";
  }
  write_text(dir.file("p.csv"), csv);
  expect_same(read_poses(dir.file("p.csv")), poses, 1e-6);
}

TEST(PoseFile, Json) {
  test::TempDir dir;
  const auto poses = two_poses();
  std::string flat = "{\"poses\": [", nested = "{\"poses\": [";
  for (size_t n = 0; n < poses.size(); ++n) {
    flat += n ? ", [" : "[";
    nested += n ? ", [" : "[";
    for (int r = 0; r < 4; ++r) {
      nested += r ? ", [" : "[";
      for (int c = 0; c < 4; ++c) {
        const std::string v = std::to_string(poses[n].m[r][c]);
        flat += (r || c ? ", " : "") + v;
        nested += (c ? ", " : "") + v;
      }
      nested += "]";
    }
    flat += "]";
    nested += "]";
  }
  write_text(dir.file("flat.json"), flat + "]}");
  write_text(dir.file("nested.json"), nested + "]}");
  expect_same(read_poses(dir.file("flat.json")), poses, 1e-6);
  expect_same(read_poses(dir.file("nested.json")), poses, 1e-6);
}

TEST(PoseFile, RasConversion) {
  test::TempDir dir;
  const auto poses = two_poses();
  write_poses_text(dir.file("p.txt"), poses);
  const auto lps = read_poses(dir.file("p.txt"), WorldFrame::RAS);
  EXPECT_DOUBLE_EQ(lps[0].m[0][3], -poses[0].m[0][3]);
  EXPECT_DOUBLE_EQ(lps[0].m[1][0], -poses[0].m[1][0]);
  EXPECT_DOUBLE_EQ(lps[0].m[2][3], poses[0].m[2][3]);
}

TEST(PoseFile, Errors) {
  test::TempDir dir;
  // Wrong .npy shape.
  std::vector<double> bad(3 * 5, 0.0);
  write_npy(dir.file("shape.npy"), PixelType::Float64, {3, 5}, bad.data());
  EXPECT_NE(pose_file_error(dir.file("shape.npy")).find("shape (3, 5)"), std::string::npos);
  // Wrong dtype.
  std::vector<int32_t> ints(16, 0);
  write_npy(dir.file("int.npy"), PixelType::Int32, {1, 4, 4}, ints.data());
  EXPECT_NE(pose_file_error(dir.file("int.npy")).find("dtype int32"), std::string::npos);
  // Text line with 15 numbers.
  write_text(dir.file("short.txt"), "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n");
  EXPECT_NE(pose_file_error(dir.file("short.txt")).find("line 1 has 15 numbers"),
            std::string::npos);
  write_text(dir.file("word.txt"), "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 x1\n");
  EXPECT_NE(pose_file_error(dir.file("word.txt")).find("'x1' is not a number"), std::string::npos);
  // Non-finite entry, index named.
  write_text(dir.file("nan.txt"),
             "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1\n");
  EXPECT_NE(pose_file_error(dir.file("nan.txt")).find("pose 1"), std::string::npos);
  // Degenerate axes.
  write_text(dir.file("flat.txt"), "1 1 0 0 0 0 0 0 0 0 1 0 0 0 0 1\n");
  EXPECT_NE(pose_file_error(dir.file("flat.txt")).find("pose 0"), std::string::npos);
  // Empty file, unknown extension, unknown JSON key, missing file, truncated npy.
  write_text(dir.file("empty.txt"), "# nothing\n");
  EXPECT_NE(pose_file_error(dir.file("empty.txt")).find("no poses"), std::string::npos);
  EXPECT_NE(pose_file_error(dir.file("p.xyz")).find("unknown extension"), std::string::npos);
  write_text(dir.file("k.json"), R"({"poses": [], "frame": "RAS"})");
  EXPECT_NE(pose_file_error(dir.file("k.json")).find("unknown key 'frame'"), std::string::npos);
  EXPECT_THROW(read_poses(dir.file("missing.txt")), FileError);
  write_poses_npy(dir.file("t.npy"), two_poses());
  std::filesystem::resize_file(dir.file("t.npy"), 200);
  EXPECT_NE(pose_file_error(dir.file("t.npy")).find("truncated"), std::string::npos);
  // Every message names the file.
  EXPECT_NE(pose_file_error(dir.file("flat.txt")).find(dir.file("flat.txt")), std::string::npos);
}

// A bad-input probe found this: "--image-to-probe" with 7 numbers was taken for a file name and
// reported as "poses '1,0,...': unknown extension".
TEST(PoseFile, ReadMatrixCountsNumbersAndNamesTheFlag) {
  test::TempDir dir;
  auto error_for = [](const std::string& text) {
    try {
      read_matrix(text, "--image-to-probe");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(read_matrix("2,0,0,1, 0,3,0,2, 0,0,1,0", "m").m[1][1], 3.0);
  EXPECT_EQ(error_for("1,0,0,0,0,1,0"),
            "--image-to-probe '1,0,0,0,0,1,0': 7 numbers (expected 16 for a 4x4 or 12 for a 3x4 "
            "matrix, row by row)");
  EXPECT_NE(error_for("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 5").find("17 numbers"), std::string::npos);
  EXPECT_NE(error_for(dir.file("cal.txt")).find("nor an existing matrix file"), std::string::npos);
  // A file's errors name the flag, not "poses".
  write_text(dir.file("cal.txt"), "1 0 0 0 0 1 0\n");
  EXPECT_NE(error_for(dir.file("cal.txt")).find("--image-to-probe '" + dir.file("cal.txt") + "'"),
            std::string::npos)
      << error_for(dir.file("cal.txt"));
  write_text(dir.file("two.txt"), "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_NE(error_for(dir.file("two.txt")).find("the file has 2"), std::string::npos);
}

}  // namespace
}  // namespace sonoslice
