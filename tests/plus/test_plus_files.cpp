// PLUS toolkit files (docs/conventions.md §7): tracked-frame sequences (.mha / .nrrd, compressed or
// raw), their orientations, the transform repository, and PLUS configuration XML. Real data from
// PlusLibData (data/plus), synthetic files for every corner the real ones do not reach.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>

#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkMetaImageIO.h>

#include "../common/TestUtil.h"
#include "sonoslice/compound/Reconstruction.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/plus/FrameSelection.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice {
namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------------
// Helpers

std::string plus_data(const std::string& name) {
  return test::data_dir() + "/plus/" + name;
}

#define REQUIRE_PLUS_DATA()                                       \
  do {                                                            \
    SONOSLICE_REQUIRE_DATA();                                     \
    if (!fs::exists(plus_data("NwirePhantomFreehand.igs.mha")))   \
      GTEST_FAIL() << "data/plus (PlusLibData files) is missing"; \
  } while (0)

/// Runs f and returns the message of the exception E it throws (a test failure otherwise).
template <typename E>
std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const E& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "unexpected exception type: " << e.what();
    return "";
  }
  ADD_FAILURE() << "no exception thrown";
  return "";
}

std::vector<std::string>& captured_warnings() {
  static std::vector<std::string> w;
  return w;
}
void capture_warning(const std::string& m) {
  captured_warnings().push_back(m);
}
/// Collects sonoslice::warn messages for the lifetime of the object.
struct WarningCapture {
  WarningCapture() {
    captured_warnings().clear();
    set_warning_handler(&capture_warning);
  }
  ~WarningCapture() { set_warning_handler(nullptr); }
  const std::vector<std::string>& list() const { return captured_warnings(); }
  std::string all() const {
    std::string s;
    for (const auto& m : captured_warnings()) s += m + "\n";
    return s;
  }
};

/// Skips the test when sonoslice was built without pugixml (read_plus_config says so).
#define REQUIRE_PUGIXML()                                                     \
  do {                                                                        \
    try {                                                                     \
      read_plus_config("/nonexistent/sonoslice-probe.xml");                   \
    } catch (const FileError&) {                                              \
    } catch (const Error& e) {                                                \
      if (std::string(e.what()).find("without pugixml") != std::string::npos) \
        GTEST_SKIP() << "built without pugixml";                              \
    }                                                                         \
  } while (0)

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
  ASSERT_TRUE(out.good()) << path;
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

Mat4 row_major(std::initializer_list<double> v) {
  std::vector<double> values(v);
  return Mat4::from_row_major(values.data());
}

void expect_matrix_near(const Mat4& a, const Mat4& b, double tol, const std::string& what = "") {
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      EXPECT_NEAR(a.m[r][c], b.m[r][c], tol) << what << " [" << r << "][" << c << "]";
}

/// The inverse of an affine matrix through Mat3::inverse (independent of the repository's).
Mat4 affine_inverse(const Mat4& m) {
  const Mat3 inv = m.linear().inverse();
  const Vec3 t = inv * m.column3(3);
  return Mat4::from_rotation_translation(inv, {-t[0], -t[1], -t[2]});
}

/// Pixel (x, y) of frame f of a synthetic sequence: distinct along x and y, so any flip shows.
double pattern(int x, int y, int f) {
  return double((x + 7 * y + 31 * f) % 97);
}

PlusSequence make_sequence(PixelType type, int w, int h, int n, const std::string& orientation) {
  PlusSequence s;
  s.width = w, s.height = h, s.frame_count = n, s.pixel_type = type, s.orientation = orientation;
  s.pixels.resize(s.frame_bytes() * size_t(n));
  visit_pixel_type(type, [&](auto zero) {
    using T = decltype(zero);
    T* p = reinterpret_cast<T*>(s.pixels.data());
    for (int f = 0; f < n; ++f)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          double v = pattern(x, y, f);
          if (std::is_signed<T>::value) v -= 40;            // negative values too
          if (std::is_floating_point<T>::value) v += 0.25;  // and fractions
          p[(size_t(f) * h + y) * w + x] = static_cast<T>(v);
        }
    return 0;
  });
  s.frame_fields.resize(size_t(n));
  for (int f = 0; f < n; ++f) {
    auto& fields = s.frame_fields[size_t(f)];
    fields["ProbeToTrackerTransform"] =
        "1 0 0 " + std::to_string(f) + " 0 1 0 2.5 0 0 1 -3 0 0 0 1";
    fields["ProbeToTrackerTransformStatus"] = f == 1 ? "INVALID" : "OK";
    fields["Timestamp"] = std::to_string(100.0 + 0.1 * f);
    fields["ImageStatus"] = "OK";
  }
  return s;
}

void expect_same_sequence(const PlusSequence& a, const PlusSequence& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.frame_count, b.frame_count);
  EXPECT_EQ(a.pixel_type, b.pixel_type);
  EXPECT_EQ(a.orientation, b.orientation);
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  EXPECT_TRUE(a.pixels == b.pixels) << "pixels differ";
  EXPECT_EQ(a.frame_fields, b.frame_fields);
}

/// A MetaImage sequence written by hand: header fields + frame fields + raw pixels.
std::string meta_header(int w, int h, int n, const std::string& type, const std::string& extra,
                        const std::string& frame_fields = "") {
  std::ostringstream s;
  s << "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
    << "CompressedData = False\nDimSize = " << w << " " << h << " " << n
    << "\nKinds = domain domain list\nElementType = " << type << "\n"
    << extra << frame_fields << "ElementDataFile = LOCAL\n";
  return s.str();
}

// ---------------------------------------------------------------------------------------------
// Real sequences

// The same sweep in both PLUS formats: identical frames, fields and transforms; the values are
// those printed in the header; ITK's MetaImage reader (an independent decoder) agrees.
TEST(PlusSequenceReal, NwireMhaAndNrrdAgree) {
  REQUIRE_PLUS_DATA();
  const PlusSequence mha = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const PlusSequence nrrd = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.nrrd"));
  for (const PlusSequence* s : {&mha, &nrrd}) {
    EXPECT_EQ(s->width, 820);
    EXPECT_EQ(s->height, 616);
    EXPECT_EQ(s->frame_count, 97);
    EXPECT_EQ(s->pixel_type, PixelType::UInt8);
    EXPECT_EQ(s->orientation, "MFA");
    ASSERT_EQ(s->pixels.size(), size_t(820) * 616 * 97);
    ASSERT_EQ(s->frame_fields.size(), 97u);
  }
  EXPECT_TRUE(mha.pixels == nrrd.pixels) << "the .mha and .nrrd frames differ";
  size_t nonzero = 0;
  for (uint8_t v : mha.pixels) nonzero += v != 0;
  EXPECT_GT(nonzero, mha.pixels.size() / 200) << "suspiciously empty frames";

  for (int f = 0; f < 97; ++f) {
    for (const char* name : {"ProbeToTracker", "ReferenceToTracker"}) {
      const auto a = mha.transform(f, name), b = nrrd.transform(f, name);
      ASSERT_EQ(a.has_value(), b.has_value()) << name << " frame " << f;
      if (a) expect_matrix_near(*a, *b, 0, std::string(name) + " frame " + std::to_string(f));
    }
    EXPECT_EQ(mha.timestamp(f), nrrd.timestamp(f));
    EXPECT_TRUE(mha.image_ok(f));
    EXPECT_TRUE(nrrd.image_ok(f));
  }
  // Every field, the image status included (ImageStatus in .mha, Status in .nrrd).
  EXPECT_EQ(mha.frame_fields, nrrd.frame_fields);
  const Mat4 probe0 =
      row_major({0.956683, -0.263308, 0.124204, -190.886, 0.269031, 0.962616, -0.0315089, -98.0911,
                 -0.111264, 0.0635588, 0.991756, -1949.07, 0, 0, 0, 1});
  ASSERT_TRUE(mha.transform(0, "ProbeToTracker"));
  expect_matrix_near(*mha.transform(0, "ProbeToTracker"), probe0, 0);
  expect_matrix_near(*nrrd.transform(0, "ProbeToTracker"), probe0, 0);
  EXPECT_DOUBLE_EQ(mha.timestamp(0), 345.627957);
  EXPECT_TRUE(mha.image_ok(0));
  // Stylus transforms are INVALID in this recording.
  EXPECT_FALSE(mha.transform(0, "StylusToTracker").has_value());
  EXPECT_FALSE(mha.transform(0, "NoSuchToTracker").has_value());
  const auto names = mha.transform_names(0);
  for (const char* n : {"ProbeToTracker", "ReferenceToTracker", "StylusToTracker"})
    EXPECT_NE(std::find(names.begin(), names.end(), n), names.end()) << n;

  // ITK reads the .mha as a 820x616x97 volume: its bytes are the MF frames (MFA = MF).
  using Image = itk::Image<unsigned char, 3>;
  auto reader = itk::ImageFileReader<Image>::New();
  reader->SetImageIO(itk::MetaImageIO::New());
  reader->SetFileName(plus_data("NwirePhantomFreehand.igs.mha"));
  reader->Update();
  const Image* img = reader->GetOutput();
  ASSERT_EQ(img->GetLargestPossibleRegion().GetNumberOfPixels(), mha.pixels.size());
  EXPECT_EQ(std::memcmp(img->GetBufferPointer(), mha.pixels.data(), mha.pixels.size()), 0);
}

