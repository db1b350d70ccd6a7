// The ITK edge of sonoslice: medical image formats in and out, geometry included.
#include "ItkImageIO.h"

#include <sys/mman.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>

#include <gdcmImageHelper.h>
#include <gdcmReader.h>
#include <gdcmTrace.h>
#include <itkGDCMImageIO.h>
#include <itkGDCMImageIOFactory.h>
#include <itkGDCMSeriesFileNames.h>
#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageIOFactory.h>
#include <itkImageSeriesReader.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>
#include <itkPNGImageIOFactory.h>

#include <itkOutputWindow.h>

#include "DicomStructure.h"
#include "NiftiData.h"
#include "TextParse.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {
namespace itk_io {
namespace {

// ITK's warnings arrive as multi-line text with source locations; pass on one clean line.
class WarningWindow : public itk::OutputWindow {
 public:
  itkNewMacro(WarningWindow);
  void DisplayText(const char* text) override {
    // "WARNING: In /path/file.cxx, line N\nClass (0x...): message" → "message"
    const std::string t = text::one_line_message(text ? text : "", /*drop_location=*/true);
    // A directory without a DICOM series is sonoslice's own error (naming the directory).
    if (t.find("No Series were found") != std::string::npos) return;
    if (!t.empty()) warn("ITK: " + t);
  }
};

// MetaIO (MetaImage's library) reports trouble only on std::cerr: short reads, after which it
// returns success, and header errors, after which ITK says "No such file or directory" about a
// file that exists. This captures what it prints during a read so that it can become the error.
class CerrCapture {
 public:
  CerrCapture() : old_(std::cerr.rdbuf(text_.rdbuf())) {}
  ~CerrCapture() { std::cerr.rdbuf(old_); }
  std::string text() const { return text::one_line_message(text_.str()); }
  /// The first line printed: the cause; what follows is the library unwinding. A source location
  /// in front ("./Modules/.../vnl_svd.hxx: ") goes.
  std::string first_line() const {
    const std::string all = text_.str();
    std::string line = text::one_line_message(all.substr(0, all.find('\n')));
    const size_t colon = line.find(": ");
    if ((line.rfind("./", 0) == 0 || line.rfind("/", 0) == 0) && colon != std::string::npos)
      line = line.substr(colon + 2);
    return line;
  }

 private:
  std::stringstream text_;
  std::streambuf* old_;
};

// Everything a library prints on the process's standard error while ITK writes: NIfTI's C library
// prints "** ERROR: NWAD: wrote only N of M bytes" with C stdio and carries on, MetaIO prints on
// std::cerr. Captured (fd 2 into a memory file, std::cerr into a string) so the caller can say it
// in its one line, or pass it on as a warning, instead of the library's lines reaching the
// terminal. Process-wide while it lasts: meant for the short write and re-read of one file.
class StderrCapture {
 public:
  StderrCapture() : cerr_(std::cerr.rdbuf(text_.rdbuf())) {
    std::fflush(stderr);
    saved_ = ::dup(STDERR_FILENO);
    memory_ = ::memfd_create("sonoslice-stderr", MFD_CLOEXEC);
    if (saved_ < 0 || memory_ < 0 || ::dup2(memory_, STDERR_FILENO) < 0) release_fds();
  }
  ~StderrCapture() { finish(); }
  StderrCapture(const StderrCapture&) = delete;
  StderrCapture& operator=(const StderrCapture&) = delete;

  /// Stops capturing; what was printed, as one line.
  std::string finish() {
    if (cerr_) std::cerr.rdbuf(cerr_);
    cerr_ = nullptr;
    std::string captured = text_.str();
    if (saved_ >= 0) {
      std::fflush(stderr);
      ::dup2(saved_, STDERR_FILENO);
      char buffer[4096];
      for (off_t at = 0;;) {
        const ssize_t n = ::pread(memory_, buffer, sizeof buffer, at);
        if (n <= 0 || captured.size() > 16384) break;
        captured.append(buffer, size_t(n));
        at += n;
      }
    }
    release_fds();
    return text::one_line_message(captured);
  }

