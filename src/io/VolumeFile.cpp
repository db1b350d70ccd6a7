#include "sonoslice/io/VolumeFile.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>

#include "../core/Text.h"
#include "JsonFile.h"
#include "MappedFile.h"
#include "PngFile.h"
#include "TextParse.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/Npy.h"

#ifdef SONOSLICE_HAVE_ITK
#include <zlib.h>

#include <fstream>

#include "ItkImageIO.h"
#endif

namespace fs = std::filesystem;

namespace sonoslice {
namespace {

#ifndef SONOSLICE_HAVE_ITK
[[noreturn]] void no_itk(const std::string& path) {
  throw Error("'" + path +
              "': this sonoslice was built without ITK; only .npy volumes are available");
}
#endif

template <size_t N>
std::array<double, N> json_numbers(const nlohmann::json& j, const std::string& where) {
  std::array<double, N> out{};
  if (!j.is_array() || j.size() != N)
    throw InputError(where + " must be a list of " + std::to_string(N) + " numbers");
  for (size_t i = 0; i < N; ++i) {
    if (!j[i].is_number())
      throw InputError(where + " must be a list of " + std::to_string(N) + " numbers");
    out[i] = j[i].get<double>();
  }
  return out;
}

// Copies a C-order array whose axes are a permutation of (z, y, x) into x-fastest order,
// keeping the native type: `axis_of[d]` is the volume axis (0 = x, 1 = y, 2 = z) of array
// dimension d.
Volume permuted(const NpyArray& a, const int axis_of[3], const VolumeGrid& grid_without_dims) {
  VolumeGrid g = grid_without_dims;
  for (int d = 0; d < 3; ++d) g.dims[axis_of[d]] = a.shape[d];
  Volume v = Volume::allocate(a.type, g);
  // Strides of the source array per volume axis (in elements).
  const std::vector<int64_t> strides = npy_element_strides(a);
  int64_t src_stride[3];
  for (int d = 0; d < 3; ++d) src_stride[axis_of[d]] = strides[size_t(d)];
  const size_t item = pixel_size(a.type);
  const auto* src = static_cast<const unsigned char*>(a.data.get());
  auto* dst = static_cast<unsigned char*>(v.data());
  size_t out = 0;
  for (int64_t k = 0; k < g.dims[2]; ++k)
    for (int64_t j = 0; j < g.dims[1]; ++j)
      for (int64_t i = 0; i < g.dims[0]; ++i, ++out)
        std::memcpy(dst + out * item,
                    src + size_t(i * src_stride[0] + j * src_stride[1] + k * src_stride[2]) * item,
                    item);
  return v;
}

Volume read_npy_volume(const std::string& path, const VolumeReadOptions& options) {
  // C order and native byte order (the usual case) maps the file: no copy, no load time.
  const NpyArray header = read_npy_header(path);
  const bool mappable = !header.fortran_order && !header.swapped_on_disk &&
                        options.fanslicer_npy_config.empty() && header.shape.size() == 3;
  NpyArray a = mappable ? header : read_npy(path);
  if (a.shape.size() != 3)
    throw InputError("volume '" + path + "': a .npy volume must be 3-D (nz, ny, nx); got " +
                     std::to_string(a.shape.size()) + "-D");
  for (int64_t d : a.shape)
    if (d <= 0) throw InputError("volume '" + path + "': empty array");

  VolumeGrid g;
  if (!options.fanslicer_npy_config.empty()) {
    // docs/conventions.md §4: array axes [Y, X, Z], spacing = voxel size, origin = bounding-box
    // minimum.
    const std::string cfg = options.fanslicer_npy_config;
    const auto j = read_json_file(cfg, "npy_config");
    const std::string where = "npy_config '" + cfg + "'";
    if (!j.is_object() || !j.contains("voxel size") || !j.contains("bounding box"))
      throw InputError(where + ": needs \"voxel size\" and \"bounding box\"");
    for (auto it = j.begin(); it != j.end(); ++it)
      if (it.key() != "voxel size" && it.key() != "bounding box" && it.key() != "planar resolution")
        throw InputError(where + ": unknown key '" + it.key() + "'");
    const auto voxel = json_numbers<3>(j["voxel size"], where + ": \"voxel size\"");
    const auto& box = j["bounding box"];
    if (!box.is_array() || box.size() != 2)
      throw InputError(where +
                       ": \"bounding box\" must be [[xmin, ymin, zmin], [xmax, ymax, zmax]]");
    const auto lo = json_numbers<3>(box[0], where + ": \"bounding box\"[0]");
    const auto hi = json_numbers<3>(box[1], where + ": \"bounding box\"[1]");
    g.spacing_mm = {voxel[0], voxel[1], voxel[2]};
    g.origin_mm = {lo[0], lo[1], lo[2]};
    const int axis_of[3] = {1, 0, 2};  // array [Y, X, Z]
    Volume v = permuted(a, axis_of, g);
    v.grid().validate("volume '" + path + "'");
    for (int k = 0; k < 3; ++k) {
      const double extent = (hi[k] - lo[k]) / voxel[k] + 1;
      if (std::fabs(extent - double(v.grid().dims[k])) > 1.5)
        warn(where + ": bounding box spans " + std::to_string(extent) + " voxels along axis " +
             std::to_string(k) + " but the array has " + std::to_string(v.grid().dims[k]));
    }
    return v;
  }

  // Geometry: sidecar JSON, then flags.
  const fs::path sidecar = fs::path(path).replace_extension(".json");
  bool have_geometry = options.spacing_mm.has_value();
  if (fs::exists(sidecar)) {
    const auto j = read_json_file(sidecar.string(), "volume sidecar");
    const std::string where = "volume sidecar '" + sidecar.string() + "'";
    if (!j.is_object()) throw InputError(where + ": expected a JSON object");
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (it.key() == "spacing") {
        const auto v = json_numbers<3>(*it, where + ": \"spacing\"");
        g.spacing_mm = {v[0], v[1], v[2]};
        have_geometry = true;
      } else if (it.key() == "origin") {
        const auto v = json_numbers<3>(*it, where + ": \"origin\"");
        g.origin_mm = {v[0], v[1], v[2]};
      } else if (it.key() == "direction") {
        const auto v = json_numbers<9>(*it, where + ": \"direction\" (row-major 3x3)");
        for (int i = 0; i < 9; ++i) g.direction.m[i / 3][i % 3] = v[size_t(i)];
      } else {
        throw InputError(where + ": unknown key '" + it.key() +
                         "' (expected spacing, origin, direction)");
      }
    }
  }
  if (options.spacing_mm) g.spacing_mm = *options.spacing_mm;
  if (options.origin_mm) g.origin_mm = *options.origin_mm;
  if (options.direction) g.direction = *options.direction;
  // Said once the file is known to be readable: a truncated file gets its error alone.
  const auto warn_if_assumed = [&] {
    if (!have_geometry)
      warn("volume '" + path + "': no spacing given (a spacing option or a sidecar " +
           sidecar.filename().string() + "); assuming 1 mm voxels at the origin");
  };

