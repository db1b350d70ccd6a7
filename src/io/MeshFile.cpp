// The VTK edge of sonoslice: surface meshes in and out.
#include "sonoslice/io/MeshFile.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <sstream>
#include <vector>

#include "PlyParse.h"
#include "TextParse.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/VolumeFile.h"

#ifdef SONOSLICE_HAVE_VTK
#include <vtkAlgorithm.h>
#include <vtkCellArray.h>
#include <vtkCleanPolyData.h>
#include <vtkIdList.h>
#include <vtkIdTypeArray.h>
#include <vtkLogger.h>
#include <vtkNew.h>
#include <vtkOBJReader.h>
#include <vtkOBJWriter.h>
#include <vtkOutputWindow.h>
#include <vtkPLYWriter.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataWriter.h>
#include <vtkSTLReader.h>
#include <vtkSTLWriter.h>
#include <vtkSmartPointer.h>
#include <vtkTriangleFilter.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>
#endif

namespace sonoslice {

bool built_with_vtk() {
#ifdef SONOSLICE_HAVE_VTK
  return true;
#else
  return false;
#endif
}

#ifdef SONOSLICE_HAVE_VTK
namespace {

// VTK readers report trouble through vtkOutputWindow and carry on; this window collects what
// they say during one read so that it can become an error (or a warning) with the file's name.
class CollectingWindow : public vtkOutputWindow {
 public:
  static CollectingWindow* New();
  vtkTypeMacro(CollectingWindow, vtkOutputWindow);
  void DisplayErrorText(const char* t) override { add(errors, t); }
  void DisplayWarningText(const char* t) override { add(warnings, t); }
  void DisplayGenericWarningText(const char* t) override { add(warnings, t); }
  void DisplayText(const char*) override {}
  bool failed() const { return pipeline_failed || !errors.empty(); }
  // What to tell the user when the read failed: the reader's errors, else its warnings (some
  // readers only log), else that the pipeline failed.
  std::string error_text() const {
    if (!errors.empty()) return errors;
    return warnings.empty() ? "not a valid file of its format; " : warnings;
  }
  std::string errors, warnings;  // "message; message; "

  void add(std::string& to, const char* text) {
    // "ERROR: In /path/x.cxx, line N\nvtkClass (0x...): message" → "message"
    const std::string message = text::one_line_message(text ? text : "", /*drop_location=*/true);
    if (message.empty()) return;
    // The pipeline's "Algorithm vtkXReader(0x...) returned failure for request: vtkInformation
    // (...)" dump follows the reader's own message and says nothing more.
    if (message.rfind("Algorithm ", 0) == 0 &&
        message.find(" returned failure for request") != std::string::npos) {
      pipeline_failed = true;
      return;
    }
    if (to.find(message + "; ") == std::string::npos) to += message + "; ";
  }

 private:
  bool pipeline_failed = false;
};
vtkStandardNewMacro(CollectingWindow);

// Some VTK 9 readers log through vtkLogger (to stderr) instead: silence that and collect it too.
void collect_log(void* user, const vtkLogger::Message& m) {
  auto* window = static_cast<CollectingWindow*>(user);
  window->add(window->warnings, m.message);
}

struct WindowScope {
  vtkSmartPointer<vtkOutputWindow> previous;
  vtkNew<CollectingWindow> window;
  WindowScope() : previous(vtkOutputWindow::GetInstance()) {
    vtkOutputWindow::SetInstance(window);
    vtkLogger::SetStderrVerbosity(vtkLogger::VERBOSITY_OFF);
    vtkLogger::AddCallback("sonoslice-mesh-read", &collect_log, window.GetPointer(),
                           vtkLogger::VERBOSITY_WARNING);
  }
  ~WindowScope() {
    vtkLogger::RemoveCallback("sonoslice-mesh-read");
    vtkOutputWindow::SetInstance(previous);
  }
};

std::string trimmed(const std::string& s) {
  return s.size() > 2 ? s.substr(0, s.size() - 2) : s;
}

[[noreturn]] void corrupt(const std::string& path, const std::string& why) {
  throw FileError("cannot read mesh '" + path + "': " + why);
}

std::string read_whole_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) corrupt(path, std::strerror(errno));
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) corrupt(path, "read error");
  return bytes;
}

