// Stanford PLY meshes (PlyParse.h says why they are parsed here).
#include "PlyParse.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include "TextParse.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

struct PlyType {
  const char* name;
  const char* alias;
  int bytes;
  bool is_float, is_signed;
};
constexpr PlyType kPlyTypes[] = {
    {"char", "int8", 1, false, true},    {"uchar", "uint8", 1, false, false},
    {"short", "int16", 2, false, true},  {"ushort", "uint16", 2, false, false},
    {"int", "int32", 4, false, true},    {"uint", "uint32", 4, false, false},
    {"float", "float32", 4, true, true}, {"double", "float64", 8, true, true},
};

struct Property {
  std::string name;
  const PlyType* type = nullptr;
  const PlyType* count_type = nullptr;  // a list's; nullptr for a scalar property
};

struct Element {
  std::string name;
  int64_t count = 0;
  std::vector<Property> properties;
};

enum class Format { Ascii, LittleEndian, BigEndian };

class PlyParser {
 public:
  PlyParser(const std::string& path, const std::string& bytes) : path_(path), bytes_(bytes) {}

  PolygonSoup parse() {
    header();
    for (const Element& e : elements_) element(e);
    if (format_ == Format::Ascii) {
      std::string extra;
      if (token(&extra))
        corrupt("more values after the last element (" + text::quote_value(extra) + ")");
    }
    const int64_t points = int64_t(soup_.points.size() / 3);
    for (size_t k = 0; k + 1 < soup_.offsets.size(); ++k)
      for (int64_t i = soup_.offsets[k]; i < soup_.offsets[k + 1]; ++i)
        if (soup_.connectivity[size_t(i)] >= points)
          corrupt("face " + std::to_string(face_index_[k]) + " uses vertex " +
                  std::to_string(soup_.connectivity[size_t(i)]) + ", but the file has " +
                  std::to_string(points));
    return std::move(soup_);
  }

 private:
  [[noreturn]] void corrupt(const std::string& why) const {
    throw FileError("cannot read mesh '" + path_ + "': " + why);
  }

  // One header line, without its line end ("\n" or "\r\n").
  std::string line() {
    if (at_ >= bytes_.size()) corrupt("not a PLY mesh (its header has no end_header line)");
    size_t end = bytes_.find('\n', at_);
    if (end == std::string::npos) end = bytes_.size();
    std::string l = bytes_.substr(at_, end - at_);
    at_ = std::min(end + 1, bytes_.size());
    if (!l.empty() && l.back() == '\r') l.pop_back();
    return l;
  }

  const PlyType* type_named(const std::string& name, const std::string& where) const {
    for (const PlyType& t : kPlyTypes)
      if (name == t.name || name == t.alias) return &t;
    corrupt(where + ": unknown type " + text::quote_value(name));
  }

