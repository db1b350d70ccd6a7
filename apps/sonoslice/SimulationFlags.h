#pragma once
// The flags of a simulation (source, tissues, probe, settings) that `sonoslice simulate` and
// `sonoslice live simulate` share, and what they read.
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "Common.h"
#include "sonoslice/simulate/Simulator.h"

namespace sonoslice {
namespace cli {

struct SimulateFlags {
  VolumeFlags volume;
  std::string labels, tissues;
  std::vector<std::string> meshes;
  std::optional<double> voxel_size;
  std::string probe, poses, out, mask, world = "LPS";
  int downsampling = 1;
  // The simulation settings the user gave; the library has the defaults (SimulationSettings).
  std::string preset, device, tgc, output;
  std::optional<double> frequency, dynamic_range;
  std::optional<uint64_t> seed;
  std::optional<int> threads;
  bool quiet = false, verbose = false, list_presets = false, print_tissues = false;
};

/// The source, tissue, probe and setting flags (not the batch's --poses, --out, --mask).
void add_simulation_flags(CLI::App& cmd, SimulateFlags& flags);
/// The flag of a simulation setting.
std::string simulate_flag(const std::string& setting);
/// The settings the flags give, resolved: unset flags keep the library's defaults.
SimulationSettings settings_of(const SimulateFlags& flags);
/// The checks that need no file: one source, tissues where they apply, a probe or a preset
/// (UsageError / InputError naming the flags; `command` starts usage messages).
void check_simulation_flags(const SimulateFlags& flags, const std::string& command);
/// --probe at --downsampling; std::nullopt: the preset's probe.
std::optional<ProbeGeometry> probe_of(const SimulateFlags& flags);
/// --tissues, else the default table.
std::vector<Tissue> tissues_of(const SimulateFlags& flags);

/// The volume the flags name: a CT (HU), labels, or meshes voxelised at --voxel-size.
struct SimulationInput {
  Volume volume;
  SimulationSource source = SimulationSource::Labels;
  std::string description;
};
SimulationInput read_simulation_input(const SimulateFlags& flags);
/// The simulator of `input`; a label the tissue table lacks is named with the table's file (or
/// the default table) and the input that holds it.
Simulator simulator_of(const SimulateFlags& flags, const SimulationInput& input,
                       const std::optional<ProbeGeometry>& probe,
                       const std::vector<Tissue>& tissues, const SimulationSettings& settings);

}  // namespace cli
}  // namespace sonoslice
