// PLUS toolkit tracked-frame sequences (docs/conventions.md §7): MetaImage (.mha) and NRRD (.nrrd) sequence
// files read and written without ITK. The header text is parsed here; the pixel data is read (or
// inflated with zlib) straight into the sequence's one pixel buffer, then flipped to MF in place.
//
// We do not use ITK's readers: its NRRD reader turns the `list` axis into vector components, and
// neither keeps the per-frame `Seq_FrameNNNN_<Field>` entries in order.
//
// Image orientation (IGSIO, Source/IGSIOCommon/igsioVideoFrame.h and igsioVideoFrame.cxx,
// igsioVideoFrame::GetFlipAxes):
//   - the first letter names the transducer side image x points to: M = marked, U = unmarked;
//   - the second letter names where image y points: F = far (away from the transducer), N = near;
//   - an optional third letter (A = ascending, D = descending) orders the slices of 3D frames;
//     IGSIO defines MFA = MF, UFD = UF, UNA = UN, MND = MN, and a z flip of a one-slice 2D frame
//     changes nothing, so for 2D frames the third letter never moves a pixel.
//   Converting to MF: U <-> M reverses each row (hFlip, "flip x"); N <-> F reverses the order of
//   the rows (vFlip, "flip y"); UN needs both. Each flip is its own inverse, so the writer applies
//   the same flips to go from MF back to the file's orientation. The RF orientations (FM, NM, FU,
//   NU: image x along the beam) are a transpose, which PLUS reserves for RF data; we refuse them.
//   A file without the field is MF (PLUS's default for B-mode images).
#include "sonoslice/io/PlusSequence.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <limits>
#include <memory>
#include <sstream>

#ifdef SONOSLICE_HAVE_ITK  // ITK builds find and link zlib (src/io/CMakeLists.txt)
#define SONOSLICE_PLUS_HAVE_ZLIB 1
#include <zlib.h>
#endif

#include "TextParse.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "PLUS sequence I/O assumes a little-endian host"
#endif

namespace fs = std::filesystem;

namespace sonoslice {
namespace {

using namespace text;

// ---------------------------------------------------------------------------------------------
// Strings and numbers

std::string frame_label(int frame) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%04d", frame);
  return buf;
}

/// Gauss-Jordan elimination with partial pivoting; std::nullopt when singular (a pivot below
/// 1e-12 of the matrix's largest entry) or not finite.
std::optional<Mat4> invert(const Mat4& m) {
  double a[4][8];
  double scale = 0;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(m.m[r][c])) return std::nullopt;
      scale = std::max(scale, std::fabs(m.m[r][c]));
    }
  if (scale == 0) return std::nullopt;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 8; ++c) a[r][c] = c < 4 ? m.m[r][c] : (c - 4 == r ? 1.0 : 0.0);
  for (int col = 0; col < 4; ++col) {
    int pivot = col;
    for (int r = col + 1; r < 4; ++r)
      if (std::fabs(a[r][col]) > std::fabs(a[pivot][col])) pivot = r;
    if (std::fabs(a[pivot][col]) <= 1e-12 * scale) return std::nullopt;
    if (pivot != col)
      for (int c = 0; c < 8; ++c) std::swap(a[pivot][c], a[col][c]);
    const double inv = 1.0 / a[col][col];
    for (int c = 0; c < 8; ++c) a[col][c] *= inv;
    for (int r = 0; r < 4; ++r) {
      if (r == col || a[r][col] == 0) continue;
      const double f = a[r][col];
      for (int c = 0; c < 8; ++c) a[r][c] -= f * a[col][c];
    }
  }
  Mat4 out;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out.m[r][c] = a[r][c + 4];
  return out;
}

// ---------------------------------------------------------------------------------------------
// Orientation (see the comment at the top of this file)

struct Flips {
  bool x = false, y = false;
};

Flips orientation_flips(const std::string& orientation, const std::string& where) {
  const std::string o = upper(trim(orientation));
  const bool ok = (o.size() == 2 || o.size() == 3) && (o[0] == 'M' || o[0] == 'U') &&
                  (o[1] == 'F' || o[1] == 'N') && (o.size() == 2 || o[2] == 'A' || o[2] == 'D');
  if (!ok)
    throw InputError(where + ": unsupported ultrasound image orientation " +
                     quote_value(orientation) +
                     " (accepted: MF, MN, UF, UN, optionally followed by A or D; the RF "
                     "orientations FM, FU, NM, NU are not supported)");
  return Flips{o[0] == 'U', o[1] == 'N'};
}

template <size_t N>
void flip_frame_bytes(uint8_t* frame, int width, int height, Flips flips) {
  struct Px {
    uint8_t b[N];
  };
  Px* p = reinterpret_cast<Px*>(frame);
  const size_t w = size_t(width), h = size_t(height);
  if (flips.x)
    for (size_t y = 0; y < h; ++y) std::reverse(p + y * w, p + (y + 1) * w);
  if (flips.y)
    for (size_t y = 0; y < h / 2; ++y)
      std::swap_ranges(p + y * w, p + (y + 1) * w, p + (h - 1 - y) * w);
}

void flip_frame(uint8_t* frame, int width, int height, size_t pixel_bytes, Flips flips) {
  if (!flips.x && !flips.y) return;
  switch (pixel_bytes) {
    case 1:
      return flip_frame_bytes<1>(frame, width, height, flips);
    case 2:
      return flip_frame_bytes<2>(frame, width, height, flips);
    case 4:
      return flip_frame_bytes<4>(frame, width, height, flips);
    default:
      return flip_frame_bytes<8>(frame, width, height, flips);
  }
}

// ---------------------------------------------------------------------------------------------
// Pixel types

PixelType meta_pixel_type(const std::string& name, const std::string& where) {
  const std::string n = upper(trim(name));
  if (n == "MET_UCHAR") return PixelType::UInt8;
  if (n == "MET_CHAR") return PixelType::Int8;
  if (n == "MET_USHORT") return PixelType::UInt16;
  if (n == "MET_SHORT") return PixelType::Int16;
  if (n == "MET_UINT") return PixelType::UInt32;
  if (n == "MET_INT") return PixelType::Int32;
  if (n == "MET_FLOAT") return PixelType::Float32;
  if (n == "MET_DOUBLE") return PixelType::Float64;
  throw InputError(where + ": unsupported ElementType " + quote_value(name) +
                   " (accepted: MET_UCHAR, MET_CHAR, MET_USHORT, MET_SHORT, MET_UINT, MET_INT, "
                   "MET_FLOAT, MET_DOUBLE)");
}

