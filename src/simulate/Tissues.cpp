// The default tissue table and the CT (Hounsfield unit) → acoustic property knots of
// docs/simulation.md §1; the simulation's settings: their spelling, checks and defaults.
#include <cmath>
#include <set>
#include <utility>

#include "../core/Text.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/simulate/Simulator.h"

namespace sonoslice {

std::vector<Tissue> default_tissues() {
  // name, label, Z (MRayl), α (dB/cm/MHz), scatter mean, scatter density. Z and α: the values
  // tabulated in Szabo, Diagnostic Ultrasound Imaging: Inside Out (2nd ed., 2014), appendix B,
  // and Duck, Physical Properties of Tissue (1990), rounded (docs/simulation.md §1 lists them
  // with the ranges those books give). Scatter means are this model's relative echogenicities
  // (dB below an ideal reflector), chosen so that a default B-mode image ranks the tissues as
  // clinical images do; they are not measured quantities.
  return {
      {"water", 1, 1.48, 0.0022, 0.0, 10.0},       {"blood", 2, 1.61, 0.18, 0.002, 10.0},
      {"fat", 3, 1.38, 0.48, 0.012, 10.0},         {"liver", 4, 1.65, 0.50, 0.025, 10.0},
      {"kidney", 5, 1.62, 1.00, 0.020, 10.0},      {"muscle", 6, 1.70, 1.09, 0.018, 10.0},
      {"soft tissue", 7, 1.63, 0.54, 0.020, 10.0}, {"vessel wall", 8, 1.68, 0.90, 0.040, 10.0},
      {"bone", 9, 7.80, 20.0, 0.050, 10.0},        {"gas", 10, 0.0004, 12.0, 0.0, 10.0},
  };
}

namespace {
struct Knot {
  double hu, z, alpha, scatter;
};
// Piecewise linear in HU. Gas up to −400 HU (lung and bowel gas with partial volume), fat at
// −100, water at 0, blood at 20, soft tissue and liver at 40–60, a bone ramp from 300 (cancellous)
// to 1900 HU (cortical). Values are those of the default table's tissues.
constexpr Knot kKnots[] = {
    {-1000, 0.0004, 12.0, 0.0}, {-400, 0.0004, 12.0, 0.0}, {-100, 1.38, 0.48, 0.012},
    {0, 1.48, 0.0022, 0.0},     {20, 1.61, 0.18, 0.002},   {40, 1.63, 0.54, 0.020},
    {60, 1.65, 0.50, 0.025},    {300, 1.70, 1.09, 0.030},  {1900, 7.80, 20.0, 0.050},
};
}  // namespace

Tissue tissue_from_hu(double hu) {
  constexpr int n = int(sizeof(kKnots) / sizeof(kKnots[0]));
  Tissue t;
  t.name.clear();
  t.label = 0;
  const Knot* k = kKnots;
  if (!(hu > k[0].hu)) {  // NaN too
    t.impedance_mrayl = k[0].z;
    t.attenuation_db_cm_mhz = k[0].alpha;
    t.scatter_mean = k[0].scatter;
    return t;
  }
  for (int i = 1; i < n; ++i) {
    if (hu <= k[i].hu) {
      const double w = (hu - k[i - 1].hu) / (k[i].hu - k[i - 1].hu);
      t.impedance_mrayl = k[i - 1].z + w * (k[i].z - k[i - 1].z);
      t.attenuation_db_cm_mhz = k[i - 1].alpha + w * (k[i].alpha - k[i - 1].alpha);
      t.scatter_mean = k[i - 1].scatter + w * (k[i].scatter - k[i - 1].scatter);
      return t;
    }
  }
  t.impedance_mrayl = k[n - 1].z;
  t.attenuation_db_cm_mhz = k[n - 1].alpha;
  t.scatter_mean = k[n - 1].scatter;
  return t;
}

void validate_tissues(const std::vector<Tissue>& tissues, const std::string& what) {
  if (tissues.empty()) throw InputError(what + ": the tissue table is empty");
  std::set<int> labels;
  for (const Tissue& t : tissues) {
    const std::string name =
        what + ": tissue '" + t.name + "' (label " + std::to_string(t.label) + ")";
    if (t.label < 0 || t.label > 65535)
      throw InputError(name + ": the label must be in [0, 65535]");
    if (!labels.insert(t.label).second)
      throw InputError(what + ": label " + std::to_string(t.label) + " is listed twice");
    // The upper bounds lie far beyond any material (tungsten: 100 MRayl; lung: 40 dB/cm/MHz;
    // a reflection's amplitude: at most 1): a value past them is a typo or a unit mistake.
    const auto check = [&](double value, bool above_zero, double most, const char* key) {
      if (!(above_zero ? value > 0 : value >= 0) || !(value <= most))
        throw InputError(name + ": " + key + " " + text::number(value) + " must be " +
                         (above_zero ? "> 0" : ">= 0") + " and <= " + text::number(most));
    };
    check(t.impedance_mrayl, true, 1000, "impedance_mrayl");
    check(t.attenuation_db_cm_mhz, false, 1000, "attenuation_db_cm_mhz");
    check(t.scatter_mean, false, 1000, "scatter_mean");
    check(t.scatter_density, true, 1e6, "scatter_density");
  }
}

const char* to_string(SimulationSource source) {
  switch (source) {
    case SimulationSource::HounsfieldUnits:
      return "ct";
    case SimulationSource::Labels:
      return "labels";
  }
  return "?";
}

SimulationSource parse_simulation_source(const std::string& name, const std::string& what) {
  if (const auto* s = text::find_named(kSimulationSources, name)) return *s;
  throw InputError(what + " " + name + ": expected " + text::spellings(kSimulationSources));
}

SimulationSource default_simulation_source(const Volume& volume, bool tissue_table_given) {
  return tissue_table_given || volume.pixel_type() == PixelType::UInt8
             ? SimulationSource::Labels
             : SimulationSource::HounsfieldUnits;
}

const char* to_string(SimulationOutput output) {
  switch (output) {
    case SimulationOutput::BMode:
      return "bmode";
    case SimulationOutput::Envelope:
      return "envelope";
  }
  return "?";
}

SimulationOutput parse_simulation_output(const std::string& name, const std::string& what) {
  if (const auto* o = text::find_named(kSimulationOutputs, name)) return *o;
  throw InputError(what + " " + name + ": expected " + text::spellings(kSimulationOutputs));
}

void SimulationSettings::validate(const ParameterNames& names) const {
  const auto name = [&](const char* setting) { return spelled(names, setting); };
  if (preset) simulation_preset(*preset, name("preset"));
  // Medical ultrasound spans about 1 to 70 MHz; a dynamic range beyond 200 dB exceeds what any
  // echo (or double arithmetic's log compression of it) holds: both bounds catch typos.
  if (frequency_mhz && !(*frequency_mhz >= 0.1 && *frequency_mhz <= 100))
    throw InputError(name("frequency_mhz") + ": frequency " + text::number(*frequency_mhz) +
                     " MHz must be in [0.1, 100]");
  if (!(dynamic_range_db > 0 && dynamic_range_db <= 200))
    throw InputError(name("dynamic_range_db") + ": dynamic range " +
                     text::number(dynamic_range_db) + " dB must be in (0, 200]");
  for (const auto& [setting, w] : {std::pair<const char*, double>{"axial_fwhm_mm", axial_fwhm_mm},
                                   {"lateral_fwhm_mm", lateral_fwhm_mm},
                                   {"elevation_fwhm_mm", elevation_fwhm_mm}})
    if (!(w >= 0) || !std::isfinite(w))
      throw InputError(name(setting) + ": point-spread width " + text::number(w) +
                       " mm must be >= 0");
}

SimulationSettings SimulationSettings::resolved(const ParameterNames& names) const {
  validate(names);
  SimulationSettings s = *this;
  if (!s.frequency_mhz)
    s.frequency_mhz = preset ? simulation_preset(*preset).frequency_mhz : kDefaultFrequencyMhz;
  return s;
}

}  // namespace sonoslice
