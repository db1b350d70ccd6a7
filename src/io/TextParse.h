#pragma once
// Internal: the small string and number helpers the text-based readers share (PLUS sequence
// headers and configuration XML attributes), and the tidying of ITK/VTK messages. Numbers must
// use the whole token; errors are the caller's, which knows the file and the field.
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "../core/Text.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {
namespace text {

inline std::string trim(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return s.substr(b, e - b);
}

inline bool iequals(const std::string& a, const std::string& b) {
  return lower(a) == lower(b);
}

inline bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

/// Natural order of names: runs of digits compare as numbers ("frame2" before "frame10"),
/// everything else byte by byte; names equal that way ("img_7", "img_007") fall back to plain
/// byte order, so the order is total.
inline bool natural_less(const std::string& a, const std::string& b) {
  const auto digit = [](char c) { return c >= '0' && c <= '9'; };
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (digit(a[i]) && digit(b[j])) {
      size_t ie = i, je = j;
      while (ie < a.size() && digit(a[ie])) ++ie;
      while (je < b.size() && digit(b[je])) ++je;
      size_t is = i, js = j;  // without leading zeros: the longer number is the larger
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      if (ie - is != je - js) return ie - is < je - js;
      const int c = a.compare(is, ie - is, b, js, je - js);
      if (c != 0) return c < 0;
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
      ++i;
      ++j;
    }
  }
  if ((i < a.size()) != (j < b.size())) return j < b.size();
  return a < b;
}

inline std::vector<std::string> split_ws(const std::string& s) {
  std::vector<std::string> out;
  std::istringstream in(s);
  std::string token;
  while (in >> token) out.push_back(token);
  return out;
}

/// A multi-line ITK/VTK message as one line: newlines become spaces, trailing spaces go. With
/// `drop_location`, everything up to the first "): " goes first
/// ("ERROR: In /path/x.cxx, line N\nClass (0x...): message" → "message").
inline std::string one_line_message(std::string s, bool drop_location = false) {
  if (drop_location) {
    const size_t colon = s.find("): ");
    if (colon != std::string::npos) s = s.substr(colon + 3);
  }
  for (char& c : s)
    if (c == '\n') c = ' ';
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

/// A value quoted for an error message, shortened when long. Bytes outside printable ASCII
/// become '?': the value may come from a binary or corrupt file, and a message must stay one line
/// of valid text (Python decodes it as UTF-8).
inline std::string quote_value(const std::string& s) {
  std::string shown = s.size() > 120 ? s.substr(0, 117) + "..." : s;
  for (char& c : shown)
    if (c < 0x20 || c > 0x7e) c = '?';
  return "'" + shown + "'";
}

/// A decimal number, the whole token: strtod alone would also take leading blanks and C's hex
/// floats ("0x10" as 16), which no file format or query of ours means.
inline bool parse_double(const std::string& token, double* out) {
  if (token.empty() || std::isspace(static_cast<unsigned char>(token[0])) ||
      token.find_first_of("xX") != std::string::npos)
    return false;
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(token.c_str(), &end);  // underflow to 0 is fine, overflow is not
  if (end != token.c_str() + token.size() || !std::isfinite(v)) return false;
  *out = v;
  return true;
}

/// Numbers separated by commas, blanks around each allowed ("1, 2.5,-3"): every value, or false
/// at the first item that is not one parse_double takes, so "1,,2" and "1,2," are refused rather
/// than read as fewer numbers.
inline bool parse_number_list(const std::string& text, std::vector<double>* values) {
  values->clear();
  for (size_t at = 0;;) {
    const size_t comma = std::min(text.find(',', at), text.size());
    double value = 0;
    if (!parse_double(trim(text.substr(at, comma - at)), &value)) return false;
    values->push_back(value);
    if (comma == text.size()) return true;
    at = comma + 1;
  }
}

inline bool parse_int64(const std::string& token, int64_t* out) {
  if (token.empty() || std::isspace(static_cast<unsigned char>(token[0]))) return false;
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(token.c_str(), &end, 10);
  if (end != token.c_str() + token.size() || errno == ERANGE) return false;
  *out = v;
  return true;
}

inline bool parse_int(const std::string& token, int* out) {
  int64_t v = 0;
  if (!parse_int64(token, &v) || v < -2147483647LL || v > 2147483647LL) return false;
  *out = static_cast<int>(v);
  return true;
}

/// 16 whitespace-separated numbers, row-major.
inline bool parse_matrix16(const std::string& text, Mat4* m) {
  const std::vector<std::string> tokens = split_ws(text);
  if (tokens.size() != 16) return false;
  double v[16];
  for (int i = 0; i < 16; ++i)
    if (!parse_double(tokens[i], &v[i])) return false;
  *m = Mat4::from_row_major(v);
  return true;
}

/// parse_matrix16's text of `m`: 16 numbers, row-major, each to 17 significant digits (read back
/// exactly), as PLUS writes a sequence's transforms.
inline std::string format_matrix16(const Mat4& m) {
  std::string s;
  char b[40];
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      std::snprintf(b, sizeof(b), "%.17g", m.m[r][c]);
      if (!s.empty()) s += ' ';
      s += b;
    }
  return s;
}

}  // namespace text
}  // namespace sonoslice
