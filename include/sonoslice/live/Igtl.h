#pragma once
/// @file OpenIGTLink messages (protocol v3; header versions 1 and 2): the wire of `sonoslice live`
/// (docs/live.md). Only what live ultrasound needs: IMAGE, TRANSFORM, STRING, STATUS and, with
/// header version 2, COMMAND / RTS_COMMAND with metadata. Written here rather than taken from
/// Debian's libopenigtlink (1.11) because that library has no header version 2 and the GPU
/// machines have no Debian packages; tests prove it byte for byte against pyigtl and a peer
/// linked to Debian's library, and fuzz/ fuzzes the parser.
///
/// Every number on the wire is big-endian; image pixels carry their own byte order.
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace igtl {

constexpr size_t kHeaderBytes = 58;
constexpr size_t kExtendedHeaderBytes = 12;  ///< header version 2: before the content
/// The largest body accepted (bytes): a 4096×4096 float32 frame fits, an absurd size does not
/// make the receiver allocate.
constexpr uint64_t kMaxBodyBytes = uint64_t(256) << 20;

/// The 58-byte header.
struct Header {
  uint16_t version = 1;    ///< header version: 1 (OpenIGTLink 1-2) or 2 (OpenIGTLink 3)
  std::string type;        ///< "IMAGE", "TRANSFORM", ... (at most 12 characters)
  std::string device;      ///< device name (at most 20 characters)
  uint64_t timestamp = 0;  ///< seconds in the high 32 bits, fraction of a second in the low 32
  uint64_t body_bytes = 0;
  uint64_t crc = 0;  ///< CRC-64 (ECMA-182) of the body
};

/// Parses the 58 bytes at `p` (any values; check them with header_problem()).
Header parse_header(const uint8_t* p);
/// Why a header cannot start a message ("" when it can): unknown header version, a body over
/// kMaxBodyBytes, a type that is not printable ASCII.
std::string header_problem(const Header& header);

/// OpenIGTLink's CRC-64: polynomial 0x42F0E1EBA9EA3693, initial value 0, not reflected.
uint64_t crc64(const uint8_t* data, size_t n, uint64_t crc = 0);

/// Seconds (since the Unix epoch, or any clock) ↔ the header's 32.32 fixed-point timestamp,
/// rounded as OpenIGTLink's igtl_nanosec_to_frac does.
uint64_t timestamp_of_seconds(double seconds);
double seconds_of_timestamp(uint64_t timestamp);

/// A message: header fields, and the body split into content and (header v2) metadata.
struct Message {
  Header header;
  uint32_t message_id = 0;                                    ///< header v2
  std::vector<std::pair<std::string, std::string>> metadata;  ///< header v2, in order
  std::vector<uint8_t> content;  ///< the body without the extended header and metadata
};

/// Splits `body` (header.body_bytes bytes) into `out`; "" or why it cannot (CRC mismatch, an
/// extended header or metadata that overruns the body).
std::string parse_body(const Header& header, const uint8_t* body, size_t n, Message& out);

/// A whole message on the wire: header (CRC computed) + [extended header] + content +
/// [metadata]. `version` 1 drops message_id and metadata.
std::vector<uint8_t> pack(const std::string& type, const std::string& device, uint64_t timestamp,
                          const std::vector<uint8_t>& content, uint16_t version = 1,
                          uint32_t message_id = 0,
                          const std::vector<std::pair<std::string, std::string>>& metadata = {});

/// IMAGE content (image header version 1).
struct Image {
  int size[3] = {0, 0, 0};  ///< i, j, k (i fastest)
  int components = 1;
  PixelType type = PixelType::UInt8;
  bool big_endian = false;  ///< of the pixels
  bool ras = false;         ///< coordinate field: 1 = RAS, 2 = LPS (the default)
  /// Pixel (i, j, k) → mm: OpenIGTLink sends the columns with spacing and the image centre;
  /// this is the matrix to the first pixel's centre (the centre minus half the image).
  Mat4 ijk_to_world;
  int subvolume_offset[3] = {0, 0, 0};
  int subvolume_size[3] = {0, 0, 0};
  const uint8_t* pixels = nullptr;  ///< into the content it was parsed from
  size_t pixel_bytes = 0;
};
/// "" or why `content` is not an image this parser takes (short, unknown scalar type, pixel
/// bytes not matching the sizes, a sub-volume that is not the whole image).
std::string parse_image(const std::vector<uint8_t>& content, Image& out);
/// Content of an IMAGE holding `pixels` (size[0]·size[1]·size[2] values of `type`, one
/// component, little-endian) placed by `ijk_to_world` (first pixel's centre).
std::vector<uint8_t> image_content(const void* pixels, PixelType type, const int size[3],
                                   const Mat4& ijk_to_world, bool ras = false);

/// A whole IMAGE message (as pack() of image_content() would give it) built in one buffer: `fill`
/// writes the pixels in place, so a large image is not copied on its way out.
std::vector<uint8_t> pack_image(const std::string& device, uint64_t timestamp, PixelType type,
                                const int size[3], const Mat4& ijk_to_world, bool ras,
                                const std::function<void(uint8_t* pixels)>& fill,
                                uint16_t version = 1, uint32_t message_id = 0);

/// TRANSFORM: 12 float32s (the rotation's columns, then the translation).
std::string parse_transform(const std::vector<uint8_t>& content, Mat4& out);
std::vector<uint8_t> transform_content(const Mat4& m);

/// STRING: encoding (MIBenum; 3 = US-ASCII, 106 = UTF-8), length, bytes.
std::string parse_string(const std::vector<uint8_t>& content, std::string& out);
std::vector<uint8_t> string_content(const std::string& text, uint16_t encoding = 3);

/// STATUS: code (1 OK), subcode, error name (20 bytes), status text (zero-terminated).
enum StatusCode : uint16_t { kStatusInvalid = 0, kStatusOk = 1, kStatusUnknownError = 2 };
std::vector<uint8_t> status_content(uint16_t code, int64_t subcode, const std::string& error_name,
                                    const std::string& text);
std::string parse_status(const std::vector<uint8_t>& content, uint16_t& code, std::string& text);

/// COMMAND / RTS_COMMAND (header v2): id, name (128 bytes), encoding, length, text.
struct Command {
  uint32_t id = 0;
  std::string name;
  std::string text;
};
std::string parse_command(const std::vector<uint8_t>& content, Command& out);
std::vector<uint8_t> command_content(const Command& command, uint16_t encoding = 3);

/// OpenIGTLink's scalar type code ↔ PixelType (2 int8, 3 uint8, 4 int16, 5 uint16, 6 int32,
/// 7 uint32, 10 float32, 11 float64).
std::optional<PixelType> pixel_type_of_scalar(int scalar_type);
int scalar_of_pixel_type(PixelType type);

}  // namespace igtl
}  // namespace sonoslice