TEST(PlusSequenceReal, BoneUltrasoundReads) {
  REQUIRE_PLUS_DATA();
  const PlusSequence s = read_plus_sequence(plus_data("BoneUltrasound_L14.igs.mha"));
  EXPECT_EQ(s.width, 820);
  EXPECT_EQ(s.height, 616);
  EXPECT_EQ(s.frame_count, 21);
  EXPECT_EQ(s.orientation, "MF");
  EXPECT_EQ(s.pixels.size(), size_t(820) * 616 * 21);
  ASSERT_TRUE(s.transform(0, "ProbeToTracker"));
  EXPECT_DOUBLE_EQ(s.transform(0, "ProbeToTracker")->m[0][3], 257.956);
  EXPECT_TRUE(s.transform(0, "StylusToTracker").has_value());  // OK in this recording
}

// ImageToReference from the repository (configuration XML + frame 0) equals the chain computed
// by hand from the numbers in the files: inv(ReferenceToTracker) · ProbeToTracker · ImageToProbe.
TEST(PlusSequenceReal, ImageToReferenceFromConfig) {
  REQUIRE_PLUS_DATA();
  REQUIRE_PUGIXML();
  const PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const PlusReconstructionConfig c = read_plus_config(
      plus_data("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"));
  TransformRepository repo = c.coordinate_definitions;
  repo.set_frame(s, 0);
  const auto image_to_reference = repo.get(c.image_frame, c.reference_frame);
  ASSERT_TRUE(image_to_reference.has_value());

  const Mat4 image_to_probe =
      row_major({-0.0094, -0.0739, -0.0028, -103.5322, 0.0774, -0.0076, -0.0049, -43.1227, 0.0046,
                 -0.0032, 0.0760, -93.3, 0, 0, 0, 1});
  const Mat4 probe_to_tracker =
      row_major({0.956683, -0.263308, 0.124204, -190.886, 0.269031, 0.962616, -0.0315089, -98.0911,
                 -0.111264, 0.0635588, 0.991756, -1949.07, 0, 0, 0, 1});
  const Mat4 reference_to_tracker =
      row_major({0.260287, 0.964665, 0.0408926, -208.632, -0.96117, 0.262899, -0.0838866, -115.511,
                 -0.0916731, -0.0174702, 0.995636, -1992.7, 0, 0, 0, 1});
  const Mat4 expected = affine_inverse(reference_to_tracker) * probe_to_tracker * image_to_probe;
  expect_matrix_near(*image_to_reference, expected, 1e-9);
  // And the reverse chain is its inverse.
  const auto reference_to_image = repo.get(c.reference_frame, c.image_frame);
  ASSERT_TRUE(reference_to_image.has_value());
  expect_matrix_near(*reference_to_image * *image_to_reference, Mat4::identity(), 1e-9);
  // Frames with no Image→Probe calibration: no chain at all.
  EXPECT_NE(error_of<InputError>([&] { repo.get("Image", "Nowhere"); }).find("Nowhere"),
            std::string::npos);
}

// PLUS's own reconstruction of this sweep is the bounding box of the clipped frames mapped by
// ImageToReference: our frames, transforms and chain reproduce its origin and size.
TEST(PlusSequenceReal, ClippedFootprintMatchesPlusReconstruction) {
  REQUIRE_PLUS_DATA();
  REQUIRE_PUGIXML();
  const PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const PlusReconstructionConfig c = read_plus_config(
      plus_data("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"));
  Vec3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  int used = 0;
  for (int f = 0; f < s.frame_count; ++f) {
    TransformRepository repo = c.coordinate_definitions;
    repo.set_frame(s, f);
    const auto m = repo.get(c.image_frame, c.reference_frame);
    if (!m || !s.image_ok(f)) continue;
    ++used;
    // PLUS's corners: origin and origin + size of the clip rectangle (its last pixels).
    for (double x : {double(c.clip.x), double(c.clip.x + c.clip.width - 1)})
      for (double y : {double(c.clip.y), double(c.clip.y + c.clip.height - 1)}) {
        const Vec3 p = m->transform_point({x, y, 0});
        for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
      }
  }
  EXPECT_EQ(used, 97);
  // NwirePhantomFreehandReconstructed.mha: Offset = -22.2573 -137.793 -58.5829,
  // ElementSpacing = 0.5 0.5 0.5, DimSize = 101 104 74. Its origin is the footprint's minimum
  // (not snapped to the spacing as newer PLUS does) and its size floor((max - min) / 0.5) + 1
  // (extents 100.45, 103.90 and 73.05 voxels here).
  const Vec3 offset{-22.2573, -137.793, -58.5829};
  const int dims[3] = {101, 104, 74};
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(lo[a], offset[a], 1e-3) << "axis " << a;
    EXPECT_EQ(int(std::floor((hi[a] - lo[a]) / 0.5)) + 1, dims[a])
        << "axis " << a << ": " << (hi[a] - lo[a]) / 0.5 << " voxels";
  }
}

// ---------------------------------------------------------------------------------------------
// Round trips

struct RoundTripCase {
  std::string extension;
  bool compress;
  PixelType type;
};

void PrintTo(const RoundTripCase& c, std::ostream* os) {
  *os << c.extension << (c.compress ? " compressed " : " raw ") << to_string(c.type);
}

class PlusSequenceRoundTrip : public ::testing::TestWithParam<RoundTripCase> {};

TEST_P(PlusSequenceRoundTrip, Exact) {
  const RoundTripCase& p = GetParam();
  test::TempDir dir;
  for (const char* orientation : {"MF", "UN", "MNA"}) {
    const PlusSequence s = make_sequence(p.type, 13, 9, 4, orientation);
    const std::string path = dir.file(std::string("seq_") + orientation + p.extension);
    write_plus_sequence(path, s, p.compress);
    PlusSequence back = read_plus_sequence(path);
    EXPECT_EQ(back.path, path);
    expect_same_sequence(s, back);
    // Written again from what was read: the same bytes.
    const std::string again = dir.file(std::string("again_") + orientation + p.extension);
    write_plus_sequence(again, back, p.compress);
    EXPECT_EQ(read_file(path), read_file(again));
  }
  // No temporary files left behind.
  for (const auto& e : fs::directory_iterator(dir.path()))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
}

std::vector<RoundTripCase> round_trip_cases() {
  std::vector<RoundTripCase> cases;
  for (const char* ext : {".igs.mha", ".igs.nrrd"})
    for (bool compress : {true, false})
      for (PixelType t :
           {PixelType::UInt8, PixelType::Int16, PixelType::UInt16, PixelType::Float32})
        cases.push_back({ext, compress, t});
  return cases;
}

INSTANTIATE_TEST_SUITE_P(Formats, PlusSequenceRoundTrip, ::testing::ValuesIn(round_trip_cases()),
                         [](const ::testing::TestParamInfo<RoundTripCase>& info) {
                           return std::string(info.param.extension == ".igs.mha" ? "mha" : "nrrd") +
                                  (info.param.compress ? "_compressed_" : "_raw_") +
                                  to_string(info.param.type);
                         });

