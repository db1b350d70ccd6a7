#include "sonoslice/surface/SurfaceConfig.h"

#include <algorithm>
#include <filesystem>

#include <nlohmann/json.hpp>

#include "../io/JsonFile.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

std::array<uint8_t, 3> default_label_color(int label) {
  // fan-slicer's LUS palette first, then well-separated hues.
  static const std::array<uint8_t, 3> palette[] = {
      {150, 0, 0},   {0, 200, 0},     {0, 120, 180}, {200, 0, 0},  {230, 160, 0},   {160, 0, 200},
      {0, 200, 200}, {255, 110, 180}, {120, 120, 0}, {90, 60, 30}, {255, 255, 255}, {80, 80, 255}};
  const int n = int(sizeof(palette) / sizeof(palette[0]));
  return palette[(std::max(label, 1) - 1) % n];
}

namespace {

std::vector<SurfaceModel> models_of(const nlohmann::json& j, const std::string& where,
                                    const std::string& mesh_dir) {
  if (!j.is_object() || !j.contains("models") || !j["models"].is_object() ||
      !j["models"].contains("files") || !j["models"]["files"].is_array())
    throw InputError(where + ": no \"models\": {\"files\": [...]} (a surface configuration)");
  const auto& files = j["models"]["files"];
  const auto sim = j.value("simulation", nlohmann::json::object());
  std::vector<bool> enabled(files.size(), true);
  if (sim.contains("simulation_models")) {
    const auto& flags = sim["simulation_models"];
    if (!flags.is_array() || flags.size() != files.size())
      throw InputError(where + ": \"simulation_models\" must have one flag per model file (" +
                       std::to_string(files.size()) + ")");
    for (size_t k = 0; k < files.size(); ++k) {
      // A flag that is not a number was read as "off" without a word.
      if (!flags[k].is_number() && !flags[k].is_boolean())
        throw InputError(where + ": \"simulation_models\"[" + std::to_string(k) +
                         "] must be 0 or 1");
      enabled[k] = flags[k].is_boolean() ? flags[k].get<bool>() : flags[k].get<double>() != 0;
    }
  }
  if (sim.contains("colors") && (!sim["colors"].is_array() || sim["colors"].size() != files.size()))
    throw InputError(where + ": \"colors\" must have one [r, g, b] per model file");
  std::vector<SurfaceModel> models;
  for (size_t k = 0; k < files.size(); ++k) {
    if (!files[k].is_string()) throw InputError(where + ": \"files\" must be names (strings)");
    if (!enabled[k]) continue;
    SurfaceModel m;
    m.name = files[k].get<std::string>();
    m.path = (std::filesystem::path(mesh_dir) / (m.name + ".vtk")).string();
    m.label = uint16_t(models.size() + 1);
    m.color = default_label_color(m.label);
    if (sim.contains("colors")) {
      const auto& c = sim["colors"][k];
      if (!c.is_array() || c.size() != 3 || !c[0].is_number() || !c[1].is_number() ||
          !c[2].is_number())
        throw InputError(where + ": colour of '" + m.name + "' must be [r, g, b] (numbers)");
      for (int i = 0; i < 3; ++i)
        m.color[size_t(i)] = uint8_t(std::clamp(c[size_t(i)].get<double>(), 0.0, 255.0));
    }
    std::error_code ec;
    if (!std::filesystem::is_regular_file(m.path, ec))
      throw FileError(where + ": mesh '" + m.path + "' not found (listed in the config's models)");
    models.push_back(m);
  }
  if (models.empty()) throw InputError(where + ": no model is enabled in \"simulation_models\"");
  return models;
}

}  // namespace

std::vector<SurfaceModel> read_fanslicer_models(const std::string& config_path,
                                                const std::string& mesh_dir) {
  const nlohmann::json j = read_json_file(config_path, "fan-slicer config");
  const std::string where = "fan-slicer config '" + config_path + "'";
  return with_json_errors_named(where, [&] { return models_of(j, where, mesh_dir); });
}

}  // namespace sonoslice