 private:
  void release_fds() {
    if (saved_ >= 0) ::close(saved_);
    if (memory_ >= 0) ::close(memory_);
    saved_ = memory_ = -1;
  }
  std::stringstream text_;
  std::streambuf* cerr_;
  int saved_ = -1, memory_ = -1;
};

// Registered explicitly so the formats work however the executable was linked.
void register_factories() {
  static std::once_flag once;
  std::call_once(once, [] {
    itk::OutputWindow::SetInstance(WarningWindow::New());
    // GDCM prints its warnings and errors to std::cerr, several lines each; its failures reach
    // sonoslice as ITK exceptions, and the series checks say what its warnings would.
    gdcm::Trace::WarningOff();
    gdcm::Trace::ErrorOff();
    itk::NiftiImageIOFactory::RegisterOneFactory();
    itk::MetaImageIOFactory::RegisterOneFactory();
    itk::NrrdImageIOFactory::RegisterOneFactory();
    itk::GDCMImageIOFactory::RegisterOneFactory();
    itk::PNGImageIOFactory::RegisterOneFactory();
  });
}

// ITK's exception text is several lines with source locations and object addresses
// ("ITK ERROR: NrrdImageIO(0x55c3d78f3040): Read: Error reading ..."); keep what it says. Teem's
// NRRD errors are a chain of "[nrrd] function: trouble" clauses whose last one is the cause.
std::string describe(const itk::ExceptionObject& e) {
  std::string s = text::one_line_message(e.GetDescription());
  for (const char* prefix : {"ITK ERROR: ", "itk::ERROR: "})
    if (s.rfind(prefix, 0) == 0) {
      const size_t close = s.find("): ");
      if (close != std::string::npos) s = s.substr(close + 3);
    }
  const size_t nrrd = s.rfind("[nrrd] ");
  if (nrrd != std::string::npos) {
    std::string cause = s.substr(nrrd + 7);
    const size_t colon = cause.find(": ");  // "_nrrdCalloc: couldn't allocate ..."
    if (colon != std::string::npos && cause.compare(0, 1, "_") == 0)
      cause = cause.substr(colon + 2);
    s = "NRRD: " + cause;
  }
  return s;
}

// ---- text headers (MetaImage, NRRD), checked before ITK reads them -----------------------------
//
// MetaIO keeps sizes in `int` and turns an unparsable number into a cascade of messages on
// std::cerr ("ElementType required and not defined" for "ElementSpacing = nan 1 1"); ITK's NRRD
// reader turns a NaN spacing into 1 mm. The few fields that carry sizes and geometry are checked
// here so that the error names the field and its value.

// `key → value` of the header lines: MetaImage `Key = Value` up to ElementDataFile, NRRD
// `key: value` up to the blank line before the data. Keys are lower-case.
std::map<std::string, std::string> header_fields(const std::string& path, bool nrrd) {
  std::ifstream in(path, std::ios::binary);
  std::map<std::string, std::string> fields;
  std::string line;
  size_t bytes = 0;
  while (std::getline(in, line) && bytes < (size_t(1) << 20)) {
    bytes += line.size() + 1;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (nrrd && line.empty()) break;
    if (nrrd && line[0] == '#') continue;
    const size_t at = line.find(nrrd ? ':' : '=');
    if (at == std::string::npos || (nrrd && line.compare(at, 2, ":=") == 0)) continue;
    const std::string key = text::lower(text::trim(line.substr(0, at)));
    fields[key] = text::trim(line.substr(at + 1));
    if (!nrrd && key == "elementdatafile") break;
  }
  return fields;
}

void check_numbers(const std::string& path, const std::string& field, const std::string& value,
                   bool positive) {
  // NRRD writes vectors as "(1,0,0) (0,1,0)" and "none" for axes without a direction.
  std::string v = value;
  for (char& c : v)
    if (c == '(' || c == ')' || c == ',') c = ' ';
  for (const std::string& t : text::split_ws(v)) {
    double x = 0;
    if (t == "none") continue;
    if (!text::parse_double(t, &x) || (positive && !(x > 0)))
      throw InputError(
          "volume '" + path + "': " + field + " " + text::quote_value(value) + ": " +
          (positive ? "spacings must be positive numbers of mm" : "expected finite numbers"));
    // ITK's readers turn what overflows on the way (the norm of a 1e300 NRRD space direction)
    // into a 1 mm spacing without a word.
    if (std::fabs(x) > kMaxGeometryMm)
      throw InputError("volume '" + path + "': " + field + " " + text::quote_value(value) +
                       ": beyond any scanner's extent (at most 1e9 mm)");
  }
}

void check_sizes(const std::string& path, const std::string& field, const std::string& value,
                 int64_t limit) {
  const std::vector<std::string> tokens = text::split_ws(value);
  for (const std::string& t : tokens) {
    int64_t n = 0;
    if (!text::parse_int64(t, &n) || n < 1 || n > limit)
      throw InputError("volume '" + path + "': " + field + " " + text::quote_value(value) +
                       " is not a list of sizes (whole numbers from 1 to " + std::to_string(limit) +
                       ")");
  }
  if (tokens.empty()) throw InputError("volume '" + path + "': " + field + " is empty");
}

// A detached header's data file must exist: ITK reports its absence as the header's ("File cannot
// be read: x.mhd ... No such file or directory").
void check_data_file(const std::string& path, const std::string& field, const std::string& name) {
  const std::string lower = text::lower(name);
  if (name.empty() || lower == "local" || lower.rfind("list", 0) == 0 ||
      name.find('%') != std::string::npos)
    return;  // inline data, or one file per slice (ITK lists them)
  const std::filesystem::path data = std::filesystem::path(name).is_absolute()
                                         ? std::filesystem::path(name)
                                         : std::filesystem::path(path).parent_path() / name;
  std::error_code ec;
  if (!std::filesystem::exists(data, ec))
    throw FileError("cannot read volume '" + path + "': its data file '" + data.string() + "' (" +
                    field + ") does not exist");
}

void check_text_header(const std::string& path, ImageFormat format) {
  if (format == ImageFormat::MetaImage) {
    const auto f = header_fields(path, false);
    if (auto it = f.find("elementdatafile"); it != f.end())
      check_data_file(path, "ElementDataFile", it->second);
    if (auto it = f.find("dimsize"); it != f.end())
      check_sizes(path, "DimSize", it->second, std::numeric_limits<int>::max());
    for (const char* key : {"elementspacing", "elementsize"})
      if (auto it = f.find(key); it != f.end())
        check_numbers(path, key == std::string("elementspacing") ? "ElementSpacing" : "ElementSize",
                      it->second, true);
    for (const char* key : {"offset", "origin", "position", "transformmatrix", "rotation",
                            "orientation", "centerofrotation"})
      if (auto it = f.find(key); it != f.end()) check_numbers(path, key, it->second, false);
  } else if (format == ImageFormat::Nrrd) {
    std::ifstream in(path, std::ios::binary);
    char magic[4] = {0};
    in.read(magic, 4);
    if (std::memcmp(magic, "NRRD", 4) != 0) return;  // ITK says what it is not
    const auto f = header_fields(path, true);
    for (const char* key : {"data file", "datafile"})
      if (auto it = f.find(key); it != f.end()) check_data_file(path, key, it->second);
    if (auto it = f.find("sizes"); it != f.end())
      check_sizes(path, "sizes", it->second, std::numeric_limits<int64_t>::max());
    int64_t dimension = 0;
    auto dim = f.find("dimension");
    // NaN is NRRD's "unknown", legitimate for a non-spatial axis (vector components, time); a
    // scalar image of up to three dimensions has spatial axes only.
    if (dim == f.end() || !text::parse_int64(dim->second, &dimension) || dimension > 3) return;
    if (auto it = f.find("spacings"); it != f.end())
      check_numbers(path, "spacings", it->second, true);
    for (const char* key : {"space directions", "space origin"})
      if (auto it = f.find(key); it != f.end()) check_numbers(path, key, it->second, false);
  }
}

// The byte count of the image a header describes, checked for overflow before ITK multiplies the
// sizes itself (a MetaImage "DimSize = -5 4 4" reached ITK as 2^64 - 5 voxels).
uint64_t checked_image_bytes(itk::ImageIOBase* io, const std::string& path) {
  uint64_t bytes = uint64_t(io->GetComponentSize()) * io->GetNumberOfComponents();
  std::ostringstream sizes;
  for (unsigned d = 0; d < io->GetNumberOfDimensions(); ++d)
    sizes << (d ? " x " : "") << io->GetDimensions(d);
  for (unsigned d = 0; d < io->GetNumberOfDimensions(); ++d) {
    const uint64_t n = io->GetDimensions(d);
    if (n == 0 || n > uint64_t(std::numeric_limits<int64_t>::max()) ||
        (bytes != 0 && n > uint64_t(std::numeric_limits<int64_t>::max()) / bytes))
      throw InputError("volume '" + path + "': the header's sizes (" + sizes.str() +
                       ") are not a valid image size");
    bytes *= n;
  }
  const unsigned long long available = available_memory_bytes();
  if (bytes > available) {
    std::ostringstream s;
    s << "volume '" << path << "': its header describes " << sizes.str() << " voxels ("
      << bytes / kMiB << " MiB), more than the " << available / kMiB << " MiB of memory available";
    throw ResourceError(s.str());
  }
  return bytes;
}

PixelType to_pixel_type(itk::IOComponentEnum component, const std::string& path) {
  using C = itk::IOComponentEnum;
  switch (component) {
    case C::UCHAR:
      return PixelType::UInt8;
    case C::CHAR:
      return PixelType::Int8;
    case C::USHORT:
      return PixelType::UInt16;
    case C::SHORT:
      return PixelType::Int16;
    case C::UINT:
      return PixelType::UInt32;
    case C::INT:
      return PixelType::Int32;
    case C::FLOAT:
      return PixelType::Float32;
    case C::DOUBLE:
      return PixelType::Float64;
    default:
      break;
  }
  throw InputError("volume '" + path + "': unsupported pixel type " +
                   itk::ImageIOBase::GetComponentTypeAsString(component) +
                   " (supported: uint8, int8, uint16, int16, uint32, int32, float32, float64)");
}

template <typename T>
using Image3 = itk::Image<T, 3>;

template <typename T>
Volume to_volume(typename Image3<T>::Pointer image, const std::string& path) {
  VolumeGrid g;
  const auto size = image->GetLargestPossibleRegion().GetSize();
  for (int a = 0; a < 3; ++a) {
    g.dims[a] = int64_t(size[a]);
    g.spacing_mm[a] = image->GetSpacing()[a];
    g.origin_mm[a] = image->GetOrigin()[a];
    for (int b = 0; b < 3; ++b) g.direction.m[a][b] = image->GetDirection()[a][b];
  }
  g.validate("volume '" + path + "'");
  T* data = image->GetBufferPointer();
  // The ITK image owns the voxels; the Volume keeps it alive (no copy).
  auto holder = std::make_shared<typename Image3<T>::Pointer>(image);
  return Volume::wrap(data, PixelTypeOf<T>::value, g, holder);
}

template <typename T>
Volume read_typed(const std::string& path, itk::ImageIOBase* io) {
  auto reader = itk::ImageFileReader<Image3<T>>::New();
  reader->SetFileName(path);
  reader->SetImageIO(io);
  const bool metaio = std::string(io->GetNameOfClass()) == "MetaImageIO";
  std::string complaint;
  {
    std::unique_ptr<CerrCapture> capture(metaio ? new CerrCapture : nullptr);
    try {
      reader->Update();
    } catch (const itk::ExceptionObject& e) {
      // The header was read before: what fails now is the voxel data (NRRD's "fread got only
      // 49814 2-sized things, not 1638400").
      throw FileError("cannot read volume '" + path + "': truncated or corrupt file (" +
                      describe(e) + ")");
    }
    if (capture) complaint = capture->text();
  }
  if (!complaint.empty())
    throw FileError("cannot read volume '" + path + "': truncated or corrupt file (" + complaint +
                    ")");
  return to_volume<T>(reader->GetOutput(), path);
}

// The geometry a header describes, as ITK's reader gives it to a 3-D image: the missing axes of a
// 2-D image have unit spacing, zero origin and the identity's direction.
VolumeGrid grid_of(itk::ImageIOBase* io, const std::string& path) {
  const unsigned dims = io->GetNumberOfDimensions();
  VolumeGrid grid;
  for (unsigned a = 0; a < 3; ++a) {
    grid.dims[a] = a < dims ? int64_t(io->GetDimensions(a)) : 1;
    grid.spacing_mm[a] = a < dims ? io->GetSpacing(a) : 1.0;
    grid.origin_mm[a] = a < dims ? io->GetOrigin(a) : 0.0;
    const auto axis = io->GetDirection(a < dims ? a : 0);
    for (unsigned b = 0; b < 3; ++b)
      grid.direction.m[b][a] = a < dims ? (b < axis.size() ? axis[b] : 0.0) : (a == b ? 1.0 : 0.0);
  }
  grid.validate("volume '" + path + "'");
  return grid;
}

// An RGB or RGBA image as its first component (first_component(): what PLUS reconstructs of
// colour frames); the pixels whose colour components differ are counted into `colour_pixels`.
Volume read_first_component(const std::string& path, itk::ImageIOBase* io, PixelType type,
                            int64_t* colour_pixels) {
  const VolumeGrid grid = grid_of(io, path);
  const int components = int(io->GetNumberOfComponents());
  const int64_t count = grid.voxel_count();
  std::vector<uint8_t> pixels(size_t(count) * size_t(components) * pixel_size(type));
  std::string complaint;
  itk::ImageIORegion region(io->GetNumberOfDimensions());
  for (unsigned d = 0; d < io->GetNumberOfDimensions(); ++d) {
    region.SetIndex(d, 0);
    region.SetSize(d, io->GetDimensions(d));
  }
  io->SetIORegion(region);
  {
    CerrCapture capture;
    io->Read(pixels.data());
    complaint = capture.text();
  }
  if (!complaint.empty())
    throw FileError("cannot read volume '" + path + "': truncated or corrupt file (" + complaint +
                    ")");
  Volume volume = Volume::allocate(type, grid);
  *colour_pixels +=
      first_component(pixels.data(), type, count, components, static_cast<uint8_t*>(volume.data()));
  return volume;
}

template <typename T>
Volume read_series_typed(const std::vector<std::string>& files, const std::string& directory) {
  auto reader = itk::ImageSeriesReader<Image3<T>>::New();
  auto io = itk::GDCMImageIO::New();
  reader->SetImageIO(io);
  reader->SetFileNames(files);
  reader->Update();
  return to_volume<T>(reader->GetOutput(), directory);
}

itk::IOComponentEnum to_component(PixelType type) {
  using C = itk::IOComponentEnum;
  switch (type) {
    case PixelType::UInt8:
      return C::UCHAR;
    case PixelType::Int8:
      return C::CHAR;
    case PixelType::UInt16:
      return C::USHORT;
    case PixelType::Int16:
      return C::SHORT;
    case PixelType::UInt32:
      return C::UINT;
    case PixelType::Int32:
      return C::INT;
    case PixelType::Float32:
      return C::FLOAT;
    case PixelType::Float64:
      return C::DOUBLE;
  }
  throw InputError("unknown pixel type");
}

// What itk::ImageFileWriter<itk::Image<T, Dim>>::Update() does for an image in memory (ITK 5.2,
// itkImageFileWriter.hxx: the IO the file name's extension picks, the geometry with direction
// column i as axis i, no compression, an empty metadata dictionary, one piece), through the
// ImageIO directly: one code path instead of 18 instantiations of the writer's pipeline, which
// cost a third of this file's compile time.
void write_with_image_io(const std::string& path, const void* data, PixelType type, int components,
                         const std::vector<int64_t>& dims, const std::vector<double>& spacing,
                         const std::vector<double>& origin, const std::vector<double>& direction) {
  itk::ImageIOBase::Pointer io =
      itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::WriteMode);
  if (!io) throw FileError("cannot write '" + path + "': no image format for its extension");
  const unsigned n = unsigned(dims.size());
  io->SetNumberOfDimensions(n);
  itk::ImageIORegion region(n);
  for (unsigned a = 0; a < n; ++a) {
    io->SetDimensions(a, itk::SizeValueType(dims[a]));
    io->SetSpacing(a, spacing[a]);
    io->SetOrigin(a, origin[a]);
    std::vector<double> axis(n);
    for (unsigned b = 0; b < n; ++b) axis[b] = direction[b * n + a];
    io->SetDirection(a, axis);
    region.SetIndex(a, 0);
    region.SetSize(a, itk::SizeValueType(dims[a]));
  }
  io->SetUseCompression(false);
  io->SetMetaDataDictionary(itk::MetaDataDictionary());
  io->SetComponentType(to_component(type));
  const bool rgb = components == 3;
  io->SetNumberOfComponents(rgb ? 3 : 1);
  io->SetPixelType(rgb ? itk::IOPixelEnum::RGB : itk::IOPixelEnum::SCALAR);
  io->SetFileName(path);
  io->SetIORegion(region);
  io->Write(data);
}

// ---- DICOM series, checked slice by slice before ITK stacks them -------------------------------
//
// ITK's series reader reads a slice whose pixel data is cut short with zeros (GDCM reads the short
// element and carries on), stacks two slices found at one position, and, when a slice is missing,
// only warns while it stretches or keeps the spacing. The slices' headers are read here with GDCM
// (up to the pixel data) and checked: each pixel data element must fit in its file, and the
// positions along the slice normal must be distinct and evenly spaced.

struct DicomSlice {
  std::string file;
  double z = 0;  // ImagePositionPatient along the slice normal, mm
  std::vector<double> cosines;
  bool has_position = false;
};

std::string file_name(const std::string& path) {
  return std::filesystem::path(path).filename().string();
}

// The pixel data element whose value starts at `value_offset` of `file` (where GDCM stopped,
// having read its header): its declared length must fit in the file and hold the image's pixels.
// `packed12`: 12 bits allocated, two pixels in three bytes, which GDCM unpacks only from exactly
// as many bytes as the pixels need (its decoder asserts otherwise); `pixel_bytes` then counts
// the unpacked pixels, two bytes each. `where` names the file in messages.
void check_pixel_data(const std::string& where, const std::string& file, uint64_t value_offset,
                      uint64_t pixel_bytes, bool packed12) {
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(file, ec);
  // Implicit VR: tag, 32-bit length; explicit VR (OB, OW): tag, VR, 2 reserved bytes, 32-bit
  // length. Either way the length is the 4 bytes before the value, the tag 8 or 12 before.
  unsigned char h[12] = {0};
  std::ifstream in(file, std::ios::binary);
  if (value_offset >= 12) in.seekg(std::streamoff(value_offset - 12));
  in.read(reinterpret_cast<char*>(h), sizeof h);
  static const unsigned char kTag[4] = {0xe0, 0x7f, 0x10, 0x00};
  if (value_offset > size || in.gcount() < 12 ||
      (std::memcmp(h + 4, kTag, 4) != 0 && std::memcmp(h, kTag, 4) != 0))
    throw FileError("cannot read " + where + ": truncated or corrupt file (no pixel data)");
  const uint64_t length =
      uint64_t(h[8]) | uint64_t(h[9]) << 8 | uint64_t(h[10]) << 16 | uint64_t(h[11]) << 24;
  // Encapsulated (compressed) frames: dicom::check_structure() has walked their fragments.
  if (length == 0xffffffffu) return;
  if (value_offset + length > size) {
    std::ostringstream s;
    s << "cannot read " << where << ": truncated or corrupt file (its pixel data needs "
      << value_offset + length << " bytes, the file has " << size << ")";
    throw FileError(s.str());
  }
  if (packed12 && length * 16 / 12 != pixel_bytes) {
    std::ostringstream s;
    s << "cannot read " << where << ": corrupt file (" << length << " bytes of pixel data for "
      << pixel_bytes / 2 << " pixels of 12 bits, packed two in three bytes)";
    throw FileError(s.str());
  }
  if (length < pixel_bytes && !packed12) {
    std::ostringstream s;
    s << "cannot read " << where << ": corrupt file (" << length << " bytes of pixel data for "
      << pixel_bytes << " bytes of pixels)";
    throw FileError(s.str());
  }
}

// Reads the elements of `file` before its pixel data (and that element's header, not its value)
// into `reader`, and checks the pixel data: it must fit in the file and hold the image's pixels
// (every frame of a multi-frame file). `where` names the file in messages. The caller has had
// dicom::check_structure() walk the file first (GDCM aborts on broken structure).
void read_checked_dicom_header(gdcm::Reader& reader, const std::string& file,
                               const std::string& where) {
  reader.SetFileName(file.c_str());
  const gdcm::Tag pixel_data(0x7fe0, 0x0010);
  if (!reader.ReadUpToTag(pixel_data, {pixel_data}))
    throw FileError("cannot read " + where + ": not a readable DICOM file");
  const gdcm::File& f = reader.GetFile();
  const std::vector<unsigned int> dims = gdcm::ImageHelper::GetDimensionsValue(f);
  const gdcm::PixelFormat format = gdcm::ImageHelper::GetPixelFormatValue(f);
  uint64_t pixel_bytes =
      (uint64_t(format.GetBitsAllocated()) + 7) / 8 * format.GetSamplesPerPixel();
  for (unsigned int d : dims) pixel_bytes *= d;
  check_pixel_data(where, file, reader.GetStreamCurrentPosition(), pixel_bytes,
                   format.GetBitsAllocated() == 12);
}

// The DICOM files of a folder as GDCM's series scan is allowed to see them. The scan parses every
// file it finds, guessing the syntax of those without the Part 10 preamble, and asserts (aborting
// the process) on broken structure and on some bytes it guesses wrong (fuzzing found such files
// of 5 to 200 bytes). So each file is first told DICOM or not (dicom::is_dicom) and walked
// (dicom::check_structure, and an image's pixel data as read_checked_dicom_header checks it;
// errors named in the folder's words), and the scan runs on a temporary
// folder of links to the walked files only: the others (a README, .DS_Store) are passed over, as
// GDCM passes over what it does not read, without GDCM ever parsing them.
class WalkedDicomFolder {
 public:
  explicit WalkedDicomFolder(const std::string& directory) : directory_(directory) {
    std::error_code ec;
    std::vector<std::filesystem::path> dicom;
    for (const auto& entry : std::filesystem::directory_iterator(directory, ec)) {
      if (!entry.is_regular_file(ec)) continue;
      ++files_;
      if (!dicom::is_dicom(entry.path().string())) continue;
      const std::string where =
          "DICOM directory '" + directory + "': file '" + entry.path().filename().string() + "'";
      // The scan reads each file's image too (GDCM's SerieHelper), so an image's pixel data
      // gets the checks a single file's does.
      if (dicom::check_structure(entry.path().string(), where)) {
        gdcm::Reader reader;
        read_checked_dicom_header(reader, entry.path().string(), where);
      }
      dicom.push_back(std::filesystem::absolute(entry.path(), ec));
    }
    std::string pattern = (std::filesystem::temp_directory_path(ec) / "sonoslice-dicom-XXXXXX");
    if (ec || !::mkdtemp(pattern.data()))
      throw FileError("cannot read DICOM directory '" + directory +
                      "': cannot make a temporary folder for its series scan (" +
                      std::strerror(errno) + ")");
    links_ = pattern;
    for (const std::filesystem::path& file : dicom) {
      std::filesystem::create_symlink(file, links_ / file.filename(), ec);
      if (ec) {
        const std::string why = ec.message();
        std::filesystem::remove_all(links_, ec);  // the destructor does not run for a throw here
        throw FileError("cannot read DICOM directory '" + directory + "': cannot link '" +
                        file.filename().string() + "' for its series scan (" + why + ")");
      }
    }
  }
  ~WalkedDicomFolder() {
    std::error_code ec;
    if (!links_.empty()) std::filesystem::remove_all(links_, ec);
  }
  WalkedDicomFolder(const WalkedDicomFolder&) = delete;
  WalkedDicomFolder& operator=(const WalkedDicomFolder&) = delete;

