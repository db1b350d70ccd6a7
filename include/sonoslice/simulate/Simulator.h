#pragma once
/// @file Ultrasound simulation: B-mode-like images from a CT in Hounsfield
/// units or from a label volume with a tissue table, batched over probe poses, on the CPU.
/// Deterministic: the same seed and pose give the same bytes on any number of threads.
/// The model, its formulas and its constants are in docs/simulation.md.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// Acoustic properties of one tissue (one label of a label volume).
struct Tissue {
  std::string name;                    ///< lower case: "liver", "soft tissue", ...
  int label = 0;                       ///< the label value in a label volume (0..65535)
  double impedance_mrayl = 1.63;       ///< acoustic impedance Z (MRayl = 1e6 kg/(m²·s))
  double attenuation_db_cm_mhz = 0.5;  ///< α: amplitude attenuation, dB per cm per MHz
  double scatter_mean = 0.0;      ///< mean diffuse-scatter amplitude (linear, 1 = a full reflector)
  double scatter_density = 10.0;  ///< scatterers per resolution cell (10 and more: fully developed)
};

/// A label the label volume holds and the tissue table lacks. Front ends that know where the
/// table and the labels came from (the CLI's files) reword it from label().
class UnlistedLabelError : public InputError {
 public:
  explicit UnlistedLabelError(int label)
      : InputError("tissues: the label volume holds label " + std::to_string(label) +
                   ", which the tissue table does not list"),
        label_(label) {}
  int label() const { return label_; }

 private:
  int label_;
};

/// The default table (water, blood, fat, liver, kidney, muscle, soft tissue, vessel wall, bone,
/// gas; labels 1..10), with the literature values docs/simulation.md cites.
std::vector<Tissue> default_tissues();

/// The properties a CT voxel of `hu` Hounsfield units gets: piecewise-linear between the knots
/// of docs/simulation.md §1 (gas below about −400 HU, fat, water/blood, soft tissue, a bone ramp
/// above about 300 HU). The name is empty and the label 0.
Tissue tissue_from_hu(double hu);

/// Throws InputError naming `what` for an empty table, a repeated label, a label outside
/// [0, 65535], or a non-positive or non-finite impedance, a negative or non-finite attenuation,
/// scatter mean or density.
void validate_tissues(const std::vector<Tissue>& tissues, const std::string& what);

enum class SimulationSource {
  HounsfieldUnits,  ///< a CT: any pixel type, values in HU, trilinear
  Labels            ///< a uint8/uint16 label volume, nearest, properties from the tissue table
};
/// Every source, in the order of its spelling table.
inline constexpr SimulationSource kSimulationSources[] = {SimulationSource::HounsfieldUnits,
                                                          SimulationSource::Labels};
/// "ct", "labels" (Python's kind=).
const char* to_string(SimulationSource source);
/// InputError "<what> <name>: expected ct or labels" for another name.
SimulationSource parse_simulation_source(const std::string& name,
                                         const std::string& what = "source");
/// The source a volume is when the caller does not say: labels when a tissue table is given or
/// the volume is uint8, else a CT in HU.
SimulationSource default_simulation_source(const Volume& volume, bool tissue_table_given);

enum class SimulationOutput {
  BMode,    ///< uint8 after time-gain compensation and log compression
  Envelope  ///< float32 linear envelope amplitude, before TGC and log compression
};
/// Every output, in the order of its spelling table.
inline constexpr SimulationOutput kSimulationOutputs[] = {SimulationOutput::BMode,
                                                          SimulationOutput::Envelope};
/// "bmode", "envelope".
const char* to_string(SimulationOutput output);
/// InputError "<what> <name>: expected bmode or envelope" for another name.
SimulationOutput parse_simulation_output(const std::string& name,
                                         const std::string& what = "output");

/// What a simulation does. Every default is here, once: `sonoslice simulate` and Python's
/// Simulator set only what their user gave.
struct SimulationSettings {
  /// The frequency when none is given.
  static constexpr double kDefaultFrequencyMhz = 5.0;