std::string meta_type_name(PixelType t) {
  switch (t) {
    case PixelType::UInt8:
      return "MET_UCHAR";
    case PixelType::Int8:
      return "MET_CHAR";
    case PixelType::UInt16:
      return "MET_USHORT";
    case PixelType::Int16:
      return "MET_SHORT";
    case PixelType::UInt32:
      return "MET_UINT";
    case PixelType::Int32:
      return "MET_INT";
    case PixelType::Float32:
      return "MET_FLOAT";
    case PixelType::Float64:
      break;
  }
  return "MET_DOUBLE";
}

PixelType nrrd_pixel_type(const std::string& name, const std::string& where) {
  // The NRRD format's type names (teem.sourceforge.net/nrrd/format.html#type).
  const std::string n = lower(trim(name));
  if (n == "uchar" || n == "unsigned char" || n == "uint8" || n == "uint8_t")
    return PixelType::UInt8;
  if (n == "signed char" || n == "int8" || n == "int8_t") return PixelType::Int8;
  if (n == "ushort" || n == "unsigned short" || n == "unsigned short int" || n == "uint16" ||
      n == "uint16_t")
    return PixelType::UInt16;
  if (n == "short" || n == "short int" || n == "signed short" || n == "signed short int" ||
      n == "int16" || n == "int16_t")
    return PixelType::Int16;
  if (n == "uint" || n == "unsigned int" || n == "uint32" || n == "uint32_t")
    return PixelType::UInt32;
  if (n == "int" || n == "signed int" || n == "int32" || n == "int32_t") return PixelType::Int32;
  if (n == "float") return PixelType::Float32;
  if (n == "double") return PixelType::Float64;
  throw InputError(where + ": unsupported NRRD type " + quote_value(name) +
                   " (accepted: uint8, int8, uint16, int16, uint32, int32, float, double)");
}

std::string nrrd_type_name(PixelType t) {
  // NRRD's names, except for the two float types.
  if (t == PixelType::Float32) return "float";
  if (t == PixelType::Float64) return "double";
  return to_string(t);
}

// ---------------------------------------------------------------------------------------------
// Reading

constexpr size_t kMaxHeaderLine = size_t(1) << 20;  // a longer "line" is not a text header
constexpr size_t kChunk = size_t(1) << 20;

class InputFile {
 public:
  explicit InputFile(const std::string& path) : path_(path) {
    std::error_code ec;
    if (!fs::exists(path, ec)) throw FileError("PLUS sequence '" + path + "' not found");
    if (fs::is_directory(path, ec))
      throw FileError("cannot read PLUS sequence '" + path + "': it is a directory");
    file_ = std::fopen(path.c_str(), "rb");
    if (!file_)
      throw FileError("cannot open PLUS sequence '" + path + "': " + std::strerror(errno));
    size_ = fs::file_size(path, ec);
    if (ec) size_ = 0;
  }
  ~InputFile() {
    if (file_) std::fclose(file_);
  }
  InputFile(const InputFile&) = delete;
  InputFile& operator=(const InputFile&) = delete;

  /// One header line without its end ('\n' or "\r\n"); false at the end of the file.
  bool line(std::string* out) {
    out->clear();
    int c;
    while ((c = std::getc(file_)) != EOF) {
      if (c == '\n') break;
      if (out->size() >= kMaxHeaderLine)
        throw FileError(path_ + ": not a PLUS sequence file (no text header)");
      out->push_back(static_cast<char>(c));
    }
    if (c == EOF && out->empty()) return false;
    if (!out->empty() && out->back() == '\r') out->pop_back();
    return true;
  }
  uint64_t tell() const { return static_cast<uint64_t>(::ftello(file_)); }
  void seek(uint64_t offset) {
    if (::fseeko(file_, static_cast<off_t>(offset), SEEK_SET) != 0)
      throw FileError(path_ + ": cannot seek to byte " + std::to_string(offset));
  }
  size_t read(void* dst, size_t n) { return std::fread(dst, 1, n, file_); }
  uint64_t size() const { return size_; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  FILE* file_ = nullptr;
  uint64_t size_ = 0;
};

/// What a header says about the pixel data.
struct DataLayout {
  int width = 0, height = 0, frames = 0;
  PixelType type = PixelType::UInt8;
  enum Encoding { Raw, Zlib, Gzip } encoding = Raw;
  uint64_t compressed_size = 0;  ///< Zlib: the CompressedDataSize field (0: to the end)
  std::string data_path;         ///< where the data lies (the header file unless detached)
  uint64_t data_offset = 0;
};

struct FrameFieldSink {
  std::map<int, std::map<std::string, std::string>> pending;  // frame number → fields

