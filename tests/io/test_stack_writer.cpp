// Output stacks (docs/conventions.md §6): formats, windows, atomic replacement.
#include <gtest/gtest.h>

#include <fstream>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace {

namespace fs = std::filesystem;

StackSpec spec(int64_t n) {
  StackSpec s;
  s.type = PixelType::Float32;
  s.width = 5;
  s.height = 4;
  s.count = n;
  s.spacing_mm[0] = 0.25;
  s.spacing_mm[1] = 0.5;
  s.poses.assign(size_t(n), Pose::identity());
  return s;
}

void write_stack(const std::string& path, const StackSpec& s, float offset, int64_t chunk = 2) {
  auto w = StackWriter::create(path, s);
  for (int64_t first = 0; first < s.count; first += chunk) {
    const int64_t n = std::min(chunk, s.count - first);
    float* buf = static_cast<float*>(w->buffer(first, n));
    for (int64_t i = 0; i < n * 20; ++i) buf[i] = offset + float(first * 20 + i);
    w->write(first, n);
  }
  w->commit();
}

TEST(StackWriter, FormatsByExtension) {
  EXPECT_EQ(stack_format("a.npy"), StackFormat::Npy);
  EXPECT_EQ(stack_format("a.nii.gz"), StackFormat::ItkImage);
  EXPECT_EQ(stack_format("a.NRRD"), StackFormat::ItkImage);
  EXPECT_EQ(stack_format("pngs"), StackFormat::PngDirectory);
  EXPECT_EQ(stack_format("pngs/"), StackFormat::PngDirectory);
  EXPECT_THROW(stack_format("a.jpg"), InputError);
}

TEST(StackWriter, NpyStreamsInChunksAndMhaHoldsGeometry) {
  test::TempDir dir;
  write_stack(dir.file("s.npy"), spec(5), 0);
  const NpyArray a = read_npy(dir.file("s.npy"));
  EXPECT_EQ(a.shape, (std::vector<int64_t>{5, 4, 5}));
  for (int i = 0; i < 100; ++i) ASSERT_EQ(static_cast<const float*>(a.data.get())[i], float(i));
  write_stack(dir.file("s.mha"), spec(5), 0);
  const Volume v = read_volume(dir.file("s.mha"));
  EXPECT_EQ(v.grid().dims, (std::array<int64_t, 3>{5, 4, 5}));
  EXPECT_EQ(v.grid().spacing_mm, (Vec3{0.25, 0.5, 1.0}));
  EXPECT_EQ(v.grid().origin_mm, (Vec3{0, 0, 0}));
  for (int i = 0; i < 100; ++i) ASSERT_EQ(v.data_as<float>()[i], float(i));
  EXPECT_EQ(stack_memory_bytes("s.npy", spec(1000), 10), 10u * 80u);
  EXPECT_EQ(stack_memory_bytes("s.nii", spec(1000), 10), 1000u * 80u);
}

TEST(StackWriter, PngDirectoryReplacedAtomically) {
  test::TempDir dir;
  const std::string out = dir.file("pngs");
  write_stack(out, spec(3), 0);
  EXPECT_TRUE(fs::exists(out + "/img_00002.png"));
  EXPECT_TRUE(fs::exists(out + "/poses.txt"));
  // A second, smaller run replaces the directory as a whole.
  write_stack(out, spec(1), 0);
  EXPECT_TRUE(fs::exists(out + "/img_00000.png"));
  EXPECT_FALSE(fs::exists(out + "/img_00002.png"));
  // An abandoned writer leaves the old directory and no temporary behind.
  {
    auto w = StackWriter::create(out, spec(4));
    w->buffer(0, 1);
    w->write(0, 1);
  }
  EXPECT_TRUE(fs::exists(out + "/img_00000.png"));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 1);
}

