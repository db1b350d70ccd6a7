// Volumes in and out with their full geometry: NIfTI, MetaImage, NRRD, DICOM series, .npy.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <sstream>
#include <tuple>

#include <zlib.h>

#include <gdcmImageChangeTransferSyntax.h>
#include <gdcmImageReader.h>
#include <gdcmImageWriter.h>
#include <itkExtractImageFilter.h>
#include <itkGDCMImageIO.h>
#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkMetaDataObject.h>
#include <itkRGBPixel.h>

#include "../../src/io/TextParse.h"
#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace {

namespace fs = std::filesystem;

double field(const Vec3& p) {
  return std::round(20 * std::sin(p[0] * 0.3) + p[1] - 0.5 * p[2]);
}

void expect_same_geometry(const VolumeGrid& a, const VolumeGrid& b, double tol) {
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(a.dims[k], b.dims[k]);
    EXPECT_NEAR(a.spacing_mm[k], b.spacing_mm[k], tol);
    EXPECT_NEAR(a.origin_mm[k], b.origin_mm[k], tol);
    for (int j = 0; j < 3; ++j) EXPECT_NEAR(a.direction.m[k][j], b.direction.m[k][j], tol);
  }
}

template <typename T>
void expect_same_voxels(const Volume& a, const Volume& b) {
  ASSERT_EQ(a.pixel_type(), b.pixel_type());
  ASSERT_EQ(a.grid().voxel_count(), b.grid().voxel_count());
  const T* pa = a.data_as<T>();
  const T* pb = b.data_as<T>();
  for (int64_t i = 0; i < a.grid().voxel_count(); ++i) ASSERT_EQ(pa[i], pb[i]) << "voxel " << i;
}

