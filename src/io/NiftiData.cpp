#include "NiftiData.h"

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "../core/Text.h"
#include "ByteOrder.h"
#include "MappedFile.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace itk_io {
namespace {

// zlib's default buffer is 8 KiB; a larger one means fewer read calls on volumes of hundreds of MB.
constexpr unsigned kGzipBufferBytes = 1u << 20;

[[noreturn]] void throw_absurd(const std::string& where, const std::string& field, double v) {
  std::ostringstream s;
  s << where << field << " is " << v << ": beyond any scanner's extent (at most 1e9 mm)";
  throw InputError(s.str());
}

// The largest vox_offset taken (2^53 bytes, 8 PiB): exact in a double, far beyond any file.
constexpr double kMaxVoxOffset = 9007199254740992.0;

[[noreturn]] void truncated(const std::string& path, const std::string& why) {
  throw FileError("cannot read volume '" + path + "': truncated or corrupt file (" + why + ")");
}

template <typename T>
T load(const unsigned char* p, bool swap) {
  unsigned char b[sizeof(T)];
  std::memcpy(b, p, sizeof(T));
  if (swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

struct Header {
  uint64_t vox_offset = 0;
  int datatype = 0;
  bool swapped = false;
  double scl_slope = 0, scl_inter = 0;
};

// The few NIfTI-1/2 header fields this path needs (check_nifti_header has checked them, ITK the
// rest). In a single file the voxels start at byte 352 at the earliest; in a .hdr/.img pair they
// are in the .img, from vox_offset (usually 0).
Header parse_header(const unsigned char* h, size_t n, const std::string& path, bool single_file) {
  if (n < 348) truncated(path, "header shorter than 348 bytes");
  Header out;
  int32_t size = load<int32_t>(h, false);
  out.swapped = size != 348 && size != 540;
  size = load<int32_t>(h, out.swapped);
  if (size == 348) {  // NIfTI-1
    out.datatype = load<int16_t>(h + 70, out.swapped);
    const float offset = load<float>(h + 108, out.swapped);
    if (!(offset <= kMaxVoxOffset)) truncated(path, "vox_offset out of range");  // NaN too
    out.vox_offset = uint64_t(std::max(single_file ? 352.0f : 0.0f, offset));
    out.scl_slope = load<float>(h + 112, out.swapped);
    out.scl_inter = load<float>(h + 116, out.swapped);
  } else if (size == 540 && n >= 540) {  // NIfTI-2
    out.datatype = load<int16_t>(h + 12, out.swapped);
    const int64_t offset = load<int64_t>(h + 168, out.swapped);
    if (offset < 0 || double(offset) > kMaxVoxOffset) truncated(path, "vox_offset out of range");
    out.vox_offset = uint64_t(offset);
    out.scl_slope = load<double>(h + 176, out.swapped);
    out.scl_inter = load<double>(h + 184, out.swapped);
  } else {
    truncated(path, "not a NIfTI header");
  }
  return out;
}

std::optional<PixelType> pixel_type_of(int datatype) {
  switch (datatype) {
    case 2:
      return PixelType::UInt8;
    case 4:
      return PixelType::Int16;
    case 8:
      return PixelType::Int32;
    case 16:
      return PixelType::Float32;
    case 64:
      return PixelType::Float64;
    case 256:
      return PixelType::Int8;
    case 512:
      return PixelType::UInt16;
    case 768:
      return PixelType::UInt32;
    default:
      return std::nullopt;
  }
}

// The other file of a .hdr/.img pair, in the same letter case ("a.HDR" → "a.IMG").
std::string pair_sibling(const std::string& path, const std::string& lower_ext) {
  const std::string stem = path.substr(0, path.size() - 4);
  const bool upper = std::isupper(static_cast<unsigned char>(path.back()));
  return stem + (upper ? text::upper(lower_ext) : lower_ext);
}

// The NIfTI datatype codes (nifti1.h) and their bytes per voxel; the C library prints a line to
// stderr and ITK fails obscurely for any other code.
int datatype_bytes(int datatype) {
  switch (datatype) {
    case 2:
    case 256:
      return 1;
    case 4:
    case 512:
      return 2;
    case 8:
    case 16:
    case 128:  // RGB24: 3 bytes, rounded up (only the overflow check uses this)
    case 768:
    case 2304:
      return 4;
    case 32:
    case 64:
    case 1024:
    case 1280:
      return 8;
    case 1536:
    case 1792:
      return 16;
    case 2048:
      return 32;
    case 1:  // DT_BINARY: bits, refused later as a pixel type
      return 1;
    default:
      return 0;
  }
}

// Up to 540 header bytes of a .nii, .nii.gz, .hdr (or .hdr.gz); `got` is how many there were.
size_t read_header_bytes(const std::string& path, unsigned char (&raw)[540]) {
  gzFile f = gzopen(path.c_str(), "rb");  // reads uncompressed files as they are, too
  if (!f) truncated(path, "cannot open it");
  const int n = gzread(f, raw, sizeof raw);
  gzclose(f);
  return n > 0 ? size_t(n) : 0;
}

}  // namespace

void check_nifti_header(const std::string& path) {
  std::string header_path = path;
  const std::string ext = file_extension(path);
  if (ext == ".img") {  // a header/image pair: the header is beside the image
    header_path = pair_sibling(path, ".hdr");
    std::error_code ec;
    if (!std::filesystem::exists(header_path, ec)) return;  // ITK says what is missing
  }
  unsigned char raw[540] = {0};
  const size_t got = read_header_bytes(header_path, raw);
  if (got < 348) truncated(header_path, "the header is shorter than 348 bytes");
  const int32_t size_native = load<int32_t>(raw, false), size_swapped = load<int32_t>(raw, true);
  const bool swap = size_native != 348 && size_native != 540;
  const int32_t size = swap ? size_swapped : size_native;
  if (size != 348 && size != 540)
    throw FileError("cannot read volume '" + path +
                    "': not a NIfTI or Analyze file (its header does not start with 348 or 540)");
  if (size == 540 && got < 540)
    truncated(header_path, "the NIfTI-2 header is shorter than 540 bytes");
  const bool v2 = size == 540;
  // NIfTI or Analyze 7.5, decided as the NIfTI C library (and so ITK) decides (NIFTI_VERSION in
  // nifti1.h): any magic "n+K" or "niK", K = 1..9, makes a 348-byte header NIfTI, whose orientation
  // fields ITK then reads ("n+2" in a 348-byte header once reached ITK's matrix code unchecked).
  const unsigned char* magic = raw + 344;
  const bool nifti = v2 || (magic[0] == 'n' && (magic[1] == '+' || magic[1] == 'i') &&
                            magic[2] >= '1' && magic[2] <= '9' && magic[3] == '\0');
  const std::string where = "volume '" + path + "': ";

  int64_t dim[8];
  double pixdim[8];
  for (int i = 0; i < 8; ++i) {
    dim[i] = v2 ? load<int64_t>(raw + 16 + 8 * i, swap) : load<int16_t>(raw + 40 + 2 * i, swap);
    pixdim[i] = v2 ? load<double>(raw + 104 + 8 * i, swap) : load<float>(raw + 76 + 4 * i, swap);
  }
  const int datatype = load<int16_t>(raw + (v2 ? 12 : 70), swap);
  if (dim[0] < 1 || dim[0] > 7)
    throw FileError("cannot read volume '" + path + "': corrupt header: dim[0] is " +
                    std::to_string(dim[0]) + " (the number of dimensions, 1 to 7)");
  const int bytes_per_voxel = datatype_bytes(datatype);
  if (bytes_per_voxel == 0)
    throw FileError("cannot read volume '" + path + "': corrupt header: datatype " +
                    std::to_string(datatype) + " is not a NIfTI data type");
  // The voxel count and byte count, checked for overflow: the C library and ITK multiply the
  // dimensions without checks.
  uint64_t bytes = uint64_t(bytes_per_voxel);
  for (int i = 1; i <= dim[0]; ++i) {
    if (dim[i] < 1)
      throw FileError("cannot read volume '" + path + "': corrupt header: dim[" +
                      std::to_string(i) + "] is " + std::to_string(dim[i]) +
                      " (sizes must be at least 1)");
    if (bytes > uint64_t(std::numeric_limits<int64_t>::max()) / uint64_t(dim[i]))
      throw InputError(where + "the header's sizes overflow (more bytes than a file can hold)");
    bytes *= uint64_t(dim[i]);
  }
  // Spacing: the C library and ITK turn a zero or NaN pixdim into 1 mm without a word.
  for (int i = 1; i <= std::min<int64_t>(dim[0], 3); ++i) {
    if (!(pixdim[i] > 0) || !std::isfinite(pixdim[i])) {
      std::ostringstream s;
      s << where << "pixdim[" << i << "] is " << pixdim[i] << ": the voxel spacing along axis "
        << i - 1 << " must be a positive number of mm";
      throw InputError(s.str());
    }
    if (pixdim[i] > kMaxGeometryMm)
      throw_absurd(where, "pixdim[" + std::to_string(i) + "]", pixdim[i]);
  }
  // Where the voxels start: a float in NIfTI-1 (NaN, infinite or beyond any file size here would
  // be undefined behaviour in the conversion to an offset), a signed 64-bit count in NIfTI-2.
  const double vox_offset =
      v2 ? double(load<int64_t>(raw + 168, swap)) : load<float>(raw + 108, swap);
  if (!std::isfinite(vox_offset) || vox_offset < 0 || vox_offset > kMaxVoxOffset) {
    std::ostringstream s;
    s << "cannot read volume '" << path << "': corrupt header: vox_offset is " << vox_offset
      << " (the byte where the voxels start)";
    throw FileError(s.str());
  }
  // An uncompressed file must hold its voxels (the C library zero-fills a short one, and ITK
  // first allocates what the header claims: an Analyze header of 373 bytes once asked for 6 GB).
  const bool single = ext == ".nii";
  if (single || ext == ".hdr" || ext == ".img") {
    const std::string data_path = single ? path : pair_sibling(path, ".img");
    const uint64_t start =
        uint64_t(single ? std::max(vox_offset, double(v2 ? 544 : 352)) : vox_offset);
    std::error_code ec;
    const uint64_t file_size = std::filesystem::file_size(data_path, ec);
    if (!ec && file_size < start + bytes) {
      std::ostringstream s;
      s << "'" << data_path << "' has " << file_size << " bytes, the header describes "
        << start + bytes;
      truncated(path, s.str());
    }
  }
  // A gzip stream cannot hold more than 1032 bytes per compressed byte (deflate's limit): a header
  // claiming more is refused before anything allocates for it.
  if (ext == ".nii.gz") {
    std::error_code ec;
    const uint64_t file_size = std::filesystem::file_size(path, ec);
    const double most = double(file_size) * 1032.0 + 1024.0;
    if (!ec && most < double(bytes) + vox_offset) {
      std::ostringstream s;
      s << "its " << file_size << " compressed bytes cannot hold the " << bytes
        << " voxel bytes the header describes";
      truncated(path, s.str());
    }
  }
  if (!nifti) return;  // Analyze 7.5: no scaling or orientation fields

  // Scaling, y = scl_slope · x + scl_inter when scl_slope is not 0 (nifti1.h). Readers disagree
  // on the rest: ITK adds the intercept when the slope is 0 or NaN, other readers ignore both.
  const double slope = v2 ? load<double>(raw + 176, swap) : load<float>(raw + 112, swap);
  const double inter = v2 ? load<double>(raw + 184, swap) : load<float>(raw + 116, swap);
  if (!std::isfinite(slope) && inter != 0 && !std::isnan(inter)) {
    std::ostringstream s;
    s << where << "scl_slope is " << slope << " with scl_inter " << inter
      << " (give a finite slope, or 0 for no scaling)";
    throw InputError(s.str());
  }
  if (std::isfinite(slope) && slope != 0 && !std::isfinite(inter)) {
    std::ostringstream s;
    s << where << "scl_inter is " << inter << " (scaling by " << slope
      << " needs a finite intercept)";
    throw InputError(s.str());
  }
  if (slope == 0 && inter != 0 && std::isfinite(inter)) {
    std::ostringstream s;
    s << where << "scl_slope is 0 (no scaling) but scl_inter is " << inter
      << ": readers disagree on whether to add it; set scl_slope to 1 or scl_inter to 0";
    throw InputError(s.str());
  }
  // Orientation: a NaN here aborted the process inside ITK's matrix code (vnl_matrix).
  const int qform = v2 ? load<int32_t>(raw + 344, swap) : load<int16_t>(raw + 252, swap);
  const int sform = v2 ? load<int32_t>(raw + 348, swap) : load<int16_t>(raw + 254, swap);
  static const char* const kQuatern[] = {"quatern_b", "quatern_c", "quatern_d",
                                         "qoffset_x", "qoffset_y", "qoffset_z"};
  if (qform > 0)
    for (int i = 0; i < 6; ++i) {
      const double v =
          v2 ? load<double>(raw + 352 + 8 * i, swap) : load<float>(raw + 256 + 4 * i, swap);
      if (!std::isfinite(v))
        throw InputError(where + kQuatern[i] + " is not a finite number (qform_code " +
                         std::to_string(qform) + ")");
      if (std::fabs(v) > kMaxGeometryMm) throw_absurd(where, kQuatern[i], v);
    }
  static const char* const kRows[] = {"srow_x", "srow_y", "srow_z"};
  if (sform > 0)
    for (int i = 0; i < 12; ++i) {
      const double v =
          v2 ? load<double>(raw + 400 + 8 * i, swap) : load<float>(raw + 280 + 4 * i, swap);
      const std::string name = kRows[i / 4] + ("[" + std::to_string(i % 4) + "]");
      if (!std::isfinite(v))
        throw InputError(where + name + " is not a finite number (sform_code " +
                         std::to_string(sform) + ")");
      if (std::fabs(v) > kMaxGeometryMm) throw_absurd(where, name, v);
    }
}

std::optional<Volume> read_nifti_voxels(const std::string& path, const VolumeGrid& grid,
                                        PixelType type) {
  const std::string ext = file_extension(path);
  const bool gz = ext == ".nii.gz";
  const bool pair = ext == ".hdr" || ext == ".img";
  const std::string header_path = ext == ".img" ? pair_sibling(path, ".hdr") : path;
  const std::string data_path = ext == ".hdr" ? pair_sibling(path, ".img") : path;
  unsigned char raw[540] = {0};
  gzFile f = nullptr;
  size_t got = 0;
  if (gz) {
    f = gzopen(path.c_str(), "rb");
    if (!f) truncated(path, "cannot open the gzip stream");
    gzbuffer(f, kGzipBufferBytes);
    const int n = gzread(f, raw, 348);
    got = n > 0 ? size_t(n) : 0;
    // NIfTI-2 headers are longer: read the rest of them.
    if (got == 348 && load<int32_t>(raw, false) != 348 && load<int32_t>(raw, true) != 348) {
      const int m = gzread(f, raw + 348, 540 - 348);
      got += m > 0 ? size_t(m) : 0;
    }
  } else {
    std::ifstream in(header_path, std::ios::binary);
    in.read(reinterpret_cast<char*>(raw), sizeof raw);
    got = size_t(in.gcount());
  }
  struct GzCloser {
    gzFile f;
    ~GzCloser() {
      if (f) gzclose(f);
    }
  } closer{f};
  const Header h = parse_header(raw, got, header_path, !pair);
  // Reads `count` bytes of the gzip stream into dst (or past them when dst is null).
  auto gz_read = [&](char* dst, uint64_t count, const char* what) {
    char skip[4096];
    for (uint64_t done = 0; done < count;) {
      const unsigned want =
          unsigned(std::min<uint64_t>(count - done, dst ? 1u << 30 : sizeof skip));
      const int n = gzread(f, dst ? dst + done : skip, want);
      if (n <= 0) {
        int err = Z_OK;
        const char* msg = gzerror(f, &err);
        std::ostringstream s;
        s << "the gzip stream ends after " << done << " of " << count << " " << what;
        if (err != Z_OK && msg && *msg) s << ": " << msg;
        truncated(path, s.str());
      }
      done += uint64_t(n);
    }
  };
  const uint64_t header_end = std::max<uint64_t>(got, h.vox_offset);

  const bool rescaled = !(h.scl_slope == 0 || (h.scl_slope == 1 && h.scl_inter == 0));
  if (rescaled || pixel_type_of(h.datatype) != type) {
    // ITK converts: let it, but only once the voxels are known to be all there (ITK's gzip
    // reader fills a short stream with zeros; an uncompressed file was checked by
    // check_nifti_header).
    if (gz) {
      gz_read(nullptr, header_end - got, "header bytes");
      gz_read(nullptr, uint64_t(grid.voxel_count()) * uint64_t(datatype_bytes(h.datatype)),
              "voxel bytes");
    }
    return std::nullopt;
  }

  const uint64_t bytes = uint64_t(grid.voxel_count()) * pixel_size(type);
  if (!gz && !h.swapped) {
    // Uncompressed, native byte order: map the file; pages load as slicing touches them.
    auto data = map_file_region(data_path, h.vox_offset, bytes, pixel_size(type));
    return Volume::wrap(data.get(), type, grid, data);
  }
  Volume v = Volume::allocate(type, grid);
  if (gz) {
    // Skip to vox_offset (extensions may sit between the header and the voxels).
    gz_read(nullptr, header_end - got, "header bytes");
    gz_read(static_cast<char*>(v.data()), bytes, "voxel bytes");
  } else {
    std::ifstream in(data_path, std::ios::binary);
    in.seekg(std::streamoff(h.vox_offset));
    in.read(static_cast<char*>(v.data()), std::streamsize(bytes));
    if (uint64_t(in.gcount()) != bytes)
      truncated(path, "fewer voxel bytes than the header announces");
  }
  if (h.swapped) byteswap(v.data(), size_t(grid.voxel_count()), pixel_size(type));
  return v;
}

}  // namespace itk_io
}  // namespace sonoslice
