#include "sonoslice/io/Npy.h"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <regex>
#include <sstream>

#include "ByteOrder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"

namespace sonoslice {

// NumPy writes headers of a few hundred bytes (padded to 64); a length field beyond this is a
// corrupt file, and reading it would allocate whatever the field says.
constexpr size_t kMaxNpyHeaderBytes = size_t(1) << 20;
namespace {

constexpr char kMagic[] = "\x93NUMPY";

std::shared_ptr<void> aligned_buffer(size_t bytes, const std::string& path) {
  void* p = std::aligned_alloc(64, ((bytes + 63) / 64) * 64 + 64);
  if (!p)
    throw ResourceError("'" + path + "': cannot allocate " + std::to_string(bytes >> 20) + " MiB");
  return std::shared_ptr<void>(p, std::free);
}

// 'descr' → pixel type; `swap` is set for big-endian data.
PixelType parse_descr(const std::string& descr, bool* swap, const std::string& path) {
  if (descr.size() < 3) throw FileError("'" + path + "': bad dtype '" + descr + "'");
  const char order = descr[0];
  const std::string code = descr.substr(1);
  *swap = order == '>' && code.back() != '1';
  static const std::pair<const char*, PixelType> table[] = {
      {"u1", PixelType::UInt8},   {"i1", PixelType::Int8},    {"u2", PixelType::UInt16},
      {"i2", PixelType::Int16},   {"u4", PixelType::UInt32},  {"i4", PixelType::Int32},
      {"f4", PixelType::Float32}, {"f8", PixelType::Float64}, {"b1", PixelType::UInt8}};
  for (const auto& entry : table)
    if (code == entry.first) return entry.second;
  throw InputError("'" + path + "': unsupported dtype '" + descr +
                   "' (supported: uint8, int8, uint16, int16, uint32, int32, float32, float64)");
}

std::string descr_of(PixelType type) {
  switch (type) {
    case PixelType::UInt8:
      return "|u1";
    case PixelType::Int8:
      return "|i1";
    case PixelType::UInt16:
      return "<u2";
    case PixelType::Int16:
      return "<i2";
    case PixelType::UInt32:
      return "<u4";
    case PixelType::Int32:
      return "<i4";
    case PixelType::Float32:
      return "<f4";
    case PixelType::Float64:
      return "<f8";
  }
  return "<f4";
}

// The header's dtype, shape, order, data offset and byte order (no data yet).
NpyArray parse_header(std::ifstream& in, const std::string& path) {
  char preamble[10];
  if (!in.read(preamble, 10) || std::memcmp(preamble, kMagic, 6) != 0)
    throw FileError("'" + path + "': not a .npy file (bad magic)");
  const int major = static_cast<unsigned char>(preamble[6]);
  size_t header_len = 0, offset = 10;
  if (major == 1) {
    header_len = static_cast<unsigned char>(preamble[8]) |
                 (size_t(static_cast<unsigned char>(preamble[9])) << 8);
  } else if (major == 2 || major == 3) {
    char extra[2];
    if (!in.read(extra, 2)) throw FileError("'" + path + "': truncated .npy header");
    const unsigned char b[4] = {
        static_cast<unsigned char>(preamble[8]), static_cast<unsigned char>(preamble[9]),
        static_cast<unsigned char>(extra[0]), static_cast<unsigned char>(extra[1])};
    header_len = b[0] | (size_t(b[1]) << 8) | (size_t(b[2]) << 16) | (size_t(b[3]) << 24);
    offset = 12;
  } else {
    throw FileError("'" + path + "': unsupported .npy version " + std::to_string(major));
  }
  if (header_len > kMaxNpyHeaderBytes) throw FileError("'" + path + "': corrupt .npy header");
  std::string dict(header_len, '\0');
  if (!in.read(&dict[0], std::streamsize(header_len)))
    throw FileError("'" + path + "': truncated .npy header");

  NpyArray a;
  a.data_offset = offset + header_len;
  std::smatch m;
  static const std::regex descr_re(R"('descr'\s*:\s*'([^']*)')");
  static const std::regex fortran_re(R"('fortran_order'\s*:\s*(True|False))");
  static const std::regex shape_re(R"('shape'\s*:\s*\(([^)]*)\))");
  if (!std::regex_search(dict, m, descr_re))
    throw FileError("'" + path + "': corrupt .npy header (no descr)");
  const std::string descr = m[1];
  if (!std::regex_search(dict, m, fortran_re))
    throw FileError("'" + path + "': corrupt .npy header (no fortran_order)");
  a.fortran_order = m[1] == "True";
  if (!std::regex_search(dict, m, shape_re))
    throw FileError("'" + path + "': corrupt .npy header (no shape)");
  std::stringstream dims(m[1].str());
  std::string item;
  while (std::getline(dims, item, ',')) {
    item.erase(std::remove_if(item.begin(), item.end(), ::isspace), item.end());
    if (item.empty()) continue;
    char* end = nullptr;
    errno = 0;
    const long long v = std::strtoll(item.c_str(), &end, 10);
    if (*end != '\0' || v < 0 || errno == ERANGE)
      throw FileError("'" + path + "': corrupt .npy shape (" + m[1].str() + ")");
    a.shape.push_back(v);
  }
  a.type = parse_descr(descr, &a.swapped_on_disk, path);
  // The shape's byte count must be representable: an overflowed product once mapped 0 bytes of a
  // "(2^32, 2^32, 1)" array and read it as a volume.
  uint64_t bytes = pixel_size(a.type);
  for (int64_t d : a.shape) {
    if (d != 0 && bytes > uint64_t(std::numeric_limits<int64_t>::max()) / uint64_t(d)) {
      std::ostringstream s;
      s << "'" << path << "': the shape (" << m[1].str() << ") of " << to_string(a.type)
        << " values is more bytes than a file can hold";
      throw InputError(s.str());
    }
    bytes *= uint64_t(d);
  }
  return a;
}

}  // namespace

int64_t NpyArray::element_count() const {
  int64_t n = 1;
  for (int64_t d : shape) n *= d;
  return n;
}

std::vector<int64_t> npy_element_strides(const NpyArray& a) {
  std::vector<int64_t> strides(a.shape.size());
  int64_t stride = 1;
  if (a.fortran_order) {
    for (size_t i = 0; i < a.shape.size(); ++i) strides[i] = stride, stride *= a.shape[i];
  } else {
    for (size_t i = a.shape.size(); i-- > 0;) strides[i] = stride, stride *= a.shape[i];
  }
  return strides;
}

NpyArray read_npy_header(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw FileError("cannot open '" + path + "': " + std::strerror(errno));
  return parse_header(in, path);
}

NpyArray read_npy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw FileError("cannot open '" + path + "': " + std::strerror(errno));
  NpyArray a = parse_header(in, path);
  const size_t item = pixel_size(a.type);
  const uint64_t bytes = uint64_t(a.element_count()) * item;
  in.seekg(0, std::ios::end);
  const uint64_t file_size = uint64_t(in.tellg());
  if (file_size < a.data_offset + bytes) {
    std::ostringstream s;
    s << "'" << path << "': truncated .npy file (" << file_size - a.data_offset
      << " data bytes, the header announces " << bytes << ")";
    throw FileError(s.str());
  }
  a.data = aligned_buffer(bytes, path);
  in.seekg(std::streamoff(a.data_offset));
  if (!in.read(static_cast<char*>(a.data.get()), std::streamsize(bytes)))
    throw FileError("'" + path + "': read error");
  if (a.swapped_on_disk) byteswap(a.data.get(), size_t(a.element_count()), item);
  return a;
}

