#include "NiftiData.h"

#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <sstream>

#include "ByteOrder.h"
#include "MappedFile.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace itk_io {
namespace {

// zlib's default buffer is 8 KiB; a larger one means fewer read calls on volumes of hundreds of MB.
constexpr unsigned kGzipBufferBytes = 1u << 20;

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

// The few NIfTI-1/2 header fields this path needs (ITK has read and checked the rest).
Header parse_header(const unsigned char* h, size_t n, const std::string& path) {
  if (n < 348) truncated(path, "header shorter than 348 bytes");
  Header out;
  int32_t size = load<int32_t>(h, false);
  out.swapped = size != 348 && size != 540;
  size = load<int32_t>(h, out.swapped);
  if (size == 348) {  // NIfTI-1
    out.datatype = load<int16_t>(h + 70, out.swapped);
    out.vox_offset = uint64_t(std::max(352.0f, load<float>(h + 108, out.swapped)));
    out.scl_slope = load<float>(h + 112, out.swapped);
    out.scl_inter = load<float>(h + 116, out.swapped);
  } else if (size == 540 && n >= 540) {  // NIfTI-2
    out.datatype = load<int16_t>(h + 12, out.swapped);
    out.vox_offset = uint64_t(load<int64_t>(h + 168, out.swapped));
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

}  // namespace

std::optional<Volume> read_nifti_voxels(const std::string& path, const VolumeGrid& grid,
                                        PixelType type) {
  // A .hdr/.img pair keeps its voxels in the .img: ITK's reader knows where.
  if (file_extension(path) == ".hdr" || file_extension(path) == ".img") return std::nullopt;
  const bool gz = file_extension(path) == ".nii.gz";
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
    std::ifstream in(path, std::ios::binary);
    in.read(reinterpret_cast<char*>(raw), sizeof raw);
    got = size_t(in.gcount());
  }
  struct GzCloser {
    gzFile f;
    ~GzCloser() {
      if (f) gzclose(f);
    }
  } closer{f};
  const Header h = parse_header(raw, got, path);
  const bool rescaled = !(h.scl_slope == 0 || (h.scl_slope == 1 && h.scl_inter == 0));
  if (rescaled || pixel_type_of(h.datatype) != type) return std::nullopt;  // ITK converts: let it

  const uint64_t bytes = uint64_t(grid.voxel_count()) * pixel_size(type);
  if (!gz && !h.swapped) {
    // Uncompressed, native byte order: map the file; pages load as slicing touches them.
    auto data = map_file_region(path, h.vox_offset, bytes);
    return Volume::wrap(data.get(), type, grid, data);
  }
  Volume v = Volume::allocate(type, grid);
  if (gz) {
    // Skip to vox_offset (extensions may sit between the header and the voxels).
    uint64_t position = got;
    char skip[4096];
    while (position < h.vox_offset) {
      const int n =
          gzread(f, skip, unsigned(std::min<uint64_t>(sizeof skip, h.vox_offset - position)));
      if (n <= 0) truncated(path, "ends inside its header");
      position += uint64_t(n);
    }
    auto* dst = static_cast<char*>(v.data());
    uint64_t done = 0;
    while (done < bytes) {
      const unsigned want = unsigned(std::min<uint64_t>(bytes - done, 1u << 30));
      const int n = gzread(f, dst + done, want);
      if (n <= 0) {
        int err = Z_OK;
        const char* msg = gzerror(f, &err);
        std::ostringstream s;
        s << "the gzip stream ends after " << done << " of " << bytes << " voxel bytes";
        if (err != Z_OK && msg && *msg) s << ": " << msg;
        truncated(path, s.str());
      }
      done += uint64_t(n);
    }
  } else {
    std::ifstream in(path, std::ios::binary);
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