  if (a.fortran_order) {
    const int axis_of[3] = {2, 1, 0};  // still (nz, ny, nx), but stored Fortran-order
    Volume v = permuted(a, axis_of, g);
    v.grid().validate("volume '" + path + "'");
    warn_if_assumed();
    return v;
  }
  g.dims = {a.shape[2], a.shape[1], a.shape[0]};
  g.validate("volume '" + path + "'");
  if (mappable)
    a.data = map_file_region(path, a.data_offset, uint64_t(a.element_count()) * pixel_size(a.type),
                             pixel_size(a.type));
  warn_if_assumed();
  void* data = a.data.get();
  return Volume::wrap(data, a.type, g, a.data);  // zero-copy: the Volume owns the buffer or map
}

#ifdef SONOSLICE_HAVE_ITK
// The zlib level of the .nii.gz files sonoslice writes. ITK 5.2's NIfTI writer ignores its
// compression level and compresses at zlib's default (6), whose longer match searches crawl
// through a CT's noisy voxels: 28 s for the full phantom's 210 MB (7 MB/s, on one core of this
// project's development machine). Level 4 took 6.6 s there for a file 0.5 % smaller; smooth
// volumes (labels) come out larger (2.2 MB instead of 1.4 for the phantom's labels).
constexpr int kNiftiGzipLevel = 4;

// Compresses the file `from` into `to` (gzip at `level`) and removes `from`: "" when done, else
// why not (errno left as the failed call set it).
std::string gzip_file(const std::string& from, const std::string& to, int level) {
  std::ifstream in(from, std::ios::binary);
  if (!in) return std::string("cannot read it back: ") + std::strerror(errno);
  gzFile out = gzopen(to.c_str(), ("wb" + std::to_string(level)).c_str());
  if (!out) return std::strerror(errno ? errno : ENOMEM);
  gzbuffer(out, 1 << 18);
  std::vector<char> buffer(size_t(1) << 20);
  std::string failure;
  while (failure.empty() && in) {
    in.read(buffer.data(), std::streamsize(buffer.size()));
    const auto n = unsigned(in.gcount());
    int code = Z_OK;
    if (n > 0 && gzwrite(out, buffer.data(), n) != int(n)) failure = gzerror(out, &code);
    if (code == Z_ERRNO) failure = std::strerror(errno);
  }
  if (failure.empty() && in.bad()) failure = "cannot read it back";
  const int saved = errno;
  const int closed = gzclose(out);  // flushes: a full disk shows here
  if (failure.empty() && closed != Z_OK)
    failure = closed == Z_ERRNO ? std::strerror(errno) : "compression failed";
  else
    errno = saved;
  if (failure.empty()) fs::remove(from);
  return failure;
}

// ITK writes into a private temporary folder, under the final name (and any companion file: a
// .mhd's .raw); the file is then read back in full before it replaces anything, because ITK's
// NIfTI and MetaImage writers print a line and report success when the disk fills. Errors name
// the user's path.
void write_itk_atomic(const std::string& path, const void* data, PixelType type,
                      const std::vector<int64_t>& dims, const std::vector<double>& spacing,
                      const std::vector<double>& origin, const std::vector<double>& direction,
                      int components, OutputSet* together) {
  auto file = std::make_unique<AtomicFile>(path, OutputKind::Staged);
  const std::string temp = file->temp_path();
  std::string failure, printed;
  errno = 0;
  // A .nii.gz: ITK writes the .nii beside it, which sonoslice compresses (kNiftiGzipLevel).
  const bool gzip = file_extension(path) == ".nii.gz";
  const std::string written = gzip ? temp.substr(0, temp.size() - 3) : temp;
  try {
    printed =
        itk_io::write_image(written, data, type, dims, spacing, origin, direction, components);
  } catch (const Error& e) {
    failure = e.what();
  }
  if (gzip && failure.empty() && printed.find("ERROR") == std::string::npos)
    failure = gzip_file(written, temp, kNiftiGzipLevel);
  const int write_errno = errno;  // what the writer's last failed call left, if anything
  // A library that prints an error has not written what it was asked to (NIfTI's "** ERROR").
  if (failure.empty() && printed.find("ERROR") != std::string::npos) failure = printed;
  if (failure.empty()) {
    try {
      itk_io::verify_image_file(temp, type, dims, components);
    } catch (const Error& e) {
      failure = e.what();
    }
  }
  if (!failure.empty()) {
    std::string why;
    if (write_errno == ENOSPC || write_errno == EDQUOT || write_errno == EFBIG)
      why = write_error_reason(write_errno);
    else
      why = incomplete_write_reason(temp);
    if (why.empty()) {
      why = printed.empty() ? failure : printed;
      for (const std::string& staged : {temp, written})  // the .nii.gz, then its .nii
        for (size_t at; (at = why.find(staged)) != std::string::npos;)
          why.replace(at, staged.size(), path);
    }
    throw FileError("cannot write '" + path + "': " + why);
  }
  if (!printed.empty()) warn("writing '" + path + "': " + printed);
  if (together)
    together->add(std::move(file));
  else
    file->commit();
}
#endif

}  // namespace