// Cells as offsets into a connectivity list (n + 1 offsets for n cells).
struct Cells {
  std::vector<int64_t> offsets{0}, connectivity;
};

vtkSmartPointer<vtkCellArray> cell_array(const Cells& c) {
  vtkNew<vtkIdTypeArray> offsets, connectivity;
  offsets->SetNumberOfValues(vtkIdType(c.offsets.size()));
  for (size_t i = 0; i < c.offsets.size(); ++i) offsets->SetValue(vtkIdType(i), c.offsets[i]);
  connectivity->SetNumberOfValues(vtkIdType(c.connectivity.size()));
  for (size_t i = 0; i < c.connectivity.size(); ++i)
    connectivity->SetValue(vtkIdType(i), c.connectivity[i]);
  auto cells = vtkSmartPointer<vtkCellArray>::New();
  cells->SetData(offsets, connectivity);
  return cells;
}

// What the parsers below read (points x, y, z each; checked cells) as VTK's polygonal data, for
// VTK's triangulation and point merging.
vtkSmartPointer<vtkPolyData> poly_data(const std::vector<double>& xyz, const Cells& polys,
                                       const Cells& strips) {
  auto poly = vtkSmartPointer<vtkPolyData>::New();
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(vtkIdType(xyz.size() / 3));
  for (size_t i = 0; i < xyz.size() / 3; ++i)
    points->SetPoint(vtkIdType(i), xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
  poly->SetPoints(points);
  poly->SetPolys(cell_array(polys));
  poly->SetStrips(cell_array(strips));
  return poly;
}

// ---- legacy VTK ---------------------------------------------------------------------------
//
// Legacy .vtk files are parsed here rather than by vtkPolyDataReader, which trusts the counts in
// the file: a truncated binary file or a polygon naming point 99999 of 3 crashed it or read
// beyond its arrays. sonoslice needs only the points and the polygons and triangle
// strips; they are checked against the file's size, the point count and for finite coordinates
// while they are read, and reach VTK's triangulation and point merging as a vtkPolyData. The
// grammar is VTK's (IO/Legacy/vtkDataReader.cxx, vtkPolyDataReader.cxx): keywords in any case,
// binary values big-endian and starting after the line that announces them, cells as
// "n size" + counted lists before file version 5 and as OFFSETS + CONNECTIVITY arrays from 5.0.
// Attribute data (POINT_DATA, CELL_DATA and what follows) is not read.

// The value types a legacy file may name for an array, with their size in binary files.
struct ValueType {
  const char* name;
  int bytes;
  bool is_float, is_signed;
};
constexpr ValueType kValueTypes[] = {
    {"bit", 0, false, false},  // packed bits: never coordinates or ids, refused below
    {"char", 1, false, true},
    {"signed_char", 1, false, true},
    {"unsigned_char", 1, false, false},
    {"short", 2, false, true},
    {"unsigned_short", 2, false, false},
    {"int", 4, false, true},
    {"unsigned_int", 4, false, false},
    {"long", 8, false, true},
    {"unsigned_long", 8, false, false},
    {"vtktypeint64", 8, false, true},
    {"vtktypeuint64", 8, false, false},
    {"vtkidtype", 8, false, true},
    {"vtktypeint32", 4, false, true},
    {"vtktypeuint32", 4, false, false},
    {"float", 4, true, true},
    {"double", 8, true, true},
};

class LegacyVtkParser {
 public:
  LegacyVtkParser(std::string path, std::string bytes)
      : path_(std::move(path)), bytes_(std::move(bytes)), at_(0) {}

  vtkSmartPointer<vtkPolyData> parse() {
    header();
    while (true) {
      std::string keyword;
      if (!token(&keyword)) break;
      keyword = text::lower(keyword);
      if (keyword == "field") {
        field_data();
      } else if (keyword == "points") {
        points();
      } else if (keyword == "vertices" || keyword == "lines" || keyword == "polygons" ||
                 keyword == "triangle_strips") {
        cells(keyword);
      } else if (keyword == "point_data" || keyword == "cell_data") {
        break;  // attributes: sonoslice uses none of them
      } else {
        corrupt(path_, "unrecognized keyword " + text::quote_value(keyword) + " at byte " +
                           std::to_string(at_ - keyword.size()));
      }
    }
    return poly_data(points_, polys_, strips_);
  }

 private:
  void header() {
    const std::string first = line();
    if (first.rfind("# vtk DataFile Version", 0) != 0)
      corrupt(path_, "not a legacy VTK file (its first line is not '# vtk DataFile Version')");
    int major = 0, minor = 0;
    if (std::sscanf(first.c_str() + 22, "%d.%d", &major, &minor) == 2) major_version_ = major;
    line();  // the title
    std::string format, dataset, type;
    if (!token(&format)) truncated("the header");
    format = text::lower(format);
    if (format != "ascii" && format != "binary")
      corrupt(path_, "file type " + text::quote_value(format) + " (expected ASCII or BINARY)");
    binary_ = format == "binary";
    if (!token(&dataset) || text::lower(dataset) != "dataset" || !token(&type) ||
        text::lower(type) != "polydata")
      corrupt(path_, "not a legacy VTK POLYDATA file");
  }

  void points() {
    if (have_points_) corrupt(path_, "two POINTS sections");
    have_points_ = true;
    const int64_t n = count("POINTS", "number of points");
    // TriangleMesh indexes vertices with int32.
    if (n > int64_t(std::numeric_limits<int32_t>::max()))
      throw InputError("mesh '" + path_ + "': " + std::to_string(n) +
                       " points (sonoslice meshes hold at most 2^31 - 1)");
    const ValueType& type = value_type("POINTS");
    points_ = values(type, uint64_t(n) * 3, "POINTS");
    for (size_t i = 0; i < points_.size(); ++i)
      if (!std::isfinite(points_[i]))
        throw InputError("mesh '" + path_ + "': point " + std::to_string(i / 3) +
                         " has a non-finite coordinate");
  }

  void cells(const std::string& keyword) {
    const std::string section = text::upper(keyword);
    Cells c;
    if (major_version_ >= 5) {
      const int64_t n_offsets = count(section, "number of offsets");
      const int64_t n_ids = count(section, "connectivity size");
      expect_keyword("offsets", section);
      const std::vector<int64_t> offsets =
          ids(value_type(section + " OFFSETS"), uint64_t(n_offsets), section + " OFFSETS");
      expect_keyword("connectivity", section);
      const std::vector<int64_t> connectivity =
          ids(value_type(section + " CONNECTIVITY"), uint64_t(n_ids), section + " CONNECTIVITY");
      if (!offsets.empty() && (offsets.front() != 0 || offsets.back() != n_ids))
        corrupt(path_, section + ": the offsets must run from 0 to the connectivity size " +
                           std::to_string(n_ids));
      if (offsets.empty() && n_ids != 0) corrupt(path_, section + ": connectivity without offsets");
      for (size_t k = 0; k + 1 < offsets.size(); ++k) {
        if (offsets[k + 1] < offsets[k])
          corrupt(path_, section + ": the offsets decrease at cell " + std::to_string(k));
        add_cell(&c, connectivity.data() + offsets[k], offsets[k + 1] - offsets[k], section, k);
      }
    } else {
      const int64_t n = count(section, "number of cells");
      const int64_t size = count(section, "size");
      const std::vector<int64_t> list = ids(find_type("int"), uint64_t(size), section);
      int64_t at = 0;
      for (int64_t k = 0; k < n; ++k) {
        if (at >= size || list[size_t(at)] < 0 || list[size_t(at)] > size - at - 1)
          corrupt(path_, section + " " + std::to_string(n) + " " + std::to_string(size) +
                             ": cell " + std::to_string(k) + " runs past the announced size");
        add_cell(&c, list.data() + at + 1, list[size_t(at)], section, size_t(k));
        at += 1 + list[size_t(at)];
      }
      if (at != size)
        corrupt(path_, section + " " + std::to_string(n) + " " + std::to_string(size) + ": the " +
                           std::to_string(n) + " cells fill " + std::to_string(at) +
                           " of the announced size");
    }
    if (keyword == "polygons") polys_ = std::move(c);
    if (keyword == "triangle_strips") strips_ = std::move(c);
  }

  // Checks a cell's point ids and keeps it when it can make a triangle (VTK's triangulation
  // ignores shorter cells too).
  void add_cell(Cells* c, const int64_t* cell, int64_t n, const std::string& section, size_t k) {
    const int64_t points = int64_t(points_.size() / 3);
    for (int64_t i = 0; i < n; ++i)
      if (cell[i] < 0 || cell[i] >= points)
        corrupt(path_, section + ": cell " + std::to_string(k) + " uses point " +
                           std::to_string(cell[i]) + ", but the file has " +
                           std::to_string(points) + " points");
    if (n < 3) return;
    c->connectivity.insert(c->connectivity.end(), cell, cell + n);
    c->offsets.push_back(int64_t(c->connectivity.size()));
  }

  // "FIELD name n" and n arrays "name components tuples type" + values (skipped over).
  void field_data() {
    std::string name;
    if (!token(&name)) truncated("FIELD");
    const int64_t arrays = count("FIELD", "number of arrays");
    for (int64_t a = 0; a < arrays; ++a) {
      std::string array;
      if (!token(&array)) truncated("FIELD");
      if (array == "NULL_ARRAY") continue;
      const int64_t components = count("FIELD array " + array, "number of components");
      const int64_t tuples = count("FIELD array " + array, "number of tuples");
      const uint64_t n = checked_product(uint64_t(components), uint64_t(tuples), "FIELD " + array);
      values(value_type("FIELD array " + array), n, "FIELD array " + array);
    }
  }

  // ---- tokens, lines and values ----

  size_t left() const { return bytes_.size() - at_; }

  bool token(std::string* out) {
    while (at_ < bytes_.size() && std::isspace(static_cast<unsigned char>(bytes_[at_]))) ++at_;
    const size_t begin = at_;
    while (at_ < bytes_.size() && !std::isspace(static_cast<unsigned char>(bytes_[at_]))) ++at_;
    out->assign(bytes_, begin, at_ - begin);
    return at_ > begin;
  }

  std::string line() {
    const size_t end = bytes_.find('\n', at_);
    std::string s = bytes_.substr(at_, end == std::string::npos ? std::string::npos : end - at_);
    at_ = end == std::string::npos ? bytes_.size() : end + 1;
    if (!s.empty() && s.back() == '\r') s.pop_back();
    return s;
  }

  [[noreturn]] void truncated(const std::string& where) const {
    corrupt(path_, "truncated or corrupt file (it ends inside " + where + ")");
  }

  int64_t count(const std::string& section, const char* what) {
    std::string t;
    int64_t v = 0;
    if (!token(&t)) truncated(section);
    if (!text::parse_int64(t, &v) || v < 0)
      corrupt(path_, section + ": " + what + " " + text::quote_value(t) +
                         " is not a count (a whole number >= 0)");
    return v;
  }

  void expect_keyword(const char* keyword, const std::string& section) {
    std::string t;
    if (!token(&t)) truncated(section);
    if (text::lower(t) != keyword)
      corrupt(path_,
              section + ": expected " + text::upper(keyword) + ", found " + text::quote_value(t));
  }

  static const ValueType& find_type(const std::string& name) {
    for (const ValueType& t : kValueTypes)
      if (name == t.name) return t;
    return kValueTypes[0];
  }

  const ValueType& value_type(const std::string& section) {
    std::string t;
    if (!token(&t)) truncated(section);
    const ValueType& type = find_type(text::lower(t));
    if (type.bytes == 0)
      corrupt(path_, section + ": value type " + text::quote_value(t) + " is not supported");
    return type;
  }

  uint64_t checked_product(uint64_t a, uint64_t b, const std::string& section) const {
    if (b != 0 && a > std::numeric_limits<uint64_t>::max() / b)
      corrupt(path_, section + ": the announced sizes overflow");
    return a * b;
  }

  // `n` numbers announced by `section` (binary ones start after the current line).
  std::vector<double> values(const ValueType& type, uint64_t n, const std::string& section) {
    std::vector<double> out;
    read_values(type, n, section, &out, [&](const unsigned char* p, const std::string& t) {
      if (p) return decode_float(type, p);
      char* end = nullptr;
      const double v = std::strtod(t.c_str(), &end);
      if (end != t.c_str() + t.size())
        corrupt(path_, section + ": " + text::quote_value(t) + " is not a number");
      return v;
    });
    return out;
  }

  // `n` point ids or counts announced by `section`.
  std::vector<int64_t> ids(const ValueType& type, uint64_t n, const std::string& section) {
    if (type.is_float)
      corrupt(path_, section + ": ids of type " + std::string(type.name) + " (expected integers)");
    std::vector<int64_t> out;
    read_values(type, n, section, &out, [&](const unsigned char* p, const std::string& t) {
      if (p) return decode_integer(type, p);
      int64_t v = 0;
      if (!text::parse_int64(t, &v))
        corrupt(path_, section + ": " + text::quote_value(t) + " is not a whole number");
      return v;
    });
    return out;
  }

  // Checks that `n` values fit in what is left of the file before anything is allocated, then
  // hands each to `parse` (the bytes of a binary value, or the token of an ASCII one).
  template <typename T, typename Parse>
  void read_values(const ValueType& type, uint64_t n, const std::string& section,
                   std::vector<T>* out, Parse parse) {
    if (binary_) {
      line();  // the rest of the line that names the type
      const uint64_t bytes = checked_product(n, uint64_t(type.bytes), section);
      if (bytes > left()) {
        std::ostringstream s;
        s << "truncated or corrupt file: " << section << " announces " << n << " values (" << bytes
          << " bytes), the file has " << left() << " bytes left";
        corrupt(path_, s.str());
      }
      out->reserve(size_t(n));
      const auto* p = reinterpret_cast<const unsigned char*>(bytes_.data() + at_);
      for (uint64_t i = 0; i < n; ++i, p += type.bytes) out->push_back(parse(p, std::string()));
      at_ += size_t(bytes);
    } else {
      // Each ASCII value takes at least two bytes (a digit and a separator).
      if (n > (left() + 1) / 2) truncated(section);
      out->reserve(size_t(n));
      std::string t;
      for (uint64_t i = 0; i < n; ++i) {
        if (!token(&t)) truncated(section);
        out->push_back(parse(nullptr, t));
      }
    }
    skip_metadata();
  }

  static uint64_t big_endian(const ValueType& type, const unsigned char* p) {
    uint64_t u = 0;
    for (int i = 0; i < type.bytes; ++i) u = (u << 8) | p[i];
    return u;
  }

  static double decode_float(const ValueType& type, const unsigned char* p) {
    if (!type.is_float) return double(decode_integer(type, p));
    const uint64_t u = big_endian(type, p);
    if (type.bytes == 4) {
      const uint32_t u32 = uint32_t(u);
      float f;
      std::memcpy(&f, &u32, 4);
      return f;
    }
    double d;
    std::memcpy(&d, &u, 8);
    return d;
  }

  // Unsigned values beyond int64 become -1: no valid id or count is that large either.
  static int64_t decode_integer(const ValueType& type, const unsigned char* p) {
    uint64_t u = big_endian(type, p);
    if (!type.is_signed) return u > uint64_t(std::numeric_limits<int64_t>::max()) ? -1 : int64_t(u);
    if (type.bytes < 8 && (u >> (8 * type.bytes - 1)) != 0)
      u |= ~uint64_t(0) << (8 * type.bytes);  // sign-extend
    return int64_t(u);
  }

  // An array may be followed by a METADATA block, which ends at an empty line.
  void skip_metadata() {
    const size_t before = at_;
    std::string t;
    if (!token(&t) || text::lower(t) != "metadata") {
      at_ = before;
      return;
    }
    line();
    while (at_ < bytes_.size() && !text::trim(line()).empty()) {
    }
  }

  std::string path_;
  std::string bytes_;
  size_t at_;
  int major_version_ = 0;
  bool binary_ = false, have_points_ = false;
  std::vector<double> points_;
  Cells polys_, strips_;
};

// ---- STL and OBJ checks (the files then go to VTK's readers) -----------------------------------

// VTK's STL reader takes a file for binary when over 5% of its first 256 bytes are not text
// (vtksys::SystemTools::DetectFileType), then reads the triangle count of its header and trusts
// it: the count must fit in the file (80-byte header, 4-byte count, 50 bytes per triangle).
void check_stl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char head[256];
  in.read(head, sizeof head);
  const size_t got = size_t(in.gcount());
  size_t text_bytes = 0;
  for (size_t i = 0; i < got; ++i) {
    const auto c = static_cast<unsigned char>(head[i]);
    text_bytes += (c >= 0x20 && c <= 0x7f) || c == '\n' || c == '\r' || c == '\t';
  }
  const bool binary = got == 0 || double(got - text_bytes) / double(got) >= 0.05;
  if (!binary) return;  // ASCII: VTK's parser reports its own errors
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  if (size < 84) corrupt(path, "truncated binary STL (" + std::to_string(size) + " bytes)");
  const auto* b = reinterpret_cast<const unsigned char*>(head + 80);
  const uint64_t triangles =
      uint64_t(b[0]) | uint64_t(b[1]) << 8 | uint64_t(b[2]) << 16 | uint64_t(b[3]) << 24;
  if (84 + 50 * triangles > size) {
    std::ostringstream s;
    s << "truncated or corrupt binary STL: its header announces " << triangles << " triangles ("
      << 84 + 50 * triangles << " bytes), the file has " << size << " bytes";
    corrupt(path, s.str());
  }
}