  // "Seq_Frame0012_ProbeToTrackerTransform" → frame 12, field "ProbeToTrackerTransform".
  bool add(const std::string& key, const std::string& value, const std::string& where) {
    static const std::string prefix = "seq_frame";
    if (key.size() <= prefix.size() || lower(key.substr(0, prefix.size())) != prefix) return false;
    const size_t underscore = key.find('_', prefix.size());
    int64_t frame = -1;
    if (underscore == std::string::npos ||
        !parse_int64(key.substr(prefix.size(), underscore - prefix.size()), &frame) || frame < 0 ||
        frame > std::numeric_limits<int>::max() || underscore + 1 >= key.size())
      throw InputError(where + ": malformed frame field name " + quote_value(key) +
                       " (expected Seq_FrameNNNN_<Field>)");
    pending[static_cast<int>(frame)][key.substr(underscore + 1)] = value;
    return true;
  }
};

/// Splits a list of sizes (and optional kinds) into frames: W H, W H N or W H 1 N.
void set_frame_dims(const std::vector<int64_t>& sizes, const std::vector<std::string>& kinds,
                    const std::string& where, DataLayout* layout) {
  for (size_t k = 0; k < kinds.size() && k < 2; ++k)
    if (!iequals(kinds[k], "domain") && !iequals(kinds[k], "space"))
      throw InputError(where + ": axis " + std::to_string(k) + " is of kind " +
                       quote_value(kinds[k]) +
                       " (pixels with several components are not supported)");
  int64_t w = 0, h = 0, n = 1;
  if (sizes.size() == 2) {
    w = sizes[0], h = sizes[1];
  } else if (sizes.size() == 3) {
    if (kinds.size() == 3 && iequals(kinds[2], "domain"))
      throw InputError(where + ": a 3D volume (kinds " + kinds[0] + " " + kinds[1] + " " +
                       kinds[2] + "), not a sequence of frames");
    w = sizes[0], h = sizes[1], n = sizes[2];
  } else if (sizes.size() == 4 && sizes[2] == 1) {
    w = sizes[0], h = sizes[1], n = sizes[3];
  } else if (sizes.size() == 4) {
    throw InputError(where + ": 3D frames (" + std::to_string(sizes[0]) + "x" +
                     std::to_string(sizes[1]) + "x" + std::to_string(sizes[2]) +
                     ") are not supported");
  } else {
    throw InputError(where + ": " + std::to_string(sizes.size()) +
                     " dimensions (expected 2D frames: 2 or 3 dimensions)");
  }
  const int64_t limit = std::numeric_limits<int>::max();
  if (w < 0 || h < 0 || n < 0 || w > limit || h > limit || n > limit)
    throw InputError(where + ": invalid image size");
  layout->width = int(w), layout->height = int(h), layout->frames = int(n);
}

std::vector<int64_t> parse_sizes(const std::string& text, const std::string& what,
                                 const std::string& where) {
  std::vector<int64_t> sizes;
  for (const std::string& t : split_ws(text)) {
    int64_t v = 0;
    if (!parse_int64(t, &v) || v < 0)
      throw InputError(where + ": " + what + " " + quote_value(text) + " is not a list of sizes");
    sizes.push_back(v);
  }
  return sizes;
}

std::string data_file_path(const std::string& header_path, const std::string& name) {
  const fs::path p(name);
  if (p.is_absolute()) return name;
  return (fs::path(header_path).parent_path() / p).string();
}

/// MetaImage header: `Key = Value` lines up to `ElementDataFile = ...`.
DataLayout read_meta_header(InputFile& in, PlusSequence* seq, FrameFieldSink* sink) {
  const std::string& where = in.path();
  std::map<std::string, std::string> fields;  // lower-case key → value
  std::string line;
  bool ended = false;
  int line_number = 0;
  while (in.line(&line)) {
    ++line_number;
    if (trim(line).empty()) continue;
    const size_t eq = line.find('=');
    if (eq == std::string::npos) {
      if (line_number == 1) throw FileError(where + ": not a PLUS sequence file (no text header)");
      throw FileError(where + ": malformed header line " + std::to_string(line_number) + " " +
                      quote_value(line) + " (expected Key = Value)");
    }
    const std::string key = trim(line.substr(0, eq)), value = trim(line.substr(eq + 1));
    if (key.empty() || key.find('\0') != std::string::npos)
      throw FileError(where + ": not a PLUS sequence file (malformed header line " +
                      std::to_string(line_number) + ")");
    if (sink->add(key, value, where)) continue;
    fields[lower(key)] = value;
    if (lower(key) == "elementdatafile") {
      ended = true;
      break;
    }
  }
  if (!ended)
    throw FileError(where +
                    ": no 'ElementDataFile' line ending the header (not a PLUS "
                    "sequence file, or truncated)");

  auto get = [&](const std::string& key) -> const std::string* {
    auto it = fields.find(lower(key));
    return it == fields.end() ? nullptr : &it->second;
  };
  auto require = [&](const std::string& key) -> const std::string& {
    const std::string* v = get(key);
    if (!v) throw InputError(where + ": header has no '" + key + "' field");
    return *v;
  };

  if (const std::string* v = get("ObjectType"); v && !iequals(*v, "Image"))
    throw InputError(where + ": ObjectType " + quote_value(*v) + " (expected Image)");
  DataLayout layout;
  const std::vector<int64_t> sizes = parse_sizes(require("DimSize"), "DimSize", where);
  int64_t ndims = int64_t(sizes.size());
  if (const std::string* v = get("NDims")) {
    if (!parse_int64(*v, &ndims))
      throw InputError(where + ": NDims " + quote_value(*v) + " is not a number");
    if (ndims != int64_t(sizes.size()))
      throw InputError(where + ": NDims = " + *v + " but DimSize has " +
                       std::to_string(sizes.size()) + " values");
  }
  std::vector<std::string> kinds;
  if (const std::string* v = get("Kinds")) kinds = split_ws(*v);
  set_frame_dims(sizes, kinds, where, &layout);
  layout.type = meta_pixel_type(require("ElementType"), where);
  if (const std::string* v = get("ElementNumberOfChannels"); v && trim(*v) != "1")
    throw InputError(where + ": ElementNumberOfChannels = " + *v +
                     " (only single-channel frames are supported)");
  if (const std::string* v = get("BinaryData"); v && !iequals(*v, "True"))
    throw InputError(where + ": BinaryData = " + *v + " (only binary pixel data is supported)");
  for (const char* key : {"BinaryDataByteOrderMSB", "ElementByteOrderMSB"})
    if (const std::string* v = get(key); v && iequals(*v, "True") && pixel_size(layout.type) > 1)
      throw InputError(where + ": " + key +
                       " = True: big-endian pixel data is not supported (only little-endian)");
  const std::string* compressed = get("CompressedData");
  if (compressed && iequals(*compressed, "True")) {
    layout.encoding = DataLayout::Zlib;
    if (const std::string* v = get("CompressedDataSize")) {
      int64_t n = 0;
      if (!parse_int64(*v, &n) || n < 0)
        throw InputError(where + ": CompressedDataSize " + quote_value(*v) +
                         " is not a byte count");
      layout.compressed_size = uint64_t(n);
    }
  } else if (compressed && !iequals(*compressed, "False")) {
    throw InputError(where + ": CompressedData = " + *compressed + " (expected True or False)");
  }
  if (const std::string* v = get("UltrasoundImageOrientation"); v && !v->empty())
    seq->orientation = *v;
  const std::string& data_file = require("ElementDataFile");
  if (iequals(data_file, "LOCAL")) {
    layout.data_path = where;
    layout.data_offset = in.tell();
  } else {
    if (data_file.find('%') != std::string::npos || iequals(data_file, "LIST"))
      throw InputError(where + ": ElementDataFile = " + data_file +
                       " (one data file per slice is not supported)");
    layout.data_path = data_file_path(where, data_file);
    layout.data_offset = 0;
  }
  return layout;
}

/// NRRD header: magic line, `field: value` and `key:=value` lines, a blank line, then the data.
DataLayout read_nrrd_header(InputFile& in, PlusSequence* seq, FrameFieldSink* sink) {
  const std::string& where = in.path();
  std::map<std::string, std::string> fields, key_values;  // fields: lower-case names
  std::string line;
  in.line(&line);  // the magic, checked by the caller
  bool ended = false;
  int line_number = 1;
  while (in.line(&line)) {
    ++line_number;
    if (line.empty()) {
      ended = true;
      break;
    }
    if (line[0] == '#') continue;
    const size_t colon = line.find(':');
    if (colon == std::string::npos || colon == 0)
      throw FileError(where + ": malformed NRRD header line " + std::to_string(line_number) + " " +
                      quote_value(line));
    if (line.compare(colon, 2, ":=") == 0) {
      const std::string key = line.substr(0, colon), value = trim(line.substr(colon + 2));
      if (!sink->add(key, value, where)) key_values[key] = value;
    } else {
      fields[lower(trim(line.substr(0, colon)))] = trim(line.substr(colon + 1));
    }
  }
  auto get = [&](const std::string& key) -> const std::string* {
    auto it = fields.find(key);
    return it == fields.end() ? nullptr : &it->second;
  };
  auto require = [&](const std::string& key) -> const std::string& {
    const std::string* v = get(key);
    if (!v) throw InputError(where + ": NRRD header has no '" + key + "' field");
    return *v;
  };
  const std::string* data_file = get("data file");
  if (!data_file) data_file = get("datafile");
  if (!ended && !data_file)
    throw FileError(where + ": NRRD header does not end with a blank line (truncated file?)");

  DataLayout layout;
  const std::vector<int64_t> sizes = parse_sizes(require("sizes"), "sizes", where);
  int64_t dimension = 0;
  if (!parse_int64(require("dimension"), &dimension) || dimension != int64_t(sizes.size()))
    throw InputError(where + ": dimension " + quote_value(require("dimension")) +
                     " does not match sizes " + quote_value(require("sizes")));
  std::vector<std::string> kinds;
  if (const std::string* v = get("kinds")) kinds = split_ws(*v);
  set_frame_dims(sizes, kinds, where, &layout);
  layout.type = nrrd_pixel_type(require("type"), where);
  const std::string encoding = lower(require("encoding"));
  if (encoding == "raw") {
    layout.encoding = DataLayout::Raw;
  } else if (encoding == "gzip" || encoding == "gz") {
    layout.encoding = DataLayout::Gzip;
  } else {
    throw InputError(where + ": NRRD encoding " + quote_value(encoding) +
                     " (supported: raw, gzip)");
  }
  if (const std::string* v = get("endian"); v && lower(*v) == "big" && pixel_size(layout.type) > 1)
    throw InputError(where +
                     ": endian: big: big-endian pixel data is not supported (only little-endian)");
  for (const char* key : {"line skip", "lineskip", "byte skip", "byteskip"})
    if (const std::string* v = get(key); v && trim(*v) != "0")
      throw InputError(where + ": NRRD '" + key + "' is not supported");
  for (const auto& [key, value] : key_values)
    if (iequals(trim(key), "ultrasound image orientation") && !value.empty())
      seq->orientation = value;
  if (data_file) {
    if (data_file->find('%') != std::string::npos || lower(trim(*data_file)).rfind("list", 0) == 0)
      throw InputError(where + ": NRRD data file " + quote_value(*data_file) +
                       " (one data file per slice is not supported)");
    layout.data_path = data_file_path(where, *data_file);
    layout.data_offset = 0;
  } else {
    layout.data_path = where;
    layout.data_offset = in.tell();
  }
  return layout;
}

// The caller has checked that the file holds `bytes` more bytes.
void read_raw(InputFile& in, uint8_t* dst, uint64_t bytes) {
  uint64_t done = 0;
  while (done < bytes) {
    const size_t want = size_t(std::min<uint64_t>(bytes - done, uint64_t(1) << 30));
    const size_t got = in.read(dst + done, want);
    if (got == 0)
      throw FileError(in.path() + ": read error after " + std::to_string(done) +
                      " bytes of pixel data");
    done += got;
  }
}

#ifdef SONOSLICE_PLUS_HAVE_ZLIB
void inflate_into(InputFile& in, uint64_t compressed_bytes, int window_bits, uint8_t* dst,
                  uint64_t bytes) {
  const std::string& what = in.path();
  z_stream zs{};
  if (inflateInit2(&zs, window_bits) != Z_OK)
    throw ResourceError(what + ": cannot initialise zlib");
  struct End {
    z_stream* z;
    ~End() { inflateEnd(z); }
  } end{&zs};

  std::vector<unsigned char> input(kChunk);
  uint64_t input_left = compressed_bytes;
  bool more_input = input_left > 0;
  uint64_t produced = 0;
  unsigned char scratch[1];
  for (;;) {
    if (zs.avail_in == 0 && more_input) {
      const size_t want = size_t(std::min<uint64_t>(input.size(), input_left));
      const size_t got = in.read(input.data(), want);
      input_left -= got;
      if (got < want || input_left == 0) more_input = false;
      zs.next_in = input.data();
      zs.avail_in = uInt(got);
    }
    // Once the buffer is full, a one-byte scratch output tells a clean end from extra data.
    const bool full = produced == bytes;
    zs.next_out = full ? scratch : dst + produced;
    zs.avail_out = full ? 1u : uInt(std::min<uint64_t>(bytes - produced, uint64_t(1) << 30));
    const uInt before = zs.avail_out;
    const int ret = inflate(&zs, Z_NO_FLUSH);
    const uInt made = before - zs.avail_out;
    if (full && made > 0)
      throw FileError(what + ": corrupt pixel data: it decompresses to more than the " +
                      std::to_string(bytes) + " bytes the header describes");
    if (!full) produced += made;
    if (ret == Z_STREAM_END) {
      if (produced != bytes)
        throw FileError(what + ": corrupt pixel data: it decompresses to " +
                        std::to_string(produced) + " bytes, the header describes " +
                        std::to_string(bytes));
      return;
    }
    if (ret == Z_BUF_ERROR || (ret == Z_OK && zs.avail_in == 0 && !more_input && made == 0)) {
      if (zs.avail_in == 0 && !more_input)
        throw FileError(what + ": truncated: the compressed pixel data ends after " +
                        std::to_string(produced) + " of " + std::to_string(bytes) + " bytes");
      continue;
    }
    if (ret == Z_MEM_ERROR) throw ResourceError(what + ": out of memory while decompressing");
    if (ret != Z_OK)
      throw FileError(what + ": corrupt compressed pixel data (zlib: " +
                      (zs.msg ? std::string(zs.msg) : std::to_string(ret)) + ")");
  }
}
#endif

void read_pixels(const DataLayout& layout, InputFile& header_file, PlusSequence* seq) {
  const uint64_t frame_bytes =
      uint64_t(layout.width) * uint64_t(layout.height) * pixel_size(layout.type);
  const uint64_t bytes = frame_bytes * uint64_t(layout.frames);
  if (frame_bytes != 0 && bytes / frame_bytes != uint64_t(layout.frames))
    throw InputError(header_file.path() + ": image size overflows");
  if (bytes == 0) return;  // tracking-only sequence

  std::unique_ptr<InputFile> detached;
  InputFile* in = &header_file;
  if (layout.data_path != header_file.path()) {
    detached = std::make_unique<InputFile>(layout.data_path);
    in = detached.get();
  }
  in->seek(layout.data_offset);
  const uint64_t after_header =
      in->size() > layout.data_offset ? in->size() - layout.data_offset : 0;
  if (layout.encoding == DataLayout::Raw && after_header < bytes)
    throw FileError(in->path() + ": truncated: " + std::to_string(bytes) +
                    " bytes of pixel data expected, the file has " + std::to_string(after_header));
  if (layout.encoding == DataLayout::Zlib && layout.compressed_size > after_header)
    throw FileError(in->path() + ": truncated: CompressedDataSize is " +
                    std::to_string(layout.compressed_size) + " bytes, the file has " +
                    std::to_string(after_header) + " after the header");
#ifndef SONOSLICE_PLUS_HAVE_ZLIB
  if (layout.encoding != DataLayout::Raw)
    throw Error(in->path() +
                ": compressed PLUS sequences need zlib, and sonoslice was built "
                "without ITK/zlib");
#endif
  const unsigned long long available = available_memory_bytes();
  if (bytes > available)
    throw ResourceError(in->path() + ": the frames need " + std::to_string(bytes >> 20) +
                        " MiB of memory, " + std::to_string(available >> 20) +
                        " MiB are available");
  try {
    seq->pixels.resize(size_t(bytes));
  } catch (const std::bad_alloc&) {
    throw ResourceError(in->path() + ": cannot allocate " + std::to_string(bytes >> 20) +
                        " MiB for the frames");
  }
  switch (layout.encoding) {
    case DataLayout::Raw:
      read_raw(*in, seq->pixels.data(), bytes);
      break;
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    case DataLayout::Zlib:
      inflate_into(*in, layout.compressed_size ? layout.compressed_size : after_header, 15,
                   seq->pixels.data(), bytes);
      break;
    case DataLayout::Gzip:
      inflate_into(*in, after_header, 15 + 32, seq->pixels.data(), bytes);
      break;
#else
    default:
      break;
#endif
  }
}

void validate_frame_fields(const PlusSequence& seq) {
  for (int f = 0; f < seq.frame_count; ++f) {
    const auto& fields = seq.frame_fields[size_t(f)];
    for (const auto& [name, value] : fields) {
      const std::string where =
          seq.path + ": frame " + std::to_string(f) + ": Seq_Frame" + frame_label(f) + "_" + name;
      if (name == "Timestamp") {
        double t;
        if (!parse_double(trim(value), &t))
          throw InputError(where + " " + quote_value(value) + " is not a number");
      }
      if (!ends_with(name, "Transform")) continue;
      auto status = fields.find(name + "Status");
      if (status != fields.end() && !iequals(trim(status->second), "OK")) continue;
      Mat4 m;
      if (!parse_matrix16(value, &m))
        throw InputError(where + ": expected 16 numbers (a row-major 4x4 matrix), got " +
                         quote_value(value));
    }
  }
}

const std::map<std::string, std::string>& fields_of(const PlusSequence& seq, int frame) {
  if (frame < 0 || frame >= seq.frame_count)
    throw InputError("PLUS sequence '" + seq.path + "': frame " + std::to_string(frame) +
                     " out of range (0.." + std::to_string(seq.frame_count - 1) + ")");
  static const std::map<std::string, std::string> no_fields;
  return size_t(frame) < seq.frame_fields.size() ? seq.frame_fields[size_t(frame)] : no_fields;
}

// ---------------------------------------------------------------------------------------------
// Writing

class OutputFile {
 public:
  explicit OutputFile(const std::string& temp_path, const std::string& path) : path_(path) {
    file_ = std::fopen(temp_path.c_str(), "wb");
    if (!file_) throw FileError("cannot write '" + path + "': " + std::strerror(errno));
  }
  ~OutputFile() {
    if (file_) std::fclose(file_);
  }
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;
  void write(const void* data, size_t n) {
    if (n && std::fwrite(data, 1, n, file_) != n)
      throw FileError("cannot write '" + path_ + "': " + std::strerror(errno));
  }
  void write(const std::string& s) { write(s.data(), s.size()); }
  void seek(uint64_t offset) {
    if (::fseeko(file_, static_cast<off_t>(offset), SEEK_SET) != 0)
      throw FileError("cannot write '" + path_ + "': seek failed");
  }
  void close() {
    const bool ok = std::fflush(file_) == 0 && !std::ferror(file_);
    const bool closed = std::fclose(file_) == 0;
    file_ = nullptr;
    if (!ok || !closed) throw FileError("cannot write '" + path_ + "': " + std::strerror(errno));
  }

