#pragma once
/// @file fan-slicer surface configurations, accepted unchanged: which meshes to simulate, their
/// labels and display colours.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace sonoslice {

struct SurfaceModel {
  std::string name;                ///< as in the config ("hepatic veins")
  std::string path;                ///< mesh_dir/<name>.vtk
  uint16_t label = 0;              ///< the k-th enabled model is label k (1-based), as fan-slicer
  std::array<uint8_t, 3> color{};  ///< RGB for colour images
};

/// The enabled models of a fan-slicer configuration ("models": {"files": [...]},
/// "simulation": {"simulation_models": [0/1 ...], "colors": [[r, g, b] ...]}), resolved to
/// `mesh_dir`/<name>.vtk (names may contain spaces). Errors name the file and the key.
std::vector<SurfaceModel> read_fanslicer_models(const std::string& config_path,
                                                const std::string& mesh_dir);

/// A distinct colour for label k when no configuration gives one.
std::array<uint8_t, 3> default_label_color(int label);

}  // namespace sonoslice