// vtkOBJReader skips what it cannot parse; a file of garbage became "no triangles" and a face
// naming a vertex that does not exist was dropped without a word. Vertices must have finite
// coordinates and faces must name vertices that exist (1-based, or negative: counted back).
void check_obj(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  // Counts of v, vt and vn lines so far; a face's texture and normal indices are checked too
  // (vtkOBJReader reads a missing normal out of bounds: a fuzzer found the crash).
  int64_t counts[3] = {0, 0, 0}, faces = 0, line_number = 0;
  const char* kinds[3] = {"vertex", "texture coordinate", "normal"};
  struct Forward {
    int64_t line, index;
    int kind;
  };
  std::vector<Forward> forward;  // positive indices, checked at the end
  while (std::getline(in, line)) {
    ++line_number;
    const std::vector<std::string> t = text::split_ws(line);
    if (t.empty()) continue;
    const std::string where = "line " + std::to_string(line_number);
    if (t[0] == "v") {
      if (t.size() < 4) corrupt(path, where + ": a vertex needs three coordinates");
      for (size_t i = 1; i < 4; ++i) {
        double x = 0;
        char* end = nullptr;
        x = std::strtod(t[i].c_str(), &end);
        if (end != t[i].c_str() + t[i].size())
          corrupt(path, where + ": " + text::quote_value(t[i]) + " is not a number");
        if (!std::isfinite(x))
          throw InputError("mesh '" + path + "': " + where + ": a vertex is not finite");
      }
      ++counts[0];
    } else if (t[0] == "vt") {
      ++counts[1];
    } else if (t[0] == "vn") {
      ++counts[2];
    } else if (t[0] == "f") {
      if (t.size() < 4) corrupt(path, where + ": a face needs at least three vertices");
      for (size_t i = 1; i < t.size(); ++i) {
        // Exactly "v", "v/vt", "v//vn" or "v/vt/vn". vtkOBJReader reads "v/" or "v//" as
        // texture or normal index 0, one before its array (a fuzzer found the SIGSEGV).
        std::vector<std::string> parts;
        for (size_t from = 0;;) {
          const size_t slash = t[i].find('/', from);
          parts.push_back(t[i].substr(from, slash == std::string::npos ? slash : slash - from));
          if (slash == std::string::npos) break;
          from = slash + 1;
        }
        if (parts.size() > 3 || (parts.size() == 2 && parts[1].empty()) ||
            (parts.size() == 3 && parts[2].empty()))
          corrupt(path, where + ": " + text::quote_value(t[i]) +
                            " is not a face vertex (v, v/vt, v//vn or v/vt/vn)");
        for (int kind = 0; kind < int(parts.size()); ++kind) {
          const std::string& part = parts[size_t(kind)];
          if (part.empty() && kind > 0) continue;
          int64_t index = 0;
          if (!text::parse_int64(part, &index) || index == 0)
            corrupt(path,
                    where + ": " + text::quote_value(t[i]) + " is not a " + kinds[kind] + " index");
          if (index < 0 && -index > counts[kind])
            corrupt(path, where + ": " + kinds[kind] + " " + std::to_string(index) +
                              " counts back past the " + std::to_string(counts[kind]) +
                              " before it");
          if (index > 0) forward.push_back({line_number, index, kind});
        }
      }
      ++faces;
    }
  }
  if (counts[0] == 0 || faces == 0)
    corrupt(path, std::string("not an OBJ mesh (no ") +
                      (counts[0] == 0 ? "vertex ('v')" : "face ('f')") + " lines)");
  for (const Forward& f : forward)
    if (f.index > counts[f.kind])
      corrupt(path, "line " + std::to_string(f.line) + ": a face uses " + kinds[f.kind] + " " +
                        std::to_string(f.index) + ", but the file has " +
                        std::to_string(counts[f.kind]));
}

