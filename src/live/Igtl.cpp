// OpenIGTLink messages: the byte layouts of OpenIGTLink's igtl_header.h, igtl_image.h,
// igtl_transform.h, igtl_string.h, igtl_status.h and igtl_command.h, big-endian throughout.
#include "sonoslice/live/Igtl.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>

namespace sonoslice {
namespace igtl {
namespace {

uint64_t get_be(const uint8_t* p, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | p[i];
  return v;
}
void put_be(std::vector<uint8_t>& out, uint64_t v, int bytes) {
  for (int i = bytes - 1; i >= 0; --i) out.push_back(uint8_t(v >> (8 * i)));
}
float get_float(const uint8_t* p) {
  const uint32_t bits = uint32_t(get_be(p, 4));
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}
void put_float(std::vector<uint8_t>& out, double v) {
  const float f = float(v);
  uint32_t bits;
  std::memcpy(&bits, &f, 4);
  put_be(out, bits, 4);
}
// A fixed-size, zero-padded text field; text stops at the first zero byte.
std::string get_text(const uint8_t* p, size_t n) {
  size_t len = 0;
  while (len < n && p[len] != 0) ++len;
  return std::string(reinterpret_cast<const char*>(p), len);
}
void put_text(std::vector<uint8_t>& out, const std::string& text, size_t n) {
  for (size_t i = 0; i < n; ++i) out.push_back(i < text.size() ? uint8_t(text[i]) : 0);
}

// CRC-64 tables for eight bytes at a time ("slicing by 8"): table[k][b] is the CRC register
// after byte b followed by k zero bytes; table[0] is the classic byte-at-a-time table.
using CrcTables = std::array<std::array<uint64_t, 256>, 8>;
const CrcTables& crc_tables() {
  static const CrcTables tables = [] {
    CrcTables t{};
    const uint64_t poly = 0x42F0E1EBA9EA3693ULL;
    for (uint64_t i = 0; i < 256; ++i) {
      uint64_t c = i << 56;
      for (int b = 0; b < 8; ++b) c = (c & (1ULL << 63)) ? (c << 1) ^ poly : c << 1;
      t[0][size_t(i)] = c;
    }
    for (size_t k = 1; k < 8; ++k)
      for (size_t i = 0; i < 256; ++i)
        t[k][i] = t[0][size_t(t[k - 1][i] >> 56)] ^ (t[k - 1][i] << 8);
    return t;
  }();
  return tables;
}

}  // namespace

uint64_t crc64(const uint8_t* data, size_t n, uint64_t crc) {
  const CrcTables& t = crc_tables();
  for (; n >= 8; n -= 8, data += 8) {
    const uint64_t x = crc ^ get_be(data, 8);
    crc = t[7][x >> 56] ^ t[6][(x >> 48) & 0xFF] ^ t[5][(x >> 40) & 0xFF] ^ t[4][(x >> 32) & 0xFF] ^
          t[3][(x >> 24) & 0xFF] ^ t[2][(x >> 16) & 0xFF] ^ t[1][(x >> 8) & 0xFF] ^ t[0][x & 0xFF];
  }
  for (; n > 0; --n, ++data) crc = t[0][size_t((crc >> 56) ^ *data) & 0xFF] ^ (crc << 8);
  return crc;
}

// igtl_util.c: the fraction's bits are halves, quarters, ... of a second, found bit by bit.
uint64_t timestamp_of_seconds(double seconds) {
  if (!(seconds >= 0) || !std::isfinite(seconds) || seconds >= 4294967296.0) return 0;
  const uint64_t sec = uint64_t(seconds);
  uint32_t nanosec = uint32_t(std::llround((seconds - double(sec)) * 1e9));
  if (nanosec >= 1000000000u) nanosec = 999999999u;
  uint32_t base = 1000000000u, mask = 0x80000000u, frac = 0;
  while (mask) {
    base = (base + 1) >> 1;
    if (nanosec >= base) {
      frac |= mask;
      nanosec -= base;
    }
    mask >>= 1;
  }
  return (sec << 32) | frac;
}

double seconds_of_timestamp(uint64_t timestamp) {
  const uint32_t frac = uint32_t(timestamp);
  uint32_t base = 1000000000u, mask = 0x80000000u, nanosec = 0;
  while (mask) {
    base = (base + 1) >> 1;
    if (frac & mask) nanosec += base;
    mask >>= 1;
  }
  return double(timestamp >> 32) + nanosec * 1e-9;
}

Header parse_header(const uint8_t* p) {
  Header h;
  h.version = uint16_t(get_be(p, 2));
  h.type = get_text(p + 2, 12);
  h.device = get_text(p + 14, 20);
  h.timestamp = get_be(p + 34, 8);
  h.body_bytes = get_be(p + 42, 8);
  h.crc = get_be(p + 50, 8);
  return h;
}

std::string header_problem(const Header& h) {
  if (h.version != 1 && h.version != 2)
    return "header version " + std::to_string(h.version) + " (OpenIGTLink has 1 and 2)";
  if (h.body_bytes > kMaxBodyBytes)
    return "a body of " + std::to_string(h.body_bytes) + " bytes (the limit is " +
           std::to_string(kMaxBodyBytes >> 20) + " MiB)";
  if (h.type.empty()) return "an empty message type";
  for (char c : h.type)
    if (c < 0x20 || c > 0x7E) return "a message type that is not printable ASCII";
  return "";
}

std::string parse_body(const Header& h, const uint8_t* body, size_t n, Message& out) {
  if (n != h.body_bytes) return "a body of " + std::to_string(n) + " bytes, not the header's";
  if (crc64(body, n) != h.crc) return "a CRC that does not match its body";
  out.header = h;
  out.message_id = 0;
  out.metadata.clear();
  size_t begin = 0, end = n;
  if (h.version == 2) {
    if (n < kExtendedHeaderBytes) return "a body shorter than the extended header";
    const size_t ext = size_t(get_be(body, 2));
    const uint64_t meta_header = get_be(body + 2, 2), meta_body = get_be(body + 4, 4);
    out.message_id = uint32_t(get_be(body + 8, 4));
    if (ext < kExtendedHeaderBytes || ext > n || meta_header + meta_body > n - ext)
      return "an extended header or metadata larger than the body";
    begin = ext;
    end = n - size_t(meta_header + meta_body);
    if (meta_header > 0) {
      // The index starts with its 2-byte entry count: a shorter index has no room for it.
      if (meta_header < 2) return "a metadata index shorter than its entry count";
      const uint8_t* m = body + end;
      const size_t count = size_t(get_be(m, 2));
      if (meta_header < 2 + 8 * uint64_t(count)) return "a metadata index larger than its header";
      const uint8_t* text = m + meta_header;
      uint64_t used = 0;
      for (size_t i = 0; i < count; ++i) {
        const uint8_t* e = m + 2 + 8 * i;
        const uint64_t key = get_be(e, 2), value = get_be(e + 4, 4);
        if (used + key + value > meta_body) return "metadata entries larger than the metadata";
        out.metadata.emplace_back(
            std::string(reinterpret_cast<const char*>(text + used), size_t(key)),
            std::string(reinterpret_cast<const char*>(text + used + key), size_t(value)));
        used += key + value;
      }
    }
  }
  out.content.assign(body + begin, body + end);
  return "";
}

std::vector<uint8_t> pack(const std::string& type, const std::string& device, uint64_t timestamp,
                          const std::vector<uint8_t>& content, uint16_t version,
                          uint32_t message_id,
                          const std::vector<std::pair<std::string, std::string>>& metadata) {
  // Header v2: the extended header before the content, the metadata after it.
  std::vector<uint8_t> before, after;
  if (version >= 2) {
    std::vector<uint8_t> meta_body;
    put_be(after, metadata.size(), 2);
    for (const auto& [key, value] : metadata) {
      put_be(after, key.size(), 2);
      put_be(after, 3, 2);  // US-ASCII, as OpenIGTLink's default
      put_be(after, value.size(), 4);
      meta_body.insert(meta_body.end(), key.begin(), key.end());
      meta_body.insert(meta_body.end(), value.begin(), value.end());
    }
    put_be(before, kExtendedHeaderBytes, 2);
    put_be(before, after.size(), 2);
    put_be(before, meta_body.size(), 4);
    put_be(before, message_id, 4);
    after.insert(after.end(), meta_body.begin(), meta_body.end());
  }
  const size_t body = before.size() + content.size() + after.size();
  std::vector<uint8_t> out;
  out.reserve(kHeaderBytes + body);
  put_be(out, version, 2);
  put_text(out, type, 12);
  put_text(out, device, 20);
  put_be(out, timestamp, 8);
  put_be(out, body, 8);
  uint64_t crc = crc64(before.data(), before.size());
  crc = crc64(content.data(), content.size(), crc);
  crc = crc64(after.data(), after.size(), crc);
  put_be(out, crc, 8);
  out.insert(out.end(), before.begin(), before.end());
  out.insert(out.end(), content.begin(), content.end());
  out.insert(out.end(), after.begin(), after.end());
  return out;
}

std::optional<PixelType> pixel_type_of_scalar(int scalar_type) {
  switch (scalar_type) {
    case 2:
      return PixelType::Int8;
    case 3:
      return PixelType::UInt8;
    case 4:
      return PixelType::Int16;
    case 5:
      return PixelType::UInt16;
    case 6:
      return PixelType::Int32;
    case 7:
      return PixelType::UInt32;
    case 10:
      return PixelType::Float32;
    case 11:
      return PixelType::Float64;
    default:
      return std::nullopt;
  }
}

int scalar_of_pixel_type(PixelType type) {
  switch (type) {
    case PixelType::Int8:
      return 2;
    case PixelType::UInt8:
      return 3;
    case PixelType::Int16:
      return 4;
    case PixelType::UInt16:
      return 5;
    case PixelType::Int32:
      return 6;
    case PixelType::UInt32:
      return 7;
    case PixelType::Float32:
      return 10;
    case PixelType::Float64:
      return 11;
  }
  return 0;
}

namespace {
constexpr size_t kImageHeaderBytes = 72;
}

std::string parse_image(const std::vector<uint8_t>& c, Image& out) {
  if (c.size() < kImageHeaderBytes)
    return "an IMAGE body of " + std::to_string(c.size()) + " bytes (its header is 72)";
  const uint8_t* p = c.data();
  out.components = p[2];
  const auto type = pixel_type_of_scalar(p[3]);
  if (!type) return "an IMAGE scalar type " + std::to_string(int(p[3])) + " OpenIGTLink lacks";
  out.type = *type;
  if (p[4] != 1 && p[4] != 2) return "an IMAGE endian field " + std::to_string(int(p[4]));
  out.big_endian = p[4] == 1;
  out.ras = p[5] == 1;
  for (int a = 0; a < 3; ++a) out.size[a] = int(get_be(p + 6 + 2 * a, 2));
  float f[12];
  for (int i = 0; i < 12; ++i) f[i] = get_float(p + 12 + 4 * i);
  for (int i = 0; i < 12; ++i)
    if (!std::isfinite(f[i])) return "an IMAGE matrix with a non-finite value";
  for (int a = 0; a < 3; ++a) {
    out.subvolume_offset[a] = int(get_be(p + 60 + 2 * a, 2));
    out.subvolume_size[a] = int(get_be(p + 66 + 2 * a, 2));
  }
  // Columns with spacing (t, s, n), then the image centre: (size - 1) / 2 along each axis.
  Vec3 cols[3], centre{{f[9], f[10], f[11]}};
  for (int a = 0; a < 3; ++a) cols[a] = Vec3{{f[3 * a], f[3 * a + 1], f[3 * a + 2]}};
  // A pixel's size, the length of its column: a frame shrunk to a point (1e-30 mm) or spread
  // beyond any scanner is refused like a file's spacing (a zero column is the compounder's
  // "singular" frame).
  for (int a = 0; a < 2; ++a) {
    const double spacing = norm(cols[a]);
    if (spacing > 0 && (spacing < kMinSpacingMm || spacing > kMaxGeometryMm)) {
      char text[32];
      std::snprintf(text, sizeof text, "%g", spacing);
      return "an IMAGE pixel spacing of " + std::string(text) + " mm along axis " +
             std::to_string(a) + " (expected 1e-6 to 1e9 mm)";
    }
  }
  Vec3 origin = centre;
  for (int a = 0; a < 3; ++a)
    for (int r = 0; r < 3; ++r) origin[r] -= cols[a][r] * (out.size[a] - 1) / 2.0;
  out.ijk_to_world = Mat4::from_columns(cols[0], cols[1], cols[2], origin);
  const uint64_t values = uint64_t(out.size[0]) * out.size[1] * out.size[2] * out.components;
  out.pixels = p + kImageHeaderBytes;
  out.pixel_bytes = c.size() - kImageHeaderBytes;
  for (int a = 0; a < 3; ++a)
    if (out.subvolume_offset[a] != 0 || out.subvolume_size[a] != out.size[a])
      return "an IMAGE sub-volume (only whole images are taken)";
  if (values * pixel_size(out.type) != out.pixel_bytes)
    return "IMAGE pixels of " + std::to_string(out.pixel_bytes) + " bytes where " +
           std::to_string(out.size[0]) + "x" + std::to_string(out.size[1]) + "x" +
           std::to_string(out.size[2]) + " " + to_string(out.type) + " needs " +
           std::to_string(values * pixel_size(out.type));
  return "";
}

namespace {

// The 72-byte image header (image header version 1): one component, little-endian pixels.
void put_image_header(std::vector<uint8_t>& out, PixelType type, const int size[3],
                      const Mat4& ijk_to_world, bool ras) {
  put_be(out, 1, 2);  // image header version
  out.push_back(1);   // one component
  out.push_back(uint8_t(scalar_of_pixel_type(type)));
  out.push_back(2);  // little-endian pixels
  out.push_back(ras ? 1 : 2);
  for (int a = 0; a < 3; ++a) put_be(out, uint64_t(size[a]), 2);
  Vec3 centre = ijk_to_world.column3(3);
  for (int a = 0; a < 3; ++a)
    for (int r = 0; r < 3; ++r) centre[r] += ijk_to_world.m[r][a] * (size[a] - 1) / 2.0;
  for (int a = 0; a < 3; ++a)
    for (int r = 0; r < 3; ++r) put_float(out, ijk_to_world.m[r][a]);
  for (int r = 0; r < 3; ++r) put_float(out, centre[r]);
  for (int a = 0; a < 3; ++a) put_be(out, 0, 2);
  for (int a = 0; a < 3; ++a) put_be(out, uint64_t(size[a]), 2);
}

size_t pixel_bytes_of(PixelType type, const int size[3]) {
  return size_t(size[0]) * size_t(size[1]) * size_t(size[2]) * pixel_size(type);
}

}  // namespace

std::vector<uint8_t> image_content(const void* pixels, PixelType type, const int size[3],
                                   const Mat4& ijk_to_world, bool ras) {
  std::vector<uint8_t> out;
  const size_t bytes = pixel_bytes_of(type, size);
  out.reserve(kImageHeaderBytes + bytes);
  put_image_header(out, type, size, ijk_to_world, ras);
  const auto* b = static_cast<const uint8_t*>(pixels);
  out.insert(out.end(), b, b + bytes);
  return out;
}

std::vector<uint8_t> pack_image(const std::string& device, uint64_t timestamp, PixelType type,
                                const int size[3], const Mat4& ijk_to_world, bool ras,
                                const std::function<void(uint8_t* pixels)>& fill, uint16_t version,
                                uint32_t message_id) {
  const size_t bytes = pixel_bytes_of(type, size);
  const size_t extended = version >= 2 ? kExtendedHeaderBytes : 0;
  const size_t metadata = version >= 2 ? 2 : 0;  // an empty metadata index
  const size_t body = extended + kImageHeaderBytes + bytes + metadata;
  std::vector<uint8_t> out;
  out.reserve(kHeaderBytes + body);
  put_be(out, version, 2);
  put_text(out, "IMAGE", 12);
  put_text(out, device, 20);
  put_be(out, timestamp, 8);
  put_be(out, body, 8);
  put_be(out, 0, 8);  // the CRC, below
  if (version >= 2) {
    put_be(out, kExtendedHeaderBytes, 2);
    put_be(out, metadata, 2);
    put_be(out, 0, 4);
    put_be(out, message_id, 4);
  }
  put_image_header(out, type, size, ijk_to_world, ras);
  out.resize(out.size() + bytes);
  fill(out.data() + out.size() - bytes);
  if (version >= 2) put_be(out, 0, 2);
  const uint64_t crc = crc64(out.data() + kHeaderBytes, body);
  for (int i = 0; i < 8; ++i) out[50 + size_t(i)] = uint8_t(crc >> (56 - 8 * i));
  return out;
}

std::string parse_transform(const std::vector<uint8_t>& c, Mat4& out) {
  if (c.size() != 48)
    return "a TRANSFORM body of " + std::to_string(c.size()) + " bytes (48 expected)";
  out = Mat4::identity();
  for (int col = 0; col < 4; ++col)
    for (int r = 0; r < 3; ++r) {
      const float v = get_float(c.data() + 4 * (3 * col + r));
      if (!std::isfinite(v)) return "a TRANSFORM with a non-finite value";
      out.m[r][col] = v;
    }
  return "";
}

std::vector<uint8_t> transform_content(const Mat4& m) {
  std::vector<uint8_t> out;
  for (int col = 0; col < 4; ++col)
    for (int r = 0; r < 3; ++r) put_float(out, m.m[r][col]);
  return out;
}

std::string parse_string(const std::vector<uint8_t>& c, std::string& out) {
  if (c.size() < 4) return "a STRING body shorter than 4 bytes";
  const size_t len = size_t(get_be(c.data() + 2, 2));
  if (len > c.size() - 4) return "a STRING longer than its body";
  out.assign(reinterpret_cast<const char*>(c.data() + 4), len);
  return "";
}

std::vector<uint8_t> string_content(const std::string& text, uint16_t encoding) {
  std::vector<uint8_t> out;
  put_be(out, encoding, 2);
  put_be(out, text.size() > 0xFFFF ? 0xFFFF : text.size(), 2);
  out.insert(out.end(), text.begin(), text.begin() + std::min<size_t>(text.size(), 0xFFFF));
  return out;
}

std::vector<uint8_t> status_content(uint16_t code, int64_t subcode, const std::string& error_name,
                                    const std::string& text) {
  std::vector<uint8_t> out;
  put_be(out, code, 2);
  put_be(out, uint64_t(subcode), 8);
  put_text(out, error_name, 20);
  out.insert(out.end(), text.begin(), text.end());
  out.push_back(0);
  return out;
}

std::string parse_status(const std::vector<uint8_t>& c, uint16_t& code, std::string& text) {
  if (c.size() < 30) return "a STATUS body shorter than 30 bytes";
  code = uint16_t(get_be(c.data(), 2));
  text = get_text(c.data() + 30, c.size() - 30);
  return "";
}

namespace {
constexpr size_t kCommandNameBytes = 128;
constexpr size_t kCommandHeaderBytes = 4 + kCommandNameBytes + 2 + 4;
}  // namespace

std::string parse_command(const std::vector<uint8_t>& c, Command& out) {
  if (c.size() < kCommandHeaderBytes) return "a COMMAND body shorter than 138 bytes";
  out.id = uint32_t(get_be(c.data(), 4));
  out.name = get_text(c.data() + 4, kCommandNameBytes);
  const uint64_t len = get_be(c.data() + 4 + kCommandNameBytes + 2, 4);
  if (len > c.size() - kCommandHeaderBytes) return "a COMMAND longer than its body";
  out.text.assign(reinterpret_cast<const char*>(c.data() + kCommandHeaderBytes), size_t(len));
  return "";
}

std::vector<uint8_t> command_content(const Command& command, uint16_t encoding) {
  std::vector<uint8_t> out;
  put_be(out, command.id, 4);
  put_text(out, command.name, kCommandNameBytes);
  put_be(out, encoding, 2);
  put_be(out, command.text.size(), 4);
  out.insert(out.end(), command.text.begin(), command.text.end());
  return out;
}

}  // namespace igtl
}  // namespace sonoslice