bool built_with_itk() {
#ifdef SONOSLICE_HAVE_ITK
  return true;
#else
  return false;
#endif
}

std::string file_extension(const std::string& path) {
  const std::string name = text::lower(fs::path(path).filename().string());
  for (const char* compound : {".nii.gz", ".tar.gz"})
    if (name.size() > std::strlen(compound) &&
        name.compare(name.size() - std::strlen(compound), std::string::npos, compound) == 0)
      return compound;
  const size_t dot = name.find_last_of('.');
  return dot == std::string::npos || dot == 0 ? "" : name.substr(dot);
}

const char* to_string(ImageFormat format) {
  switch (format) {
    case ImageFormat::Npy:
      return "npy";
    case ImageFormat::Nifti:
      return "NIfTI";
    case ImageFormat::MetaImage:
      return "MetaImage";
    case ImageFormat::Nrrd:
      return "NRRD";
    case ImageFormat::Png:
      return "PNG";
    case ImageFormat::Dicom:
      return "DICOM";
    case ImageFormat::Directory:
      return "directory";
  }
  return "?";
}

ImageFormat image_format(const std::string& path, const std::string& what) {
  const std::string ext = file_extension(path);
  if (ext == ".npy") return ImageFormat::Npy;
  if (ext == ".nii" || ext == ".nii.gz" || ext == ".hdr" || ext == ".img")  // .hdr/.img: a pair
    return ImageFormat::Nifti;
  if (ext == ".mha" || ext == ".mhd") return ImageFormat::MetaImage;
  if (ext == ".nrrd" || ext == ".nhdr") return ImageFormat::Nrrd;
  if (ext == ".png") return ImageFormat::Png;
  if (ext == ".dcm") return ImageFormat::Dicom;
  std::error_code ec;
  if (ext.empty() || (!path.empty() && path.back() == '/') || fs::is_directory(path, ec))
    return ImageFormat::Directory;
  throw InputError(what + " '" + path + "': unknown format '" + ext +
                   "' (expected .nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr, .npy or .png; .dcm to "
                   "read)");
}