  /// A preset (simulation_presets()): the probe when the Simulator is given none, and the
  /// frequency when frequency_mhz is unset.
  std::optional<std::string> preset;
  /// Centre frequency f (MHz). Unset: the preset's, else kDefaultFrequencyMhz (resolved()).
  std::optional<double> frequency_mhz;
  uint64_t seed = 0;             ///< the speckle field's seed (fixed in the volume frame)
  double dynamic_range_db = 60;  ///< log compression: 0 dB (an ideal reflector) → 255, −DR → 0
  bool tgc_auto = true;          ///< compensate the attenuation met along each depth (off: none)
  SimulationOutput output = SimulationOutput::BMode;
  /// Point-spread function, full width at half maximum in mm; 0: from the frequency (axial: two
  /// cycles of the pulse, λ; lateral: 2λ·F-number 2 → ... see docs/simulation.md §3).
  double axial_fwhm_mm = 0, lateral_fwhm_mm = 0, elevation_fwhm_mm = 0;
  /// Where the images are computed: the CPU, or a GPU (the volume and tables are uploaded once
  /// per Simulator; images come back to host memory). docs/simulation.md §4.
  Device device = Device::cpu();

  /// These settings, checked (validate), with the defaults chosen: frequency_mhz set.
  SimulationSettings resolved(const ParameterNames& names = {}) const;
  /// Throws InputError naming the setting (as `names` spells it) for an unknown preset,
  /// non-finite or non-positive values (frequency, dynamic range) or negative PSF widths.
  void validate(const ParameterNames& names = {}) const;
};

/// A named probe and frequency (docs/simulation.md §7): the probe a simulation uses when none is
/// given, and the frequency when none is given.
struct SimulationPreset {
  std::string name, description;
  double frequency_mhz = 0;
  ProbeGeometry probe;
};
/// "abdominal" (3.5 MHz curvilinear), "laparoscopic" (7.5 MHz linear), "lus" (fan-slicer's
/// laparoscopic ultrasound configuration, W1, 6.5 MHz).
std::vector<SimulationPreset> simulation_presets();
/// The preset named `name`; InputError "<what> <name>: unknown (presets: ...)" otherwise.
SimulationPreset simulation_preset(const std::string& name, const std::string& what = "preset");

namespace simulate_impl {
struct Model;
}

/// Bound to one volume, one probe and one tissue model. The volume is shared, not copied.
class Simulator {
 public:
  /// `probe`: unset, the preset's (settings.preset). `tissues`: the table for a label volume
  /// (ignored for HU). InputError for a label volume that is not uint8/uint16, a label the
  /// volume holds that the table lacks (named), no probe and no preset, or bad settings.
  /// settings() are the given ones resolved().
  Simulator(Volume volume, SimulationSource source, std::optional<ProbeGeometry> probe,
            std::vector<Tissue> tissues = default_tissues(), SimulationSettings settings = {});
  ~Simulator();
  Simulator(Simulator&&) noexcept;

  int width() const;
  int height() const;
  const SimulationSettings& settings() const;  ///< resolved: the frequency chosen
  const ProbeGeometry& probe() const;          ///< the given one, else the preset's
  SimulationSource source() const;
  /// The H×W fan mask (1 inside the probe shape): the same mask as Slicer::mask().
  const std::vector<uint8_t>& mask() const;
  /// Beams per image and samples per beam of the simulation grid before scan conversion.
  int beams() const;
  int samples_per_beam() const;
  /// Bytes of one output image (uint8 for B-mode, float32 for the envelope).
  size_t image_bytes() const;

  /// Simulates `count` poses (probe mm → world mm, LPS) into `out`, a C-order (count, H, W)
  /// array (uint8 B-mode or float32 envelope). Poses are checked first (InputError naming
  /// "pose <i>", i counted from `first_index`); nothing is written when one is bad.
  void simulate(const Pose* poses, size_t count, void* out, size_t first_index = 0) const;

 private:
  std::unique_ptr<simulate_impl::Model> model_;
};

}  // namespace sonoslice
