#include "sonoslice/io/PoseFile.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>

#include <nlohmann/json.hpp>

#include "../core/Text.h"
#include "JsonFile.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/Npy.h"

namespace sonoslice {
namespace {

std::string lower_extension(const std::string& path) {
  const size_t dot = path.find_last_of('.');
  const size_t slash = path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  return text::lower(path.substr(dot));
}

std::string shape_string(const std::vector<int64_t>& shape) {
  std::ostringstream s;
  s << "(";
  for (size_t i = 0; i < shape.size(); ++i) s << (i ? ", " : "") << shape[i];
  s << (shape.size() == 1 ? ",)" : ")");
  return s.str();
}

// A 4x4 (16 numbers) or 3x4 (12, last row 0 0 0 1) row-major matrix.
Mat4 matrix_from_row_major(const std::vector<double>& values) {
  Mat4 m;
  for (size_t i = 0; i < values.size(); ++i) m.m[i / 4][i % 4] = values[i];
  return m;
}

std::vector<Pose> poses_from_npy(const std::string& path, const std::string& what) {
  const NpyArray a = read_npy(path);
  if (a.type != PixelType::Float32 && a.type != PixelType::Float64)
    throw InputError(what + " '" + path + "': dtype " + to_string(a.type) +
                     " (expected float32 or float64)");
  // Element (r, c) of pose n, honouring C or Fortran order.
  const std::vector<int64_t> strides = npy_element_strides(a);
  auto value = [&](int64_t offset) {
    return a.type == PixelType::Float64 ? static_cast<const double*>(a.data.get())[offset]
                                        : double(static_cast<const float*>(a.data.get())[offset]);
  };
  std::vector<Pose> poses;
  if (a.shape.size() == 3 && a.shape[1] == 4 && a.shape[2] == 4) {
    for (int64_t n = 0; n < a.shape[0]; ++n) {
      Pose p;
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
          p.m[r][c] = value(n * strides[0] + r * strides[1] + c * strides[2]);
      poses.push_back(p);
    }
  } else if (a.shape.size() == 2 && a.shape[0] == 4 && a.shape[1] % 4 == 0) {
    // fan-slicer's strip: pose n is columns 4n..4n+3.
    for (int64_t n = 0; n < a.shape[1] / 4; ++n) {
      Pose p;
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) p.m[r][c] = value(r * strides[0] + (4 * n + c) * strides[1]);
      poses.push_back(p);
    }
  } else {
    throw InputError(what + " '" + path + "': shape " + shape_string(a.shape) +
                     " (expected (N, 4, 4) or fan-slicer's (4, 4N))");
  }
  return poses;
}

std::vector<Pose> poses_from_text(const std::string& path, const std::string& what) {
  std::ifstream in(path);
  if (!in) throw FileError("cannot open " + what + " '" + path + "': " + std::strerror(errno));
  std::vector<Pose> poses;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    std::replace_if(
        line.begin(), line.end(), [](char c) { return c == ',' || c == '\t' || c == ';'; }, ' ');
    std::vector<double> values;
    const char* p = line.c_str();
    while (true) {
      while (*p && std::isspace(static_cast<unsigned char>(*p))) ++p;
      if (!*p) break;
      char* end = nullptr;
      const double v = std::strtod(p, &end);
      if (end == p) {
        std::string token(p);
        token = token.substr(0, token.find(' '));
        throw InputError(what + " '" + path + "': line " + std::to_string(line_number) + ": '" +
                         token + "' is not a number");
      }
      values.push_back(v);
      p = end;
    }
    if (values.empty()) continue;
    if (values.size() != 16 && values.size() != 12)
      throw InputError(what + " '" + path + "': line " + std::to_string(line_number) + " has " +
                       std::to_string(values.size()) +
                       " numbers (expected 16 for a 4x4 or 12 for a 3x4 row-major matrix)");
    poses.push_back(matrix_from_row_major(values));
  }
  return poses;
}

std::vector<Pose> poses_from_json(const std::string& path, const std::string& what) {
  nlohmann::json root = read_json_file(path, what, OpenErrorReason::Append);
  if (!root.is_object() || !root.contains("poses") || !root["poses"].is_array())
    throw InputError(what + " '" + path + "': expected {\"poses\": [[16 numbers], ...]}");
  for (auto it = root.begin(); it != root.end(); ++it)
    if (it.key() != "poses")
      throw InputError(what + " '" + path + "': unknown key '" + it.key() + "'");
  std::vector<Pose> poses;
  for (const auto& entry : root["poses"]) {
    const std::string where = what + " '" + path + "': pose " + std::to_string(poses.size());
    std::vector<double> values;
    auto take = [&](const nlohmann::json& v) {
      if (!v.is_number()) throw InputError(where + ": entries must be numbers");
      values.push_back(v.get<double>());
    };
    if (!entry.is_array()) throw InputError(where + ": expected a list of 16 numbers");
    for (const auto& e : entry) {
      if (e.is_array())  // nested 4×4
        for (const auto& v : e) take(v);
      else
        take(e);
    }
    if (values.size() != 16) throw InputError(where + ": expected 16 numbers (a 4x4 matrix)");
    poses.push_back(Mat4::from_row_major(values.data()));
  }
  return poses;
}