  /// The folder for GDCM's scan (links to the walked files).
  std::string scan_directory() const { return links_.string(); }
  /// The files the scan listed, as paths in the folder itself.
  std::vector<std::string> originals(const std::vector<std::string>& scanned) const {
    std::vector<std::string> out;
    for (const std::string& f : scanned)
      out.push_back(
          (std::filesystem::path(directory_) / std::filesystem::path(f).filename()).string());
    return out;
  }
  /// How many files the folder holds, DICOM or not.
  int64_t files() const { return files_; }

 private:
  std::string directory_;
  std::filesystem::path links_;
  int64_t files_ = 0;
};

// The series' files have been walked (WalkedDicomFolder).
void check_dicom_slices(const std::string& directory, const std::vector<std::string>& files) {
  const std::string where = "DICOM series in '" + directory + "'";
  std::vector<DicomSlice> slices;
  for (const std::string& file : files) {
    gdcm::Reader reader;
    read_checked_dicom_header(reader, file, where + ": slice '" + file_name(file) + "'");
    const gdcm::File& f = reader.GetFile();
    DicomSlice slice;
    slice.file = file;
    slice.has_position = f.GetDataSet().FindDataElement(gdcm::Tag(0x0020, 0x0032)) &&
                         f.GetDataSet().FindDataElement(gdcm::Tag(0x0020, 0x0037));
    if (slice.has_position) {
      const std::vector<double> p = gdcm::ImageHelper::GetOriginValue(f);
      slice.cosines = gdcm::ImageHelper::GetDirectionCosinesValue(f);
      const Vec3 row{slice.cosines[0], slice.cosines[1], slice.cosines[2]};
      const Vec3 column{slice.cosines[3], slice.cosines[4], slice.cosines[5]};
      slice.z = dot(cross(row, column), Vec3{p[0], p[1], p[2]});
    }
    slices.push_back(std::move(slice));
  }
  if (slices.size() < 2) return;
  for (const DicomSlice& s : slices)
    if (!s.has_position) return;  // no geometry to check: ITK stacks them 1 mm apart
  for (const DicomSlice& s : slices)
    for (size_t i = 0; i < 6; ++i)
      if (std::fabs(s.cosines[i] - slices.front().cosines[i]) > 1e-3)
        throw InputError(where + ": slices '" + file_name(slices.front().file) + "' and '" +
                         file_name(s.file) + "' have different orientations");
  std::sort(slices.begin(), slices.end(), [](const DicomSlice& a, const DicomSlice& b) {
    return a.z < b.z || (a.z == b.z && a.file < b.file);
  });
  std::vector<double> gaps;
  for (size_t k = 0; k + 1 < slices.size(); ++k) gaps.push_back(slices[k + 1].z - slices[k].z);
  std::vector<double> sorted = gaps;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double spacing = sorted[sorted.size() / 2];
  // Positions are decimal strings rounded to about a micrometre: a tolerance of 1% of the
  // spacing (at least 0.01 mm) tells rounding from a missing or misplaced slice.
  const double tolerance = std::max(0.01 * spacing, 0.01);
  for (size_t k = 0; k < gaps.size(); ++k) {
    const std::string pair =
        "'" + file_name(slices[k].file) + "' and '" + file_name(slices[k + 1].file) + "'";
    std::ostringstream s;
    s << where << ": ";
    if (gaps[k] < tolerance) {
      s << "slices " << pair << " are at the same position (" << slices[k].z
        << " mm along the slice normal)";
      throw InputError(s.str());
    }
    if (std::fabs(gaps[k] - spacing) > tolerance) {
      const double ratio = gaps[k] / spacing;
      if (std::fabs(ratio - std::round(ratio)) * spacing < tolerance)
        s << "missing slice(s) between " << pair << ": they are " << gaps[k]
          << " mm apart, the other slices " << spacing << " mm";
      else
        s << "uneven slice spacing: " << pair << " are " << gaps[k] << " mm apart, the other "
          << "slices " << spacing << " mm";
      throw InputError(s.str());
    }
  }
}

// ITK's NIfTI reader takes a short RGB file without a word (a scalar one goes through
// read_nifti_voxels, which checks). Counts the bytes after the header through zlib, which reads
// an uncompressed .nii as it is.
void check_nifti_length(const std::string& path, uint64_t data_bytes) {
  gzFile f = gzopen(path.c_str(), "rb");
  if (!f) throw FileError("cannot read '" + path + "' back: " + std::strerror(errno));
  unsigned char header[540];
  int n = gzread(f, header, 348);
  uint64_t offset = 352, total = n > 0 ? uint64_t(n) : 0;
  int32_t header_size = 0;
  if (n == 348) std::memcpy(&header_size, header, 4);  // written here, so in native order
  if (header_size == 348) {
    float vox_offset;
    std::memcpy(&vox_offset, header + 108, 4);
    // Written here, but converted with care: a float beyond uint64_t is undefined behaviour.
    offset = std::isfinite(vox_offset) && vox_offset > 352 && vox_offset < 9.0e15f
                 ? uint64_t(vox_offset)
                 : 352;
  } else if (header_size == 540) {
    n = gzread(f, header + 348, 540 - 348);
    total += n > 0 ? uint64_t(n) : 0;
    int64_t vox_offset;
    std::memcpy(&vox_offset, header + 168, 8);
    offset = vox_offset > 0 ? uint64_t(vox_offset) : 0;
  }
  std::vector<unsigned char> buffer(size_t(1) << 20);
  while ((n = gzread(f, buffer.data(), unsigned(buffer.size()))) > 0) total += uint64_t(n);
  int status = Z_OK;
  const char* message = gzerror(f, &status);
  const std::string why = status != Z_OK && status != Z_STREAM_END ? message : "";
  gzclose(f);
  if (!why.empty()) throw FileError("cannot read '" + path + "' back: " + why);
  if (total < offset + data_bytes)
    throw FileError("cannot read '" + path + "' back: truncated file (" + std::to_string(total) +
                    " bytes, " + std::to_string(offset + data_bytes) + " needed)");
}

}  // namespace

