#pragma once
// Internal: case folding for the names users type (devices, frames, modes, file fields).
#include <cctype>
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

}  // namespace text
}  // namespace sonoslice