// The header PLUS writes: fields in PLUS's order and style, the compressed size filled in.
TEST(PlusSequenceWrite, MetaImageHeaderInPlusStyle) {
  test::TempDir dir;
  const PlusSequence s = make_sequence(PixelType::UInt8, 5, 4, 2, "MF");
  const std::string path = dir.file("s.igs.mha");
  write_plus_sequence(path, s, true);
  const std::string text = read_file(path);
  const size_t data = text.find("ElementDataFile = LOCAL\n");
  ASSERT_NE(data, std::string::npos);
  const std::string header = text.substr(0, data);
  std::vector<size_t> at;
  for (const char* key :
       {"ObjectType = Image", "NDims = 3", "AnatomicalOrientation = RAI", "BinaryData = True",
        "BinaryDataByteOrderMSB = False", "CompressedData = True",
        "CompressedDataSize = ", "DimSize = 5 4 2", "Kinds = domain domain list",
        "ElementSpacing = 1 1 1", "ElementType = MET_UCHAR", "Offset = 0 0 0",
        "TransformMatrix = 1 0 0 0 1 0 0 0 1", "UltrasoundImageOrientation = MF",
        "Seq_Frame0000_ImageStatus = OK", "Seq_Frame0001_Timestamp = "}) {
    at.push_back(header.find(key));
    EXPECT_NE(at.back(), std::string::npos) << key;
  }
  EXPECT_TRUE(std::is_sorted(at.begin(), at.end())) << header;
  // CompressedDataSize is the number of bytes after the header.
  const size_t k = header.find("CompressedDataSize = ") + 21;
  const long long size = std::stoll(header.substr(k, header.find('\n', k) - k));
  EXPECT_EQ(size_t(size), text.size() - data - std::strlen("ElementDataFile = LOCAL\n"));

  // The NRRD sequence names the image status "Status", as PLUS does; read back, it is
  // ImageStatus again.
  PlusSequence invalid = s;
  invalid.frame_fields[1]["ImageStatus"] = "INVALID";
  const std::string nrrd = dir.file("s.igs.nrrd");
  write_plus_sequence(nrrd, invalid, true);
  const std::string nrrd_text = read_file(nrrd);
  EXPECT_EQ(nrrd_text.rfind("NRRD0004\n", 0), 0u);
  EXPECT_NE(nrrd_text.find("Seq_Frame0000_Status:=OK\n"), std::string::npos);
  EXPECT_NE(nrrd_text.find("Seq_Frame0001_Status:=INVALID\n"), std::string::npos);
  EXPECT_EQ(nrrd_text.find("ImageStatus"), std::string::npos);
  EXPECT_NE(nrrd_text.find("ultrasound image orientation:=MF\n"), std::string::npos);
  const PlusSequence back = read_plus_sequence(nrrd);
  EXPECT_TRUE(back.image_ok(0));
  EXPECT_FALSE(back.image_ok(1));
  EXPECT_EQ(back.frame_fields, invalid.frame_fields);
}

// Raw .mha written by us reads in ITK as the same volume (an independent check of the layout).
TEST(PlusSequenceWrite, ItkReadsWrittenMetaImage) {
  test::TempDir dir;
  for (bool compress : {false, true}) {
    const PlusSequence s = make_sequence(PixelType::Int16, 11, 6, 3, "MF");
    const std::string path = dir.file(compress ? "c.mha" : "r.mha");
    write_plus_sequence(path, s, compress);
    using Image = itk::Image<int16_t, 3>;
    auto reader = itk::ImageFileReader<Image>::New();
    reader->SetImageIO(itk::MetaImageIO::New());
    reader->SetFileName(path);
    reader->Update();
    const Image* img = reader->GetOutput();
    ASSERT_EQ(img->GetLargestPossibleRegion().GetSize()[0], 11u);
    ASSERT_EQ(img->GetLargestPossibleRegion().GetSize()[2], 3u);
    EXPECT_EQ(std::memcmp(img->GetBufferPointer(), s.pixels.data(), s.pixels.size()), 0);
  }
}

TEST(PlusSequenceWrite, BadInputs) {
  test::TempDir dir;
  PlusSequence s = make_sequence(PixelType::UInt8, 4, 3, 2, "MF");
  EXPECT_NE(error_of<InputError>([&] { write_plus_sequence(dir.file("a.png"), s); }).find(".mha"),
            std::string::npos);
  PlusSequence short_pixels = s;
  short_pixels.pixels.pop_back();
  error_of<InputError>([&] { write_plus_sequence(dir.file("a.mha"), short_pixels); });
  PlusSequence bad_orientation = s;
  bad_orientation.orientation = "FM";
  error_of<InputError>([&] { write_plus_sequence(dir.file("a.mha"), bad_orientation); });
  PlusSequence newline = s;
  newline.frame_fields[0]["Note"] = "two\nlines";
  error_of<InputError>([&] { write_plus_sequence(dir.file("a.mha"), newline); });
  error_of<FileError>([&] { write_plus_sequence(dir.file("missing_dir/a.mha"), s); });
  EXPECT_FALSE(fs::exists(dir.file("a.mha")));  // nothing written by the failed calls
}

// ---------------------------------------------------------------------------------------------
// Orientation

// Files written by hand in each orientation read back as MF frames: U reverses x, N reverses y.
TEST(PlusSequenceOrientation, FlipsToMF) {
  test::TempDir dir;
  const int w = 5, h = 3;
  // On disk, pixel (x, y) holds 10*y + x.
  std::string disk;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) disk.push_back(char(10 * y + x));
  struct Case {
    std::string orientation;
    bool flip_x, flip_y;
  };
  for (const Case& c :
       {Case{"MF", false, false}, Case{"MFA", false, false}, Case{"UF", true, false},
        Case{"MN", false, true}, Case{"UN", true, true}, Case{"UNA", true, true},
        Case{"mnd", false, true}, Case{"", false, false}}) {
    const std::string extra = c.orientation.empty()
                                  ? std::string()
                                  : "UltrasoundImageOrientation = " + c.orientation + "\n";
    const std::string path = dir.file("o.mha");
    write_file(path, meta_header(w, h, 1, "MET_UCHAR", extra) + disk);
    const PlusSequence s = read_plus_sequence(path);
    EXPECT_EQ(s.orientation, c.orientation.empty() ? "MF" : c.orientation);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const int dx = c.flip_x ? w - 1 - x : x, dy = c.flip_y ? h - 1 - y : y;
        EXPECT_EQ(int(s.pixels[size_t(y) * w + x]), 10 * dy + dx)
            << c.orientation << " pixel (" << x << ", " << y << ")";
      }
  }
}

// Written frames are flipped from MF into the file's orientation (the bytes on disk show it), for
// multi-byte pixels too.
TEST(PlusSequenceOrientation, WriterFlipsFromMF) {
  test::TempDir dir;
  for (const std::string o : {"UF", "MN", "UN"}) {
    const PlusSequence s = make_sequence(PixelType::UInt16, 6, 4, 2, o);
    const std::string path = dir.file("w.mha");
    write_plus_sequence(path, s, false);
    const std::string text = read_file(path);
    const size_t bytes = s.pixels.size();
    ASSERT_GE(text.size(), bytes);
    const uint16_t* disk = reinterpret_cast<const uint16_t*>(text.data() + text.size() - bytes);
    const uint16_t* mf = reinterpret_cast<const uint16_t*>(s.pixels.data());
    for (int f = 0; f < 2; ++f)
      for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 6; ++x) {
          const int dx = o[0] == 'U' ? 5 - x : x, dy = o[1] == 'N' ? 3 - y : y;
          EXPECT_EQ(disk[(f * 4 + y) * 6 + x], mf[(f * 4 + dy) * 6 + dx]) << o;
        }
    expect_same_sequence(s, read_plus_sequence(path));
  }
}

TEST(PlusSequenceOrientation, UnsupportedOrientationsAreRefused) {
  test::TempDir dir;
  for (const char* o : {"FM", "NU", "XX", "MFX", "M", "MFAA"}) {
    const std::string path = dir.file("bad.mha");
    write_file(path, meta_header(2, 2, 1, "MET_UCHAR",
                                 std::string("UltrasoundImageOrientation = ") + o + "\n") +
                         std::string(4, '\0'));
    const std::string e = error_of<InputError>([&] { read_plus_sequence(path); });
    EXPECT_NE(e.find("orientation"), std::string::npos) << e;
  }
}

// ---------------------------------------------------------------------------------------------
// Statuses, fields and the transform repository

