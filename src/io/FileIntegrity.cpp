// Truncation checks for the formats ITK 5.2 reads "successfully" when the file is cut short:
// NiftiImageIO zero-fills the missing voxels of a .nii or .nii.gz, and MetaIO only prints
// "data not read completely" (see ItkImageIO.cpp). A truncated CT must be an error, not a
// volume whose lower half is air.
#include "FileIntegrity.h"

#include <zlib.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "sonoslice/core/Error.h"
#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace itk_io {
namespace {

namespace fs = std::filesystem;

[[noreturn]] void truncated(const std::string& path, const std::string& why) {
  throw FileError("cannot read volume '" + path + "': truncated or corrupt file (" + why + ")");
}

uint32_t swap32(uint32_t v) {
  return (v >> 24) | ((v >> 8) & 0xff00u) | ((v << 8) & 0xff0000u) | (v << 24);
}

// Where the voxels start in an uncompressed NIfTI-1/2 header (vox_offset).
uint64_t nifti_vox_offset(const unsigned char* h, size_t n, const std::string& path) {
  if (n < 348) truncated(path, "header shorter than 348 bytes");
  uint32_t sizeof_hdr;
  std::memcpy(&sizeof_hdr, h, 4);
  const bool swap = sizeof_hdr != 348 && sizeof_hdr != 540;
  if (swap) sizeof_hdr = swap32(sizeof_hdr);
  if (sizeof_hdr == 348) {  // NIfTI-1: float vox_offset at byte 108
    uint32_t bits;
    std::memcpy(&bits, h + 108, 4);
    if (swap) bits = swap32(bits);
    float f;
    std::memcpy(&f, &bits, 4);
    return f < 352 ? 352 : uint64_t(f);
  }
  if (sizeof_hdr == 540 && n >= 176) {  // NIfTI-2: int64 vox_offset at byte 168
    uint64_t v;
    std::memcpy(&v, h + 168, 8);
    if (swap) v = (uint64_t(swap32(uint32_t(v))) << 32) | swap32(uint32_t(v >> 32));
    return v;
  }
  truncated(path, "not a NIfTI header");
}

// Decompresses the whole stream, returning its size; throws on a stream that ends early.
uint64_t gzip_stream_size(const std::string& path) {
  gzFile f = gzopen(path.c_str(), "rb");
  if (!f) truncated(path, "cannot open the gzip stream");
  gzbuffer(f, 1 << 18);
  std::vector<char> buf(1 << 20);
  uint64_t total = 0;
  int n;
  while ((n = gzread(f, buf.data(), unsigned(buf.size()))) > 0) total += uint64_t(n);
  int err = Z_OK;
  const char* msg = gzerror(f, &err);
  const std::string why = msg ? msg : "";
  gzclose(f);
  if (n < 0 || (err != Z_OK && err != Z_STREAM_END)) truncated(path, why.empty() ? "gzip error" : why);
  return total;
}

void check_nifti(const std::string& path, uint64_t data_bytes, bool gzipped) {
  unsigned char header[544] = {0};
  size_t got = 0;
  if (gzipped) {
    gzFile f = gzopen(path.c_str(), "rb");
    if (!f) truncated(path, "cannot open the gzip stream");
    const int n = gzread(f, header, sizeof header);
    gzclose(f);
    got = n > 0 ? size_t(n) : 0;
  } else {
    std::ifstream in(path, std::ios::binary);
    in.read(reinterpret_cast<char*>(header), sizeof header);
    got = size_t(in.gcount());
  }
  const uint64_t expected = nifti_vox_offset(header, got, path) + data_bytes;
  if (!gzipped) {
    const uint64_t size = fs::file_size(path);
    if (size < expected) {
      std::ostringstream s;
      s << size << " bytes, the header needs " << expected;
      truncated(path, s.str());
    }
    return;
  }
  // gzip's trailer ends with the uncompressed size mod 2^32 (ISIZE): four bytes to read instead
  // of a second decompression. Only when they disagree (a truncated file, or a multi-member
  // gzip such as bgzip writes) is the whole stream decompressed to decide.
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  const std::streamoff size = in.tellg();
  uint32_t isize = 0;
  if (size >= 18) {
    in.seekg(size - 4);
    unsigned char b[4];
    in.read(reinterpret_cast<char*>(b), 4);
    isize = uint32_t(b[0]) | (uint32_t(b[1]) << 8) | (uint32_t(b[2]) << 16) | (uint32_t(b[3]) << 24);
  }
  if (isize == uint32_t(expected)) return;
  const uint64_t total = gzip_stream_size(path);
  if (total < expected) {
    std::ostringstream s;
    s << "decompresses to " << total << " bytes, the header needs " << expected;
    truncated(path, s.str());
  }
}

}  // namespace

void check_complete(const std::string& path, uint64_t data_bytes) {
  const std::string ext = file_extension(path);
  if (ext == ".nii") check_nifti(path, data_bytes, false);
  if (ext == ".nii.gz") check_nifti(path, data_bytes, true);
}

}  // namespace itk_io
}  // namespace sonoslice