 private:
  std::string path_;
  FILE* file_ = nullptr;
};

/// Feeds frames to the file, raw or through zlib (zlib or gzip wrapper).
class PixelSink {
 public:
  PixelSink(OutputFile* out, bool compress, int window_bits, const std::string& path)
      : out_(out), compress_(compress), path_(path) {
    if (!compress_) return;
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    if (deflateInit2(&zs_, Z_DEFAULT_COMPRESSION, Z_DEFLATED, window_bits, 8, Z_DEFAULT_STRATEGY) !=
        Z_OK)
      throw ResourceError("cannot write '" + path + "': cannot initialise zlib");
    initialised_ = true;
    buffer_.resize(kChunk);
#else
    (void)window_bits;
    throw Error("cannot write '" + path +
                "': compressed PLUS sequences need zlib, and sonoslice "
                "was built without ITK/zlib (write with compression off)");
#endif
  }
  ~PixelSink() {
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    if (initialised_) deflateEnd(&zs_);
#endif
  }
  PixelSink(const PixelSink&) = delete;
  PixelSink& operator=(const PixelSink&) = delete;

  void write(const uint8_t* data, uint64_t n) {
    if (!compress_) {
      out_->write(data, size_t(n));
      written_ += n;
      return;
    }
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    while (n > 0) {
      const uInt part = uInt(std::min<uint64_t>(n, uint64_t(1) << 30));
      zs_.next_in = const_cast<uint8_t*>(data);
      zs_.avail_in = part;
      pump(Z_NO_FLUSH);
      data += part;
      n -= part;
    }
#endif
  }
  /// Ends the stream; returns the bytes written to the file.
  uint64_t finish() {
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
    if (compress_) pump(Z_FINISH);
#endif
    return written_;
  }