bool needs_itk(ImageFormat format) {
  switch (format) {
    case ImageFormat::Npy:
    case ImageFormat::Png:  // libpng
      return false;
    case ImageFormat::Nifti:
    case ImageFormat::MetaImage:
    case ImageFormat::Nrrd:
    case ImageFormat::Dicom:
    case ImageFormat::Directory:
      return true;
  }
  return true;
}

namespace {
[[noreturn]] void throw_dicom_is_read_only(const std::string& path, const std::string& what) {
  throw InputError(what + " '" + path +
                   "': sonoslice reads DICOM but does not write it; write .nii.gz, .mha, .nrrd "
                   "or .npy");
}

void check_writable(const std::string& path, const std::string& what, bool two_d) {
  const ImageFormat format = image_format(path, what);
  if (format == ImageFormat::Directory)
    throw InputError(what + " '" + path + "': give a file name with an extension (.nii.gz, " +
                     ".mha, .nrrd, .npy" + (two_d ? ", .png" : "") + ")");
  if (format == ImageFormat::Dicom) throw_dicom_is_read_only(path, what);
  if (format == ImageFormat::Png && !two_d)
    throw InputError(what + " '" + path + "': PNG holds 2-D images; write a volume as .nii.gz, " +
                     ".mha, .nrrd or .npy");
  if (format == ImageFormat::Png && !built_with_png())
    throw Error(what + " '" + path + "': this sonoslice was built without libpng; write .npy");
  if (needs_itk(format) && !built_with_itk())
    throw Error(what + " '" + path + "': this sonoslice was built without ITK; write .npy");
  check_output_path(path);
}
}  // namespace

