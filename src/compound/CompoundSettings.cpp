// The compounding settings' spellings (to_string / parse beside each enum) and the checks of
// the hole-filling elements.
#include "sonoslice/compound/CompoundSettings.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <string>

#include "../core/Text.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

const char* to_string(CompoundingMode mode) {
  switch (mode) {
    case CompoundingMode::Mean:
      return "mean";
    case CompoundingMode::Max:
      return "max";
    case CompoundingMode::Latest:
      return "latest";
  }
  return "?";
}

const char* to_string(HoleFillingKernel::Type type) {
  switch (type) {
    case HoleFillingKernel::NearestNeighbor:
      return "nearest_neighbor";
    case HoleFillingKernel::Gaussian:
      return "gaussian";
    case HoleFillingKernel::GaussianAccumulation:
      return "gaussian_accumulation";
    case HoleFillingKernel::DistanceWeightInverse:
      return "distance_weight_inverse";
    case HoleFillingKernel::Stick:
      return "stick";
  }
  return "?";
}

CompoundingMode parse_compounding_mode(const std::string& name) {
  const std::string n = text::lower(name);
  if (n == "mean") return CompoundingMode::Mean;
  if (n == "max" || n == "maximum") return CompoundingMode::Max;
  if (n == "latest") return CompoundingMode::Latest;
  throw InputError("compounding mode '" + name + "': expected mean, max or latest");
}

PlusOptimization parse_plus_optimization(const std::string& name, const std::string& what) {
  const std::string n = text::lower(name);
  if (n == "full") return PlusOptimization::Full;
  if (n == "partial") return PlusOptimization::Partial;
  if (n == "none") return PlusOptimization::None;
  if (n == "gpu")
    throw InputError(what + " \"" + name +
                     "\": PLUS's GPU (OpenCL) path is not reproduced (PLUS-exact follows NONE, "
                     "PARTIAL or FULL)");
  throw InputError(what + " \"" + name + "\": not one of NONE, PARTIAL, FULL");
}

std::string plus_hole_filling_names() {
  std::string out;
  const size_t n = std::size(kHoleFillingTypes);
  for (size_t k = 0; k < n; ++k)
    out += (k == 0       ? ""
            : k + 1 == n ? " or "
                         : ", ") +
           text::upper(to_string(kHoleFillingTypes[k]));
  return out;
}

HoleFillingKernel::Type parse_hole_filling_type(const std::string& name) {
  const std::string n = text::lower(name);
  if (n == "nearest") return HoleFillingKernel::NearestNeighbor;
  if (const HoleFillingKernel::Type* t = text::find_named(kHoleFillingTypes, n)) return *t;
  throw InputError("hole filling type '" + name + "': expected " + plus_hole_filling_names());
}

void HoleFillingKernel::validate(const std::string& what) const {
  if (type == Stick) {
    if (stick_length_limit < 3 || stick_length_limit > 255)
      throw InputError(what + ": stick_length_limit " + std::to_string(stick_length_limit) +
                       " must be between 3 and 255 voxels");
    if (sticks_to_use < 1 || sticks_to_use > 13)
      throw InputError(what + ": sticks_to_use " + std::to_string(sticks_to_use) +
                       " must be between 1 and 13");
    return;
  }
  if (size < 3 || size > 31 || size % 2 == 0)
    throw InputError(what + ": size " + std::to_string(size) + " must be odd, 3 to 31 voxels");
  if ((type == Gaussian || type == GaussianAccumulation) && !(stdev > 0 && std::isfinite(stdev)))
    throw InputError(what + ": stdev (the Gaussian's, in voxels) must be positive");
  if (!(minimum_known_ratio >= 0 && minimum_known_ratio < 1))
    throw InputError(what + ": minimum_known_ratio must be in [0, 1)");
}

}  // namespace sonoslice