TEST(PlusSequenceFields, StatusesAndTransforms) {
  test::TempDir dir;
  const std::string fields =
      "Seq_Frame0000_ProbeToTrackerTransform = 1 0 0 10 0 1 0 20 0 0 1 30 0 0 0 1\n"
      "Seq_Frame0000_ProbeToTrackerTransformStatus = OK\n"
      "Seq_Frame0000_ImageStatus = OK\n"
      "Seq_Frame0001_ProbeToTrackerTransform = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
      "Seq_Frame0001_ProbeToTrackerTransformStatus = INVALID\n"
      "Seq_Frame0001_ImageStatus = INVALID\n"
      "Seq_Frame0001_Timestamp = 12.5\n";
  const std::string path = dir.file("f.mha");
  write_file(path, meta_header(2, 2, 2, "MET_UCHAR", "", fields) + std::string(8, '\0'));
  const PlusSequence s = read_plus_sequence(path);
  EXPECT_TRUE(s.image_ok(0));
  EXPECT_FALSE(s.image_ok(1));
  EXPECT_TRUE(s.transform(0, "ProbeToTracker").has_value());
  EXPECT_FALSE(s.transform(1, "ProbeToTracker").has_value());
  EXPECT_TRUE(std::isnan(s.timestamp(0)));
  EXPECT_DOUBLE_EQ(s.timestamp(1), 12.5);
  error_of<InputError>([&] { s.image_ok(2); });

  TransformRepository repo;
  repo.set("Image", "Probe", row_major({2, 0, 0, 1, 0, 2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 1}));
  repo.set_frame(s, 0);
  const auto image_to_tracker = repo.get("Image", "Tracker");
  ASSERT_TRUE(image_to_tracker.has_value());
  EXPECT_EQ(image_to_tracker->transform_point({1, 1, 1})[0], 2 + 1 + 10);
  repo.set_frame(s, 1);  // the invalid ProbeToTracker replaces the valid one
  EXPECT_FALSE(repo.get("Probe", "Tracker").has_value());
  EXPECT_FALSE(repo.get("Image", "Tracker").has_value());
  EXPECT_FALSE(repo.get("Tracker", "Image").has_value());
  EXPECT_TRUE(repo.get("Probe", "Image").has_value());

  // NRRD sequences name the image status "Status".
  const std::string nrrd = dir.file("f.nrrd");
  write_file(nrrd,
             "NRRD0004\ndimension: 3\ntype: uint8\nsizes: 2 2 2\nkinds: domain domain list\n"
             "encoding: raw\nendian: little\nSeq_Frame0000_Status:=OK\n"
             "Seq_Frame0001_Status:=INVALID\n\n" +
                 std::string(8, '\0'));
  const PlusSequence n = read_plus_sequence(nrrd);
  EXPECT_TRUE(n.image_ok(0));
  EXPECT_FALSE(n.image_ok(1));
}

TEST(PlusSequenceFields, MalformedTransformNamesTheFrame) {
  test::TempDir dir;
  const std::string path = dir.file("m.mha");
  write_file(
      path,
      meta_header(2, 2, 3, "MET_UCHAR", "",
                  "Seq_Frame0000_ProbeToTrackerTransform = 1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
                  "Seq_Frame0002_ProbeToTrackerTransform = 1 0 0 x 0 1 0 0 0 0 1 0 0 0 0 1\n") +
          std::string(12, '\0'));
  const std::string e = error_of<InputError>([&] { read_plus_sequence(path); });
  EXPECT_NE(e.find("frame 2"), std::string::npos) << e;
  EXPECT_NE(e.find("m.mha"), std::string::npos) << e;
  write_file(path, meta_header(2, 2, 1, "MET_UCHAR", "",
                               "Seq_Frame0000_ReferenceToTrackerTransform = 1 2 3\n") +
                       std::string(4, '\0'));
  EXPECT_NE(error_of<InputError>([&] { read_plus_sequence(path); }).find("16 finite numbers"),
            std::string::npos);
  // A NaN with status OK is a corrupt file, not a tracking dropout (PLUS marks those INVALID).
  write_file(path, meta_header(2, 2, 1, "MET_UCHAR", "",
                               "Seq_Frame0000_ProbeToTrackerTransform = nan 0 0 0 0 1 0 0 0 0 1 0 "
                               "0 0 0 1\n") +
                       std::string(4, '\0'));
  EXPECT_NE(error_of<InputError>([&] {
              read_plus_sequence(path);
            }).find("frame 0: Seq_Frame0000_ProbeToTrackerTransform: expected 16 finite numbers"),
            std::string::npos);
}

TEST(PlusTransformRepository, ChainsInversesAndErrors) {
  TransformRepository repo;
  const Mat4 a_to_b = row_major({0, -1, 0, 5, 1, 0, 0, -2, 0, 0, 1, 7, 0, 0, 0, 1});  // rotation
  const Mat4 c_to_b = row_major({2, 0, 0, 1, 0, 3, 0, 0, 0, 0, 4, -1, 0, 0, 0, 1});   // scaling
  repo.set("A", "B", a_to_b);
  repo.set("C", "B", c_to_b);
  // A → B → C needs the inverse of CToB.
  const auto a_to_c = repo.get("A", "C");
  ASSERT_TRUE(a_to_c.has_value());
  expect_matrix_near(*a_to_c, affine_inverse(c_to_b) * a_to_b, 1e-12);
  expect_matrix_near(*repo.get("C", "A") * *a_to_c, Mat4::identity(), 1e-12);
  expect_matrix_near(*repo.get("A", "A"), Mat4::identity(), 0);
  // Setting the reverse direction replaces the pair.
  repo.set("B", "A", affine_inverse(a_to_b) * affine_inverse(a_to_b));
  expect_matrix_near(*repo.get("A", "B"), a_to_b * a_to_b, 1e-12);

  const std::string none = error_of<InputError>([&] { repo.get("A", "Elsewhere"); });
  EXPECT_NE(none.find("Elsewhere"), std::string::npos);
  EXPECT_NE(none.find("CToB"), std::string::npos) << "lists the known transforms: " << none;

  // A singular transform cannot be walked backwards.
  Mat4 flat = Mat4::identity();
  flat.m[2][2] = 0;
  repo.set("D", "E", flat);
  EXPECT_TRUE(repo.get("D", "E").has_value());
  EXPECT_NE(error_of<InputError>([&] { repo.get("E", "D"); }).find("not invertible"),
            std::string::npos);

  EXPECT_EQ(TransformRepository::split_name("ImageToReference"),
            (std::pair<std::string, std::string>{"Image", "Reference"}));
  EXPECT_EQ(TransformRepository::split_name("ToolToTracker"),
            (std::pair<std::string, std::string>{"Tool", "Tracker"}));
  EXPECT_EQ(TransformRepository::split_name("StylusTipToStylus"),
            (std::pair<std::string, std::string>{"StylusTip", "Stylus"}));
  error_of<InputError>([] { TransformRepository::split_name("Image"); });
  error_of<InputError>([] { TransformRepository::split_name("AToBToC"); });
}

// The real recording's INVALID stylus: the repository reports the chain through it invalid.
TEST(PlusTransformRepository, RealInvalidStylus) {
  REQUIRE_PLUS_DATA();
  const PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.nrrd"));
  TransformRepository repo;
  repo.set_frame(s, 0);
  EXPECT_FALSE(repo.get("Stylus", "Tracker").has_value());
  EXPECT_FALSE(repo.get("Stylus", "Reference").has_value());
  EXPECT_TRUE(repo.get("Probe", "Reference").has_value());
}

TEST(PlusTransformRepository, TransformProblems) {
  EXPECT_EQ(transform_problem(Mat4::identity()), "");
  EXPECT_EQ(transform_problem(row_major({0.1, 0, 0, 5, 0, 0.1, 0, 2, 0, 0, 0, 0, 0, 0, 0, 1})), "");
  EXPECT_EQ(transform_problem(Mat4::from_row_major(std::vector<double>(16, 0.0).data())),
            "is all zero");
  Mat4 m = Mat4::identity();
  m.m[0][0] = std::nan("");
  EXPECT_EQ(transform_problem(m), "has a non-finite entry");
  m = Mat4::identity();
  m.m[3][3] = 0;
  EXPECT_NE(transform_problem(m).find("last row"), std::string::npos);
  m = Mat4::identity();
  m.m[1][1] = 0;
  EXPECT_NE(transform_problem(m).find("y axis to a point"), std::string::npos);
  m = Mat4::identity();
  m.m[0][1] = 1, m.m[1][1] = 0;  // y axis along x
  EXPECT_NE(transform_problem(m).find("onto one line"), std::string::npos);
}

// Why each frame's transform is checked: one all-zero ProbeToTracker once turned the Nwire sweep's
// 101x105x74 grid into 519x689x4084 voxels (33 s, 12.9 GB) without a word, and one frame missing
// its ProbeToTracker failed the whole sweep without naming the frame. Such frames are now left out
// and named.
// PLUS fits its output box around every frame with a valid transform, also those SkipInterval
// leaves out; --plus-exact does the same. The default mode fits the frames it inserts.
TEST(PlusRecipe, PlusExactFitsTheGridAroundFramesTheSkipIntervalLeavesOut) {
  SONOSLICE_REQUIRE_DATA();
  const PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const PlusReconstructionConfig config = read_plus_config(
      plus_data("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"));
  const auto grid = [&](int skip, bool exact) {
    ReconstructionOptions o;
    o.skip = skip;
    o.plus_exact = exact;
    return Reconstruction(FrameSource::plus(s), &config, o).grid();
  };
  const VolumeGrid all = grid(1, true), every_third = grid(3, true);
  EXPECT_EQ(every_third.dims, all.dims);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(every_third.origin_mm[a], all.origin_mm[a]) << a;
  // Without --plus-exact the box is the inserted frames': here a different origin.
  const VolumeGrid used = grid(3, false), used_all = grid(1, false);
  EXPECT_NE(used.origin_mm[0], used_all.origin_mm[0]);
  EXPECT_EQ(grid(3, true).dims, (std::array<int64_t, 3>{101, 104, 74}));
}

