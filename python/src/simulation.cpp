// Ultrasound simulation: its settings and choices (SimulationSettings, SimulationSource,
// SimulationOutput), tissue tables as lists of Tissue, presets, and the Simulator (CPU) into NumPy
// arrays. Defaults and checks are the library's (SimulationSettings::resolved).
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <memory>

#include "bindings.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/simulate/Simulator.h"
#include "sonoslice/simulate/TissueFile.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;

/// The bound Simulator keeps what the volume views (as PySlicer does) and checks it before
/// each call.
struct PySimulator : Simulator {
  using Simulator::Simulator;
  std::shared_ptr<const ArraySource> array;  // what the volume views (none: it owns its voxels)
};

void simulate_into(const PySimulator& sim, Matrices pose_array, nb::ndarray<> out,
                   nb::object progress, int64_t chunk) {
  if (sim.array) sim.array->check("simulate");
  const std::vector<Pose> poses = matrices_from(pose_array);
  const int64_t n = int64_t(poses.size());
  if (!has_shape(out, n, sim.height(), sim.width()))
    throw InputError("out: expected shape " + shape_text(n, sim.height(), sim.width()));
  if (!c_contiguous(out)) throw InputError("out: must be C-contiguous");
  check_out_dtype(out, sim.settings().output == SimulationOutput::BMode ? PixelType::UInt8
                                                                        : PixelType::Float32);
  if (out.device_type() != nb::device::cpu::value)
    throw InputError("out: simulation runs on the CPU; pass a host array");
  auto* base = static_cast<char*>(out.data());
  const size_t image_bytes = sim.image_bytes();
  slice_in_chunks(poses, progress, chunk, [&](int64_t first, int64_t count) {
    sim.simulate(poses.data() + first, size_t(count), base + size_t(first) * image_bytes,
                 size_t(first));
  });
}

// ---- tissues
bool same_tissue(const Tissue& a, const Tissue& b) {
  return a.name == b.name && a.label == b.label && a.impedance_mrayl == b.impedance_mrayl &&
         a.attenuation_db_cm_mhz == b.attenuation_db_cm_mhz && a.scatter_mean == b.scatter_mean &&
         a.scatter_density == b.scatter_density;
}

// The fields in the order of the JSON files (docs/simulation.md §1).
constexpr const char* kTissueFields[] = {
    "name", "label", "impedance_mrayl", "attenuation_db_cm_mhz", "scatter_mean", "scatter_density"};

nb::object tissue_field(const Tissue& t, const std::string& key) {
  if (key == "name") return nb::cast(t.name);
  if (key == "label") return nb::cast(t.label);
  if (key == "impedance_mrayl") return nb::cast(t.impedance_mrayl);
  if (key == "attenuation_db_cm_mhz") return nb::cast(t.attenuation_db_cm_mhz);
  if (key == "scatter_mean") return nb::cast(t.scatter_mean);
  if (key == "scatter_density") return nb::cast(t.scatter_density);
  throw nb::key_error(key.c_str());
}

std::string tissue_repr(const Tissue& t) {
  std::string s = "Tissue(";
  for (const char* key : kTissueFields)
    s += std::string(key == kTissueFields[0] ? "" : ", ") + key + "=" +
         nb::repr(tissue_field(t, key)).c_str();
  return s + ")";
}

/// A tissue table from Python: a list of Tissue objects and dicts, or {"tissues": [...]}, read by
/// the same parser as a table file (its keys and values checked, errors naming "tissues").
std::vector<Tissue> tissue_table_of(nb::handle table) {
  if (nb::isinstance<nb::list>(table) || nb::isinstance<nb::tuple>(table)) {
    nb::dict wrapped;
    wrapped["tissues"] = table;
    return parse_tissue_table(json_text(wrapped, "tissues"), "tissues");
  }
  if (nb::isinstance<nb::dict>(table))
    return parse_tissue_table(json_text(table, "tissues"), "tissues");
  throw nb::type_error(("tissues: expected a list of Tissue (or of dicts) or {\"tissues\": [...]}, "
                        "got " +
                        std::string(nb::type_name(table.type()).c_str()))
                           .c_str());
}

// ---- settings
std::string settings_repr(const SimulationSettings& s) {
  const SimulationSettings d;
  std::string r = "SimulationSettings(";
  const auto field = [&r](const char* name, const std::string& value) {
    r += std::string(r.back() == '(' ? "" : ", ") + name + "=" + value;
  };
  if (s.preset) field("preset", repr(*s.preset));
  if (s.frequency_mhz) field("frequency_mhz", repr(*s.frequency_mhz));
  field("seed", repr(s.seed));
  field("dynamic_range_db", repr(s.dynamic_range_db));
  field("tgc_auto", repr(s.tgc_auto));
  field("output", repr(std::string(to_string(s.output))));
  if (s.axial_fwhm_mm != d.axial_fwhm_mm) field("axial_fwhm_mm", repr(s.axial_fwhm_mm));
  if (s.lateral_fwhm_mm != d.lateral_fwhm_mm) field("lateral_fwhm_mm", repr(s.lateral_fwhm_mm));
  if (s.elevation_fwhm_mm != d.elevation_fwhm_mm)
    field("elevation_fwhm_mm", repr(s.elevation_fwhm_mm));
  if (!(s.device == d.device)) field("device", repr(s.device.to_string()));
  return r + ")";
}

}  // namespace