Volume read_image_file(const std::string& path, int64_t* colour_pixels) {
  register_factories();
  const ImageFormat format = image_format(path, "volume");
  if (format == ImageFormat::Nifti) check_nifti_header(path);
  check_text_header(path, format);
  if (format == ImageFormat::Dicom) {  // GDCM reads pixel data cut short with zeros
    dicom::check_structure(path, "volume '" + path + "'");
    gdcm::Reader reader;
    read_checked_dicom_header(reader, path, "volume '" + path + "'");
  }
  // ITK's libraries print to std::cerr (MetaIO's header errors, VNL's remarks on a near-singular
  // orientation): held here, to become the error's cause or one warning.
  std::optional<Volume> volume;
  bool header_read = false;
  CerrCapture capture;
  try {
    itk::ImageIOBase::Pointer io =
        itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
    if (!io)
      throw FileError("cannot read volume '" + path +
                      "': not a readable image format (or corrupt)");
    io->SetFileName(path);
    io->ReadImageInformation();
    header_read = true;
    checked_image_bytes(io, path);
    const unsigned dims = io->GetNumberOfDimensions();
    if (dims > 3) {
      for (unsigned d = 3; d < dims; ++d)
        if (io->GetDimensions(d) > 1)
          throw InputError("volume '" + path + "': " + std::to_string(dims) +
                           "-D image (sonoslice slices 3-D volumes)");
    }
    const unsigned components = io->GetNumberOfComponents();
    const bool colour = colour_pixels && (components == 3 || components == 4);
    if (components != 1 && colour_pixels && !colour)
      throw InputError("image '" + path + "': " + std::to_string(components) +
                       " components (frames have 1, or 3 or 4: RGB, RGBA)");
    if (components != 1 && !colour)
      throw InputError("volume '" + path + "': unsupported pixel type " +
                       itk::ImageIOBase::GetPixelTypeAsString(io->GetPixelType()) + " with " +
                       std::to_string(io->GetNumberOfComponents()) +
                       " components (sonoslice slices scalar volumes)");
    const PixelType type = to_pixel_type(io->GetComponentType(), path);
    if (colour)
      volume = read_first_component(path, io, type, colour_pixels);
    else if (std::string(io->GetNameOfClass()) == "NiftiImageIO")
      volume = read_nifti_voxels(path, grid_of(io, path), type);
    if (!volume)
      volume =
          visit_pixel_type(type, [&](auto zero) { return read_typed<decltype(zero)>(path, io); });
  } catch (const itk::ExceptionObject& e) {
    // A header MetaIO could not parse: its first words are the cause, and ITK's exception then
    // blames errno ("No such file or directory") left over from some earlier call.
    const std::string cause = capture.first_line();
    if (!header_read && !cause.empty())
      throw FileError("cannot read volume '" + path + "': corrupt header (" + cause + ")");
    throw FileError("cannot read volume '" + path + "': " + describe(e));
  }
  if (!capture.first_line().empty()) warn("volume '" + path + "': " + capture.first_line());
  return std::move(*volume);
}