void check_volume_output(const std::string& path, const std::string& what) {
  check_writable(path, what, false);
}

void check_image_output(const std::string& path, const std::string& what) {
  check_writable(path, what, true);
}

namespace {
// NaN and infinite voxels are sampled like any other value (NaN reaches float output, 0 integer
// output): said once, with the count, rather than discovered in the slices.
Volume warn_non_finite(Volume v, const std::string& path) {
  if (const int64_t bad = v.non_finite_count())
    warn("volume '" + path + "': " + std::to_string(bad) + " of " +
         std::to_string(v.grid().voxel_count()) +
         " voxels are NaN or infinite; they are sampled as they are");
  return v;
}
}  // namespace

namespace {
/// A PNG as a W×H×1 image through libpng (read_png_file: its errors caught, which ITK's PNG reader
/// does not do): with `colour_pixels` (frames), RGB and RGBA as their first component; a volume
/// has one.
Volume read_png_image(const std::string& path, int64_t* colour_pixels) {
  const DecodedPng png = read_png_file(path);
  const bool colour = png.components == 3 || png.components == 4;
  if (png.components != 1 && colour_pixels && !colour)
    throw InputError("image '" + path + "': " + std::to_string(png.components) +
                     " components (frames have 1, or 3 or 4: RGB, RGBA)");
  if (png.components != 1 && !colour_pixels)
    throw InputError("volume '" + path + "': a PNG of " + std::to_string(png.components) +
                     " components (sonoslice slices scalar volumes)");
  VolumeGrid g;
  g.dims = {png.width, png.height, 1};
  g.spacing_mm = {png.spacing_mm[0], png.spacing_mm[1], 1.0};
  g.validate("volume '" + path + "'");
  const PixelType type = png.bit_depth == 16 ? PixelType::UInt16 : PixelType::UInt8;
  Volume image = Volume::allocate(type, g);
  if (png.components == 1)
    std::memcpy(image.data(), png.pixels.data(), image.byte_size());
  else
    *colour_pixels += first_component(png.pixels.data(), type, g.voxel_count(), png.components,
                                      static_cast<uint8_t*>(image.data()));
  return image;
}

// `colour_pixels` given: the file holds frames, whose RGB or RGBA pixels are read as their first
// component; otherwise a volume, whose components are refused.
Volume read_volume_as_stored(const std::string& path, const VolumeReadOptions& options,
                             int64_t* colour_pixels = nullptr) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw FileError("cannot read volume '" + path + "': no such file");
  const ImageFormat format = image_format(path, "volume");
  const bool npy_flags = options.spacing_mm || options.origin_mm || options.direction ||
                         !options.fanslicer_npy_config.empty();
  if (format != ImageFormat::Npy && npy_flags)
    throw InputError(
        "volume '" + path +
        "': spacing, origin, direction and a fan-slicer npy config apply to .npy volumes only "
        "(this file carries its own geometry)");
  if (format == ImageFormat::Npy) return read_npy_volume(path, options);
  if (format == ImageFormat::Png) return read_png_image(path, colour_pixels);
  if (!options.series_uid.empty() && !fs::is_directory(path, ec))
    throw ParameterError("series_uid", "applies to DICOM directories; '" + path + "' is a file");
#ifdef SONOSLICE_HAVE_ITK
  // The ITK readers check the grid they read, naming the file.
  return fs::is_directory(path, ec) ? itk_io::read_dicom_directory(path, options.series_uid)
                                    : itk_io::read_image_file(path, colour_pixels);
#else
  no_itk(path);
#endif
}
}  // namespace

Volume read_volume(const std::string& path, const VolumeReadOptions& options) {
  return warn_non_finite(read_volume_as_stored(path, options), path);
}

