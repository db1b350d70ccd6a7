// The ITK edge of sonoslice: medical image formats in and out, geometry included.
#include "ItkImageIO.h"

#include <sys/mman.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <memory>
#include <mutex>
#include <sstream>

#include <itkGDCMImageIO.h>
#include <itkGDCMImageIOFactory.h>
#include <itkGDCMSeriesFileNames.h>
#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageFileWriter.h>
#include <itkImageIOFactory.h>
#include <itkImageSeriesReader.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>
#include <itkPNGImageIOFactory.h>
#include <itkRGBPixel.h>

#include <itkOutputWindow.h>

#include "NiftiData.h"
#include "TextParse.h"
#include "sonoslice/core/Error.h"

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
    if (!t.empty()) warn("ITK: " + t);
  }
};

// MetaIO (MetaImage's library) reports short reads only on std::cerr and then returns success;
// this captures what it prints during a read so it can be turned into an error.
class CerrCapture {
 public:
  CerrCapture() : old_(std::cerr.rdbuf(text_.rdbuf())) {}
  ~CerrCapture() { std::cerr.rdbuf(old_); }
  std::string text() const { return text::one_line_message(text_.str()); }

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
    itk::NiftiImageIOFactory::RegisterOneFactory();
    itk::MetaImageIOFactory::RegisterOneFactory();
    itk::NrrdImageIOFactory::RegisterOneFactory();
    itk::GDCMImageIOFactory::RegisterOneFactory();
    itk::PNGImageIOFactory::RegisterOneFactory();
  });
}

// ITK's exception text is several lines with source locations; keep its description.
std::string describe(const itk::ExceptionObject& e) {
  return text::one_line_message(e.GetDescription());
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
Volume to_volume(typename Image3<T>::Pointer image) {
  VolumeGrid g;
  const auto size = image->GetLargestPossibleRegion().GetSize();
  for (int a = 0; a < 3; ++a) {
    g.dims[a] = int64_t(size[a]);
    g.spacing_mm[a] = image->GetSpacing()[a];
    g.origin_mm[a] = image->GetOrigin()[a];
    for (int b = 0; b < 3; ++b) g.direction.m[a][b] = image->GetDirection()[a][b];
  }
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
    reader->Update();
    if (capture) complaint = capture->text();
  }
  if (!complaint.empty())
    throw FileError("cannot read volume '" + path + "': truncated or corrupt file (" + complaint +
                    ")");
  return to_volume<T>(reader->GetOutput());
}

template <typename T>
Volume read_series_typed(const std::vector<std::string>& files) {
  auto reader = itk::ImageSeriesReader<Image3<T>>::New();
  auto io = itk::GDCMImageIO::New();
  reader->SetImageIO(io);
  reader->SetFileNames(files);
  reader->Update();
  return to_volume<T>(reader->GetOutput());
}