std::string error_of(const std::string& path, const VolumeReadOptions& o = {}) {
  try {
    read_volume(path, o);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// The message of read_image_stack's error on `path` ("" when it reads).
std::string error_of_stack(const std::string& path) {
  try {
    read_image_stack(path, "--frames");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

class ItkRoundTrip : public ::testing::TestWithParam<std::string> {};

// Oblique geometry and native pixel types survive a write/read through each ITK format.
TEST_P(ItkRoundTrip, GeometryAndNativeTypes) {
  test::TempDir dir;
  const VolumeGrid grid = test::oblique_grid({17, 13, 11});
  const Volume i16 = test::make_volume<int16_t>(grid, field);
  const std::string path = dir.file("v" + GetParam());
  write_volume(path, i16);
  const Volume back = read_volume(path);
  EXPECT_EQ(back.pixel_type(), PixelType::Int16);
  // NIfTI stores geometry as float32 quaternions/matrices.
  expect_same_geometry(grid, back.grid(),
                       GetParam().find(".nii") != std::string::npos ? 1e-4 : 1e-9);
  expect_same_voxels<int16_t>(i16, back);
  for (PixelType t :
       {PixelType::UInt8, PixelType::UInt16, PixelType::Float32, PixelType::Float64}) {
    const Volume v = i16.converted(t);
    write_volume(path, v);  // replaces the previous file atomically
    const Volume r = read_volume(path);
    EXPECT_EQ(r.pixel_type(), t) << to_string(t);
    visit_pixel_type(t, [&](auto zero) { expect_same_voxels<decltype(zero)>(v, r); });
  }
}

INSTANTIATE_TEST_SUITE_P(Formats, ItkRoundTrip,
                         ::testing::Values(".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".nhdr"),
                         [](const auto& info) {
                           return info.param.substr(1) == "nii.gz" ? std::string("nii_gz")
                                                                   : info.param.substr(1);
                         });

// Writes `volume` as a DICOM series of 2-D slices with explicit position/orientation tags and a
// rescale (stored = (HU - intercept) / slope), the way scanners do.
// `slice_at[k]`, when given, is where slice k is placed along the third axis (in slices).
void write_dicom_series(const Volume& volume, const std::string& dir, const std::string& series_uid,
                        double slope, double intercept, const std::vector<double>& slice_at = {}) {
  using Image2 = itk::Image<int16_t, 2>;
  const VolumeGrid& g = volume.grid();
  for (int64_t k = 0; k < g.dims[2]; ++k) {
    auto slice = Image2::New();
    Image2::SizeType size;
    size[0] = itk::SizeValueType(g.dims[0]);
    size[1] = itk::SizeValueType(g.dims[1]);
    slice->SetRegions(Image2::RegionType(size));
    Image2::SpacingType sp;
    sp[0] = g.spacing_mm[0];
    sp[1] = g.spacing_mm[1];
    slice->SetSpacing(sp);
    slice->Allocate();
    std::memcpy(slice->GetBufferPointer(), volume.data_as<int16_t>() + k * g.dims[0] * g.dims[1],
                size_t(g.dims[0] * g.dims[1]) * sizeof(int16_t));
    auto& dict = slice->GetMetaDataDictionary();
    const Vec3 pos = g.index_to_world({0, 0, slice_at.empty() ? double(k) : slice_at[size_t(k)]});
    std::ostringstream ipp, iop, sp_str;
    ipp.precision(12);
    iop.precision(12);
    ipp << pos[0] << "\\" << pos[1] << "\\" << pos[2];
    iop << g.direction.m[0][0] << "\\" << g.direction.m[1][0] << "\\" << g.direction.m[2][0] << "\\"
        << g.direction.m[0][1] << "\\" << g.direction.m[1][1] << "\\" << g.direction.m[2][1];
    itk::EncapsulateMetaData<std::string>(dict, "0008|0060", "CT");
    itk::EncapsulateMetaData<std::string>(dict, "0020|000d", "1.2.826.0.1.3680043.2.1125.1");
    itk::EncapsulateMetaData<std::string>(dict, "0020|000e", series_uid);
    itk::EncapsulateMetaData<std::string>(dict, "0020|0013", std::to_string(k + 1));
    itk::EncapsulateMetaData<std::string>(dict, "0020|0032", ipp.str());
    itk::EncapsulateMetaData<std::string>(dict, "0020|0037", iop.str());
    itk::EncapsulateMetaData<std::string>(dict, "0028|1052", std::to_string(intercept));
    itk::EncapsulateMetaData<std::string>(dict, "0028|1053", std::to_string(slope));
    auto io = itk::GDCMImageIO::New();
    io->KeepOriginalUIDOn();
    auto writer = itk::ImageFileWriter<Image2>::New();
    writer->SetImageIO(io);
    writer->SetInput(slice);
    // Deliberately not in slice order: the reader must sort by position.
    writer->SetFileName(dir + "/" + series_uid.substr(series_uid.size() - 2) + "_" +
                        std::to_string((k * 7) % g.dims[2]) + ".dcm");
    writer->Update();
  }
}

TEST(DicomSeries, WrittenWithItkThenReadBack) {
  test::TempDir dir;
  VolumeGrid grid;
  grid.dims = {24, 20, 9};
  grid.spacing_mm = {0.7, 0.7, 2.5};
  grid.origin_mm = {-30.5, 12.0, 100.25};
  grid.direction = test::rotation({0.2, 1.0, 0.1}, 15.0);
  // CT values, even so that a slope of 2 stores them exactly.
  const Volume hu = test::make_volume<int16_t>(
      grid, [](const Vec3& p) { return 2 * std::round(200 * std::sin(p[0] * 0.2) + p[2]) - 1000; });
  write_dicom_series(hu, dir.path().string(), "1.2.826.0.1.3680043.2.1125.2.11", 2.0, -1024.0);
  // A second, smaller series in the same directory.
  VolumeGrid small = grid;
  small.dims[2] = 3;
  write_dicom_series(test::make_volume<int16_t>(small, [](const Vec3&) { return 0.0; }),
                     dir.path().string(), "1.2.826.0.1.3680043.2.1125.2.22", 1.0, 0.0);
  // What else lies in exported folders (a README, a Mac's .DS_Store, an empty marker) is passed
  // over, as GDCM does, rather than refused as a broken DICOM file.
  std::ofstream(dir.file("README.txt")) << "Exported by a PACS viewer\n";
  std::ofstream(dir.file(".DS_Store"), std::ios::binary) << std::string("\0\0\0\1Bud1\0\0", 10);
  std::ofstream(dir.file(".keep")).close();

  const auto series = list_dicom_series(dir.path().string());
  ASSERT_EQ(series.size(), 2u);
  const Volume back = read_volume(dir.path().string());  // the largest series by default
  expect_same_geometry(grid, back.grid(), 1e-4);
  // Rescale slope/intercept applied: values equal the HU written, whatever type GDCM picked.
  const auto range_in = hu.value_range(), range_out = back.value_range();
  EXPECT_EQ(range_in, range_out);
  visit_pixel_type(back.pixel_type(), [&](auto zero) {
    using T = decltype(zero);
    for (int64_t i = 0; i < grid.voxel_count(); ++i)
      ASSERT_EQ(double(back.data_as<T>()[i]), double(hu.data_as<int16_t>()[i])) << "voxel " << i;
  });
  // --series picks the other one; an unknown UID is named in the error.
  VolumeReadOptions o;
  o.series_uid = "1.2.826.0.1.3680043.2.1125.2.22";
  EXPECT_EQ(read_volume(dir.path().string(), o).grid().dims[2], 3);
  o.series_uid = "1.2.3";
  EXPECT_NE(error_of(dir.path().string(), o).find("no series '1.2.3'"), std::string::npos);
}

// A bad-input probe found this: a slice cut short was read with zeros, slices at one position were
// both used, and a missing slice stretched the spacing; each is now an error naming the series'
// files.
TEST(DicomSeries, BrokenSeriesAreRefused) {
  VolumeGrid grid;
  grid.dims = {16, 12, 6};
  grid.spacing_mm = {0.8, 0.8, 2.0};
  grid.origin_mm = {-5.0, 3.0, 40.0};
  const Volume hu = test::make_volume<int16_t>(grid, [](const Vec3& p) { return p[2] - p[0]; });
  const std::string uid = "1.2.826.0.1.3680043.2.1125.2.33";
  {
    // A missing slice: positions 0 1 2 4 5 6 (the gap is two spacings).
    test::TempDir dir;
    write_dicom_series(hu, dir.path().string(), uid, 1.0, 0.0, {0, 1, 2, 4, 5, 6});
    const std::string e = error_of(dir.path().string());
    EXPECT_NE(e.find("missing slice"), std::string::npos) << e;
    EXPECT_NE(e.find(dir.path().string()), std::string::npos) << e;
    EXPECT_NE(e.find(".dcm"), std::string::npos) << e;
    EXPECT_THROW(read_volume(dir.path().string()), InputError);
  }
  {
    // Two slices at one position.
    test::TempDir dir;
    write_dicom_series(hu, dir.path().string(), uid, 1.0, 0.0, {0, 1, 2, 2, 3, 4});
    const std::string e = error_of(dir.path().string());
    EXPECT_NE(e.find("same position"), std::string::npos) << e;
    EXPECT_NE(e.find(".dcm"), std::string::npos) << e;
  }
  {
    // A slice file cut short inside its pixel data.
    test::TempDir dir;
    write_dicom_series(hu, dir.path().string(), uid, 1.0, 0.0);
    const std::string victim = dir.file("33_3.dcm");
    ASSERT_TRUE(fs::exists(victim));
    fs::resize_file(victim, fs::file_size(victim) - 100);
    const std::string e = error_of(dir.path().string());
    EXPECT_NE(e.find("33_3.dcm"), std::string::npos) << e;
    EXPECT_NE(e.find("truncated"), std::string::npos) << e;
    EXPECT_THROW(read_volume(dir.path().string()), FileError);
  }
  {
    // Unevenly spaced slices (not a multiple of a spacing): refused too.
    test::TempDir dir;
    write_dicom_series(hu, dir.path().string(), uid, 1.0, 0.0, {0, 1, 2, 3, 4, 5.5});
    EXPECT_NE(error_of(dir.path().string()).find("spacing"), std::string::npos);
  }
}

// How a test clip's pixel data is stored: uncompressed, or encapsulated in fragments.
enum class ClipCompression { None, JpegLossless, JpegLs };

// Writes `frames` (W x H x N, T = uint8_t or itk::RGBPixel<uint8_t>) as one multi-frame DICOM
// file, as an ultrasound scanner stores a clip.
template <typename T>
void write_dicom_clip(const std::string& path, int w, int h, int n,
                      const std::function<T(int, int, int)>& value,
                      ClipCompression compression = ClipCompression::None,
                      const std::string& instance_number = "") {
  using Image = itk::Image<T, 3>;
  auto image = Image::New();
  typename Image::SizeType size;
  size[0] = itk::SizeValueType(w);
  size[1] = itk::SizeValueType(h);
  size[2] = itk::SizeValueType(n);
  image->SetRegions(typename Image::RegionType(size));
  image->Allocate();
  for (int k = 0; k < n; ++k)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) image->SetPixel({{x, y, k}}, value(x, y, k));
  itk::EncapsulateMetaData<std::string>(image->GetMetaDataDictionary(), "0008|0060", "US");
  if (!instance_number.empty())
    itk::EncapsulateMetaData<std::string>(image->GetMetaDataDictionary(), "0020|0013",
                                          instance_number);
  auto io = itk::GDCMImageIO::New();
  auto writer = itk::ImageFileWriter<Image>::New();
  if (compression == ClipCompression::JpegLossless) {
    writer->UseCompressionOn();
  }
  writer->SetImageIO(io);
  writer->SetInput(image);
  writer->SetFileName(path);
  writer->Update();
  // ITK does not write JPEG-LS: GDCM converts the file, as `gdcmconv --jpegls` does.
  if (compression == ClipCompression::JpegLs) {
    gdcm::ImageReader reader;
    reader.SetFileName(path.c_str());
    ASSERT_TRUE(reader.Read()) << path;
    gdcm::ImageChangeTransferSyntax change;
    change.SetTransferSyntax(gdcm::TransferSyntax::JPEGLSLossless);
    change.SetInput(reader.GetImage());
    ASSERT_TRUE(change.Change()) << path;
    gdcm::ImageWriter writer_ls;
    writer_ls.SetFileName(path.c_str());
    writer_ls.SetFile(reader.GetFile());
    writer_ls.SetImage(change.GetOutput());
    ASSERT_TRUE(writer_ls.Write()) << path;
  }
}

// Writes a 12 x 10 clip of two uint8 frames as `dir`/clip.dcm and returns its bytes, for the
// tests that change some of them.
std::string dicom_clip_bytes(const test::TempDir& dir,
                             const std::function<uint8_t(int, int, int)>& value) {
  write_dicom_clip<uint8_t>(dir.file("clip.dcm"), 12, 10, 2, value);
  std::ifstream in(dir.file("clip.dcm"), std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A recorded clip is one DICOM file of N frames: read as a stack of N frames (colour ones as their
// first component, as every frame reader does); truncated pixel data is refused, not read as
// zeros; sonoslice does not write DICOM.
TEST(DicomFile, MultiFrameClipIsAStackOfFrames) {
  test::TempDir dir;
  const auto grey = [](int x, int y, int k) { return uint8_t((x * 7 + y * 3 + k * 50) % 256); };
  write_dicom_clip<uint8_t>(dir.file("clip.dcm"), 30, 20, 4, grey);
  const Volume clip = read_image_stack(dir.file("clip.dcm"), "--frames");
  ASSERT_EQ(clip.pixel_type(), PixelType::UInt8);
  ASSERT_EQ(clip.grid().dims, (std::array<int64_t, 3>{30, 20, 4}));
  for (int k = 0; k < 4; ++k)
    for (int y = 0; y < 20; ++y)
      for (int x = 0; x < 30; ++x)
        ASSERT_EQ(clip.data_as<uint8_t>()[(k * 20 + y) * 30 + x], grey(x, y, k));
  using Rgb = itk::RGBPixel<uint8_t>;
  write_dicom_clip<Rgb>(dir.file("colour.dcm"), 30, 20, 3, [&](int x, int y, int k) {
    Rgb p;
    p[0] = grey(x, y, k);
    p[1] = p[2] = uint8_t(x < 5 ? 255 : p[0]);  // a coloured overlay on the left
    return p;
  });
  const Volume colour = read_image_stack(dir.file("colour.dcm"), "--frames");
  ASSERT_EQ(colour.grid().dims, (std::array<int64_t, 3>{30, 20, 3}));
  EXPECT_EQ(colour.data_as<uint8_t>()[(2 * 20 + 7) * 30 + 11], grey(11, 7, 2));
  // Cut short inside the pixel data.
  fs::copy_file(dir.file("clip.dcm"), dir.file("short.dcm"));
  fs::resize_file(dir.file("short.dcm"), fs::file_size(dir.file("short.dcm")) - 700);
  // Named as the caller names the frames, not as a volume.
  const std::string shortened = error_of_stack(dir.file("short.dcm"));
  EXPECT_EQ(shortened.find("cannot read --frames '" + dir.file("short.dcm") +
                           "': truncated or corrupt file"),
            0u)
      << shortened;
  try {
    write_volume(dir.file("out.dcm"), clip);
    ADD_FAILURE() << "a DICOM file was written";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("sonoslice reads DICOM but does not write it"),
              std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(dir.file("out.dcm")));
  EXPECT_THROW(stack_format(dir.file("stack.dcm")), InputError);
  // Compressed frames: the same pixels; cut inside a fragment: refused, not decoded short.
  write_dicom_clip<uint8_t>(dir.file("jpeg.dcm"), 30, 20, 4, grey, ClipCompression::JpegLossless);
  const Volume jpeg = read_image_stack(dir.file("jpeg.dcm"), "--frames");
  ASSERT_EQ(jpeg.grid().dims, clip.grid().dims);
  EXPECT_EQ(std::memcmp(jpeg.data(), clip.data(), clip.byte_size()), 0);
  fs::resize_file(dir.file("jpeg.dcm"), fs::file_size(dir.file("jpeg.dcm")) - 100);
  EXPECT_NE(error_of_stack(dir.file("jpeg.dcm")).find("jpeg.dcm': truncated file"),
            std::string::npos);
}

// A folder of single-frame DICOM images (some scanners export a clip so) is a stack of frames in
// name order, as a folder of PNGs; broken files are refused naming them.
TEST(DicomFile, FolderOfSingleFrameImagesIsAStackOfFrames) {
  test::TempDir dir;
  const auto grey = [](int x, int y, int k) { return uint8_t(3 * x + y + 7 * k); };
  for (int k = 0; k < 3; ++k)
    write_dicom_clip<uint8_t>(dir.file("IM_000" + std::to_string(k) + ".dcm"), 12, 10, 1,
                              [&](int x, int y, int) { return grey(x, y, k); });
  const Volume frames = read_image_stack(dir.path().string(), "--frames");
  ASSERT_EQ(frames.grid().dims, (std::array<int64_t, 3>{12, 10, 3}));
  EXPECT_EQ(frames.data_as<uint8_t>()[(2 * 10 + 4) * 12 + 5], grey(5, 4, 2));
  // A clip among them, a PNG among them, a broken file among them: refused, naming the file.
  write_dicom_clip<uint8_t>(dir.file("IM_0003.dcm"), 12, 10, 2, grey);
  EXPECT_NE(error_of_stack(dir.path().string()).find("IM_0003.dcm': 2 frames in one file"),
            std::string::npos)
      << error_of_stack(dir.path().string());
  fs::remove(dir.file("IM_0003.dcm"));
  const std::vector<uint8_t> pixels(12 * 10, 7);
  write_image(dir.file("IM_0004.png"), pixels.data(), PixelType::UInt8, {12, 10}, {1, 1}, 1);
  EXPECT_NE(error_of_stack(dir.path().string()).find("a folder of both .png and .dcm images"),
            std::string::npos);
  fs::remove(dir.file("IM_0004.png"));
  fs::resize_file(dir.file("IM_0001.dcm"), fs::file_size(dir.file("IM_0001.dcm")) - 50);
  EXPECT_NE(error_of_stack(dir.path().string())
                .find("cannot read --frames '" + dir.file("IM_0001.dcm") + "': truncated"),
            std::string::npos)
      << error_of_stack(dir.path().string());
}

// A folder's frames come in natural name order (an unpadded numbering keeps its order), single-
// frame DICOM images in InstanceNumber order when each has its own.
TEST(FrameFolder, FramesComeInNaturalNameOrderOrByInstanceNumber) {
  EXPECT_TRUE(text::natural_less("frame2.png", "frame10.png"));
  EXPECT_FALSE(text::natural_less("frame10.png", "frame2.png"));
  EXPECT_TRUE(text::natural_less("a9b", "a10a"));
  EXPECT_TRUE(text::natural_less("img_007.png", "img_7.png"));  // equal numbers: byte order
  EXPECT_FALSE(text::natural_less("img_7.png", "img_007.png"));
  EXPECT_TRUE(text::natural_less("x", "x1"));
  EXPECT_TRUE(text::natural_less("IM_0009.dcm", "IM_0010.dcm"));
  EXPECT_TRUE(text::natural_less("f99999999999999999999999", "f100000000000000000000000"));
  EXPECT_FALSE(text::natural_less("same", "same"));
  {
    test::TempDir dir;  // frame1.png ... frame12.png, pixel value = frame number
    for (int k = 1; k <= 12; ++k) {
      const std::vector<uint8_t> pixels(6 * 4, uint8_t(k));
      write_image(dir.file("frame" + std::to_string(k) + ".png"), pixels.data(), PixelType::UInt8,
                  {6, 4}, {1, 1}, 1);
    }
    const Volume frames = read_image_stack(dir.path().string(), "--frames");
    ASSERT_EQ(frames.grid().dims[2], 12);
    for (int k = 0; k < 12; ++k) EXPECT_EQ(frames.data_as<uint8_t>()[k * 24], k + 1) << k;
  }
  test::TempDir dir;  // names in one order, instance numbers in the other
  const auto grey = [](int x, int y, int k) { return uint8_t(3 * x + y + 40 * k); };
  for (int k = 0; k < 4; ++k)
    write_dicom_clip<uint8_t>(
        dir.file("IM" + std::to_string(k) + ".dcm"), 12, 10, 1,
        [&](int x, int y, int) { return grey(x, y, k); }, ClipCompression::None,
        std::to_string(10 - k));
  const Volume frames = read_image_stack(dir.path().string(), "--frames");
  ASSERT_EQ(frames.grid().dims[2], 4);
  for (int k = 0; k < 4; ++k)
    EXPECT_EQ(frames.data_as<uint8_t>()[(k * 10 + 4) * 12 + 5], grey(5, 4, 3 - k)) << k;
  // Two images of one number: not an order, so names decide.
  write_dicom_clip<uint8_t>(
      dir.file("IM4.dcm"), 12, 10, 1, [&](int x, int y, int) { return grey(x, y, 4); },
      ClipCompression::None, "7");
  const Volume by_name = read_image_stack(dir.path().string(), "--frames");
  ASSERT_EQ(by_name.grid().dims[2], 5);
  for (int k = 0; k < 5; ++k)
    EXPECT_EQ(by_name.data_as<uint8_t>()[(k * 10 + 4) * 12 + 5], grey(5, 4, k)) << k;
}

// GDCM asserts (aborting the process) on broken DICOM structure; sonoslice walks the file first
// and refuses it, for one file and for a folder of a series alike.
TEST(DicomFile, BrokenStructureIsRefusedBeforeGdcmReadsIt) {
  test::TempDir dir;
  const std::string good =
      dicom_clip_bytes(dir, [](int x, int y, int k) { return uint8_t(x + y + k); });
  const auto corrupted = [&](const std::string& name, const std::string& element,
                             const std::string& replacement) {
    std::string bytes = good;
    const size_t at = bytes.find(element);
    EXPECT_NE(at, std::string::npos) << name;
    bytes.replace(at, replacement.size(), replacement);
    std::ofstream(dir.file(name), std::ios::binary) << bytes;
    return dir.file(name);
  };
  // The transfer syntax's length (file meta group) beyond the end of the file.
  const std::string syntax("\x02\x00\x10\x00UI", 6);
  const std::string meta = corrupted("meta.dcm", syntax, syntax + std::string("\xf0\xff", 2));
  EXPECT_NE(error_of_stack(meta).find("meta.dcm': truncated or corrupt file (element (0002,0010)"),
            std::string::npos)
      << error_of_stack(meta);
  // ITK writes implicit VR little endian: tag, 32-bit length, value.
  // Samples per pixel 2.
  const std::string samples("\x28\x00\x02\x00\x02\x00\x00\x00", 8);
  const std::string two = corrupted("samples.dcm", samples, samples + std::string("\x02\x00", 2));
  EXPECT_NE(error_of_stack(two).find("samples per pixel 2"), std::string::npos)
      << error_of_stack(two);
  // Given twice, first 5 then 1: GDCM keeps the first (and asserted on it), so the walk does.
  std::string twice = good;
  twice.insert(twice.find(samples), samples + std::string("\x05\x00", 2));
  std::ofstream(dir.file("twice.dcm"), std::ios::binary) << twice;
  EXPECT_NE(error_of_stack(dir.file("twice.dcm")).find("samples per pixel 5"), std::string::npos)
      << error_of_stack(dir.file("twice.dcm"));
  // No frames (GDCM sized the pixels by the count, and its decoder asserted).
  const std::string frames("\x28\x00\x08\x00\x02\x00\x00\x00", 8);
  const std::string none = corrupted("frames.dcm", frames + "2", frames + "0");
  EXPECT_NE(error_of_stack(none).find("its number of frames (0028,0008) is not a count"),
            std::string::npos)
      << error_of_stack(none);
  // A length past the end of the file.
  const std::string columns("\x28\x00\x11\x00", 4);
  const std::string length =
      corrupted("length.dcm", columns, columns + std::string("\xf0\xff\xff\x00", 4));
  EXPECT_NE(error_of_stack(length).find("element (0028,0011) needs"), std::string::npos)
      << error_of_stack(length);
  // The ultrasound region without its vertical delta (GDCM asserts reading the spacing).
  const std::string delta = corrupted("delta.dcm", std::string("\x18\x00\x2e\x60\x08\x00", 6),
                                      std::string("\x18\x00\x2e\xef", 4));
  EXPECT_NE(error_of_stack(delta).find("lacks the physical delta (0018,602E)"), std::string::npos)
      << error_of_stack(delta);
  // A palette image, its photometric interpretation cut short as GDCM still takes it (GDCM
  // aborted on the missing lookup tables): refused, palettes are not read.
  const std::string palette = corrupted("palette.dcm", "MONOCHROME2 ", "PALETTE COLO");
  EXPECT_NE(error_of_stack(palette).find("palette.dcm': PALETTE COLOR images are not supported"),
            std::string::npos)
      << error_of_stack(palette);
  // A folder holding one such file: every series read is refused, naming it.
  test::TempDir folder;
  fs::copy_file(meta, folder.file("broken.dcm"));
  EXPECT_NE(error_of(folder.path().string()).find("file 'broken.dcm': truncated or corrupt"),
            std::string::npos);
  // A file shorter than one element's header that starts as one (the file meta group's first
  // tag): GDCM's series scan asserted on it; it is walked and named like the others.
  test::TempDir short_folder;
  std::ofstream(short_folder.file("short.dcm"), std::ios::binary)
      << std::string("\x02\x00\x00\x00\x41", 5);
  EXPECT_NE(error_of(short_folder.path().string())
                .find("file 'short.dcm': truncated file (shorter than one element)"),
            std::string::npos)
      << error_of(short_folder.path().string());
}

// GDCM's decoders abort the process on a photometric interpretation they do not convert (or
// none they know) and read past the pixels' end, or abort, for a colour one of one sample per
// pixel: such images are refused, named, alone or in a folder, uncompressed or compressed.
// Names are matched as GDCM matches them.
TEST(DicomFile, PhotometricInterpretationsGdcmCannotDecodeAreRefused) {
  test::TempDir dir;
  const auto grey = [](int x, int y, int k) { return uint8_t(3 * x + y + 7 * k); };
  const std::string good = dicom_clip_bytes(dir, grey);
  const auto with = [&](const std::string& name, const std::string& photometric,
                        const std::string& from = "") {
    std::string bytes = from.empty() ? good : from;
    const size_t at = bytes.find("MONOCHROME2 ");
    EXPECT_NE(at, std::string::npos);
    bytes.replace(at, photometric.size(), photometric);
    std::ofstream(dir.file(name), std::ios::binary) << bytes;
    return dir.file(name);
  };
  const std::string ict = error_of_stack(with("ict.dcm", "YBR_ICT     "));
  EXPECT_NE(ict.find("ict.dcm': photometric interpretation 'YBR_ICT' is not supported in "
                     "uncompressed pixel data"),
            std::string::npos)
      << ict;
  const std::string blank = error_of_stack(with("blank.dcm", "            "));
  EXPECT_NE(blank.find("blank.dcm': an empty photometric interpretation is not supported"),
            std::string::npos)
      << blank;
  const std::string rgb = error_of_stack(with("rgb.dcm", "RGB         "));
  EXPECT_NE(rgb.find("rgb.dcm': corrupt file (photometric interpretation 'RGB' with 1 sample "
                     "per pixel"),
            std::string::npos)
      << rgb;
  // MONOCHROME1, and a name cut short that GDCM takes for it, read.
  for (const char* name : {"MONOCHROME1 ", "MONOCHROME  "}) {
    const Volume frames = read_image_stack(with("mono1.dcm", name), "--frames");
    EXPECT_EQ(frames.grid().dims[2], 2) << name;
  }
  // JPEG-LS: GDCM's decoder aborted on HSV, and on YBR_ICT for one sample per pixel.
  write_dicom_clip<uint8_t>(dir.file("jls.dcm"), 12, 10, 2, grey, ClipCompression::JpegLs);
  std::ifstream jls_in(dir.file("jls.dcm"), std::ios::binary);
  const std::string jls((std::istreambuf_iterator<char>(jls_in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(read_image_stack(dir.file("jls.dcm"), "--frames").data_as<uint8_t>()[(10 + 4) * 12 + 5],
            grey(5, 4, 1));
  const std::string hsv = error_of_stack(with("hsv.dcm", "HSV         ", jls));
  EXPECT_NE(hsv.find("hsv.dcm': photometric interpretation 'HSV' is not supported in compressed "
                     "pixel data"),
            std::string::npos)
      << hsv;
  const std::string jls_ict = error_of_stack(with("jls-ict.dcm", "YBR_ICT     ", jls));
  EXPECT_NE(jls_ict.find("jls-ict.dcm': corrupt file (photometric interpretation 'YBR_ICT' with 1 "
                         "sample per pixel"),
            std::string::npos)
      << jls_ict;
  // In a series' folder GDCM decoded it without the check ITK's reader makes of a single file.
  test::TempDir folder;
  fs::copy_file(dir.file("ict.dcm"), folder.file("slice.dcm"));
  const std::string in_folder = error_of(folder.path().string());
  EXPECT_NE(in_folder.find("file 'slice.dcm': photometric interpretation 'YBR_ICT'"),
            std::string::npos)
      << in_folder;
}

// GDCM reads what follows the pixel data, and files without the 128-byte preamble and "DICM":
// both are walked first too.
TEST(DicomFile, TailAndFilesWithoutPreambleAreWalked) {
  test::TempDir dir;
  const auto grey = [](int x, int y, int k) { return uint8_t(3 * x + y + 7 * k); };
  const std::string good = dicom_clip_bytes(dir, grey);
  const auto written = [&](const std::string& name, const std::string& bytes) {
    std::ofstream(dir.file(name), std::ios::binary) << bytes;
    return dir.file(name);
  };
  // Zero padding after the pixel data reads; an element cut short there (GDCM asserted) does not.
  const Volume padded = read_image_stack(written("padded.dcm", good + std::string(16, '\0')), "f");
  EXPECT_EQ(padded.data_as<uint8_t>()[(10 + 4) * 12 + 5], grey(5, 4, 1));
  const std::string cut =
      error_of_stack(written("cut.dcm", good + std::string("\x10\x00\x10\x00", 4)));
  EXPECT_NE(cut.find("cut.dcm': truncated file (it ends inside an element's header"),
            std::string::npos)
      << cut;
  // Without the preamble: ITK's reader does not take it as an image (GDCM's series scan does);
  // with its file meta group cut short, the walk refuses it before GDCM reads it.
  const std::string raw = error_of_stack(written("raw.dcm", good.substr(132)));
  EXPECT_NE(raw.find("raw.dcm': not a readable image format"), std::string::npos) << raw;
  const std::string meta = error_of_stack(written("raw-meta.dcm", good.substr(132, 20)));
  EXPECT_NE(
      meta.find("raw-meta.dcm': truncated file (it ends inside an element's header at byte 12)"),
      std::string::npos)
      << meta;
  const std::string text = error_of_stack(written("text.dcm", "not DICOM at all, just text"));
  EXPECT_NE(text.find("text.dcm': not a DICOM file"), std::string::npos) << text;
}

// libpng aborts the process on a corrupt PNG header unless its caller catches the error (ITK's
// PNG reader does not): frames in a folder and PNG images are read through sonoslice's libpng
// code, which names the file.
TEST(PngFile, CorruptImagesInAFolderAreNamed) {
  test::TempDir dir;
  const std::vector<uint8_t> pixels(12 * 10, 7);
  for (const char* name : {"a.png", "b.png"})
    write_image(dir.file(name), pixels.data(), PixelType::UInt8, {12, 10}, {0.5, 0.5});
  EXPECT_EQ(read_image_stack(dir.path().string(), "--frames").grid().dims,
            (std::array<int64_t, 3>{12, 10, 2}));
  EXPECT_DOUBLE_EQ(read_volume(dir.file("a.png")).grid().spacing_mm[0], 0.5);  // sCAL, as ITK
  std::fstream f(dir.file("b.png"), std::ios::binary | std::ios::in | std::ios::out);
  f.seekp(29);  // IHDR's CRC
  f.write("\xde\xad", 2);
  f.close();
  EXPECT_NE(error_of_stack(dir.path().string()).find("b.png': corrupt PNG (IHDR: CRC error)"),
            std::string::npos);
  // A header that claims 30000 x 30000 pixels in a file of a hundred bytes (a valid CRC): refused
  // before 900 MB are allocated for it.
  std::ifstream in(dir.file("a.png"), std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const char claim[8] = {0, 0, 0x75, 0x30, 0, 0, 0x75, 0x30};
  bytes.replace(16, 8, claim, 8);
  uint32_t crc = 0xffffffffu;  // CRC-32 of the chunk type and data (ISO 3309, as PNG uses)
  for (size_t i = 12; i < 29; ++i) {
    crc ^= uint8_t(bytes[i]);
    for (int k = 0; k < 8; ++k) crc = crc & 1 ? 0xedb88320u ^ (crc >> 1) : crc >> 1;
  }
  crc ^= 0xffffffffu;
  for (int k = 0; k < 4; ++k) bytes[29 + k] = char(crc >> (24 - 8 * k));
  std::ofstream(dir.file("b.png"), std::ios::binary) << bytes;
  EXPECT_NE(error_of_stack(dir.path().string())
                .find("b.png': corrupt PNG (its header claims more pixels than its bytes"),
            std::string::npos)
      << error_of_stack(dir.path().string());
}

// A NIfTI with scl_slope/scl_inter: ITK applies them (as float32), sonoslice's own voxel path
// steps aside for it.
TEST(VolumeFile, NiftiRescaleSlopeAndIntercept) {
  test::TempDir dir;
  VolumeGrid grid;
  grid.dims = {6, 5, 4};
  const Volume v =
      test::make_volume<int16_t>(grid, [](const Vec3& p) { return p[0] + 10 * p[1] + 100 * p[2]; });
  write_volume(dir.file("s.nii"), v);
  std::fstream f(dir.file("s.nii"), std::ios::in | std::ios::out | std::ios::binary);
  const float slope = 2.0f, inter = -5.0f;
  f.seekp(112);
  f.write(reinterpret_cast<const char*>(&slope), 4);
  f.write(reinterpret_cast<const char*>(&inter), 4);
  f.close();
  const Volume r = read_volume(dir.file("s.nii"));
  ASSERT_EQ(r.pixel_type(), PixelType::Float32);
  for (int64_t i = 0; i < grid.voxel_count(); ++i)
    ASSERT_EQ(r.data_as<float>()[i], 2.0f * v.data_as<int16_t>()[i] - 5.0f) << i;
}

// Overwrites `bytes` at `offset` of `path` (a header field).
void patch(const std::string& path, std::streamoff offset, const void* bytes, size_t n) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(offset);
  f.write(static_cast<const char*>(bytes), std::streamsize(n));
}
void patch_float(const std::string& path, std::streamoff offset, float v) {
  patch(path, offset, &v, sizeof v);
}
void patch_int16(const std::string& path, std::streamoff offset, int16_t v) {
  patch(path, offset, &v, sizeof v);
}

// The error of reading `path`, with what the libraries print to stderr meanwhile (nothing
// allowed: sonoslice's one line is the error).
std::string quiet_error_of(const std::string& path) {
  ::testing::internal::CaptureStderr();
  const std::string e = error_of(path);
  const std::string printed = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(printed, "") << "while reading " << path;
  return e;
}

// A bad-input probe found this: NIfTI pixdim 0 or NaN became 1 mm; a NaN scl_slope with an
// intercept was applied as a slope of 1; a NaN in the sform aborted the process in ITK's matrix
// code; a bad dimension printed a line from the NIfTI C library before the error.
TEST(VolumeFile, NiftiHeaderIsCheckedBeforeItk) {
  test::TempDir dir;
  VolumeGrid grid;
  grid.dims = {6, 5, 4};
  grid.spacing_mm = {0.5, 0.75, 2.0};
  const Volume v = test::make_volume<int16_t>(grid, [](const Vec3& p) { return p[0] + p[2]; });
  const std::string good = dir.file("good.nii");
  write_volume(good, v);
  auto variant = [&](const std::string& name) {
    fs::copy_file(good, dir.file(name), fs::copy_options::overwrite_existing);
    return dir.file(name);
  };
  const float nan = std::nanf("");
  // pixdim[1..3] at byte 80, 84, 88.
  for (const auto& [offset, value, needle] :
       std::vector<std::tuple<int, float, std::string>>{{80, 0.0f, "pixdim[1] is 0"},
                                                        {84, nan, "pixdim[2] is nan"},
                                                        {88, -2.0f, "pixdim[3] is -2"}}) {
    const std::string p = variant("pixdim.nii");
    patch_float(p, offset, value);
    const std::string e = quiet_error_of(p);
    EXPECT_NE(e.find(needle), std::string::npos) << e;
    EXPECT_NE(e.find(p), std::string::npos) << e;
    EXPECT_THROW(read_volume(p), InputError);
  }
  // scl_slope (112) and scl_inter (116).
  std::string p = variant("scl.nii");
  patch_float(p, 112, nan);
  patch_float(p, 116, 5.0f);
  EXPECT_NE(quiet_error_of(p).find("scl_slope is nan with scl_inter 5"), std::string::npos);
  patch_float(p, 112, 0.0f);
  EXPECT_NE(quiet_error_of(p).find("scl_slope is 0 (no scaling) but scl_inter is 5"),
            std::string::npos);
  patch_float(p, 112, 2.0f);
  patch_float(p, 116, nan);
  EXPECT_NE(quiet_error_of(p).find("scl_inter is nan"), std::string::npos);
  patch_float(p, 116, 5.0f);
  EXPECT_EQ(read_volume(p).pixel_type(), PixelType::Float32);  // a valid rescale still reads
  // A NaN in the sform (srow_x[0] at 280) with sform_code 1, in the quaternion with qform_code 1.
  p = variant("sform.nii");
  patch_int16(p, 254, 1);
  patch_float(p, 280, nan);
  EXPECT_NE(quiet_error_of(p).find("srow_x[0] is not a finite number"), std::string::npos);
  // A value near FLT_MAX made ITK's orientation SVD loop without end (found by fuzz_nifti).
  patch_float(p, 280, 1.0f);
  patch_float(p, 288, -1.7e38f);
  EXPECT_NE(quiet_error_of(p).find("srow_x[2] is -1.7e+38: beyond any scanner's extent"),
            std::string::npos)
      << quiet_error_of(p);
  p = variant("qform.nii");
  patch_int16(p, 252, 1);
  patch_float(p, 268, nan);
  EXPECT_NE(quiet_error_of(p).find("qoffset_x is not a finite number"), std::string::npos);
  // vox_offset (108) infinite, NaN or beyond any file: converting it was undefined behaviour
  // (found by fuzz_nifti).
  for (float bad : {std::numeric_limits<float>::infinity(), nan, 3.0e38f, -1.0f}) {
    p = variant("vox_offset.nii");
    patch_float(p, 108, bad);
    const std::string e = quiet_error_of(p);
    EXPECT_NE(e.find("corrupt header: vox_offset is"), std::string::npos) << e;
    EXPECT_THROW(read_volume(p), FileError);
  }
  // Sizes the file cannot hold, in an Analyze header too (found by fuzz_nifti: a 373-byte file
  // made ITK allocate 6 GB), and in a gzip stream (at most 1032 bytes per compressed byte).
  for (const bool analyze : {true, false}) {
    p = variant("huge.nii");
    for (int d = 1; d <= 3; ++d) patch_int16(p, 40 + 2 * d, 30000);
    if (analyze) patch(p, 344, "xx1", 4);
    std::string e = quiet_error_of(p);
    EXPECT_NE(e.find("the header describes 54000000000352"), std::string::npos) << e;
    const std::string bytes = test::read_file_bytes(p);
    const std::string gz = dir.file("huge.nii.gz");
    gzFile f = gzopen(gz.c_str(), "wb");
    gzwrite(f, bytes.data(), unsigned(bytes.size()));
    gzclose(f);
    e = quiet_error_of(gz);
    EXPECT_NE(e.find("compressed bytes cannot hold the 54000000000000 voxel bytes"),
              std::string::npos)
        << e;
  }
  // Corrupt dimensions and data type: FileErrors, and the C library says nothing.
  p = variant("dim.nii");
  patch_int16(p, 42, 0);
  EXPECT_NE(quiet_error_of(p).find("dim[1] is 0"), std::string::npos);
  patch_int16(p, 40, 9);
  EXPECT_NE(quiet_error_of(p).find("dim[0] is 9"), std::string::npos);
  EXPECT_THROW(read_volume(p), FileError);
  p = variant("type.nii");
  patch_int16(p, 70, 999);
  EXPECT_NE(quiet_error_of(p).find("datatype 999"), std::string::npos);
  // Sizes whose byte count overflows (dim[1..3] = 32767, dim[4..7] = 32767: 2^105 bytes).
  p = variant("huge.nii");
  patch_int16(p, 40, 7);
  for (int i = 1; i <= 7; ++i) patch_int16(p, 40 + 2 * i, 32767);
  EXPECT_NE(quiet_error_of(p).find("sizes overflow"), std::string::npos);
  // A rescaled (so ITK-read) uncompressed file cut short: ITK's reader zero-filled it.
  p = variant("short.nii");
  patch_float(p, 112, 2.0f);
  fs::resize_file(p, fs::file_size(p) - 20);
  EXPECT_NE(quiet_error_of(p).find("truncated"), std::string::npos);
  // A .hdr/.img pair (vox_offset 0 in the .img): sonoslice's own voxel path mapped the .hdr as
  // if it held the voxels after byte 352, and failed with "truncated".
  {
    std::ifstream in(good, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::string header = bytes.substr(0, 348);
    const float zero_offset = 0.0f;
    std::memcpy(&header[108], &zero_offset, 4);
    header.replace(344, 4, std::string("ni1\0", 4));
    std::ofstream(dir.file("pair.hdr"), std::ios::binary) << header;
    std::ofstream(dir.file("pair.img"), std::ios::binary) << bytes.substr(352);
    for (const char* name : {"pair.hdr", "pair.img"}) {
      const Volume r = read_volume(dir.file(name));
      EXPECT_EQ(r.grid().spacing_mm, grid.spacing_mm) << name;
      expect_same_voxels<int16_t>(v, r);
    }
    fs::resize_file(dir.file("pair.img"), 100);
    EXPECT_NE(quiet_error_of(dir.file("pair.hdr")).find("'" + dir.file("pair.img") + "' has 100"),
              std::string::npos);
  }
  // The same checks through .nii.gz.
  write_volume(dir.file("z.nii.gz"), v);
  EXPECT_EQ(read_volume(dir.file("z.nii.gz")).grid().spacing_mm, grid.spacing_mm);
}

// A bad-input probe found this: a MetaImage "ElementSpacing = nan 1 1" printed MetaIO's complaints,
// then "No such file or directory" for a file that exists; negative and huge sizes reached ITK's
// allocator; a NaN NRRD spacing became 1 mm.
TEST(VolumeFile, MetaImageAndNrrdHeadersNameTheField) {
  test::TempDir dir;
  const std::string voxels(64, '\1');
  auto mha = [&](const std::string& name, const std::string& fields) {
    std::ofstream(dir.file(name), std::ios::binary)
        << "ObjectType = Image\nNDims = 3\n"
        << fields << "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n"
        << voxels;
    return dir.file(name);
  };
  EXPECT_EQ(read_volume(mha("ok.mha", "DimSize = 4 4 4\n")).grid().dims[0], 4);
  std::string e = quiet_error_of(mha("nan.mha", "DimSize = 4 4 4\nElementSpacing = nan 1 1\n"));
  EXPECT_NE(e.find("ElementSpacing 'nan 1 1'"), std::string::npos) << e;
  EXPECT_EQ(e.find("No such file"), std::string::npos) << e;
  EXPECT_THROW(read_volume(dir.file("nan.mha")), InputError);
  e = quiet_error_of(mha("zero.mha", "DimSize = 4 4 4\nElementSpacing = 0 1 1\n"));
  EXPECT_NE(e.find("ElementSpacing '0 1 1'"), std::string::npos) << e;
  e = quiet_error_of(mha("neg.mha", "DimSize = -5 4 4\n"));
  EXPECT_NE(e.find("DimSize '-5 4 4' is not a list of sizes"), std::string::npos) << e;
  e = quiet_error_of(mha("big.mha", "DimSize = -9223372036854775807 1 1\n"));
  EXPECT_NE(e.find("DimSize"), std::string::npos) << e;
  e = quiet_error_of(mha("huge.mha", "DimSize = 4294967296 4294967296 1\n"));
  EXPECT_NE(e.find("DimSize"), std::string::npos) << e;
  e = quiet_error_of(mha("origin.mha", "DimSize = 4 4 4\nOffset = 0 inf 0\n"));
  EXPECT_NE(e.find("offset '0 inf 0'"), std::string::npos) << e;
  // A detached header whose data file is missing: named, not "No such file" about the header.
  std::ofstream(dir.file("d.mhd")) << "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\n"
                                      "ElementType = MET_UCHAR\nElementDataFile = d.raw\n";
  e = quiet_error_of(dir.file("d.mhd"));
  EXPECT_NE(e.find("data file '" + dir.file("d.raw") + "'"), std::string::npos) << e;
  EXPECT_THROW(read_volume(dir.file("d.mhd")), FileError);
  auto nrrd = [&](const std::string& name, const std::string& fields) {
    std::ofstream(dir.file(name), std::ios::binary) << "NRRD0004\ntype: uchar\ndimension: 3\n"
                                                    << fields << "encoding: raw\n\n"
                                                    << voxels;
    return dir.file(name);
  };
  EXPECT_EQ(read_volume(nrrd("ok.nrrd", "sizes: 4 4 4\nspacings: 1 2 3\n")).grid().spacing_mm,
            (Vec3{1, 2, 3}));
  e = quiet_error_of(nrrd("nan.nrrd", "sizes: 4 4 4\nspacings: nan 1 1\n"));
  EXPECT_NE(e.find("spacings 'nan 1 1'"), std::string::npos) << e;
  e = quiet_error_of(nrrd("huge.nrrd", "sizes: 9223372036854775809 1 1\n"));
  EXPECT_NE(e.find("sizes '9223372036854775809 1 1'"), std::string::npos) << e;
  EXPECT_THROW(read_volume(dir.file("huge.nrrd")), InputError);
}

// A bad-input probe found this: a .npy of shape (2^32, 2^32, 1) overflowed its byte count, mapped 0
// bytes and was read as a volume ("info" said 0 MiB); Fortran-ordered, it crashed.
TEST(VolumeFile, NpyShapeOverflowIsAnInputError) {
  test::TempDir dir;
  auto npy = [&](const std::string& name, const std::string& dict) {
    std::string header = dict;
    header.append(size_t(63 - (10 + header.size()) % 64), ' ');
    header += '\n';
    std::ofstream out(dir.file(name), std::ios::binary);
    out << "\x93NUMPY\x01" << '\0' << char(header.size() & 0xff) << char(header.size() >> 8)
        << header << std::string(102, '\0');
    return dir.file(name);
  };
  for (const char* order : {"False", "True"}) {
    const std::string p = npy(std::string("over_") + order + ".npy",
                              std::string("{'descr': '<f4', 'fortran_order': ") + order +
                                  ", 'shape': (4294967296, 4294967296, 1), }");
    const std::string e = error_of(p);
    EXPECT_NE(e.find("(4294967296, 4294967296, 1)"), std::string::npos) << e;
    EXPECT_THROW(read_volume(p), InputError);
    EXPECT_THROW(read_npy_header(p), InputError);
  }
  const std::string p = npy("range.npy",
                            "{'descr': '<f4', 'fortran_order': False, 'shape': "
                            "(99999999999999999999, 2, 1), }");
  EXPECT_NE(error_of(p).find("corrupt .npy shape"), std::string::npos);
}

// NaN and infinite voxels are sampled as they are; the reader says so once, with the count.
TEST(VolumeFile, NonFiniteVoxelsAreCountedOnce) {
  test::TempDir dir;
  std::vector<float> data(2 * 3 * 4, 1.0f);
  data[5] = std::nanf("");
  data[7] = -INFINITY;
  write_npy(dir.file("v.npy"), PixelType::Float32, {2, 3, 4}, data.data());
  std::vector<std::string> warnings;
  static std::vector<std::string>* sink = nullptr;
  sink = &warnings;
  set_warning_handler([](const std::string& m) { sink->push_back(m); });
  VolumeReadOptions o;
  o.spacing_mm = Vec3{1, 1, 1};
  const Volume v = read_volume(dir.file("v.npy"), o);
  write_volume(dir.file("v.nii"), v);
  read_volume(dir.file("v.nii"));
  set_warning_handler(nullptr);
  ASSERT_EQ(warnings.size(), 2u);
  EXPECT_NE(warnings[0].find("2 of 24 voxels are NaN or infinite"), std::string::npos)
      << warnings[0];
  EXPECT_NE(warnings[1].find("v.nii"), std::string::npos) << warnings[1];
  EXPECT_EQ(v.non_finite_count(), 2);
  EXPECT_EQ(v.converted(PixelType::Int16).non_finite_count(), 0);
}

TEST(VolumeFile, NpyWithFlagsSidecarAndDefaults) {
  test::TempDir dir;
  const VolumeGrid grid = test::oblique_grid({7, 6, 5});
  const Volume v = test::make_volume<uint16_t>(grid, [](const Vec3& p) { return 500 + p[0]; });
  write_volume(dir.file("v.npy"), v);  // (nz, ny, nx) + v.json sidecar
  const NpyArray header = read_npy_header(dir.file("v.npy"));
  EXPECT_EQ(header.shape, (std::vector<int64_t>{5, 6, 7}));
  const Volume back = read_volume(dir.file("v.npy"));
  expect_same_geometry(grid, back.grid(), 1e-12);
  expect_same_voxels<uint16_t>(v, back);
  // Flags win over the sidecar.
  VolumeReadOptions o;
  o.spacing_mm = Vec3{2, 3, 4};
  EXPECT_EQ(read_volume(dir.file("v.npy"), o).grid().spacing_mm, (Vec3{2, 3, 4}));
  // No sidecar: defaults, with a warning.
  fs::remove(dir.file("v.json"));
  const Volume plain = read_volume(dir.file("v.npy"));
  EXPECT_EQ(plain.grid().spacing_mm, (Vec3{1, 1, 1}));
  EXPECT_EQ(plain.grid().origin_mm, (Vec3{0, 0, 0}));
  // A sidecar with a typo is an error naming the key.
  std::ofstream(dir.file("v.json")) << R"({"spacing": [1, 1, 1], "orgin": [0, 0, 0]})";
  EXPECT_NE(error_of(dir.file("v.npy")).find("unknown key 'orgin'"), std::string::npos);
}

TEST(VolumeFile, NpyFortranOrderIsTransposed) {
  test::TempDir dir;
  // A Fortran-order (nz, ny, nx) array: element (k, j, i) at k + nz·(j + ny·i).
  const int nx = 4, ny = 3, nz = 2;
  std::vector<float> data(size_t(nx * ny * nz));
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        data[size_t(k + nz * (j + ny * i))] = float(100 * k + 10 * j + i);
  write_npy(dir.file("f.npy"), PixelType::Float32, {nz, ny, nx}, data.data());
  // Patch the header to say fortran_order: True (same length as False + one space of padding).
  std::fstream f(dir.file("f.npy"), std::ios::in | std::ios::out | std::ios::binary);
  std::string head(128, '\0');
  f.read(&head[0], 128);
  const size_t at = head.find("False");
  ASSERT_NE(at, std::string::npos);
  head.replace(at, 6, "True, ");
  f.seekp(0);
  f.write(head.data(), 128);
  f.close();
  VolumeReadOptions o;
  o.spacing_mm = Vec3{1, 1, 1};
  const Volume v = read_volume(dir.file("f.npy"), o);
  ASSERT_EQ(v.grid().dims, (std::array<int64_t, 3>{nx, ny, nz}));
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        EXPECT_EQ(v.data_as<float>()[(k * ny + j) * nx + i], float(100 * k + 10 * j + i));
}

TEST(VolumeFile, FanSlicerNpyConfig) {
  test::TempDir dir;
  // fan-slicer's array axes are [Y, X, Z].
  const int nx = 5, ny = 4, nz = 3;
  std::vector<int16_t> a(size_t(nx * ny * nz));
  for (int y = 0; y < ny; ++y)
    for (int x = 0; x < nx; ++x)
      for (int z = 0; z < nz; ++z) a[size_t((y * nx + x) * nz + z)] = int16_t(100 * z + 10 * y + x);
  write_npy(dir.file("ct.npy"), PixelType::Int16, {ny, nx, nz}, a.data());
  std::ofstream(dir.file("cfg.json"))
      << R"({"planar resolution": [0.5, 0.5], "voxel size": [0.5, 0.5, 2.0],
      "bounding box": [[-1.0, -2.0, -3.0], [1.0, -0.5, 1.0]]})";
  VolumeReadOptions o;
  o.fanslicer_npy_config = dir.file("cfg.json");
  const Volume v = read_volume(dir.file("ct.npy"), o);
  ASSERT_EQ(v.grid().dims, (std::array<int64_t, 3>{nx, ny, nz}));
  EXPECT_EQ(v.grid().spacing_mm, (Vec3{0.5, 0.5, 2.0}));
  EXPECT_EQ(v.grid().origin_mm, (Vec3{-1.0, -2.0, -3.0}));
  for (int z = 0; z < nz; ++z)
    for (int y = 0; y < ny; ++y)
      for (int x = 0; x < nx; ++x)
        EXPECT_EQ(v.data_as<int16_t>()[(z * ny + y) * nx + x], 100 * z + 10 * y + x);
}

TEST(VolumeFile, FanSlicerSharedNpyConfigParses) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir dir;
  // The shared config describes a 312 x 312 x 191 CT; give it a matching (small-valued) array.
  std::vector<uint8_t> a(size_t(312) * 312 * 191, 7);
  write_npy(dir.file("ct.npy"), PixelType::UInt8, {312, 312, 191}, a.data());
  VolumeReadOptions o;
  o.fanslicer_npy_config = test::data_dir() + "/fanslicer/CT_npy_volume_config.json";
  const Volume v = read_volume(dir.file("ct.npy"), o);
  EXPECT_EQ(v.grid().origin_mm, (Vec3{-94.3125, -84.2125, -410.0}));
  EXPECT_EQ(v.grid().spacing_mm, (Vec3{0.671875, 0.671875, 1.0}));
}

// A .npy whose header length is not a multiple of 8 (NumPy pads to 64; other writers need not):
// its float64 data start at an odd offset. Mapped as it was, the volume's values sat at a
// misaligned address (undefined behaviour, found by fuzz_npy); now they are read into aligned
// memory, with the same values.
TEST(VolumeFile, NpyDataAtAMisalignedOffsetIsReadAligned) {
  test::TempDir dir;
  std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2, 3), }";
  while ((10 + header.size() + 1) % 8 != 3) header += ' ';  // data at offset 8k + 3
  header += "\n";
  ASSERT_NE((10 + header.size()) % 8, 0u);
  std::string bytes = std::string("\x93NUMPY\x01\x00", 8);
  bytes.push_back(char(header.size() & 0xff));
  bytes.push_back(char(header.size() >> 8));
  bytes += header;
  std::vector<double> values(12);
  for (size_t i = 0; i < values.size(); ++i) values[i] = 0.5 + double(i);
  bytes.append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(double));
  std::ofstream(dir.file("odd.npy"), std::ios::binary) << bytes;
  const Volume v = read_volume(dir.file("odd.npy"));
  ASSERT_EQ(v.pixel_type(), PixelType::Float64);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(v.data()) % alignof(double), 0u);
  EXPECT_EQ(std::memcmp(v.data(), values.data(), values.size() * sizeof(double)), 0);
  EXPECT_EQ(v.non_finite_count(), 0);
}

TEST(VolumeFile, BadInputsNameTheFile) {
  test::TempDir dir;
  // Missing.
  EXPECT_NE(error_of(dir.file("nope.nii.gz")).find("no such file"), std::string::npos);
  // Corrupt: not an image at all.
  std::ofstream(dir.file("junk.nii")) << "this is not a NIfTI file";
  const std::string junk = error_of(dir.file("junk.nii"));
  EXPECT_NE(junk.find(dir.file("junk.nii")), std::string::npos) << junk;
  // Truncated .nii.gz and .mha.
  const Volume v = test::make_volume<int16_t>(test::oblique_grid({40, 40, 40}), field);
  for (const char* name : {"t.nii.gz", "t.nii", "t.mha", "t.nrrd"}) {
    write_volume(dir.file(name), v);
    fs::resize_file(dir.file(name), fs::file_size(dir.file(name)) / 2);
    const std::string e = error_of(dir.file(name));
    EXPECT_NE(e.find("cannot read volume '" + dir.file(name) + "': truncated or corrupt file"),
              std::string::npos)
        << name << ": '" << e << "'";
  }
  // A truncated .nii.gz that ITK converts (scl_slope 2, scl_inter 10 at bytes 112/116): ITK's
  // gzip reader filled the missing half with zeros and the read succeeded. Once as a gzip stream
  // of half the file, once as the whole stream cut in half.
  write_volume(dir.file("r.nii"), v);
  patch_float(dir.file("r.nii"), 112, 2.0f);
  patch_float(dir.file("r.nii"), 116, 10.0f);
  const std::string nii = test::read_file_bytes(dir.file("r.nii"));
  for (const bool cut_stream : {false, true}) {
    const std::string name = dir.file(cut_stream ? "cut.nii.gz" : "half.nii.gz");
    gzFile gz = gzopen(name.c_str(), "wb");
    const size_t n = cut_stream ? nii.size() : nii.size() / 2;
    ASSERT_EQ(gzwrite(gz, nii.data(), unsigned(n)), int(n));
    gzclose(gz);
    if (cut_stream) fs::resize_file(name, fs::file_size(name) / 2);
    const std::string e = error_of(name);
    EXPECT_NE(e.find("cannot read volume '" + name + "': truncated or corrupt file"),
              std::string::npos)
        << e;
  }
  // The whole stream reads, rescaled.
  {
    const std::string name = dir.file("whole.nii.gz");
    gzFile gz = gzopen(name.c_str(), "wb");
    gzwrite(gz, nii.data(), unsigned(nii.size()));
    gzclose(gz);
    const Volume r = read_volume(name);
    ASSERT_EQ(r.pixel_type(), PixelType::Float32);
    EXPECT_EQ(static_cast<const float*>(r.data())[7],
              2.0f * static_cast<const int16_t*>(v.data())[7] + 10.0f);
  }
  // Truncated .npy.
  write_volume(dir.file("t.npy"), v);
  fs::resize_file(dir.file("t.npy"), 1000);
  EXPECT_NE(error_of(dir.file("t.npy")).find("truncated"), std::string::npos);
  // Unsupported pixel types: RGB, and a 2-D npy.
  using Rgb = itk::Image<itk::RGBPixel<uint8_t>, 3>;
  auto rgb = Rgb::New();
  Rgb::SizeType size;
  size.Fill(4);
  rgb->SetRegions(Rgb::RegionType(size));
  rgb->Allocate(true);
  auto writer = itk::ImageFileWriter<Rgb>::New();
  writer->SetInput(rgb);
  writer->SetFileName(dir.file("rgb.mha"));
  writer->Update();
  EXPECT_NE(error_of(dir.file("rgb.mha")).find("unsupported pixel type"), std::string::npos);
  std::vector<float> flat(12);
  write_npy(dir.file("flat.npy"), PixelType::Float32, {3, 4}, flat.data());
  EXPECT_NE(error_of(dir.file("flat.npy")).find("must be 3-D"), std::string::npos);
  // Zero spacing from flags.
  write_volume(dir.file("ok.npy"), v);
  VolumeReadOptions o;
  o.spacing_mm = Vec3{1, 0, 1};
  EXPECT_NE(error_of(dir.file("ok.npy"), o).find("spacing along axis 1"), std::string::npos);
  // .npy-only flags on a NIfTI.
  write_volume(dir.file("ok.nii"), v);
  EXPECT_NE(error_of(dir.file("ok.nii"), o).find(".npy volumes only"), std::string::npos);
}

TEST(VolumeFile, WriteIsAtomic) {
  test::TempDir dir;
  const Volume v = test::make_volume<int16_t>(test::oblique_grid({8, 8, 8}), field);
  write_volume(dir.file("good.nii.gz"), v);
  const auto size = fs::file_size(dir.file("good.nii.gz"));
  // An unwritable destination: a missing directory. Nothing appears, nothing is left behind.
  EXPECT_THROW(write_volume(dir.file("missing/v.nii.gz"), v), FileError);
  size_t entries = 0;
  for (const auto& e : fs::directory_iterator(dir.path())) {
    (void)e;
    ++entries;
  }
  EXPECT_EQ(entries, 1u);
  EXPECT_EQ(fs::file_size(dir.file("good.nii.gz")), size);
}

}  // namespace
}  // namespace sonoslice