namespace {
/// Frames read as their first component say once how many pixels had colour.
void warn_colour_frames(const std::string& what, const std::string& path, int64_t colour_pixels,
                        int64_t pixels) {
  if (colour_pixels > 0)
    warn(what + " '" + path + "': colour images read as their first (red) component; " +
         std::to_string(colour_pixels) + " of " + std::to_string(pixels) +
         " pixels have other colours");
}

/// A .npy of frames that is not a plain (N, H, W) stack: one 2-D image (H, W), or colour frames
/// (N, H, W, 3|4) read as their first component (first_component(): what PLUS reconstructs of
/// colour frames; one warning when the colours differ). A (W, H, N) volume of unit spacing, in C
/// order whatever the file's.
Volume read_npy_frames(const std::string& path, const std::string& what) {
  const NpyArray a = read_npy(path);
  const bool colour = a.shape.size() == 4;
  const int64_t n = colour ? a.shape[0] : 1, h = a.shape[colour ? 1 : 0],
                w = a.shape[colour ? 2 : 1], components = colour ? a.shape[3] : 1;
  if (n <= 0 || h <= 0 || w <= 0) throw InputError(what + " '" + path + "': empty array");
  VolumeGrid g;
  g.dims = {w, h, n};
  Volume image = Volume::allocate(a.type, g);
  const std::vector<int64_t> strides = npy_element_strides(a);
  const size_t size = pixel_size(a.type);
  const auto* from = static_cast<const char*>(a.data.get());
  auto* to = static_cast<uint8_t*>(image.data());
  std::vector<uint8_t> pixel(size * size_t(components));
  int64_t differing = 0;
  for (int64_t k = 0; k < n; ++k)
    for (int64_t v = 0; v < h; ++v)
      for (int64_t u = 0; u < w; ++u) {
        const int64_t at = colour ? k * strides[0] + v * strides[1] + u * strides[2]
                                  : v * strides[0] + u * strides[1];
        for (int64_t c = 0; c < components; ++c)
          std::memcpy(pixel.data() + size * size_t(c),
                      from + size_t(at + (colour ? c * strides[3] : 0)) * size, size);
        differing += first_component(pixel.data(), a.type, 1, int(components),
                                     to + size_t((k * h + v) * w + u) * size);
      }
  warn_colour_frames(what, path, differing, g.voxel_count());
  return image;
}

/// The readers call their file a volume; a file of frames is named in their errors as the caller
/// names it (`what`: "--frames", "stack"), with the same error type.
template <typename Read>
Volume naming_frames(const std::string& path, const std::string& what, Read&& read) {
  const auto renamed = [&](const Error& e) {
    std::string message = e.what();
    const std::string volume = "volume '" + path + "'";
    const size_t at = message.find(volume);
    if (at != std::string::npos) message.replace(at, volume.size(), what + " '" + path + "'");
    return message;
  };
  try {
    return read();
  } catch (const FileError& e) {
    throw FileError(renamed(e));
  } catch (const ResourceError& e) {
    throw ResourceError(renamed(e));
  } catch (const InputError& e) {
    throw InputError(renamed(e));
  }
}

// The order of a folder's frames (docs/conventions.md §6): DICOM images by InstanceNumber when
// each has its own, else every folder by name in natural order, so that an unpadded numbering
// (frame2 before frame10) keeps its order; byte order would interleave it without a word.
void frame_order(std::vector<std::string>& files, bool dicom, const std::string& what) {
  std::sort(files.begin(), files.end(), text::natural_less);
#ifdef SONOSLICE_HAVE_ITK
  if (!dicom) return;
  std::vector<std::pair<int64_t, std::string>> numbered;
  for (const std::string& file : files) {
    const std::optional<int64_t> n = itk_io::dicom_instance_number(file, what + " '" + file + "'");
    if (!n) return;
    numbered.emplace_back(*n, file);
  }
  std::stable_sort(numbered.begin(), numbered.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  for (size_t k = 0; k + 1 < numbered.size(); ++k)
    if (numbered[k].first == numbered[k + 1].first) return;  // not one frame a number
  for (size_t k = 0; k < files.size(); ++k) files[k] = numbered[k].second;
#else
  (void)dicom;
  (void)what;
#endif
}

}  // namespace

Volume read_image_stack(const std::string& path, const std::string& what) {
  std::error_code ec;
  if (!fs::is_directory(path, ec)) {
    if (!fs::exists(path, ec)) throw FileError(what + " '" + path + "': no such file");
    // A stack of images has no voxel geometry to warn about: .npy frames get the default one.
    VolumeReadOptions options;
    if (image_format(path, what) == ImageFormat::Npy) {
      options.spacing_mm = Vec3{1, 1, 1};
      // One 2-D image (H, W), as `slice --mask` writes it: a stack of one; (N, H, W, 3|4):
      // colour frames, as `slice --colors` writes them.
      const std::vector<int64_t> shape = read_npy_header(path).shape;
      if (shape.size() == 2 || (shape.size() == 4 && (shape[3] == 3 || shape[3] == 4)))
        return read_npy_frames(path, what);
      if (shape.size() != 3)
        throw InputError(what + " '" + path + "': expected (N, H, W) frames, (N, H, W, 3|4) " +
                         "colour frames or one (H, W) image; got a " +
                         std::to_string(shape.size()) + "-D array");
    }
    // Images are not sampled: what their NaN pixels mean is the caller's to say.
    int64_t colour_pixels = 0;
    Volume stack = naming_frames(
        path, what, [&] { return read_volume_as_stored(path, options, &colour_pixels); });
    warn_colour_frames(what, path, colour_pixels, stack.grid().voxel_count());
    return stack;
  }
  // A folder of frames: PNG images, or single-frame DICOM images (as some scanners export a
  // clip), one frame a file, in frame order (frame_order).
  std::vector<std::string> files;
  bool png = false, dicom = false;
  for (const auto& entry : fs::directory_iterator(path, ec)) {
    const std::string extension = file_extension(entry.path().string());
    if (!entry.is_regular_file() || (extension != ".png" && extension != ".dcm")) continue;
    files.push_back(entry.path().string());
    (extension == ".png" ? png : dicom) = true;
  }
  if (ec) throw FileError(what + " '" + path + "': cannot list the folder (" + ec.message() + ")");
  if (files.empty())
    throw InputError(what + " '" + path + "': a folder without .png or .dcm images");
  if (png && dicom)
    throw InputError(what + " '" + path + "': a folder of both .png and .dcm images (frames are " +
                     "one kind)");
  frame_order(files, dicom, what);
  Volume stack;
  int64_t colour_pixels = 0;
  for (size_t k = 0; k < files.size(); ++k) {
    const Volume image =
        png ? read_png_image(files[k], &colour_pixels) : naming_frames(files[k], what, [&] {
          return read_volume_as_stored(files[k], VolumeReadOptions{}, &colour_pixels);
        });
    const VolumeGrid& g = image.grid();
    if (g.dims[2] != 1)
      throw InputError(what + " '" + files[k] + "': " + std::to_string(g.dims[2]) +
                       " frames in one file of a folder of frames (give the clip itself)");
    if (k == 0) {
      VolumeGrid grid = g;
      grid.dims[2] = int64_t(files.size());
      stack = Volume::allocate(image.pixel_type(), grid);
    } else if (g.dims[0] != stack.grid().dims[0] || g.dims[1] != stack.grid().dims[1] ||
               image.pixel_type() != stack.pixel_type()) {
      throw InputError(what + " '" + files[k] + "': " + std::to_string(g.dims[0]) + "x" +
                       std::to_string(g.dims[1]) + " " + to_string(image.pixel_type()) +
                       ", unlike the first image's " + std::to_string(stack.grid().dims[0]) + "x" +
                       std::to_string(stack.grid().dims[1]) + " " + to_string(stack.pixel_type()));
    }
    const size_t bytes = size_t(g.dims[0] * g.dims[1]) * pixel_size(image.pixel_type());
    std::memcpy(static_cast<uint8_t*>(stack.data()) + k * bytes, image.data(), bytes);
  }
  warn_colour_frames(what, path, colour_pixels, stack.grid().voxel_count());
  return stack;
}

std::vector<DicomSeriesInfo> list_dicom_series(const std::string& directory) {
#ifdef SONOSLICE_HAVE_ITK
  return itk_io::list_dicom_series(directory);
#else
  no_itk(directory);
#endif
}

void write_image(const std::string& path, const void* data, PixelType type,
                 const std::vector<int64_t>& dims, const std::vector<double>& spacing,
                 int components, OutputSet* together) {
  if (components != 1 && components != 3)
    throw InputError("'" + path + "': images have 1 or 3 (RGB) components");
  const ImageFormat format = image_format(path, "output");
  if (format == ImageFormat::Directory)
    throw InputError("output '" + path + "': give a file name with an extension");
  if (format == ImageFormat::Dicom) throw_dicom_is_read_only(path, "output");
  if (format == ImageFormat::Npy) {
    std::vector<int64_t> shape(dims.rbegin(), dims.rend());  // C order: slowest axis first
    if (components == 3) shape.push_back(3);
    write_npy(path, type, shape, data, together);
    return;
  }
  if (format == ImageFormat::Png) {  // libpng, which reports every failed write
    if (dims.size() != 2 || spacing.size() < 2)
      throw InputError("output '" + path + "': PNG holds 2-D images; write .nii.gz or .npy");
    if (dims[0] > INT_MAX || dims[1] > INT_MAX)
      throw InputError("output '" + path + "': too large for a PNG");
    auto file = std::make_unique<AtomicFile>(path);
    const double spacing_mm[2] = {spacing[0], spacing[1]};
    write_png(file->fd(), path, data, type, int(dims[0]), int(dims[1]), components, spacing_mm);
    if (together)
      together->add(std::move(file));
    else
      file->commit();
    return;
  }
#ifdef SONOSLICE_HAVE_ITK
  const size_t n = dims.size();
  std::vector<double> origin(n, 0.0), direction(n * n, 0.0);
  for (size_t i = 0; i < n; ++i) direction[i * n + i] = 1.0;
  write_itk_atomic(path, data, type, dims, spacing, origin, direction, components, together);
#else
  (void)type, (void)spacing, (void)data;
  no_itk(path);
#endif
}

void write_volume(const std::string& path, const Volume& volume, OutputSet* together) {
  const VolumeGrid& g = volume.grid();
  g.validate("output '" + path + "'");  // a file that can be read back (ITK aborts on some)
  const ImageFormat format = image_format(path, "output");
  if (format == ImageFormat::Dicom) throw_dicom_is_read_only(path, "output");
  if (format == ImageFormat::Directory || format == ImageFormat::Png)
    throw InputError("output '" + path + "': write a volume as .nii.gz, .mha, .nrrd or .npy");
  if (format == ImageFormat::Npy) {
    // The array and its sidecar go into place together (a run's own set, or one for the two).
    OutputSet pair;
    OutputSet* both = together ? together : &pair;
    write_npy(path, volume.pixel_type(), {g.dims[2], g.dims[1], g.dims[0]}, volume.data(), both);
    nlohmann::json j;
    j["spacing"] = {g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]};
    j["origin"] = {g.origin_mm[0], g.origin_mm[1], g.origin_mm[2]};
    j["direction"] = g.direction.row_major();
    const std::string sidecar = fs::path(path).replace_extension(".json").string();
    write_text_file(sidecar, j.dump(2) + "\n", both);
    if (!together) pair.commit();
    return;
  }
#ifdef SONOSLICE_HAVE_ITK
  std::vector<double> spacing(g.spacing_mm.begin(), g.spacing_mm.end());
  std::vector<double> origin(g.origin_mm.begin(), g.origin_mm.end());
  const auto d = g.direction.row_major();
  const std::vector<double> direction(d.begin(), d.end());
  write_itk_atomic(path, volume.data(), volume.pixel_type(), {g.dims[0], g.dims[1], g.dims[2]},
                   spacing, origin, direction, 1, together);
#else
  no_itk(path);
#endif
}

}  // namespace sonoslice