// What any reader produced, checked before VTK's filters work on it: finite points, and cells
// that name existing points.
void check_poly(const std::string& path, vtkPolyData* poly) {
  const vtkIdType n = poly->GetNumberOfPoints();
  for (vtkIdType i = 0; i < n; ++i) {
    double p[3];
    poly->GetPoint(i, p);
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
      throw InputError("mesh '" + path + "': point " + std::to_string(i) +
                       " has a non-finite coordinate");
  }
  for (vtkCellArray* cells : {poly->GetPolys(), poly->GetStrips()}) {
    if (!cells) continue;
    vtkNew<vtkIdList> ids;
    cells->InitTraversal();
    while (cells->GetNextCell(ids))
      for (vtkIdType k = 0; k < ids->GetNumberOfIds(); ++k)
        if (ids->GetId(k) < 0 || ids->GetId(k) >= n)
          corrupt(path, "a cell uses point " + std::to_string(ids->GetId(k)) + " of " +
                            std::to_string(n));
  }
}

// The VTK reader of the formats sonoslice does not parse itself.
vtkSmartPointer<vtkAlgorithm> reader_for(const std::string& path, const std::string& ext) {
  if (ext == ".vtp") {
    auto r = vtkSmartPointer<vtkXMLPolyDataReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  if (ext == ".stl") {
    auto r = vtkSmartPointer<vtkSTLReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  if (ext == ".obj") {
    auto r = vtkSmartPointer<vtkOBJReader>::New();
    r->SetFileName(path.c_str());
    return r;
  }
  throw InputError("mesh '" + path + "': unknown format '" + ext +
                   "' (expected .vtk, .vtp, .stl, .obj or .ply)");
}

}  // namespace

TriangleMesh read_mesh(const std::string& path, WorldFrame frame) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw FileError(
        "cannot read mesh '" + path +
        "': " + (std::filesystem::is_directory(path, ec) ? "it is a directory" : "no such file"));
  const std::string ext = file_extension(path);
  WindowScope scope;
  vtkSmartPointer<vtkPolyData> input;
  if (ext == ".vtk") {
    input = LegacyVtkParser(path, read_whole_file(path)).parse();
  } else if (ext == ".ply") {
    PolygonSoup soup = parse_ply(path, read_whole_file(path));
    input = poly_data(soup.points, {std::move(soup.offsets), std::move(soup.connectivity)}, {});
  } else {
    auto reader = reader_for(path, ext);
    if (ext == ".stl") check_stl(path);
    if (ext == ".obj") check_obj(path);
    reader->Update();
    if (scope.window->failed())
      throw FileError("cannot read mesh '" + path + "': " + trimmed(scope.window->error_text()));
    input = vtkPolyData::SafeDownCast(reader->GetOutputDataObject(0));
    if (!input) throw FileError("cannot read mesh '" + path + "': no polygonal data");
    check_poly(path, input);
  }
  vtkNew<vtkTriangleFilter> triangles;
  triangles->SetInputData(input);
  triangles->PassVertsOff();
  triangles->PassLinesOff();
  vtkNew<vtkCleanPolyData> clean;  // merge coincident points: shared edges share vertices
  clean->SetInputConnection(triangles->GetOutputPort());
  clean->PointMergingOn();
  clean->SetTolerance(0.0);
  clean->Update();
  if (scope.window->failed())
    throw FileError("cannot read mesh '" + path + "': " + trimmed(scope.window->error_text()));
  vtkPolyData* poly = clean->GetOutput();
  TriangleMesh mesh;
  mesh.name = std::filesystem::path(path).filename().string();
  const vtkIdType np = poly->GetNumberOfPoints();
  mesh.vertices.resize(size_t(np));
  for (vtkIdType i = 0; i < np; ++i) {
    double p[3];
    poly->GetPoint(i, p);
    mesh.vertices[size_t(i)] = {p[0], p[1], p[2]};
  }
  vtkCellArray* polys = poly->GetPolys();
  vtkNew<vtkIdList> ids;
  polys->InitTraversal();
  while (polys->GetNextCell(ids)) {
    if (ids->GetNumberOfIds() != 3) continue;
    mesh.triangles.push_back(
        {int32_t(ids->GetId(0)), int32_t(ids->GetId(1)), int32_t(ids->GetId(2))});
  }
  if (mesh.triangles.empty()) {
    if (!scope.window->warnings.empty())  // what VTK said is the likelier story
      throw FileError("cannot read mesh '" + path + "': " + trimmed(scope.window->warnings));
    throw InputError("mesh '" + path + "': no triangles");
  }
  if (!scope.window->warnings.empty())
    warn("mesh '" + path + "': VTK: " + trimmed(scope.window->warnings));
  if (frame == WorldFrame::RAS) mesh.transform(pose_to_lps(Pose::identity(), WorldFrame::RAS));
  mesh.validate();
  return mesh;
}

