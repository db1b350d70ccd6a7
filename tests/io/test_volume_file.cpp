// Volumes in and out with their full geometry: NIfTI, MetaImage, NRRD, DICOM series, .npy.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include <itkExtractImageFilter.h>
#include <itkGDCMImageIO.h>
#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkMetaDataObject.h>
#include <itkRGBPixel.h>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/Npy.h"
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
void write_dicom_series(const Volume& volume, const std::string& dir, const std::string& series_uid,
                        double slope, double intercept) {
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
    const Vec3 pos = g.index_to_world({0, 0, double(k)});
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
    EXPECT_NE(e.find(dir.file(name)), std::string::npos) << name << ": '" << e << "'";
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