std::vector<DicomSeriesInfo> list_dicom_series(const std::string& directory) {
  register_factories();
  const WalkedDicomFolder folder(directory);
  try {
    auto names = itk::GDCMSeriesFileNames::New();
    names->SetUseSeriesDetails(true);
    names->SetDirectory(folder.scan_directory());
    std::vector<DicomSeriesInfo> out;
    for (const std::string& uid : names->GetSeriesUIDs())
      out.push_back({uid, names->GetFileNames(uid).size()});
    return out;
  } catch (const itk::ExceptionObject& e) {
    throw FileError("cannot read DICOM directory '" + directory + "': " + describe(e));
  }
}

std::optional<int64_t> dicom_instance_number(const std::string& file, const std::string& where) {
  register_factories();
  dicom::check_structure(file, where);
  gdcm::Reader reader;
  read_checked_dicom_header(reader, file, where);
  const gdcm::DataSet& data = reader.GetFile().GetDataSet();
  const gdcm::Tag instance_number(0x0020, 0x0013);
  if (!data.FindDataElement(instance_number)) return std::nullopt;
  const gdcm::ByteValue* value = data.GetDataElement(instance_number).GetByteValue();
  if (!value) return std::nullopt;
  // An IS value: a decimal integer, padded with spaces (or a NUL) to an even length.
  std::string text(value->GetPointer(), value->GetLength());
  while (!text.empty() && text.back() == '\0') text.pop_back();
  int64_t number = 0;
  if (!text::parse_int64(text::trim(text), &number)) return std::nullopt;
  return number;
}