// Matrices from a pose file; errors call the file `what` ("poses", "--image-to-probe").
std::vector<Mat4> matrices_from_file(const std::string& path, const std::string& what) {
  const std::string ext = lower_extension(path);
  std::vector<Mat4> matrices;
  if (ext == ".npy")
    matrices = poses_from_npy(path, what);
  else if (ext == ".txt" || ext == ".csv")
    matrices = poses_from_text(path, what);
  else if (ext == ".json")
    matrices = poses_from_json(path, what);
  else
    throw InputError(what + " '" + path +
                     "': unknown extension (expected .npy, .txt, .csv or .json)");
  if (matrices.empty()) throw InputError(what + " '" + path + "': no poses in the file");
  return matrices;
}

}  // namespace

std::vector<Mat4> read_matrices(const std::string& path) {
  return matrices_from_file(path, "poses");
}

Mat4 read_matrix(const std::string& text, const std::string& what) {
  // 16 (or 12) numbers separated by commas or spaces, else a file holding one matrix.
  std::string t = text;
  std::replace_if(
      t.begin(), t.end(), [](char c) { return c == ',' || c == ';' || c == '\t'; }, ' ');
  std::istringstream in(t);
  std::vector<double> values;
  double v;
  while (in >> v) values.push_back(v);
  // operator>> never yields inf or nan, so these numbers are finite.
  if (in.eof() && (values.size() == 16 || values.size() == 12))
    return matrix_from_row_major(values);
  // Numbers only, but not 12 or 16 of them: a miscounted matrix, not a file name.
  if (in.eof() && !values.empty())
    throw InputError(what + " '" + text + "': " + std::to_string(values.size()) +
                     " numbers (expected 16 for a 4x4 or 12 for a 3x4 matrix, row by row)");
  std::error_code ec;
  if (!std::filesystem::exists(text, ec))
    throw InputError(what + " '" + text +
                     "': neither 16 (or 12) numbers nor an existing matrix file");
  const std::vector<Mat4> m = matrices_from_file(text, what);
  if (m.size() != 1)
    throw InputError(what + " '" + text + "': expected one 4x4 matrix, the file has " +
                     std::to_string(m.size()));
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      if (!std::isfinite(m[0].m[r][c]))
        throw InputError(what + " '" + text + "': non-finite matrix element");
  return m[0];
}

std::vector<Pose> read_poses(const std::string& path, WorldFrame frame, bool warn_non_orthonormal) {
  std::vector<Pose> poses = read_matrices(path);
  for (Pose& p : poses) p = pose_to_lps(p, frame);
  validate_poses(poses.data(), poses.size(), "poses '" + path + "'", 0, warn_non_orthonormal);
  return poses;
}

namespace {
// What is written must read back: poses the readers would refuse are refused here.
void check_poses_to_write(const std::string& path, const std::vector<Pose>& poses) {
  validate_poses(poses.data(), poses.size(), "poses for '" + path + "'", 0, false);
}
}  // namespace

void write_poses_text(const std::string& path, const std::vector<Pose>& poses) {
  check_poses_to_write(path, poses);
  std::ostringstream out;
  out << "# sonoslice poses: one 4x4 probe-to-world (LPS, mm) matrix per line, row-major\n";
  out << std::setprecision(17);
  for (const Pose& p : poses) {
    for (int i = 0; i < 16; ++i) out << (i ? " " : "") << p.m[i / 4][i % 4];
    out << "\n";
  }
  write_text_file(path, out.str());
}

void write_poses_npy(const std::string& path, const std::vector<Pose>& poses) {
  check_poses_to_write(path, poses);
  std::vector<double> flat;
  flat.reserve(poses.size() * 16);
  for (const Pose& p : poses)
    for (int i = 0; i < 16; ++i) flat.push_back(p.m[i / 4][i % 4]);
  write_npy(path, PixelType::Float64, {int64_t(poses.size()), 4, 4}, flat.data());
}

}  // namespace sonoslice