TEST(PlusFrameSelection, FramesTheirTransformsCannotPlaceAreSkippedAndNamed) {
  REQUIRE_PLUS_DATA();
  REQUIRE_PUGIXML();
  PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const PlusReconstructionConfig config = read_plus_config(
      plus_data("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"));
  const std::string zeros = "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0";
  s.frame_fields[5]["ProbeToTrackerTransform"] = "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1";
  s.frame_fields[9]["ProbeToTrackerTransform"] = zeros;
  s.frame_fields[12].erase("ProbeToTrackerTransform");
  s.frame_fields[20]["ReferenceToTrackerTransform"] = zeros;  // cannot be inverted
  WarningCapture warnings;
  const Reconstruction recon(FrameSource::plus(s), &config, ReconstructionOptions{});
  EXPECT_EQ(recon.grid().dims, (std::array<int64_t, 3>{101, 105, 74}));
  EXPECT_EQ(recon.report().frames_used, 93);
  EXPECT_EQ(recon.report().skipped_unusable_transform, 4);
  const std::string w = warnings.all();
  EXPECT_NE(w.find("skipped 4 of 97 frames"), std::string::npos) << w;
  EXPECT_NE(w.find("frame 5: its ImageToReference maps the image's x axis to a point"),
            std::string::npos)
      << w;
  EXPECT_NE(w.find("frame 9: its ImageToReference is all zero"), std::string::npos) << w;
  EXPECT_NE(w.find("frame 12: no chain of transforms from 'Image' to 'Reference'"),
            std::string::npos)
      << w;
  EXPECT_NE(w.find("1 more"), std::string::npos) << w;
  const PlusFrameSelection sel =
      select_plus_frames(s, config.coordinate_definitions, "Image", "Reference");
  ASSERT_EQ(sel.unusable.size(), 4u);
  EXPECT_EQ(sel.unusable[3].first, 20);
  EXPECT_NE(sel.unusable[3].second.find("ReferenceToTracker is not invertible"), std::string::npos);
  // No frame with a chain at all: the calibration is missing, an error naming the first frame.
  for (auto& fields : s.frame_fields) fields.erase("ProbeToTrackerTransform");
  const std::string e =
      error_of<InputError>([&] { Reconstruction(FrameSource::plus(s), &config, {}); });
  EXPECT_NE(e.find("NwirePhantomFreehand.igs.mha: frame 0: no chain of transforms"),
            std::string::npos)
      << e;
}

// A tracking transform that scales or shears is used as given (as PLUS does), with a warning
// naming the frame and the transform; the real sweep's own transforms raise none.
TEST(PlusFrameSelection, NonRigidTrackingTransformsAreUsedAndNamed) {
  REQUIRE_PLUS_DATA();
  REQUIRE_PUGIXML();
  PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const PlusReconstructionConfig config = read_plus_config(
      plus_data("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"));
  {
    WarningCapture warnings;
    select_plus_frames(s, config.coordinate_definitions, "Image", "Reference");
    EXPECT_EQ(warnings.all().find("not rigid"), std::string::npos) << warnings.all();
  }
  Mat4 m = *s.transform(7, "ProbeToTracker");
  for (int r = 0; r < 3; ++r) m.m[r][0] *= 1.5;  // the x axis stretched
  std::ostringstream text;
  text.precision(17);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) text << m.m[r][c] << " ";
  s.frame_fields[7]["ProbeToTrackerTransform"] = text.str();
  WarningCapture warnings;
  const PlusFrameSelection sel =
      select_plus_frames(s, config.coordinate_definitions, "Image", "Reference");
  EXPECT_EQ(sel.frames.size(), 97u);
  EXPECT_NE(warnings.all().find("frame 7's ProbeToTrackerTransform is not rigid (0.5"),
            std::string::npos)
      << warnings.all();
}

// A transform from the image's frame (ImageToReference, as PlusServer and `live compound
// --record` write it) carries the pixel spacing and may mirror an axis: no warning for that, but
// one for a shear.
TEST(PlusFrameSelection, ImageTransformsMayScaleAndMirrorButNotShear) {
  REQUIRE_PLUS_DATA();
  PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  const auto set_image_to_reference = [&](const Mat4& m) {
    std::ostringstream text;
    text.precision(17);
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) text << m.m[r][c] << " ";
    for (int k = 0; k < s.frame_count; ++k) {
      s.frame_fields[size_t(k)]["ImageToReferenceTransform"] = text.str();
      s.frame_fields[size_t(k)]["ImageToReferenceTransformStatus"] = "OK";
    }
  };
  Mat4 m = Mat4::identity();
  const double spacing[3] = {0.191, 0.191, -1.0};  // a flipped z axis, as an MF image may have
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m.m[r][c] = (r == c ? 1.0 : 0.0) * spacing[c];
  set_image_to_reference(m);
  {
    WarningCapture warnings;
    const PlusFrameSelection sel = select_plus_frames(s, {}, "Image", "Reference");
    EXPECT_EQ(sel.frames.size(), 97u);
    EXPECT_EQ(warnings.all().find("Transform"), std::string::npos) << warnings.all();
  }
  m.m[0][1] = 0.1;  // the y axis leans towards x
  set_image_to_reference(m);
  WarningCapture warnings;
  select_plus_frames(s, {}, "Image", "Reference");
  EXPECT_NE(warnings.all().find("ImageToReferenceTransform shears (axes 0.4"), std::string::npos)
      << warnings.all();
}