 private:
#ifdef SONOSLICE_PLUS_HAVE_ZLIB
  void pump(int flush) {
    for (;;) {
      zs_.next_out = buffer_.data();
      zs_.avail_out = uInt(buffer_.size());
      const int ret = deflate(&zs_, flush);
      if (ret == Z_STREAM_ERROR) throw FileError("cannot write '" + path_ + "': zlib error");
      const size_t have = buffer_.size() - zs_.avail_out;
      out_->write(buffer_.data(), have);
      written_ += have;
      if (flush == Z_FINISH ? ret == Z_STREAM_END : (zs_.avail_in == 0 && zs_.avail_out != 0))
        return;
    }
  }
  z_stream zs_{};
  bool initialised_ = false;
  std::vector<unsigned char> buffer_;
#endif
  OutputFile* out_;
  bool compress_;
  std::string path_;
  uint64_t written_ = 0;
};

void check_header_text(const std::string& text, const std::string& what, const std::string& path) {
  if (text.find_first_of("\r\n") != std::string::npos || text.find('\0') != std::string::npos)
    throw InputError("cannot write '" + path + "': " + what + " " + quote_value(text) +
                     " contains a line break");
}

}  // namespace

// -------------------------------------------------------------------------------------------------
// PlusSequence

bool PlusSequence::image_ok(int frame) const {
  const auto& fields = fields_of(*this, frame);
  auto it = fields.find("ImageStatus");
  if (it == fields.end()) it = fields.find("Status");  // NRRD's name, in sequences built by hand
  return it == fields.end() || iequals(trim(it->second), "OK");
}

