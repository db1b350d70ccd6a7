// The header parsers of PLUS sequence files, MetaImage (.mha) and NRRD (.nrrd): the header text,
// the frame fields kept in order, and where and how the pixel data lies (DataLayout).
#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <iterator>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "PlusSequenceRead.h"
#include "sonoslice/core/Error.h"

namespace fs = std::filesystem;

namespace sonoslice {
namespace plus {

using namespace text;

// "Seq_Frame0012_ProbeToTrackerTransform" → frame 12, field "ProbeToTrackerTransform".
bool FrameFieldSink::add(const std::string& key, const std::string& value,
                         const std::string& where) {
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

namespace {

/// Values per pixel: grey (1), RGB (3) or RGBA (4) frames, as a video grabber records them.
int frame_components(int64_t n, const std::string& what, const std::string& where) {
  if (n != 1 && n != 3 && n != 4)
    throw InputError(where + ": " + what + " " + std::to_string(n) +
                     " (frames of 1, 3 or 4 components are read: grey, RGB, RGBA)");
  return int(n);
}

/// Splits a list of sizes (and optional kinds) into frames: W H, W H N or W H 1 N, each after a
/// component axis C when the first kind says so (IGSIO writes RGB frames as `sizes: 3 W H N`,
/// `kinds: vector domain domain list`).
void set_frame_dims(std::vector<int64_t> sizes, std::vector<std::string> kinds,
                    const std::string& where, DataLayout* layout) {
  static const char* const component_kinds[] = {"vector",     "3-vector", "4-vector", "RGB-color",
                                                "RGBA-color", "3-color",  "4-color"};
  if (!kinds.empty() && sizes.size() > 2 &&
      std::any_of(std::begin(component_kinds), std::end(component_kinds),
                  [&](const char* k) { return iequals(kinds[0], k); })) {
    layout->components =
        frame_components(sizes[0], "a component axis (" + kinds[0] + ") of", where);
    sizes.erase(sizes.begin());
    kinds.erase(kinds.begin());
  }
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
  if (n > 0 && (w == 0 || h == 0))
    throw InputError(where + ": " + std::to_string(n) + " frames of " + std::to_string(w) + "x" +
                     std::to_string(h) + " pixels: a frame needs at least one pixel");
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

}  // namespace

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
      if (std::any_of(line.begin(), line.end(),
                      [](char c) { return (unsigned char)c < 32 && c != '\t' && c != '\r'; }))
        throw FileError(where + ": binary data at header line " + std::to_string(line_number) +
                        " before the header's ElementDataFile line (it ends a MetaImage header)");
      throw FileError(where + ": malformed header line " + std::to_string(line_number) + " " +
                      quote_value(line) + " (expected Key = Value)");
    }
    const std::string key = trim(line.substr(0, eq)), value = trim(line.substr(eq + 1));
    if (key.empty() || key.find('\0') != std::string::npos)
      throw FileError(where + ": not a PLUS sequence file (malformed header line " +
                      std::to_string(line_number) + ")");
    if (sink->add(key, value, where)) continue;
    if (!fields.emplace(lower(key), value).second)
      throw FileError(where + ": header field " + quote_value(key) +
                      " given twice (again at line " + std::to_string(line_number) + ")");
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
  if (const std::string* v = get("ElementNumberOfChannels")) {
    int64_t n = 0;
    if (!parse_int64(*v, &n))
      throw InputError(where + ": ElementNumberOfChannels " + quote_value(*v) + " is not a number");
    layout.components = frame_components(n, "ElementNumberOfChannels =", where);
  }
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
      const std::string field = trim(line.substr(0, colon));
      if (!fields.emplace(lower(field), trim(line.substr(colon + 1))).second)
        throw FileError(where + ": header field " + quote_value(field) +
                        " given twice (again at line " + std::to_string(line_number) + ")");
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

}  // namespace plus
}  // namespace sonoslice