  void header() {
    if (line() != "ply") corrupt("not a PLY mesh (its first line is not 'ply')");
    bool have_format = false;
    for (int number = 2;; ++number) {
      const std::vector<std::string> t = text::split_ws(line());
      const std::string where = "header line " + std::to_string(number);
      if (t.empty() || t[0] == "comment" || t[0] == "obj_info") continue;
      if (t[0] == "end_header") break;
      if (t[0] == "format") {
        if (t.size() != 3 || t[2] != "1.0")
          corrupt(where + ": expected 'format ascii|binary_little_endian|binary_big_endian 1.0'");
        if (t[1] == "ascii")
          format_ = Format::Ascii;
        else if (t[1] == "binary_little_endian")
          format_ = Format::LittleEndian;
        else if (t[1] == "binary_big_endian")
          format_ = Format::BigEndian;
        else
          corrupt(where + ": unknown format " + text::quote_value(t[1]));
        have_format = true;
      } else if (t[0] == "element") {
        Element e;
        if (t.size() != 3 || !text::parse_int64(t[2], &e.count) || e.count < 0)
          corrupt(where + ": expected 'element NAME COUNT'");
        e.name = t[1];
        for (const Element& other : elements_)
          if (other.name == e.name && (e.name == "vertex" || e.name == "face"))
            corrupt(where + ": a second " + e.name + " element");
        elements_.push_back(e);
      } else if (t[0] == "property") {
        if (elements_.empty()) corrupt(where + ": a property before any element");
        Property p;
        if (t.size() == 5 && t[1] == "list") {
          p.count_type = type_named(t[2], where);
          if (p.count_type->is_float) corrupt(where + ": a list's count must be an integer type");
          p.type = type_named(t[3], where);
          p.name = t[4];
        } else if (t.size() == 3) {
          p.type = type_named(t[1], where);
          p.name = t[2];
        } else {
          corrupt(where + ": expected 'property TYPE NAME' or 'property list COUNT ITEM NAME'");
        }
        elements_.back().properties.push_back(p);
      } else {
        corrupt(where + ": unknown keyword " + text::quote_value(t[0]));
      }
    }
    if (!have_format) corrupt("its header has no format line");
    bool geometry = false;
    for (const Element& e : elements_)
      if (e.name == "vertex") {
        for (const char* axis : {"x", "y", "z"})
          if (scalar_index(e, axis) < 0)
            corrupt("the vertex element has no scalar property '" + std::string(axis) + "'");
        if (e.count > int64_t(std::numeric_limits<int32_t>::max()))
          throw InputError("mesh '" + path_ + "': " + std::to_string(e.count) +
                           " vertices (sonoslice meshes hold at most 2^31 - 1)");
        geometry = true;
      } else if (e.name == "face" && faces_list(e) < 0) {
        corrupt("the face element has no list property 'vertex_indices'");
      }
    if (!geometry) corrupt("no vertex element");
  }

  static int scalar_index(const Element& e, const char* name) {
    for (size_t i = 0; i < e.properties.size(); ++i)
      if (e.properties[i].name == name && !e.properties[i].count_type) return int(i);
    return -1;
  }

  static int faces_list(const Element& e) {
    for (size_t i = 0; i < e.properties.size(); ++i)
      if ((e.properties[i].name == "vertex_indices" || e.properties[i].name == "vertex_index") &&
          e.properties[i].count_type)
        return int(i);
    return -1;
  }

  // ---- values ----

  bool token(std::string* out) {
    while (at_ < bytes_.size() && std::isspace(static_cast<unsigned char>(bytes_[at_]))) ++at_;
    const size_t start = at_;
    while (at_ < bytes_.size() && !std::isspace(static_cast<unsigned char>(bytes_[at_]))) ++at_;
    out->assign(bytes_, start, at_ - start);
    return at_ > start;
  }

  [[noreturn]] void truncated(const Element& e, int64_t record) const {
    corrupt("truncated: the file ends in " + e.name + " " + std::to_string(record) + " of " +
            std::to_string(e.count));
  }

  // The next value of type t in record `record` of e.
  double value(const PlyType& t, const Element& e, int64_t record) {
    if (format_ == Format::Ascii) {
      std::string s;
      if (!token(&s)) truncated(e, record);
      double v = 0;
      int64_t i = 0;
      if (t.is_float ? !text::parse_double(s, &v) : !text::parse_int64(s, &i))
        corrupt(e.name + " " + std::to_string(record) + ": " + text::quote_value(s) + " is not " +
                (t.is_float ? "a number" : "an integer"));
      return t.is_float ? v : double(i);
    }
    if (bytes_.size() - at_ < size_t(t.bytes)) truncated(e, record);
    unsigned char b[8];
    std::memcpy(b, bytes_.data() + at_, size_t(t.bytes));
    at_ += size_t(t.bytes);
    if (format_ == Format::BigEndian)
      for (int i = 0; i < t.bytes / 2; ++i) std::swap(b[i], b[t.bytes - 1 - i]);
    uint64_t u = 0;
    for (int i = t.bytes - 1; i >= 0; --i) u = u << 8 | b[i];
    if (t.is_float) {
      if (t.bytes == 4) {
        float f;
        const uint32_t u32 = uint32_t(u);
        std::memcpy(&f, &u32, 4);
        return double(f);
      }
      double d;
      std::memcpy(&d, &u, 8);
      return d;
    }
    if (t.is_signed && (u >> (8 * t.bytes - 1)) & 1)
      return double(int64_t(u - (uint64_t(1) << (8 * t.bytes))));
    return double(u);
  }