void bind_simulation(nb::module_& m) {
  bind_enum(m, "SimulationSource", kSimulationSources,
            "What a volume holds: ct (Hounsfield units, trilinear) or labels (uint8/uint16 with a "
            "tissue table, nearest).");
  bind_enum(m, "SimulationOutput", kSimulationOutputs,
            "bmode (uint8 after TGC and log compression) or envelope (float32, before them).");

  const Tissue tissue;
  nb::class_<Tissue>(m, "Tissue",
                     "Acoustic properties of one tissue (one label of a label volume; "
                     "docs/simulation.md §1). Reads as a dict too: dict(t), t[\"label\"].")
      .def(
          "__init__",
          [](Tissue* self, const std::string& name, int label, double impedance_mrayl,
             double attenuation_db_cm_mhz, double scatter_mean, double scatter_density,
             const nb::kwargs& unknown) {
            refuse_unknown_keywords(unknown, "Tissue", kTissueFields);
            const Tissue t{name,         label,          impedance_mrayl, attenuation_db_cm_mhz,
                           scatter_mean, scatter_density};
            validate_tissues({t}, "Tissue");
            new (self) Tissue(t);
          },
          nb::kw_only(), "name"_a = tissue.name, "label"_a = tissue.label,
          "impedance_mrayl"_a = tissue.impedance_mrayl,
          "attenuation_db_cm_mhz"_a = tissue.attenuation_db_cm_mhz,
          "scatter_mean"_a = tissue.scatter_mean, "scatter_density"_a = tissue.scatter_density,
          "unknown"_a)
      .def_ro("name", &Tissue::name, "lower case: \"liver\", \"soft tissue\", ...")
      .def_ro("label", &Tissue::label, "the label value in a label volume (0..65535)")
      .def_ro("impedance_mrayl", &Tissue::impedance_mrayl, "acoustic impedance Z (MRayl)")
      .def_ro("attenuation_db_cm_mhz", &Tissue::attenuation_db_cm_mhz,
              "amplitude attenuation, dB per cm per MHz")
      .def_ro("scatter_mean", &Tissue::scatter_mean, "mean diffuse-scatter amplitude (linear)")
      .def_ro("scatter_density", &Tissue::scatter_density,
              "scatterers per resolution cell (10 and more: fully developed speckle)")
      .def("keys",
           [](const Tissue&) {
             nb::list keys;
             for (const char* key : kTissueFields) keys.append(key);
             return keys;
           })
      .def("__getitem__", &tissue_field, "key"_a)
      .def("__eq__", &same_tissue, nb::is_operator())
      .def("__repr__", &tissue_repr);

  m.def("default_tissues", &default_tissues,
        "The default table: water, blood, fat, liver, kidney, muscle, soft tissue, vessel wall, "
        "bone, gas (labels 1..10).");
  m.def("phantom_tissues", &phantom_tissues, "The table of the built-in phantom's labels.");
  m.def("read_tissue_table", &read_tissue_table, "path"_a,
        "A tissue table JSON file ({\"tissues\": [...]}).");
  m.def("tissue_table", &tissue_table_of, "table"_a,
        "A table from a list of Tissue objects or dicts, or {\"tissues\": [...]}: the keys and "
        "values checked as in a table file.");
  m.def("simulation_presets", [] {
    std::vector<std::pair<std::string, std::string>> out;
    for (const SimulationPreset& p : simulation_presets()) out.emplace_back(p.name, p.description);
    return out;
  });

  const SimulationSettings settings;
  static constexpr const char* kSettingNames[] = {"preset",
                                                  "frequency_mhz",
                                                  "seed",
                                                  "dynamic_range_db",
                                                  "tgc_auto",
                                                  "output",
                                                  "axial_fwhm_mm",
                                                  "lateral_fwhm_mm",
                                                  "elevation_fwhm_mm",
                                                  "device"};
  nb::class_<SimulationSettings>(
      m, "SimulationSettings",
      "What a simulation does (docs/simulation.md); unset values take the library's defaults. "
      "Checked when made (ValueError naming the setting).")
      .def(
          "__init__",
          [](SimulationSettings* self, std::optional<std::string> preset,
             std::optional<double> frequency_mhz, nb::int_ seed, double dynamic_range_db,
             bool tgc_auto, SimulationOutput output, double axial_fwhm_mm, double lateral_fwhm_mm,
             double elevation_fwhm_mm, const std::string& device, const nb::kwargs& unknown) {
            refuse_unknown_keywords(unknown, "SimulationSettings", kSettingNames);
            SimulationSettings s;
            s.preset = std::move(preset);
            s.frequency_mhz = frequency_mhz;
            s.seed = seed_value(seed, "seed");
            s.dynamic_range_db = dynamic_range_db;
            s.tgc_auto = tgc_auto;
            s.output = output;
            s.axial_fwhm_mm = axial_fwhm_mm;
            s.lateral_fwhm_mm = lateral_fwhm_mm;
            s.elevation_fwhm_mm = elevation_fwhm_mm;
            s.device = Device::parse(device);
            s.validate();
            new (self) SimulationSettings(std::move(s));
          },
          nb::kw_only(), "preset"_a.none() = nb::none(), "frequency_mhz"_a.none() = nb::none(),
          "seed"_a = nb::int_(settings.seed), "dynamic_range_db"_a = settings.dynamic_range_db,
          "tgc_auto"_a = settings.tgc_auto, "output"_a = settings.output,
          "axial_fwhm_mm"_a = settings.axial_fwhm_mm,
          "lateral_fwhm_mm"_a = settings.lateral_fwhm_mm,
          "elevation_fwhm_mm"_a = settings.elevation_fwhm_mm,
          "device"_a = settings.device.to_string(), "unknown"_a,
          "preset: a probe and frequency (simulation_presets()); frequency_mhz: default the "
          "preset's, else 5 MHz.")
      .def_ro("preset", &SimulationSettings::preset)
      .def_ro("frequency_mhz", &SimulationSettings::frequency_mhz,
              "centre frequency (MHz); None: not chosen yet (resolved() chooses)")
      .def_ro("seed", &SimulationSettings::seed, "the speckle field's seed")
      .def_ro("dynamic_range_db", &SimulationSettings::dynamic_range_db)
      .def_ro("tgc_auto", &SimulationSettings::tgc_auto)
      .def_ro("output", &SimulationSettings::output)
      .def_ro("axial_fwhm_mm", &SimulationSettings::axial_fwhm_mm)
      .def_ro("lateral_fwhm_mm", &SimulationSettings::lateral_fwhm_mm)
      .def_ro("elevation_fwhm_mm", &SimulationSettings::elevation_fwhm_mm)
      .def_prop_ro("device", [](const SimulationSettings& s) { return s.device.to_string(); })
      .def(
          "resolved", [](const SimulationSettings& s) { return s.resolved(); },
          "These settings with the defaults chosen (the frequency).")
      .def("__repr__", &settings_repr);

  nb::class_<PySimulator>(m, "Simulator",
                          "Bound to one volume, one probe and one tissue model (use "
                          "sonoslice.Simulator).")
      .def(
          "__init__",
          [](PySimulator* self, nb::pointer_and_handle<Volume> volume,
             std::optional<ProbeGeometry> probe, std::optional<SimulationSource> source,
             std::optional<std::vector<Tissue>> tissues, const SimulationSettings& settings) {
            auto array = volume_source(volume.h);
            if (array) array->check("make a Simulator");
            const SimulationSource s =
                source ? *source : default_simulation_source(*volume.p, tissues.has_value());
            {
              nb::gil_scoped_release release;
              new (self) PySimulator(*volume.p, s, std::move(probe),
                                     tissues ? std::move(*tissues) : default_tissues(), settings);
            }
            self->array = std::move(array);
          },
          "volume"_a, "probe"_a.none() = nb::none(), nb::kw_only(), "source"_a.none() = nb::none(),
          "tissues"_a.none() = nb::none(), "settings"_a = SimulationSettings(),
          "probe: default the settings' preset's; source: default labels when a tissue table is "
          "given or the volume is uint8, else ct; tissues: default default_tissues().")
      .def("simulate_into", &simulate_into, "poses"_a, "out"_a, "progress"_a = nb::none(),
           "chunk"_a = 0)
      .def_prop_ro(
          "settings", [](const PySimulator& s) { return s.settings(); },
          "the settings as resolved (the frequency chosen)")
      .def_prop_ro("probe", [](const PySimulator& s) { return s.probe(); })
      .def_prop_ro("source", [](const PySimulator& s) { return s.source(); })
      .def_prop_ro("width", [](const PySimulator& s) { return s.width(); })
      .def_prop_ro("height", [](const PySimulator& s) { return s.height(); })
      .def_prop_ro("beams", [](const PySimulator& s) { return s.beams(); })
      .def_prop_ro("samples_per_beam", [](const PySimulator& s) { return s.samples_per_beam(); })
      .def("mask", [](const PySimulator& s) {
        auto mk = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(mk->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8,
                          mk);
      });
}

}  // namespace sonoslice::bindings
