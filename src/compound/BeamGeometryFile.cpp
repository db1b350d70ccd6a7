#include "sonoslice/compound/BeamGeometryFile.h"

#include <nlohmann/json.hpp>

#include "../io/JsonFile.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"

namespace sonoslice {

namespace {
struct Key {
  const char* name;
  double BeamGeometry::*field;
  bool required;
};
constexpr Key kKeys[] = {
    {"r0_mm", &BeamGeometry::r0_mm, true},
    {"dr_mm", &BeamGeometry::dr_mm, true},
    {"azimuth0_deg", &BeamGeometry::azimuth0_deg, true},
    {"dazimuth_deg", &BeamGeometry::dazimuth_deg, true},
    {"elevation0_deg", &BeamGeometry::elevation0_deg, true},
    {"delevation_deg", &BeamGeometry::delevation_deg, true},
    {"apex_offset_mm", &BeamGeometry::apex_offset_mm, false},
};
}  // namespace

BeamGeometry read_beam_geometry(const std::string& path) {
  nlohmann::json root = read_json_file(path, "beam geometry", OpenErrorReason::Append);
  if (!root.is_object()) throw InputError("beam geometry '" + path + "': expected a JSON object");
  BeamGeometry g;
  for (auto it = root.begin(); it != root.end(); ++it) {
    const Key* key = nullptr;
    for (const Key& k : kKeys)
      if (it.key() == k.name) key = &k;
    if (!key) {
      std::string known;
      for (const Key& k : kKeys) known += std::string(known.empty() ? "" : ", ") + k.name;
      throw InputError("beam geometry '" + path + "': unknown key '" + it.key() +
                       "' (known: " + known + ")");
    }
    if (!it->is_number())
      throw InputError("beam geometry '" + path + "': '" + it.key() + "' must be a number");
    g.*(key->field) = it->get<double>();
  }
  for (const Key& k : kKeys)
    if (k.required && !root.contains(k.name))
      throw InputError("beam geometry '" + path + "': missing '" + k.name + "'");
  return g;
}

void write_beam_geometry(const std::string& path, const BeamGeometry& geometry) {
  nlohmann::json root;
  for (const Key& k : kKeys) root[k.name] = geometry.*(k.field);
  write_text_file(path, root.dump(2) + "\n");
}

}  // namespace sonoslice