namespace {

// The byte count of an array of this shape, refused (naming the output) when a size is negative
// or the count overflows: an overflowed product once wrote a 102-byte "volume".
uint64_t checked_byte_count(PixelType type, const std::vector<int64_t>& shape,
                            const std::string& path) {
  uint64_t bytes = pixel_size(type);
  for (int64_t d : shape) {
    if (d < 0 || (d != 0 && bytes > uint64_t(std::numeric_limits<int64_t>::max()) / uint64_t(d))) {
      std::ostringstream s;
      s << "cannot write '" << path << "': the shape (";
      for (size_t i = 0; i < shape.size(); ++i) s << (i ? ", " : "") << shape[i];
      s << ") of " << to_string(type) << " values "
        << (d < 0 ? "has a negative size" : "is more bytes than a file can hold");
      throw InputError(s.str());
    }
    bytes *= uint64_t(d);
  }
  return bytes;
}

}  // namespace

NpyWriter::NpyWriter(const std::string& path, PixelType type, const std::vector<int64_t>& shape)
    : path_(path), expected_(checked_byte_count(type, shape, path)) {
  file_ = std::make_unique<AtomicFile>(path);  // only once the shape is known to be sound
  std::ostringstream dict;
  dict << "{'descr': '" << descr_of(type) << "', 'fortran_order': False, 'shape': (";
  for (size_t i = 0; i < shape.size(); ++i) {
    dict << shape[i] << (shape.size() == 1 || i + 1 < shape.size() ? "," : "");
    if (i + 1 < shape.size()) dict << " ";
  }
  dict << "), }";
  std::string header = dict.str();
  // Version 1 header: 10-byte preamble + dict padded with spaces to a multiple of 64, ending in \n.
  const size_t total = ((10 + header.size() + 1 + 63) / 64) * 64;
  header.append(total - 10 - header.size() - 1, ' ');
  header.push_back('\n');
  unsigned char preamble[10] = {0x93,
                                'N',
                                'U',
                                'M',
                                'P',
                                'Y',
                                1,
                                0,
                                static_cast<unsigned char>(header.size() & 0xff),
                                static_cast<unsigned char>(header.size() >> 8)};
  write_fully(file_->fd(), preamble, sizeof preamble, path_);
  write_fully(file_->fd(), header.data(), header.size(), path_);
  header_bytes_ = sizeof preamble + header.size();
}

NpyWriter::~NpyWriter() = default;  // an uncommitted temporary goes with file_

void NpyWriter::write(const void* data, size_t bytes) {
  if (written_ + bytes > expected_) throw Error("'" + path_ + "': more data than the shape holds");
  write_fully(file_->fd(), data, bytes, path_);
  written_ += bytes;
}

void NpyWriter::commit(OutputSet* together) {
  if (written_ != expected_) throw Error("'" + path_ + "': incomplete data");
  // Every write was checked; the size on disk is the last word before the rename.
  struct stat st;
  if (::fstat(file_->fd(), &st) != 0) throw FileError(write_error_message(path_, errno));
  if (uint64_t(st.st_size) != header_bytes_ + expected_)
    throw FileError("cannot write '" + path_ + "': " + std::to_string(st.st_size) +
                    " bytes on disk, " + std::to_string(header_bytes_ + expected_) + " expected");
  if (together)
    together->add(std::move(file_));
  else
    file_->commit();
}

void write_npy(const std::string& path, PixelType type, const std::vector<int64_t>& shape,
               const void* data, OutputSet* together) {
  NpyWriter w(path, type, shape);
  w.write(data, w.expected_bytes());
  w.commit(together);
}

}  // namespace sonoslice