std::vector<std::string> PlusSequence::transform_names(int frame) const {
  std::vector<std::string> names;
  for (const auto& [name, value] : fields_of(*this, frame))
    if (ends_with(name, "Transform") && name.size() > 9)
      names.push_back(name.substr(0, name.size() - 9));
  return names;
}

std::optional<Mat4> PlusSequence::transform(int frame, const std::string& name) const {
  const auto& fields = fields_of(*this, frame);
  auto it = fields.find(name + "Transform");
  if (it == fields.end()) return std::nullopt;
  auto status = fields.find(name + "TransformStatus");
  if (status != fields.end() && !iequals(trim(status->second), "OK")) return std::nullopt;
  Mat4 m;
  if (!parse_matrix16(it->second, &m))
    throw InputError(path + ": frame " + std::to_string(frame) + ": " + name +
                     "Transform: expected 16 numbers, got " + quote_value(it->second));
  return m;
}

double PlusSequence::timestamp(int frame) const {
  const auto& fields = fields_of(*this, frame);
  auto it = fields.find("Timestamp");
  if (it == fields.end()) return std::numeric_limits<double>::quiet_NaN();
  double t;
  if (!parse_double(trim(it->second), &t))
    throw InputError(path + ": frame " + std::to_string(frame) + ": Timestamp " +
                     quote_value(it->second) + " is not a number");
  return t;
}

PlusSequence read_plus_sequence(const std::string& path) {
  InputFile in(path);
  PlusSequence seq;
  seq.path = path;

  // The format comes from the content: NRRD files start with their magic, MetaImage with
  // `Key = Value` lines.
  char magic[8] = {0};
  const size_t got = in.read(magic, sizeof magic);
  in.seek(0);
  if (got == 0) throw FileError(path + ": empty file (not a PLUS sequence)");
  FrameFieldSink sink;
  const bool nrrd = got >= 7 && std::memcmp(magic, "NRRD000", 7) == 0;
  const DataLayout layout =
      nrrd ? read_nrrd_header(in, &seq, &sink) : read_meta_header(in, &seq, &sink);

  // Validates the orientation before any pixel is read; the flips apply once they are.
  const Flips flips = orientation_flips(seq.orientation, path);
  seq.width = layout.width;
  seq.height = layout.height;
  seq.frame_count = layout.frames;
  seq.pixel_type = layout.type;
  seq.frame_fields.assign(size_t(seq.frame_count), {});
  int beyond = 0;
  for (auto& [frame, fields] : sink.pending) {
    if (frame >= seq.frame_count) {
      ++beyond;
      continue;
    }
    // NRRD sequences call the image status `Status`: kept under MetaImage's name, ImageStatus,
    // so that frame fields mean the same whatever the format (the writer renames it back).
    if (nrrd) {
      auto status = fields.find("Status");
      if (status != fields.end() && !fields.count("ImageStatus")) {
        fields["ImageStatus"] = status->second;
        fields.erase(status);
      }
    }
    seq.frame_fields[size_t(frame)] = std::move(fields);
  }
  if (beyond > 0)
    warn(path + ": fields of " + std::to_string(beyond) + " frame(s) numbered beyond the " +
         std::to_string(seq.frame_count) + " frames of pixel data are ignored");
  validate_frame_fields(seq);

  read_pixels(layout, in, &seq);
  const size_t frame_bytes = seq.frame_bytes();
  if (frame_bytes > 0)
    for (int f = 0; f < seq.frame_count; ++f)
      flip_frame(seq.pixels.data() + frame_bytes * size_t(f), seq.width, seq.height,
                 pixel_size(seq.pixel_type), flips);
  return seq;
}