// A calibration applies to every frame: an all-zero one (XML, option or Python) is refused.
TEST(PlusFrameSelection, DegenerateCalibrationIsRefused) {
  REQUIRE_PLUS_DATA();
  const PlusSequence s = read_plus_sequence(plus_data("NwirePhantomFreehand.igs.mha"));
  ReconstructionOptions o;
  o.spacing_mm = Vec3{1, 1, 1};
  o.image_to_probe = Mat4::from_row_major(std::vector<double>(16, 0.0).data());
  EXPECT_NE(error_of<InputError>([&] {
              Reconstruction(FrameSource::plus(s), nullptr, o);
            }).find("image_to_probe: the pixel-to-probe matrix is all zero"),
            std::string::npos);
  o.image_to_probe->m[3][3] = 1;
  EXPECT_NE(error_of<InputError>([&] {
              Reconstruction(FrameSource::plus(s), nullptr, o);
            }).find("x axis to a point"),
            std::string::npos);
  // The same for 2D frames placed by poses.
  VolumeGrid g;
  g.dims = {8, 6, 2};
  const Volume frames = Volume::allocate(PixelType::UInt8, g);
  const FrameSource images = FrameSource::images(frames, {Pose{}, Pose{}}, "frames.npy");
  EXPECT_NE(error_of<InputError>([&] {
              Reconstruction(images, nullptr, o);
            }).find("image_to_probe: the pixel-to-probe matrix"),
            std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// Broken files

TEST(PlusSequenceErrors, TruncatedFilesAreFileErrors) {
  REQUIRE_PLUS_DATA();
  test::TempDir dir;
  // Real compressed files cut in half.
  for (const char* name : {"NwirePhantomFreehand.igs.mha", "NwirePhantomFreehand.igs.nrrd"}) {
    const std::string text = read_file(plus_data(name));
    const std::string path = dir.file(std::string("half_") + name);
    write_file(path, text.substr(0, text.size() / 2));
    const std::string e = error_of<FileError>([&] { read_plus_sequence(path); });
    EXPECT_NE(e.find(path), std::string::npos) << e;
    EXPECT_NE(e.find("truncated"), std::string::npos) << e;
  }
  // Raw files written by us cut in half, and short by one byte.
  for (const char* ext : {".mha", ".nrrd"}) {
    const PlusSequence s = make_sequence(PixelType::Float32, 30, 20, 5, "MF");
    const std::string full = dir.file(std::string("raw") + ext);
    write_plus_sequence(full, s, false);
    const std::string text = read_file(full);
    for (size_t keep : {text.size() / 2, text.size() - 1}) {
      const std::string path = dir.file(std::string("cut") + ext);
      write_file(path, text.substr(0, keep));
      const std::string e = error_of<FileError>([&] { read_plus_sequence(path); });
      EXPECT_NE(e.find(path), std::string::npos) << e;
    }
  }
}

TEST(PlusSequenceErrors, CorruptCompressedData) {
  test::TempDir dir;
  for (const char* ext : {".mha", ".nrrd"}) {
    const PlusSequence s = make_sequence(PixelType::UInt8, 64, 48, 6, "MF");
    const std::string path = dir.file(std::string("c") + ext);
    write_plus_sequence(path, s, true);
    std::string text = read_file(path);
    // Scribble over the middle of the compressed stream.
    const size_t header =
        std::string(ext) == ".mha" ? text.find("LOCAL\n") + 6 : text.find("\n\n") + 2;
    const size_t mid = header + (text.size() - header) / 2;
    for (size_t i = mid; i < mid + 16 && i < text.size(); ++i) text[i] = char(text[i] ^ 0x5a);
    write_file(path, text);
    const std::string e = error_of<FileError>([&] { read_plus_sequence(path); });
    EXPECT_NE(e.find(path), std::string::npos) << e;
  }
  // A header describing more pixels than the stream holds.
  const PlusSequence s = make_sequence(PixelType::UInt8, 8, 8, 2, "MF");
  const std::string path = dir.file("more.mha");
  write_plus_sequence(path, s, true);
  std::string text = read_file(path);
  const size_t at = text.find("DimSize = 8 8 2");
  text.replace(at, 15, "DimSize = 8 8 3");
  write_file(path, text);
  EXPECT_NE(error_of<FileError>([&] { read_plus_sequence(path); }).find("decompresses to"),
            std::string::npos);
}

TEST(PlusSequenceErrors, MissingAndGarbageFiles) {
  test::TempDir dir;
  const std::string missing = dir.file("nothing.igs.mha");
  EXPECT_NE(error_of<FileError>([&] { read_plus_sequence(missing); }).find(missing),
            std::string::npos);

  std::string noise(100000, '\0');
  uint32_t state = 12345;
  for (char& c : noise) {
    state = state * 1664525u + 1013904223u;
    c = char(state >> 24);
  }
  const std::string garbage = dir.file("garbage.igs.mha");
  write_file(garbage, noise);
  error_of<FileError>([&] { read_plus_sequence(garbage); });
  write_file(garbage, "hello world\nthis is not a sequence\n");
  error_of<FileError>([&] { read_plus_sequence(garbage); });
  write_file(garbage, "");
  error_of<FileError>([&] { read_plus_sequence(garbage); });
  // A MetaImage header that never reaches ElementDataFile.
  write_file(garbage, "ObjectType = Image\nNDims = 3\n");
  error_of<FileError>([&] { read_plus_sequence(garbage); });
}

TEST(PlusSequenceErrors, UnsupportedContents) {
  test::TempDir dir;
  const std::string path = dir.file("u.mha");
  auto expect_input_error = [&](const std::string& file, const std::string& needle) {
    write_file(path, file);
    const std::string e = error_of<InputError>([&] { read_plus_sequence(path); });
    EXPECT_NE(e.find(needle), std::string::npos) << e;
  };
  const std::string px(64, '\0');
  std::string msb = meta_header(2, 2, 2, "MET_SHORT", "");
  msb.replace(msb.find("MSB = False"), 11, "MSB = True");
  expect_input_error(msb + px, "big-endian");
  expect_input_error(meta_header(2, 2, 2, "MET_LONG_LONG", "") + px, "ElementType");
  expect_input_error(meta_header(2, 2, 2, "MET_UCHAR", "ElementNumberOfChannels = 2\n") + px,
                     "ElementNumberOfChannels = 2 (frames of 1, 3 or 4 components are read");
  const std::string nrrd = dir.file("u.nrrd");
  write_file(nrrd,
             "NRRD0004\ndimension: 3\ntype: uint16\nsizes: 2 2 1\nkinds: domain domain list\n"
             "encoding: raw\nendian: big\n\n" +
                 std::string(8, '\0'));
  EXPECT_NE(error_of<InputError>([&] { read_plus_sequence(nrrd); }).find("big-endian"),
            std::string::npos);
  write_file(nrrd,
             "NRRD0004\ndimension: 3\ntype: uint8\nsizes: 2 2 1\nkinds: domain domain list\n"
             "encoding: bzip2\n\n" +
                 std::string(4, '\0'));
  EXPECT_NE(error_of<InputError>([&] { read_plus_sequence(nrrd); }).find("encoding"),
            std::string::npos);
}

// RGB and RGBA frames (a video grabber's), laid out as IGSIO writes them: MetaImage with
// ElementNumberOfChannels, NRRD with a leading `vector` axis. They are read as their first
// component, what PLUS's reconstruction writes; grey frames stored so lose nothing, and colour
// in them is said once.
TEST(PlusSequenceFormats, RgbFramesAreReadAsTheirFirstComponent) {
  test::TempDir dir;
  const int w = 5, h = 4, n = 3;
  const PlusSequence grey = make_sequence(PixelType::UInt16, w, h, n, "MF");
  const auto interleaved = [&](int components) {  // RGBA: an opaque alpha, which is no colour
    std::string bytes;
    for (size_t i = 0; i < grey.pixels.size(); i += 2)
      for (int c = 0; c < components; ++c)
        bytes.append(c == 3 ? "\xff\xff" : reinterpret_cast<const char*>(&grey.pixels[i]), 2);
    return bytes;
  };
  const std::string mha = dir.file("rgb.igs.mha"), nrrd = dir.file("rgba.igs.nrrd");
  const std::string rgb = interleaved(3);
  write_file(mha, meta_header(w, h, n, "MET_USHORT", "ElementNumberOfChannels = 3\n") + rgb);
  write_file(nrrd,
             "NRRD0004\ndimension: 4\ntype: uint16\nsizes: 4 5 4 3\n"
             "kinds: vector domain domain list\nencoding: raw\nendian: little\n\n" +
                 interleaved(4));
  for (const std::string& path : {mha, nrrd}) {
    const test::CapturedWarnings warnings;
    const PlusSequence s = read_plus_sequence(path);
    EXPECT_EQ(s.width, w);
    EXPECT_EQ(s.height, h);
    EXPECT_EQ(s.frame_count, n);
    EXPECT_EQ(s.pixel_type, PixelType::UInt16);
    EXPECT_TRUE(s.pixels == grey.pixels) << path;
    EXPECT_TRUE(warnings.messages().empty()) << warnings.messages()[0];
  }
  // One pixel with colour: its red value is kept, and the file says so.
  std::string coloured = rgb;
  coloured[3 * 2 * 7 + 2] ^= 0x5a;  // pixel 7's green
  write_file(mha, meta_header(w, h, n, "MET_USHORT", "ElementNumberOfChannels = 3\n") + coloured);
  const test::CapturedWarnings warnings;
  EXPECT_TRUE(read_plus_sequence(mha).pixels == grey.pixels);
  ASSERT_EQ(warnings.messages().size(), 1u);
  EXPECT_EQ(warnings.messages()[0],
            mha +
                ": frames of 3 components: the first is used, as PLUS's reconstruction writes "
                "it; 1 of 60 pixels have components that differ (colour in the frames)");
  // Two components are no colour image: refused, naming the axis.
  write_file(nrrd,
             "NRRD0004\ndimension: 4\ntype: uint16\nsizes: 2 5 4 3\n"
             "kinds: vector domain domain list\nencoding: raw\nendian: little\n\n" +
                 interleaved(2));
  EXPECT_NE(error_of<InputError>([&] {
              read_plus_sequence(nrrd);
            }).find("a component axis (vector) of 2 (frames of 1, 3 or 4 components"),
            std::string::npos);
}

// Float frames holding NaN or infinite pixels are read as they are, with one warning.
TEST(PlusSequenceFormats, NonFinitePixelsAreCounted) {
  test::TempDir dir;
  PlusSequence s = make_sequence(PixelType::Float32, 4, 3, 2, "MF");
  reinterpret_cast<float*>(s.pixels.data())[5] = std::nanf("");
  write_plus_sequence(dir.file("f.mha"), s, false);
  WarningCapture warnings;
  read_plus_sequence(dir.file("f.mha"));
  ASSERT_EQ(warnings.list().size(), 1u);
  EXPECT_NE(warnings.list()[0].find("1 of 24 pixels are NaN or infinite"), std::string::npos)
      << warnings.all();
}

TEST(PlusSequenceFormats, TwoDimensionalAndOtherTypes) {
  test::TempDir dir;
  const std::string path = dir.file("single.mha");
  std::string h =
      "ObjectType = Image\nNDims = 2\nBinaryData = True\nDimSize = 3 2\n"
      "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n";
  const float v[6] = {1.5f, -2, 3, 4, 5, 6.25f};
  write_file(path, h + std::string(reinterpret_cast<const char*>(v), sizeof v));
  const PlusSequence s = read_plus_sequence(path);
  EXPECT_EQ(s.frame_count, 1);
  EXPECT_EQ(s.width, 3);
  EXPECT_EQ(s.height, 2);
  EXPECT_EQ(s.pixel_type, PixelType::Float32);
  EXPECT_EQ(std::memcmp(s.pixels.data(), v, sizeof v), 0);
}

// ---------------------------------------------------------------------------------------------
// Configuration XML

TEST(PlusConfigReal, NwireSettings) {
  REQUIRE_PLUS_DATA();
  REQUIRE_PUGIXML();
  WarningCapture warnings;
  const std::string path =
      plus_data("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml");
  const PlusReconstructionConfig c = read_plus_config(path);
  EXPECT_EQ(c.path, path);
  EXPECT_EQ(c.settings.interpolation, Interpolation::Linear);
  EXPECT_EQ(c.settings.mode, CompoundingMode::Mean);
  EXPECT_FALSE(c.settings.fill_holes);
  EXPECT_EQ(c.clip.x, 167);
  EXPECT_EQ(c.clip.y, 62);
  EXPECT_EQ(c.clip.width, 496);  // PLUS's size 495 covers 496 pixels
  EXPECT_EQ(c.clip.height, 489);
  EXPECT_FALSE(c.clip.fan);
  ASSERT_TRUE(c.output_spacing_mm.has_value());
  EXPECT_EQ(*c.output_spacing_mm, (Vec3{0.5, 0.5, 0.5}));
  EXPECT_FALSE(c.output_origin_mm.has_value());
  EXPECT_FALSE(c.output_extent.has_value());
  EXPECT_EQ(c.skip_interval, 1);
  EXPECT_EQ(c.image_frame, "Image");
  EXPECT_EQ(c.reference_frame, "Reference");
  const auto image_to_probe = c.coordinate_definitions.get("Image", "Probe");
  ASSERT_TRUE(image_to_probe.has_value());
  expect_matrix_near(*image_to_probe,
                     row_major({-0.0094, -0.0739, -0.0028, -103.5322, 0.0774, -0.0076, -0.0049,
                                -43.1227, 0.0046, -0.0032, 0.0760, -93.3, 0, 0, 0, 1}),
                     0);
  EXPECT_TRUE(c.coordinate_definitions.get("Phantom", "Reference").has_value());
  // Optimization is acted on (by --plus-exact), so it is not among the ignored attributes.
  EXPECT_EQ(c.optimization, "NONE");
  EXPECT_EQ(c.settings.plus_optimization, PlusOptimization::None);
  EXPECT_EQ(c.ignored_attributes, (std::vector<std::string>{"NumberOfThreads"}));
  EXPECT_TRUE(c.unknown_attributes.empty());
  EXPECT_TRUE(warnings.list().empty()) << warnings.all();
}

TEST(PlusConfigReal, BoneDeprecatedCompounding) {
  REQUIRE_PLUS_DATA();
  REQUIRE_PUGIXML();
  WarningCapture warnings;
  const PlusReconstructionConfig c = read_plus_config(plus_data("BoneUltrasound_L14_config.xml"));
  EXPECT_EQ(c.settings.mode, CompoundingMode::Mean);  // Compounding="On"
  EXPECT_EQ(c.settings.interpolation, Interpolation::Linear);
  EXPECT_FALSE(c.settings.fill_holes);  // FillHoles="Off"
  EXPECT_EQ(c.clip.width, 821);         // cut at the frame's edge when used
  EXPECT_EQ(c.clip.height, 617);
  EXPECT_TRUE(c.coordinate_definitions.get("Image", "Probe").has_value());  // tabs and newlines
  EXPECT_DOUBLE_EQ(c.coordinate_definitions.get("Image", "Probe")->m[1][3], 50.76);
  ASSERT_FALSE(warnings.list().empty());
  EXPECT_NE(warnings.all().find("Compounding"), std::string::npos) << warnings.all();
  EXPECT_NE(warnings.all().find("deprecated"), std::string::npos) << warnings.all();
}

class PlusConfigSynthetic : public ::testing::Test {
 protected:
  void SetUp() override { REQUIRE_PUGIXML(); }
  std::string write(const std::string& volume_reconstruction, const std::string& extra = "") {
    const std::string path = dir_.file("config.xml");
    write_file(path,
               "<PlusConfiguration version=\"2.0\">\n"
               "  <CoordinateDefinitions>\n"
               "    <Transform From=\"Image\" To=\"Probe\" Matrix=\"\n\t0.1 0 0 1\n\t0 0.1 0 2\n"
               "\t0 0 0.1 3\n\t0 0 0 1\" />\n"
               "  </CoordinateDefinitions>\n" +
                   extra + volume_reconstruction + "\n</PlusConfiguration>\n");
    return path;
  }
  test::TempDir dir_;
};

TEST_F(PlusConfigSynthetic, FanHoleFillingAndUnknownAttributes) {
  WarningCapture warnings;
  const std::string path = write(
      "<VolumeReconstruction ImageCoordinateFrame=\"Image\" ReferenceCoordinateFrame=\"Tracker\"\n"
      "  OutputSpacing=\"0.2 0.3 0.4\" OutputOrigin=\"-1 -2 -3\" OutputExtent=\"0 9 0 19 0 29\"\n"
      "  ClipRectangleOrigin=\"10 20\" ClipRectangleSize=\"100 200\"\n"
      "  FanAnglesDeg=\"-30 35\" FanOriginPixel=\"60 -5\" FanRadiusStartPixel=\"12\"\n"
      "  FanRadiusStopPixel=\"190\" PixelRejectionThreshold=\"3.5\" SkipInterval=\"2\"\n"
      "  Interpolation=\"nearest_neighbor\" CompoundingMode=\"maximum\" FillHoles=\"on\"\n"
      "  NumberOfThreads=\"4\" FooBar=\"1\">\n"
      "  <HoleFilling>\n"
      "    <HoleFillingElement Type=\"GAUSSIAN\" Size=\"5\" Stdev=\"1.25\" "
      "MinimumKnownVoxelsRatio=\"0.25\"/>\n"
      "    <HoleFillingElement Type=\"STICK\" StickLengthLimit=\"7\" NumberOfSticksToUse=\"3\"/>\n"
      "    <HoleFillingElement Type=\"NEAREST_NEIGHBOR\" Size=\"3\" "
      "MinimumKnownVoxelsRatio=\"0.5\"/>\n"
      "    <HoleFillingElement Type=\"DISTANCE_WEIGHT_INVERSE\" Size=\"7\" "
      "MinimumKnownVoxelsRatio=\"0.1\" Colour=\"red\"/>\n"
      "    <HoleFillingElement Type=\"GAUSSIAN_ACCUMULATION\" Size=\"3\" Stdev=\"0.5\" "
      "MinimumKnownVoxelsRatio=\"0.2\"/>\n"
      "  </HoleFilling>\n"
      "</VolumeReconstruction>");
  const PlusReconstructionConfig c = read_plus_config(path);
  EXPECT_EQ(c.reference_frame, "Tracker");
  EXPECT_EQ(*c.output_spacing_mm, (Vec3{0.2, 0.3, 0.4}));
  EXPECT_EQ(*c.output_origin_mm, (Vec3{-1, -2, -3}));
  EXPECT_EQ(*c.output_extent, (std::array<int, 6>{0, 9, 0, 19, 0, 29}));
  EXPECT_EQ(c.clip.x, 10);
  EXPECT_EQ(c.clip.y, 20);
  EXPECT_EQ(c.clip.width, 101);
  EXPECT_EQ(c.clip.height, 201);
  EXPECT_TRUE(c.clip.fan);
  EXPECT_EQ(c.clip.fan_angles_deg[0], -30);
  EXPECT_EQ(c.clip.fan_angles_deg[1], 35);
  EXPECT_EQ(c.clip.fan_origin_px[0], 60);
  EXPECT_EQ(c.clip.fan_origin_px[1], -5);
  EXPECT_EQ(c.clip.fan_radius_px[0], 12);
  EXPECT_EQ(c.clip.fan_radius_px[1], 190);
  EXPECT_EQ(c.settings.rejection_threshold, 3.5);
  EXPECT_EQ(c.skip_interval, 2);
  EXPECT_EQ(c.settings.interpolation, Interpolation::Nearest);
  EXPECT_EQ(c.settings.mode, CompoundingMode::Max);
  ASSERT_TRUE(c.settings.fill_holes);
  ASSERT_EQ(c.settings.hole_filling.size(), 5u);
  const auto& k = c.settings.hole_filling;
  EXPECT_EQ(k[0].type, HoleFillingKernel::Gaussian);
  EXPECT_EQ(k[0].size, 5);
  EXPECT_EQ(k[0].stdev, 1.25);
  EXPECT_EQ(k[0].minimum_known_ratio, 0.25);
  EXPECT_EQ(k[1].type, HoleFillingKernel::Stick);
  EXPECT_EQ(k[1].stick_length_limit, 7);
  EXPECT_EQ(k[1].sticks_to_use, 3);
  EXPECT_EQ(k[2].type, HoleFillingKernel::NearestNeighbor);
  EXPECT_EQ(k[2].size, 3);
  EXPECT_EQ(k[3].type, HoleFillingKernel::DistanceWeightInverse);
  EXPECT_EQ(k[3].size, 7);
  EXPECT_EQ(k[3].minimum_known_ratio, 0.1);
  EXPECT_EQ(k[4].type, HoleFillingKernel::GaussianAccumulation);
  EXPECT_EQ(k[4].stdev, 0.5);
  EXPECT_EQ(c.ignored_attributes, (std::vector<std::string>{"NumberOfThreads"}));
  ASSERT_EQ(c.unknown_attributes.size(), 2u);
  EXPECT_EQ(c.unknown_attributes[0], "FooBar");
  EXPECT_NE(c.unknown_attributes[1].find("Colour"), std::string::npos);
  // One warning lists the unknown attributes (GAUSSIAN_ACCUMULATION is read as it is).
  int listing = 0;
  for (const std::string& w : warnings.list())
    if (w.find("FooBar") != std::string::npos) {
      ++listing;
      EXPECT_NE(w.find("Colour"), std::string::npos) << w;
    }
  EXPECT_EQ(listing, 1) << warnings.all();
  EXPECT_EQ(warnings.all().find("GAUSSIAN_ACCUMULATION"), std::string::npos) << warnings.all();
  EXPECT_EQ(warnings.list().size(), 1u) << warnings.all();
}

TEST_F(PlusConfigSynthetic, DefaultsAndDeprecatedNames) {
  {
    WarningCapture warnings;
    const PlusReconstructionConfig c = read_plus_config(write("<VolumeReconstruction/>"));
    EXPECT_EQ(c.settings.interpolation, Interpolation::Nearest);  // PLUS's default
    EXPECT_EQ(c.settings.mode, CompoundingMode::Mean);
    EXPECT_EQ(c.clip.width, -1);
    EXPECT_FALSE(c.clip.fan);
    EXPECT_FALSE(c.output_spacing_mm.has_value());
    EXPECT_NE(warnings.all().find("no CompoundingMode"), std::string::npos) << warnings.all();
  }
  {
    WarningCapture warnings;
    const PlusReconstructionConfig c = read_plus_config(
        write("<VolumeReconstruction Compounding=\"OFF\" FanAngles=\"-10 10\" FanOrigin=\"5 6\" "
              "FanDepth=\"300\" SkipInterval=\"0\" ClipRectangleOrigin=\"4 4\"/>"));
    EXPECT_EQ(c.settings.mode, CompoundingMode::Latest);
    EXPECT_TRUE(c.clip.fan);
    EXPECT_EQ(c.clip.fan_angles_deg[0], -10);
    EXPECT_EQ(c.clip.fan_origin_px[1], 6);
    EXPECT_EQ(c.clip.fan_radius_px[0], 0);
    EXPECT_EQ(c.clip.fan_radius_px[1], 300);
    EXPECT_EQ(c.skip_interval, 1);
    EXPECT_EQ(c.clip.width, -1);  // an origin without a size clips nothing (PLUS)
    for (const char* w : {"Compounding", "FanAngles", "FanOrigin", "FanDepth", "SkipInterval"})
      EXPECT_NE(warnings.all().find(w), std::string::npos) << w << "\n" << warnings.all();
  }
  {
    WarningCapture warnings;
    const PlusReconstructionConfig c =
        read_plus_config(write("<VolumeReconstruction Calculation=\"MAXIMUM\" Compounding=\"OFF\" "
                               "FanAnglesDeg=\"0 0\" FanRadiusStopPixel=\"100\"/>"));
    EXPECT_EQ(c.settings.mode, CompoundingMode::Max);
    EXPECT_FALSE(c.clip.fan);  // both angles zero: no fan (PLUS's FanClippingApplied)
  }
  {
    WarningCapture warnings;
    const PlusReconstructionConfig c =
        read_plus_config(write("<VolumeReconstruction CompoundingMode=\"LATEST\" "
                               "Compounding=\"ON\" FanAnglesDeg=\"0 20\"/>"));
    EXPECT_EQ(c.settings.mode, CompoundingMode::Latest);  // CompoundingMode wins
    EXPECT_TRUE(c.clip.fan);                              // one non-zero angle is a fan
    EXPECT_EQ(c.clip.fan_radius_px[1], 500);              // PLUS's default stop radius
  }
}

TEST_F(PlusConfigSynthetic, BadValuesAreInputErrors) {
  struct Case {
    std::string xml, needle;
  };
  for (const Case& c : std::vector<Case>{
           {"<VolumeReconstruction OutputSpacing=\"0.5 0.5\"/>",
            "OutputSpacing: expected 3 numbers, got '0.5 0.5'"},
           {"<VolumeReconstruction OutputSpacing=\"0.5 x 0.5\"/>", "OutputSpacing"},
           {"<VolumeReconstruction OutputSpacing=\"0.5 0 0.5\"/>", "positive"},
           {"<VolumeReconstruction ClipRectangleSize=\"10.5 20\"/>", "expected 2 integers"},
           {"<VolumeReconstruction OutputExtent=\"0 1 2 3 4\"/>", "OutputExtent"},
           {"<VolumeReconstruction CompoundingMode=\"IMPORTANCE_MASK\"/>", "not supported"},
           {"<VolumeReconstruction CompoundingMode=\"MEDIAN\"/>", "MEAN, MAXIMUM, LATEST"},
           {"<VolumeReconstruction Interpolation=\"CUBIC\"/>", "LINEAR, NEAREST_NEIGHBOR"},
           {"<VolumeReconstruction Optimization=\"TURBO\"/>", "NONE, PARTIAL, FULL"},
           {"<VolumeReconstruction FillHoles=\"MAYBE\"/>", "FillHoles"},
           {"<VolumeReconstruction FillHoles=\"ON\"/>", "HoleFilling"},
           {"<VolumeReconstruction FillHoles=\"ON\"><HoleFilling><HoleFillingElement "
            "Type=\"GAUSSIAN\" Size=\"3\" MinimumKnownVoxelsRatio=\"0.5\"/></HoleFilling>"
            "</VolumeReconstruction>",
            "Stdev"},
           {"<VolumeReconstruction FillHoles=\"ON\"><HoleFilling><HoleFillingElement "
            "Type=\"CUBIC\"/></HoleFilling></VolumeReconstruction>",
            "Type"},
           {"<Nothing/>", "no VolumeReconstruction"},
       }) {
    WarningCapture quiet;
    const std::string path = write(c.xml);
    const std::string e = error_of<InputError>([&] { read_plus_config(path); });
    EXPECT_NE(e.find(c.needle), std::string::npos) << c.xml << "\n" << e;
    EXPECT_NE(e.find(path), std::string::npos) << e;
  }
  // An all-zero calibration would put every pixel of every frame at one point.
  write(R"(<VolumeReconstruction CompoundingMode="MEAN"/>)");
  const std::string zero = dir_.file("zero.xml");
  write_file(zero,
             "<PlusConfiguration><CoordinateDefinitions><Transform From=\"Image\" To=\"Probe\" "
             "Matrix=\"0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\"/></CoordinateDefinitions>"
             "<VolumeReconstruction CompoundingMode=\"MEAN\"/></PlusConfiguration>");
  EXPECT_NE(error_of<InputError>([&] {
              read_plus_config(zero);
            }).find("Transform[1] (ImageToProbe)/@Matrix is all zero"),
            std::string::npos);
  // A malformed calibration matrix.
  const std::string path = dir_.file("matrix.xml");
  write_file(path,
             "<PlusConfiguration><CoordinateDefinitions><Transform From=\"Image\" To=\"Probe\" "
             "Matrix=\"1 0 0 0 1 0\"/></CoordinateDefinitions><VolumeReconstruction "
             "CompoundingMode=\"MEAN\"/></PlusConfiguration>");
  EXPECT_NE(error_of<InputError>([&] { read_plus_config(path); }).find("16 finite numbers"),
            std::string::npos);
}

TEST_F(PlusConfigSynthetic, MissingAndMalformedFiles) {
  const std::string missing = dir_.file("none.xml");
  EXPECT_NE(error_of<FileError>([&] { read_plus_config(missing); }).find(missing),
            std::string::npos);
  const std::string broken = dir_.file("broken.xml");
  write_file(broken, "<PlusConfiguration><VolumeReconstruction></PlusConfiguration>");
  EXPECT_NE(error_of<FileError>([&] { read_plus_config(broken); }).find("malformed XML"),
            std::string::npos);
}

}  // namespace
}  // namespace sonoslice