template <typename T, unsigned Dim>
void write_typed(const std::string& path, const void* data, const std::vector<int64_t>& dims,
                 const std::vector<double>& spacing, const std::vector<double>& origin,
                 const std::vector<double>& direction) {
  using Image = itk::Image<T, Dim>;
  auto image = Image::New();
  typename Image::SizeType size;
  typename Image::SpacingType sp;
  typename Image::PointType org;
  typename Image::DirectionType dir;
  size_t count = 1;
  for (unsigned a = 0; a < Dim; ++a) {
    size[a] = itk::SizeValueType(dims[a]);
    sp[a] = spacing[a];
    org[a] = origin[a];
    for (unsigned b = 0; b < Dim; ++b) dir[a][b] = direction[a * Dim + b];
    count *= size_t(dims[a]);
  }
  image->SetRegions(typename Image::RegionType(size));
  image->SetSpacing(sp);
  image->SetOrigin(org);
  image->SetDirection(dir);
  // Borrow the caller's buffer: no copy of a possibly large output stack.
  image->GetPixelContainer()->SetImportPointer(const_cast<T*>(static_cast<const T*>(data)), count,
                                               false);
  auto writer = itk::ImageFileWriter<Image>::New();
  writer->SetFileName(path);
  writer->SetInput(image);
  writer->Update();
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
    offset = std::max<uint64_t>(352, uint64_t(vox_offset));
  } else if (header_size == 540) {
    n = gzread(f, header + 348, 540 - 348);
    total += n > 0 ? uint64_t(n) : 0;
    int64_t vox_offset;
    std::memcpy(&vox_offset, header + 168, 8);
    offset = uint64_t(vox_offset);
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

Volume read_image_file(const std::string& path) {
  register_factories();
  try {
    itk::ImageIOBase::Pointer io =
        itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
    if (!io)
      throw FileError("cannot read volume '" + path +
                      "': not a readable image format (or corrupt)");
    io->SetFileName(path);
    io->ReadImageInformation();
    const unsigned dims = io->GetNumberOfDimensions();
    if (dims > 3) {
      for (unsigned d = 3; d < dims; ++d)
        if (io->GetDimensions(d) > 1)
          throw InputError("volume '" + path + "': " + std::to_string(dims) +
                           "-D image (sonoslice slices 3-D volumes)");
    }
    if (io->GetNumberOfComponents() != 1)
      throw InputError("volume '" + path + "': unsupported pixel type " +
                       itk::ImageIOBase::GetPixelTypeAsString(io->GetPixelType()) + " with " +
                       std::to_string(io->GetNumberOfComponents()) +
                       " components (sonoslice slices scalar volumes)");
    const PixelType type = to_pixel_type(io->GetComponentType(), path);
    if (std::string(io->GetNameOfClass()) == "NiftiImageIO") {
      VolumeGrid grid;
      for (unsigned a = 0; a < 3; ++a) {
        grid.dims[a] = a < dims ? int64_t(io->GetDimensions(a)) : 1;
        grid.spacing_mm[a] = a < dims ? io->GetSpacing(a) : 1.0;
        grid.origin_mm[a] = a < dims ? io->GetOrigin(a) : 0.0;
        const auto axis = io->GetDirection(a < dims ? a : 0);
        for (unsigned b = 0; b < 3; ++b)
          grid.direction.m[b][a] =
              a < dims ? (b < axis.size() ? axis[b] : 0.0) : (a == b ? 1.0 : 0.0);
      }
      if (auto v = read_nifti_voxels(path, grid, type)) return std::move(*v);
    }
    return visit_pixel_type(type, [&](auto zero) { return read_typed<decltype(zero)>(path, io); });
  } catch (const itk::ExceptionObject& e) {
    throw FileError("cannot read volume '" + path + "': " + describe(e));
  }
}

std::vector<DicomSeriesInfo> list_dicom_series(const std::string& directory) {
  register_factories();
  try {
    auto names = itk::GDCMSeriesFileNames::New();
    names->SetUseSeriesDetails(true);
    names->SetDirectory(directory);
    std::vector<DicomSeriesInfo> out;
    for (const std::string& uid : names->GetSeriesUIDs())
      out.push_back({uid, names->GetFileNames(uid).size()});
    return out;
  } catch (const itk::ExceptionObject& e) {
    throw FileError("cannot read DICOM directory '" + directory + "': " + describe(e));
  }
}

Volume read_dicom_directory(const std::string& directory, const std::string& series_uid) {
  register_factories();
  try {
    auto names = itk::GDCMSeriesFileNames::New();
    names->SetUseSeriesDetails(true);
    names->SetDirectory(directory);
    const auto uids = names->GetSeriesUIDs();
    if (uids.empty())
      throw FileError("cannot read volume '" + directory + "': no DICOM series in the directory");
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
    const std::vector<std::string> files = names->GetFileNames(chosen);
    // The pixel type after rescale slope/intercept, as GDCM reports it for the first file.
    auto io = itk::GDCMImageIO::New();
    io->SetFileName(files.front());
    io->ReadImageInformation();
    const PixelType type = to_pixel_type(io->GetComponentType(), directory);
    if (io->GetNumberOfComponents() != 1)
      throw InputError("DICOM directory '" + directory + "': colour images are not supported");
    return visit_pixel_type(type,
                            [&](auto zero) { return read_series_typed<decltype(zero)>(files); });
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
    if (components == 3) {  // RGB colour images
      if (type != PixelType::UInt8) throw InputError("'" + path + "': colour images are uint8");
      using Rgb = itk::RGBPixel<uint8_t>;
      if (dims.size() == 2)
        write_typed<Rgb, 2>(path, data, dims, spacing, origin, direction);
      else
        write_typed<Rgb, 3>(path, data, dims, spacing, origin, direction);
      return capture.finish();
    }
    visit_pixel_type(type, [&](auto zero) {
      using T = decltype(zero);
      if (dims.size() == 2)
        write_typed<T, 2>(path, data, dims, spacing, origin, direction);
      else
        write_typed<T, 3>(path, data, dims, spacing, origin, direction);
    });
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