Volume read_dicom_directory(const std::string& directory, const std::string& series_uid) {
  register_factories();
  const WalkedDicomFolder folder(directory);
  const int64_t files = folder.files();
  try {
    auto names = itk::GDCMSeriesFileNames::New();
    names->SetUseSeriesDetails(true);
    names->SetDirectory(folder.scan_directory());
    const auto uids = names->GetSeriesUIDs();
    if (uids.empty())
      throw FileError("cannot read volume '" + directory + "': no DICOM series in the directory" +
                      (files > 0
                           ? " (" + std::to_string(files) + (files == 1 ? " file" : " files") +
                                 ", none in a DICOM series)"
                           : std::string()));
    std::string chosen;
    if (!series_uid.empty()) {
      // With series details, ITK's UIDs carry extra details after the SeriesInstanceUID.
      for (const auto& uid : uids)
        if (uid == series_uid || uid.rfind(series_uid + ".", 0) == 0) chosen = uid;
      if (chosen.empty()) {
        std::ostringstream s;
        s << "DICOM directory '" << directory << "': no series '" << series_uid << "' (found:";
        for (const auto& uid : uids) s << " " << uid;
        s << ")";
        throw InputError(s.str());
      }
    } else {
      size_t best = 0;
      for (const auto& uid : uids) {
        const size_t n = names->GetFileNames(uid).size();
        if (n > best) best = n, chosen = uid;
      }
    }
    const std::vector<std::string> files = folder.originals(names->GetFileNames(chosen));
    check_dicom_slices(directory, files);
    // The pixel type after rescale slope/intercept, as GDCM reports it for the first file.
    auto io = itk::GDCMImageIO::New();
    io->SetFileName(files.front());
    io->ReadImageInformation();
    const PixelType type = to_pixel_type(io->GetComponentType(), directory);
    if (io->GetNumberOfComponents() != 1)
      throw InputError("DICOM directory '" + directory + "': colour images are not supported");
    return visit_pixel_type(
        type, [&](auto zero) { return read_series_typed<decltype(zero)>(files, directory); });
  } catch (const itk::ExceptionObject& e) {
    throw FileError("cannot read DICOM directory '" + directory + "': " + describe(e));
  }
}

