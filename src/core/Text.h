#pragma once
// Internal: case folding for the names users type (devices, frames, modes, file fields), the
// lookup of an enum value by its spelling, and numbers as error messages quote them.
#include <cctype>
#include <cstddef>
#include <sstream>
#include <string>

namespace sonoslice {
namespace text {

inline std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

inline std::string upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

/// A number as a message quotes it: the shortest of iostream's default form (1.5, 1e+300, nan).
inline std::string number(double v) {
  std::ostringstream out;
  out << v;
  return out.str();
}

/// The value of `values` whose to_string() is `name`, or null.
template <typename E, size_t N>
const E* find_named(const E (&values)[N], const std::string& name) {
  for (const E& v : values)
    if (name == to_string(v)) return &v;
  return nullptr;
}

/// The spellings of `values` for a message: "a, b or c".
template <typename E, size_t N>
std::string spellings(const E (&values)[N]) {
  std::string out;
  for (size_t k = 0; k < N; ++k)
    out += std::string(k == 0 ? "" : (k + 1 == N ? " or " : ", ")) + to_string(values[k]);
  return out;
}

}  // namespace text
}  // namespace sonoslice
