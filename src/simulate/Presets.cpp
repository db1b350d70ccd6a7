// The simulation presets (docs/simulation.md §7).
#include "sonoslice/core/Error.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/simulate/Simulator.h"

namespace sonoslice {

std::vector<SimulationPreset> simulation_presets() {
  std::vector<SimulationPreset> out;
  {
    // A convex abdominal probe: 60° sector, 50 mm radius, 160 mm deep, at 0.4 mm pixels.
    SimulationPreset p;
    p.name = "abdominal";
    p.description = "3.5 MHz curvilinear, 60 deg sector, R 50 mm, 160 mm deep, 528x420 at 0.4 mm";
    p.frequency_mhz = 3.5;
    p.probe = ProbeGeometry::curvilinear(50, 160, 60, ImageGrid::centred(528, 420, 0.4, 0.4));
    out.push_back(p);
  }
  {
    // A laparoscopic linear probe: 40 mm wide, 60 mm deep, at 0.125 mm pixels.
    SimulationPreset p;
    p.name = "laparoscopic";
    p.description = "7.5 MHz linear, 40 mm wide, 60 mm deep, 320x480 at 0.125 mm";
    p.frequency_mhz = 7.5;
    p.probe = ProbeGeometry::linear(ImageGrid::centred(320, 480, 0.125, 0.125));
    out.push_back(p);
  }
  {
    SimulationPreset p;
    p.name = "lus";
    p.description =
        "6.5 MHz, fan-slicer's models_intensity_LUS_config.json at downsampling 2 (W1: 334x272, "
        "36 deg, R 46.93 mm, 64.96 mm deep)";
    p.frequency_mhz = 6.5;
    p.probe = workload_w1_fan_probe();
    out.push_back(p);
  }
  return out;
}

SimulationPreset simulation_preset(const std::string& name, const std::string& what) {
  std::string names;
  for (const SimulationPreset& p : simulation_presets()) {
    if (p.name == name) return p;
    names += (names.empty() ? "" : ", ") + p.name;
  }
  throw InputError(what + " " + name + ": unknown (presets: " + names + ")");
}

}  // namespace sonoslice