  // The fewest bytes a record of e can take: refuses a count the file cannot hold before
  // anything of that size is allocated.
  size_t least_record_bytes(const Element& e) const {
    size_t n = 0;
    for (const Property& p : e.properties)
      n +=
          format_ == Format::Ascii ? 2 : size_t(p.count_type ? p.count_type->bytes : p.type->bytes);
    return n;
  }

  void element(const Element& e) {
    const size_t least = least_record_bytes(e);
    if (least > 0 && uint64_t(e.count) > (bytes_.size() - at_ + 1) / least)
      corrupt("truncated: " + std::to_string(e.count) + " " + e.name + " records need at least " +
              std::to_string(uint64_t(e.count) * least - 1) + " bytes, " +
              std::to_string(bytes_.size() - at_) + " are left");
    const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
    const int x = scalar_index(e, "x"), y = scalar_index(e, "y"), z = scalar_index(e, "z");
    const int list = is_face ? faces_list(e) : -1;
    if (is_vertex) soup_.points.reserve(size_t(e.count) * 3);
    std::vector<int64_t> face;
    for (int64_t r = 0; r < e.count; ++r) {
      double xyz[3] = {0, 0, 0};
      for (int i = 0; i < int(e.properties.size()); ++i) {
        const Property& p = e.properties[size_t(i)];
        if (!p.count_type) {
          const double v = value(*p.type, e, r);
          if (is_vertex && (i == x || i == y || i == z)) xyz[i == x ? 0 : i == y ? 1 : 2] = v;
          continue;
        }
        const double n = value(*p.count_type, e, r);
        const size_t item = format_ == Format::Ascii ? 2 : size_t(p.type->bytes);
        if (n < 0 || n > double(bytes_.size() - at_) / double(item))
          corrupt("truncated: " + e.name + " " + std::to_string(r) + " lists " +
                  std::to_string(int64_t(n)) + " values, more than the rest of the file holds");
        if (i == list) face.clear();
        for (int64_t k = 0; k < int64_t(n); ++k) {
          const double v = value(*p.type, e, r);
          if (i != list) continue;
          if (p.type->is_float || v < 0)
            corrupt("face " + std::to_string(r) + ": a vertex index must be a whole number >= 0");
          face.push_back(int64_t(v));
        }
      }
      if (is_vertex) {
        if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2]))
          throw InputError("mesh '" + path_ + "': point " + std::to_string(r) +
                           " has a non-finite coordinate");
        soup_.points.insert(soup_.points.end(), xyz, xyz + 3);
      }
      if (is_face && face.size() >= 3) {
        soup_.connectivity.insert(soup_.connectivity.end(), face.begin(), face.end());
        soup_.offsets.push_back(int64_t(soup_.connectivity.size()));
        face_index_.push_back(r);
      }
    }
  }

  const std::string& path_;
  const std::string& bytes_;
  size_t at_ = 0;
  Format format_ = Format::Ascii;
  std::vector<Element> elements_;
  PolygonSoup soup_;
  std::vector<int64_t> face_index_;  // each kept polygon's face record, for messages
};

}  // namespace

PolygonSoup parse_ply(const std::string& path, const std::string& bytes) {
  return PlyParser(path, bytes).parse();
}

}  // namespace sonoslice
