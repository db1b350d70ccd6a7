#include "sonoslice/core/Interpolation.h"

#include "Text.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

const char* to_string(Interpolation interpolation) {
  switch (interpolation) {
    case Interpolation::Linear:
      return "linear";
    case Interpolation::Nearest:
      return "nearest";
  }
  return "?";
}

Interpolation parse_interpolation(const std::string& name, const std::string& what) {
  const std::string n = text::lower(name);
  if (n == "linear" || n == "trilinear") return Interpolation::Linear;
  if (n == "nearest" || n == "nearest_neighbor" || n == "nn") return Interpolation::Nearest;
  throw InputError(what + " '" + name + "': expected linear or nearest");
}

}  // namespace sonoslice
