// sonoslice simulate: a CT (HU), a label volume with a tissue table, or surface meshes, a probe
// and a pose file → a stack of simulated ultrasound images (docs/simulation.md).
#include <cstdio>
#include <iostream>
#include <memory>

#include "Commands.h"
#include "Common.h"
#include "SimulationFlags.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/simulate/Simulator.h"
#include "sonoslice/simulate/TissueFile.h"
#include "sonoslice/surface/Voxelize.h"

namespace sonoslice {
namespace cli {

std::string simulate_flag(const std::string& setting) {
  if (setting == "frequency_mhz") return "--frequency";
  if (setting == "dynamic_range_db") return "--dynamic-range";
  if (setting == "tgc_auto") return "--tgc";
  return flag_named(setting);
}

SimulationSettings settings_of(const SimulateFlags& f) {
  SimulationSettings s;
  if (!f.preset.empty()) s.preset = f.preset;
  s.frequency_mhz = f.frequency;
  if (f.seed) s.seed = *f.seed;
  if (f.dynamic_range) s.dynamic_range_db = *f.dynamic_range;
  if (!f.tgc.empty()) {
    if (f.tgc != "auto" && f.tgc != "off")
      throw InputError("--tgc " + f.tgc + ": expected auto or off");
    s.tgc_auto = f.tgc == "auto";
  }
  if (!f.output.empty()) s.output = parse_simulation_output(f.output, "--output");
  if (!f.device.empty()) s.device = Device::parse(f.device);
  return s.resolved(simulate_flag);
}

void check_simulation_flags(const SimulateFlags& f, const std::string& command) {
  const int sources = !f.volume.path.empty() + !f.labels.empty() + !f.meshes.empty();
  if (sources != 1)
    throw UsageError(command + ": give exactly one of --volume, --labels, --meshes");
  if (!f.tissues.empty() && !f.volume.path.empty())
    throw InputError(
        "--tissues: a CT (--volume) maps HU to tissues itself; --tissues is for "
        "--labels and --meshes");
  if (!f.meshes.empty() && f.tissues.empty())
    throw InputError(
        "--meshes: give --tissues, a table for label 0 (outside every mesh) and "
        "label k (inside the k-th mesh)");
  if (f.probe.empty() && f.preset.empty())
    throw UsageError(command + ": give --probe or --preset (sonoslice simulate --list-presets)");
  mesh_voxel_size(f.voxel_size, !f.meshes.empty());
  if (!f.output.empty() &&
      parse_simulation_output(f.output, "--output") == SimulationOutput::Envelope) {
    // The envelope is taken before TGC and log compression: these flags would change nothing.
    if (f.dynamic_range)
      throw InputError(
          "--dynamic-range: applies to --output bmode (envelope is before log "
          "compression)");
    if (f.tgc == "auto")  // off says what an envelope is: taken, like no flag
      throw InputError("--tgc auto: applies to --output bmode (envelope is before TGC)");
  }
}

std::optional<ProbeGeometry> probe_of(const SimulateFlags& f) {
  if (!f.probe.empty()) return read_probe(f.probe, f.downsampling);
  if (f.downsampling != 1) throw InputError("--downsampling applies to --probe files");
  return std::nullopt;  // the preset's
}

std::vector<Tissue> tissues_of(const SimulateFlags& f) {
  return f.tissues.empty() ? default_tissues() : read_tissue_table(f.tissues);
}

Simulator simulator_of(const SimulateFlags& f, const SimulationInput& input,
                       const std::optional<ProbeGeometry>& probe,
                       const std::vector<Tissue>& tissues, const SimulationSettings& settings) {
  try {
    return Simulator(input.volume, input.source, probe, tissues, settings);
  } catch (const UnlistedLabelError& e) {
    const std::string table = f.tissues.empty()
                                  ? "the default tissue table (--print-tissues; give --tissues)"
                                  : "--tissues '" + f.tissues + "'";
    const std::string label = "label " + std::to_string(e.label());
    const std::string holder =
        !f.labels.empty() ? "--labels '" + f.labels + "' holds " + label
        : e.label() == 0 || size_t(e.label()) > f.meshes.size()
            ? "outside every mesh of --meshes is " + label
            : "--meshes '" + f.meshes[size_t(e.label() - 1)] + "' is " + label;
    throw InputError(holder + ", which " + table + " does not list");
  }
}

SimulationInput read_simulation_input(const SimulateFlags& f) {
  const WorldFrame frame = parse_world_frame(f.world);
  SimulationInput in;
  if (!f.volume.path.empty()) {
    in.volume = read_volume(f.volume.path, f.volume.options());
    in.source = SimulationSource::HounsfieldUnits;
    in.description = f.volume.path + " (HU)";
  } else if (!f.labels.empty()) {
    in.volume = read_volume(f.labels, f.volume.options());
    check_label_volume(in.volume, "--labels '" + f.labels + "'");
    in.description = f.labels + " (labels)";
  } else {
    // Meshes: label k for the k-th mesh, voxelised at --voxel-size.
    std::vector<TriangleMesh> meshes;
    std::vector<uint16_t> labels;
    for (const std::string& path : f.meshes) {
      meshes.push_back(read_mesh(path, frame));
      labels.push_back(uint16_t(labels.size() + 1));
    }
    const double voxel_size = mesh_voxel_size(f.voxel_size, true);
    VolumeGrid grid;
    try {
      grid = voxel_grid_around(meshes, voxel_size, voxel_size);
    } catch (const ParameterError& e) {
      throw InputError("--voxel-size " + e.detail());
    }
    in.volume = voxelize(meshes, grid, labels);
    in.description = std::to_string(meshes.size()) + " meshes voxelised at " +
                     std::to_string(voxel_size) + " mm";
  }
  return in;
}

void add_simulation_flags(CLI::App& cmd, SimulateFlags& f) {
  f.volume.add_to(cmd, /*path_required=*/false);
  cmd.add_option("--labels", f.labels, "A label volume (uint8/uint16) with --tissues");
  cmd.add_option("--tissues", f.tissues,
                 "Tissue table JSON for labels and meshes (default: --print-tissues)");
  cmd.add_option("--meshes", f.meshes, "Surface meshes: label k for the k-th, voxelised");
  cmd.add_option("--voxel-size", f.voxel_size, "Meshes: voxel size (mm, default 0.5)");
  cmd.add_option("--probe", f.probe, "Probe JSON (native or fan-slicer config)");
  cmd.add_option("--preset", f.preset,
                 "A probe and frequency: abdominal, laparoscopic, lus (--list-presets)");
  cmd.add_option("--downsampling", f.downsampling, "Divide the probe image size by K");
  const SimulationSettings defaults;
  cmd.add_option("--frequency", f.frequency,
                 "Centre frequency in MHz (default: the preset's, else " +
                     default_text(SimulationSettings::kDefaultFrequencyMhz).substr(1));
  add_seed_option(
      cmd, [&f](uint64_t s) { f.seed = s; }, "Speckle seed " + default_text(defaults.seed));
  cmd.add_option("--dynamic-range", f.dynamic_range,
                 "Log compression range in dB " + default_text(defaults.dynamic_range_db));
  cmd.add_option("--tgc", f.tgc,
                 std::string("Time-gain compensation: auto or off (default ") +
                     (defaults.tgc_auto ? "auto" : "off") + ")");
  cmd.add_option("--output", f.output,
                 std::string("bmode (uint8) or envelope (float32, before TGC and log "
                             "compression); default ") +
                     to_string(defaults.output));
  cmd.add_option("--world", f.world, "Frame of the poses and meshes: LPS (default) or RAS");
  add_threads_option(cmd, f.threads);
  cmd.add_option("--device", f.device, "cpu (default), cuda or cuda:K");
}

namespace {

void run_simulate(const SimulateFlags& f) {
  if (f.list_presets) {
    for (const SimulationPreset& p : simulation_presets())
      std::printf("%-14s %s\n", p.name.c_str(), p.description.c_str());
    return;
  }
  if (f.print_tissues) {
    std::cout << tissue_table_json(default_tissues());
    return;
  }
  Stopwatch total;
  check_simulation_flags(f, "simulate");
  setup_threads(f.threads);
  if (f.poses.empty()) throw UsageError("simulate: --poses is required");
  if (f.out.empty()) throw UsageError("simulate: --out is required");
  const SimulationSettings settings = settings_of(f);

  // Everything small and checkable first, so a typo fails before a CT is loaded.
  std::vector<NamedPath> inputs = {
      {"--volume", f.volume.path}, {"--labels", f.labels}, {"--tissues", f.tissues},
      {"--probe", f.probe},        {"--poses", f.poses},   {"--npy-config", f.volume.npy_config}};
  for (const std::string& mesh : f.meshes) inputs.push_back({"--meshes", mesh});
  check_distinct_outputs({{"--out", f.out}, {"--mask", f.mask}}, inputs);
  const std::optional<ProbeGeometry> given_probe = probe_of(f);
  const WorldFrame frame = parse_world_frame(f.world);
  const std::vector<Pose> poses = read_poses(f.poses, frame);
  const std::vector<Tissue> tissues = tissues_of(f);
  const StackFormat format = stack_format(f.out);
  check_output_path(f.out, format == StackFormat::PngDirectory);
  if (!f.mask.empty()) check_image_output(f.mask, "--mask");

  Stopwatch load;
  const SimulationInput input = read_simulation_input(f);
  const std::string& description = input.description;
  const double load_seconds = load.seconds();
  const Simulator sim = simulator_of(f, input, given_probe, tissues, settings);
  const ProbeGeometry& probe = sim.probe();

  StackSpec spec = probe_stack_spec(
      probe, settings.output == SimulationOutput::BMode ? PixelType::UInt8 : PixelType::Float32,
      poses);
  spec.mask = sim.mask().data();
  // B-mode grey levels are final: PNGs show them as they are (0..255), not auto-windowed.
  if (settings.output == SimulationOutput::BMode) spec.window = std::make_pair(127.5, 255.0);
  const int64_t chunk = chunk_images(sim.image_bytes(), spec.count);
  check_stack_resources(f.out, spec, chunk);

  std::unique_ptr<StackWriter> writer = StackWriter::create(f.out, spec);
  ProgressBar progress("simulating", spec.count, !f.quiet);
  double simulate_seconds = 0, write_seconds = 0;
  for (int64_t first = 0; first < spec.count; first += chunk) {
    const int64_t count = std::min(chunk, spec.count - first);
    void* out = writer->buffer(first, count);
    Stopwatch s;
    sim.simulate(poses.data() + first, size_t(count), out, size_t(first));
    simulate_seconds += s.seconds();
    Stopwatch w;
    writer->write(first, count);
    write_seconds += w.seconds();
    progress.update(first + count);
  }
  Stopwatch commit_clock;
  OutputSet outputs;  // all outputs or none
  writer->finish(outputs);
  if (!f.mask.empty()) write_mask(f.mask, probe, sim.mask(), &outputs);
  outputs.commit();
  write_seconds += commit_clock.seconds();
  progress.finish();
  if (f.verbose)
    std::fprintf(stderr,
                 "sonoslice: source %s\n"
                 "sonoslice: probe: %s; %d beams x %d samples, %.2f MHz\n"
                 "sonoslice: load %.3f s, simulate %.3f s (%.1f images/s, %d threads), write "
                 "%.3f s, total %.3f s\n",
                 description.c_str(), probe.describe().c_str(), sim.beams(), sim.samples_per_beam(),
                 *sim.settings().frequency_mhz, load_seconds, simulate_seconds,
                 double(spec.count) / std::max(simulate_seconds, 1e-9), cpu_threads(),
                 write_seconds, total.seconds());
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto flags = std::make_shared<SimulateFlags>();
  CLI::App* cmd = app.add_subcommand(
      "simulate", "Simulate ultrasound images from a CT, labels or meshes (docs/simulation.md)");
  add_simulation_flags(*cmd, *flags);
  cmd->add_option("--poses", flags->poses, "Pose file: .npy, .txt/.csv, .json");
  cmd->add_option("--out", flags->out,
                  "Output: .nii/.nii.gz/.mha/.nrrd stack, .npy (N,H,W), or a directory of PNGs");
  cmd->add_option("--mask", flags->mask, "Also write the HxW fan mask here");
  cmd->add_flag("--list-presets", flags->list_presets, "Print the presets and exit");
  cmd->add_flag("--print-tissues", flags->print_tissues,
                "Write the default tissue table to stdout as JSON and exit");
  cmd->add_flag("--quiet,-q", flags->quiet, "No progress bar");
  cmd->add_flag("--verbose,-v", flags->verbose, "Print time spent loading, simulating, writing");
  cmd->callback([flags] { run_simulate(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