void write_plus_sequence(const std::string& path, const PlusSequence& s, bool compress) {
  const std::string name = lower(path);
  const bool nrrd = ends_with(name, ".nrrd");
  if (!nrrd && !ends_with(name, ".mha"))
    throw InputError("cannot write PLUS sequence '" + path +
                     "': unsupported file name ending (expected .mha or .nrrd, e.g. .igs.mha)");
  if (s.width <= 0 || s.height <= 0 || s.frame_count <= 0)
    throw InputError("cannot write PLUS sequence '" + path + "': " + std::to_string(s.width) + "x" +
                     std::to_string(s.height) + " pixels, " + std::to_string(s.frame_count) +
                     " frames (need at least one frame of at least one pixel)");
  const uint64_t frame_bytes = s.frame_bytes();
  if (uint64_t(s.pixels.size()) != frame_bytes * uint64_t(s.frame_count))
    throw InputError("cannot write PLUS sequence '" + path +
                     "': " + std::to_string(s.pixels.size()) + " pixel bytes, expected " +
                     std::to_string(frame_bytes * uint64_t(s.frame_count)) + " for " +
                     std::to_string(s.frame_count) + " frames of " + std::to_string(s.width) + "x" +
                     std::to_string(s.height) + " " + to_string(s.pixel_type));
  if (s.frame_fields.size() > size_t(s.frame_count))
    throw InputError("cannot write PLUS sequence '" + path + "': fields for " +
                     std::to_string(s.frame_fields.size()) + " frames but " +
                     std::to_string(s.frame_count) + " frames of pixels");
  const Flips flips = orientation_flips(s.orientation, "cannot write PLUS sequence '" + path + "'");
  check_header_text(s.orientation, "orientation", path);

  std::ostringstream h;
  const std::string dims = std::to_string(s.width) + " " + std::to_string(s.height) + " " +
                           std::to_string(s.frame_count);
  // PLUS pads CompressedDataSize so that it can be filled in once the data is written.
  const std::string size_placeholder(20, ' ');
  if (nrrd) {
    h << "NRRD0004\n"
      << "# Complete NRRD file format specification at:\n"
      << "# http://teem.sourceforge.net/nrrd/format.html\n"
      << "dimension: 3\n"
      << "encoding: " << (compress ? "gz" : "raw") << "\n"
      << "endian: little\n"
      << "kinds: domain domain list\n"
      << "sizes: " << dims << "\n"
      << "space dimension: 2\n"
      << "space directions: (1,0) (0,1) none\n"
      << "space origin: (0,0)\n"
      << "type: " << nrrd_type_name(s.pixel_type) << "\n"
      << "ultrasound image orientation:=" << s.orientation << "\n"
      << "ultrasound image type:=BRIGHTNESS\n";
  } else {
    h << "ObjectType = Image\n"
      << "NDims = 3\n"
      << "AnatomicalOrientation = RAI\n"
      << "BinaryData = True\n"
      << "BinaryDataByteOrderMSB = False\n"
      << "CenterOfRotation = 0 0 0\n"
      << "CompressedData = " << (compress ? "True" : "False") << "\n";
    if (compress) h << "CompressedDataSize = " << size_placeholder << "\n";
    h << "DimSize = " << dims << "\n"
      << "Kinds = domain domain list\n"
      << "ElementSpacing = 1 1 1\n"
      << "ElementType = " << meta_type_name(s.pixel_type) << "\n"
      << "Offset = 0 0 0\n"
      << "TransformMatrix = 1 0 0 0 1 0 0 0 1\n"
      << "UltrasoundImageOrientation = " << s.orientation << "\n"
      << "UltrasoundImageType = BRIGHTNESS\n";
  }
  for (size_t f = 0; f < s.frame_fields.size(); ++f) {
    const auto& fields = s.frame_fields[f];
    // NRRD sequences call the image status `Status` (the reader stores it as ImageStatus).
    const bool rename_status = nrrd && fields.count("ImageStatus") && !fields.count("Status");
    for (const auto& [key, value] : fields) {
      const std::string field = rename_status && key == "ImageStatus" ? "Status" : key;
      check_header_text(field, "frame field name", path);
      check_header_text(value, "frame field value", path);
      if (field.empty() || trim(field) != field ||
          (nrrd ? field.find(":=") != std::string::npos : field.find('=') != std::string::npos))
        throw InputError("cannot write PLUS sequence '" + path + "': frame field name " +
                         quote_value(field) + " cannot be written");
      h << "Seq_Frame" << frame_label(int(f)) << "_" << field << (nrrd ? ":=" : " = ") << value
        << "\n";
    }
  }
  h << (nrrd ? "\n" : "ElementDataFile = LOCAL\n");
  const std::string header = h.str();

  AtomicFile atomic(path);
  {
    OutputFile out(atomic.temp_path(), path);
    out.write(header);
    PixelSink sink(&out, compress, nrrd ? 15 + 16 : 15, path);
    std::vector<uint8_t> frame;
    for (int f = 0; f < s.frame_count; ++f) {
      const uint8_t* src = s.pixels.data() + frame_bytes * size_t(f);
      if (flips.x || flips.y) {
        frame.assign(src, src + frame_bytes);
        flip_frame(frame.data(), s.width, s.height, pixel_size(s.pixel_type), flips);
        src = frame.data();
      }
      sink.write(src, frame_bytes);
    }
    const uint64_t data_bytes = sink.finish();
    if (compress && !nrrd) {
      const std::string value = std::to_string(data_bytes);
      const size_t at = header.find("CompressedDataSize = ") + std::strlen("CompressedDataSize = ");
      out.seek(at);
      out.write(value);  // shorter than the padding, which stays as trailing spaces
    }
    out.close();
  }
  atomic.commit();
}

