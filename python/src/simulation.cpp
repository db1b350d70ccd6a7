// Ultrasound simulation: the Simulator (CPU) into NumPy arrays, tissue tables and presets.
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
  std::shared_ptr<const ArraySource> source;
};

void simulate_into(const PySimulator& sim, Matrices pose_array, nb::ndarray<> out,
                   nb::object progress, int64_t chunk) {
  if (sim.source) sim.source->check("simulate");
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

}  // namespace

void bind_simulation(nb::module_& m) {
  nb::class_<PySimulator>(m, "Simulator")
      .def(
          "__init__",
          [](PySimulator* self, nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe,
             const std::string& kind, const std::string& tissues_json, double frequency_mhz,
             uint64_t seed, double dynamic_range_db, bool tgc_auto, const std::string& output) {
            SimulationSettings s;
            s.frequency_mhz = frequency_mhz;
            s.seed = seed;
            s.dynamic_range_db = dynamic_range_db;
            s.tgc_auto = tgc_auto;
            if (output != "bmode" && output != "envelope")
              throw InputError("output \"" + output + "\": expected \"bmode\" or \"envelope\"");
            s.output = output == "bmode" ? SimulationOutput::BMode : SimulationOutput::Envelope;
            if (kind != "ct" && kind != "labels")
              throw InputError("kind \"" + kind + "\": expected \"ct\" or \"labels\"");
            const std::vector<Tissue> tissues = tissues_json.empty()
                                                    ? default_tissues()
                                                    : parse_tissue_table(tissues_json, "tissues");
            auto source = volume_source(volume.h);
            if (source) source->check("make a Simulator");
            {
              nb::gil_scoped_release release;
              new (self) PySimulator(
                  *volume.p,
                  kind == "ct" ? SimulationSource::HounsfieldUnits : SimulationSource::Labels,
                  probe, tissues, s);
            }
            self->source = std::move(source);
          },
          "volume"_a, "probe"_a, "kind"_a, "tissues_json"_a, "frequency_mhz"_a, "seed"_a,
          "dynamic_range_db"_a, "tgc_auto"_a, "output"_a)
      .def("simulate_into", &simulate_into, "poses"_a, "out"_a, "progress"_a = nb::none(),
           "chunk"_a = 0)
      .def_prop_ro("width", [](const PySimulator& s) { return s.width(); })
      .def_prop_ro("height", [](const PySimulator& s) { return s.height(); })
      .def_prop_ro("beams", [](const PySimulator& s) { return s.beams(); })
      .def_prop_ro("samples_per_beam", [](const PySimulator& s) { return s.samples_per_beam(); })
      .def("mask", [](const PySimulator& s) {
        auto mk = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(mk->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8,
                          mk);
      });
  m.def("default_tissues_json", [] { return tissue_table_json(default_tissues()); });
  m.def("phantom_tissues_json", [] { return tissue_table_json(phantom_tissues()); });
  m.def("read_tissue_table_json",
        [](const std::string& path) { return tissue_table_json(read_tissue_table(path)); });
  m.def("simulation_presets", [] {
    std::vector<std::pair<std::string, std::string>> out;
    for (const SimulationPreset& p : simulation_presets()) out.emplace_back(p.name, p.description);
    return out;
  });
  m.def("simulation_preset_probe",
        [](const std::string& name) { return simulation_preset(name).probe; });
  m.def("simulation_preset_frequency",
        [](const std::string& name) { return simulation_preset(name).frequency_mhz; });
}

}  // namespace sonoslice::bindings