void write_mesh(const std::string& path, const TriangleMesh& mesh) {
  mesh.validate();
  const std::string ext = file_extension(path);
  vtkNew<vtkPoints> points;
  for (const Vec3& v : mesh.vertices) points->InsertNextPoint(v[0], v[1], v[2]);
  vtkNew<vtkCellArray> cells;
  for (const auto& t : mesh.triangles) {
    const vtkIdType ids[3] = {t[0], t[1], t[2]};
    cells->InsertNextCell(3, ids);
  }
  vtkNew<vtkPolyData> poly;
  poly->SetPoints(points);
  poly->SetPolys(cells);
  AtomicFile file(path);
  WindowScope scope;
  bool ok = false;
  if (ext == ".vtk") {
    vtkNew<vtkPolyDataWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    w->SetFileTypeToBinary();
    ok = w->Write() == 1;
  } else if (ext == ".vtp") {
    vtkNew<vtkXMLPolyDataWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    ok = w->Write() == 1;
  } else if (ext == ".stl") {
    vtkNew<vtkSTLWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    w->SetFileTypeToBinary();
    ok = w->Write() == 1;
  } else if (ext == ".obj") {
    vtkNew<vtkOBJWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    ok = w->Write() == 1;
  } else if (ext == ".ply") {
    vtkNew<vtkPLYWriter> w;
    w->SetFileName(file.temp_path().c_str());
    w->SetInputData(poly);
    ok = w->Write() == 1;
  } else {
    throw InputError("mesh '" + path + "': unknown format '" + ext + "'");
  }
  if (!ok || scope.window->failed()) throw FileError("cannot write mesh '" + path + "'");
  file.commit();
}

#else

TriangleMesh read_mesh(const std::string& path, WorldFrame) {
  throw Error("mesh '" + path + "': this sonoslice was built without VTK; meshes cannot be read");
}
void write_mesh(const std::string& path, const TriangleMesh&) {
  throw Error("mesh '" + path + "': this sonoslice was built without VTK");
}

#endif

}  // namespace sonoslice