// -------------------------------------------------------------------------------------------------
// TransformRepository

std::pair<std::string, std::string> TransformRepository::split_name(const std::string& name) {
  // PLUS names are <From>To<To> with capitalised frame names; "To" followed by a capital letter
  // (or digit) separates them, e.g. StylusTipToStylus, ToolToTracker.
  std::vector<size_t> splits;
  for (size_t p = 1; p + 2 < name.size(); ++p)
    if (name.compare(p, 2, "To") == 0 && (std::isupper(static_cast<unsigned char>(name[p + 2])) ||
                                          std::isdigit(static_cast<unsigned char>(name[p + 2]))))
      splits.push_back(p);
  if (splits.empty())
    throw InputError("transform name " + quote_value(name) +
                     " is not of the form <From>To<To> "
                     "(e.g. ImageToReference)");
  if (splits.size() > 1)
    throw InputError("transform name " + quote_value(name) +
                     " is ambiguous: more than one 'To' "
                     "followed by a capital letter");
  return {name.substr(0, splits[0]), name.substr(splits[0] + 2)};
}

void TransformRepository::set(const std::string& from, const std::string& to, const Mat4& m,
                              bool valid) {
  if (from.empty() || to.empty() || from == to)
    throw InputError("transform " + quote_value(from + "To" + to) +
                     ": needs two different, non-empty coordinate frame names");
  transforms_.erase({to, from});  // one direction per pair: the newest wins
  transforms_[{from, to}] = Entry{m, valid};
}

void TransformRepository::set_frame(const PlusSequence& sequence, int frame) {
  const auto& fields = fields_of(sequence, frame);
  for (const std::string& name : sequence.transform_names(frame)) {
    std::pair<std::string, std::string> ends;
    try {
      ends = split_name(name);
    } catch (const InputError&) {
      continue;  // a field ending in "Transform" that is not a PLUS transform name
    }
    if (ends.first == ends.second) continue;
    std::optional<Mat4> m = sequence.transform(frame, name);
    if (m) {
      set(ends.first, ends.second, *m, true);
    } else {
      Mat4 stored;  // kept for completeness; a chain through it is reported invalid
      parse_matrix16(fields.at(name + "Transform"), &stored);
      set(ends.first, ends.second, stored, false);
    }
  }
}

std::optional<Mat4> TransformRepository::get(const std::string& from, const std::string& to) const {
  if (from == to) return Mat4::identity();
  struct Edge {
    std::string next;
    const Entry* entry;
    bool inverse;
    std::string name;  // AToB as stored
  };
  std::map<std::string, std::vector<Edge>> graph;
  for (const auto& [key, entry] : transforms_) {
    const std::string name = key.first + "To" + key.second;
    graph[key.first].push_back({key.second, &entry, false, name});
    graph[key.second].push_back({key.first, &entry, true, name});
  }
  // Breadth-first: the chain with the fewest transforms; valid transforms only first, so that a
  // valid chain is found even when an equally short one passes through an invalid transform.
  auto search = [&](bool valid_only) -> std::optional<std::vector<const Edge*>> {
    std::map<std::string, const Edge*> came_by;
    std::map<std::string, std::string> came_from;
    std::deque<std::string> queue{from};
    came_from[from] = "";
    while (!queue.empty()) {
      const std::string node = queue.front();
      queue.pop_front();
      if (node == to) break;
      auto it = graph.find(node);
      if (it == graph.end()) continue;
      for (const Edge& e : it->second) {
        if (valid_only && !e.entry->valid) continue;
        if (came_from.count(e.next)) continue;
        came_from[e.next] = node;
        came_by[e.next] = &e;
        queue.push_back(e.next);
      }
    }
    if (!came_from.count(to)) return std::nullopt;
    std::vector<const Edge*> path;
    for (std::string node = to; node != from; node = came_from[node]) path.push_back(came_by[node]);
    std::reverse(path.begin(), path.end());
    return path;
  };
  std::optional<std::vector<const Edge*>> path = search(true);
  if (!path) {
    if (search(false)) return std::nullopt;  // only through an invalid transform
    std::string known;
    for (const auto& [key, entry] : transforms_)
      known += (known.empty() ? "" : ", ") + key.first + "To" + key.second +
               (entry.valid ? "" : " (invalid)");
    throw InputError("no chain of transforms from '" + from + "' to '" + to +
                     "' (known: " + (known.empty() ? "none" : known) + ")");
  }
  Mat4 result = Mat4::identity();
  for (const Edge* e : *path) {
    Mat4 step = e->entry->matrix;
    if (e->inverse) {
      std::optional<Mat4> inv = invert(step);
      if (!inv)
        throw InputError("transform " + e->name + " is not invertible, so " + from + "To" + to +
                         " cannot be computed through it");
      step = *inv;
    }
    result = step * result;
  }
  return result;
}

std::string PlusFrameSelection::skipped_reason(const std::string& from,
                                               const std::string& to) const {
  std::string why;
  if (bad_transform)
    why += std::to_string(bad_transform) + " with an invalid " + from + "To" + to + " transform";
  if (bad_image)
    why += (why.empty() ? "" : ", ") + std::to_string(bad_image) + " with an image status not OK";
  return why;
}

PlusFrameSelection select_plus_frames(const PlusSequence& sequence,
                                      const TransformRepository& calibration,
                                      const std::string& from, const std::string& to, int skip,
                                      const std::string& hint) {
  if (skip < 1) throw InputError("skip interval " + std::to_string(skip) + ": must be >= 1");
  PlusFrameSelection sel;
  for (int k = 0; k < sequence.frame_count; k += skip) {
    if (!sequence.image_ok(k)) {
      ++sel.bad_image;
      continue;
    }
    TransformRepository repo = calibration;
    repo.set_frame(sequence, k);
    std::optional<Mat4> m;
    try {
      m = repo.get(from, to);
    } catch (const InputError& e) {
      throw InputError(sequence.path + ": " + e.what() + hint);
    }
    if (!m) {
      ++sel.bad_transform;
      continue;
    }
    sel.frames.push_back(k);
    sel.to_reference.push_back(*m);
  }
  return sel;
}

}  // namespace sonoslice