std::string write_image(const std::string& path, const void* data, PixelType type,
                        const std::vector<int64_t>& dims, const std::vector<double>& spacing,
                        const std::vector<double>& origin, const std::vector<double>& direction,
                        int components) {
  register_factories();
  StderrCapture capture;
  try {
    if (components == 3 && type != PixelType::UInt8)  // RGB colour images
      throw InputError("'" + path + "': colour images are uint8");
    write_with_image_io(path, data, type, components, dims, spacing, origin, direction);
  } catch (const itk::ExceptionObject& e) {
    capture.finish();
    throw FileError("cannot write '" + path + "': " + describe(e));
  }
  return capture.finish();
}

void verify_image_file(const std::string& path, PixelType type, const std::vector<int64_t>& dims,
                       int components) {
  register_factories();
  StderrCapture capture;  // keeps the readers' lines off the terminal
  std::string complaint;
  try {
    itk::ImageIOBase::Pointer io =
        itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
    if (!io) throw FileError("cannot read '" + path + "' back: not a readable image");
    io->SetFileName(path);
    io->ReadImageInformation();
    std::ostringstream found, expected;
    bool same = io->GetNumberOfComponents() == unsigned(components) &&
                to_pixel_type(io->GetComponentType(), path) == type;
    const size_t axes = std::max<size_t>(io->GetNumberOfDimensions(), dims.size());
    for (size_t a = 0; a < axes; ++a) {
      const int64_t n =
          a < io->GetNumberOfDimensions() ? int64_t(io->GetDimensions(unsigned(a))) : 1;
      const int64_t want = a < dims.size() ? dims[a] : 1;
      same = same && n == want;
      found << (a ? "x" : "") << n;
      expected << (a ? "x" : "") << want;
    }
    if (!same)
      throw FileError("cannot read '" + path + "' back as written: " + found.str() + " " +
                      itk::ImageIOBase::GetComponentTypeAsString(io->GetComponentType()) + " x" +
                      std::to_string(io->GetNumberOfComponents()) + ", expected " + expected.str() +
                      " " + to_string(type) + " x" + std::to_string(components));
    // Every voxel must come back: a short file is what a full disk leaves.
    if (components == 1) {
      read_image_file(path);  // sonoslice's reader: catches truncated NIfTI, MetaImage, NRRD
    } else {
      std::vector<unsigned char> voxels(io->GetImageSizeInBytes());
      itk::ImageIORegion region(unsigned(io->GetNumberOfDimensions()));
      for (unsigned a = 0; a < io->GetNumberOfDimensions(); ++a) {
        region.SetIndex(a, 0);
        region.SetSize(a, io->GetDimensions(a));
      }
      io->SetIORegion(region);
      io->Read(voxels.data());
      complaint = capture.finish();  // MetaIO reports a short read only on std::cerr
      if (std::string(io->GetNameOfClass()) == "NiftiImageIO")
        check_nifti_length(path, uint64_t(voxels.size()));
    }
  } catch (const itk::ExceptionObject& e) {
    throw FileError("cannot read '" + path + "' back: " + describe(e));
  }
  if (!complaint.empty()) throw FileError("cannot read '" + path + "' back: " + complaint);
}

}  // namespace itk_io
}  // namespace sonoslice