// PNGs come from libpng (ITK's 2-D writer crashed on a full disk): the same pixels and the pixel
// spacing (ITK's sCAL convention) come back through ITK's reader.
TEST(StackWriter, PngImagesReadBackWithTheirPixelsAndSpacing) {
  test::TempDir dir;
  StackSpec s = spec(2);
  s.window = std::make_pair(20.0, 40.0);  // [0, 40] → [0, 255]
  write_stack(dir.file("pngs"), s, 0);
  std::vector<float> values(20);
  for (int i = 0; i < 20; ++i) values[size_t(i)] = float(20 + i);  // image 1 of write_stack
  std::vector<uint8_t> expected(20);
  apply_window(values.data(), PixelType::Float32, 20, 20.0, 40.0, expected.data());
  const Volume v = read_volume(dir.file("pngs/img_00001.png"));
  EXPECT_EQ(v.pixel_type(), PixelType::UInt8);
  EXPECT_EQ(v.grid().dims, (std::array<int64_t, 3>{5, 4, 1}));
  EXPECT_NEAR(v.grid().spacing_mm[0], 0.25, 1e-9);
  EXPECT_NEAR(v.grid().spacing_mm[1], 0.5, 1e-9);
  for (int i = 0; i < 20; ++i) EXPECT_EQ(v.data_as<uint8_t>()[i], expected[size_t(i)]) << i;
  // Single images too, 16-bit included.
  std::vector<uint16_t> deep(6);
  for (int i = 0; i < 6; ++i) deep[size_t(i)] = uint16_t(1000 * i + 7);
  write_image(dir.file("deep.png"), deep.data(), PixelType::UInt16, {3, 2}, {0.1, 0.2});
  const Volume d = read_volume(dir.file("deep.png"));
  EXPECT_EQ(d.pixel_type(), PixelType::UInt16);
  EXPECT_EQ(d.grid().dims, (std::array<int64_t, 3>{3, 2, 1}));
  for (int i = 0; i < 6; ++i) EXPECT_EQ(d.data_as<uint16_t>()[i], deep[size_t(i)]) << i;
  EXPECT_THROW(write_image(dir.file("f.png"), values.data(), PixelType::Float32, {5, 4}, {1, 1}),
               InputError);
}

TEST(StackWriter, IncompleteNpyIsNeverCommitted) {
  test::TempDir dir;
  auto w = StackWriter::create(dir.file("s.npy"), spec(4));
  w->buffer(0, 2);
  w->write(0, 2);
  EXPECT_THROW(w->commit(), Error);
  w.reset();
  EXPECT_FALSE(fs::exists(dir.file("s.npy")));
  EXPECT_TRUE(fs::is_empty(dir.path()));
}

TEST(StackWriter, WindowsAndAutoWindow) {
  const float values[] = {-200, 0, 41, 240, 1000};
  uint8_t out[5];
  apply_window(values, PixelType::Float32, 5, 40, 400, out);  // [-160, 240] → [0, 255]
  EXPECT_EQ(out[0], 0);
  EXPECT_EQ(out[1], 102);  // 160/400·255 = 102
  EXPECT_EQ(out[2], 128);  // 201/400·255 = 128.1
  EXPECT_EQ(out[3], 255);
  EXPECT_EQ(out[4], 255);
  // The auto-window ignores pixels outside the mask and the extreme 0.5 % tails.
  std::vector<float> img(1000);
  std::vector<uint8_t> mask(1000, 1);
  for (int i = 0; i < 1000; ++i) img[size_t(i)] = float(i);
  img[0] = -1e6f;  // an outlier
  for (int i = 900; i < 1000; ++i) mask[size_t(i)] = 0;
  const auto w = auto_window(img.data(), PixelType::Float32, 1, 1000, mask.data());
  EXPECT_NEAR(w.first - w.second / 2, 5, 2);    // ≈ 0.5th percentile of 1..899
  EXPECT_NEAR(w.first + w.second / 2, 895, 2);  // ≈ 99.5th percentile
}

}  // namespace
}  // namespace sonoslice
