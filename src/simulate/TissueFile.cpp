// Tissue tables as JSON (include/sonoslice/simulate/TissueFile.h), through nlohmann-json.
#include "sonoslice/simulate/TissueFile.h"

#include <algorithm>
#include <cmath>
#include <iterator>

#include "../io/JsonFile.h"

namespace sonoslice {

namespace {
std::vector<Tissue> tissues_from(const nlohmann::json& doc, const std::string& where) {
  if (!doc.is_object() || !doc.contains("tissues") || !doc["tissues"].is_array())
    throw InputError(where + ": expected an object with a \"tissues\" array");
  // A key sonoslice does not read is a typo ("impedence") that would otherwise run with a
  // default or fail later without naming it; descriptive keys (notes, a colour, any "_key") are
  // kept for the people who read the table.
  const auto descriptive = [](const std::string& key) {
    return key == "notes" || key == "comment" || key == "description" || key == "colour" ||
           key == "color" || (!key.empty() && key[0] == '_');
  };
  for (const auto& item : doc.items())
    if (item.key() != "tissues" && !descriptive(item.key()))
      throw InputError(where + ": unknown key \"" + item.key() + "\" (expected \"tissues\")");
  static const char* const kKeys[] = {
      "name",         "label",          "impedance_mrayl", "attenuation_db_cm_mhz",
      "scatter_mean", "scatter_density"};
  std::vector<Tissue> out;
  int index = 0;
  for (const nlohmann::json& e : doc["tissues"]) {
    const std::string entry = where + ": tissues[" + std::to_string(index++) + "]";
    if (!e.is_object()) throw InputError(entry + ": expected an object");
    for (const auto& item : e.items())
      if (std::find(std::begin(kKeys), std::end(kKeys), item.key()) == std::end(kKeys) &&
          !descriptive(item.key()))
        throw InputError(entry + ": unknown key \"" + item.key() +
                         "\" (expected name, label, impedance_mrayl, attenuation_db_cm_mhz, "
                         "scatter_mean, scatter_density; or notes, comment, description, "
                         "colour, _any)");
    const auto number = [&](const char* key, bool required, double fallback) {
      if (!e.contains(key)) {
        if (required) throw InputError(entry + ": missing \"" + key + "\"");
        return fallback;
      }
      const nlohmann::json& v = e[key];
      if (!v.is_number()) throw InputError(entry + ": \"" + key + "\" must be a number");
      const double d = v.get<double>();
      if (!std::isfinite(d)) throw InputError(entry + ": \"" + key + "\" must be finite");
      return d;
    };
    Tissue t;
    if (!e.contains("name") || !e["name"].is_string())
      throw InputError(entry + ": \"name\" must be a string");
    t.name = e["name"].get<std::string>();
    if (!e.contains("label") || !e["label"].is_number_integer())
      throw InputError(entry + " ('" + t.name + "'): \"label\" must be an integer");
    const int64_t label = e["label"].get<int64_t>();
    if (label < 0 || label > 65535)
      throw InputError(entry + " ('" + t.name + "'): label " + std::to_string(label) +
                       " is outside [0, 65535]");
    t.label = int(label);
    t.impedance_mrayl = number("impedance_mrayl", true, 0);
    t.attenuation_db_cm_mhz = number("attenuation_db_cm_mhz", true, 0);
    t.scatter_mean = number("scatter_mean", true, 0);
    t.scatter_density = number("scatter_density", false, 10.0);
    out.push_back(t);
  }
  validate_tissues(out, where);
  return out;
}
}  // namespace

std::vector<Tissue> read_tissue_table(const std::string& path) {
  const nlohmann::json doc = read_json_file(path, "tissues", OpenErrorReason::Append);
  return tissues_from(doc, "tissues '" + path + "'");
}

std::vector<Tissue> parse_tissue_table(const std::string& text, const std::string& where) {
  return tissues_from(parse_json(text, where), where);
}

std::string tissue_table_json(const std::vector<Tissue>& tissues) {
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (const Tissue& t : tissues) {
    nlohmann::ordered_json e;
    e["name"] = t.name;
    e["label"] = t.label;
    e["impedance_mrayl"] = t.impedance_mrayl;
    e["attenuation_db_cm_mhz"] = t.attenuation_db_cm_mhz;
    e["scatter_mean"] = t.scatter_mean;
    e["scatter_density"] = t.scatter_density;
    list.push_back(e);
  }
  nlohmann::ordered_json doc;
  doc["tissues"] = list;
  return doc.dump(2) + "\n";
}

}  // namespace sonoslice
