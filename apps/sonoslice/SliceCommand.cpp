// sonoslice slice: a volume (or labels, or surface meshes), a probe and a pose file → a stack of
// ultrasound-shaped images (and, for labels, colour images).
#include <cstdio>
#include <memory>
#include <sstream>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/surface/Colorize.h"
#include "sonoslice/surface/SurfaceConfig.h"
#include "sonoslice/surface/SurfaceSlicer.h"
#include "sonoslice/surface/Voxelize.h"

namespace sonoslice {
namespace cli {
namespace {

struct SliceFlags {
  VolumeFlags volume;
  std::string labels, mesh_dir, surface_mode = "voxel", colors;
  std::vector<std::string> meshes;
  std::optional<double> voxel_size;
  std::string probe, poses, out, mask;
  std::string interp = "linear", dtype = "float32", world = "LPS", device = "cpu", window;
  double fill = 0.0;
  int downsampling = 1;
  std::optional<int> threads;  // unset: all hardware threads
  bool quiet = false, verbose = false;
  bool interp_given = false, dtype_given = false;
};

// Where the images come from: a volume (intensities or labels) or surface meshes.
struct Source {
  std::unique_ptr<Slicer> slicer;              // volumes, and voxelised meshes
  std::unique_ptr<SurfaceSlicer> surfaces;     // exact cuts
  std::vector<std::array<uint8_t, 3>> colors;  // label k → colors[k - 1]
  std::string description;
  void slice(const Pose* poses, size_t count, void* out, size_t first) const {
    if (surfaces)
      surfaces->slice(poses, count, out, first);
    else
      slicer->slice(poses, count, out, first);
  }
  const std::vector<uint8_t>& mask() const { return surfaces ? surfaces->mask() : slicer->mask(); }
};

Source make_source(const SliceFlags& f, const ProbeGeometry& probe, SliceSettings settings,
                   const Device& device, double* load_seconds) {
  Source src;
  Stopwatch load;
  const WorldFrame frame = parse_world_frame(f.world);
  if (!f.volume.path.empty() || !f.labels.empty()) {
    const std::string path = f.volume.path.empty() ? f.labels : f.volume.path;
    Volume v = read_volume(path, f.volume.options());
    *load_seconds = load.seconds();
    src.description = path + ": " + std::to_string(v.grid().dims[0]) + "x" +
                      std::to_string(v.grid().dims[1]) + "x" + std::to_string(v.grid().dims[2]) +
                      " " + to_string(v.pixel_type());
    if (!f.labels.empty()) check_label_volume(v, "--labels '" + path + "'");
    for (int k = 1; k <= 255; ++k) src.colors.push_back(default_label_color(k));
    src.slicer = std::make_unique<Slicer>(v, probe, settings, device);
    return src;
  }
  // Surface meshes: from the command line (label k = k-th mesh) or a fan-slicer configuration.
  std::vector<TriangleMesh> meshes;
  std::vector<uint16_t> labels;
  if (!f.mesh_dir.empty()) {
    for (const SurfaceModel& m : read_fanslicer_models(f.probe, f.mesh_dir)) {
      meshes.push_back(read_mesh(m.path, frame));
      labels.push_back(m.label);
      src.colors.push_back(m.color);
    }
  } else {
    for (const std::string& path : f.meshes) {
      meshes.push_back(read_mesh(path, frame));
      labels.push_back(uint16_t(labels.size() + 1));
      src.colors.push_back(default_label_color(labels.back()));
    }
  }
  *load_seconds = load.seconds();
  src.description = std::to_string(meshes.size()) + " meshes, " + f.surface_mode + " mode";
  if (f.surface_mode == "exact") {
    src.surfaces =
        std::make_unique<SurfaceSlicer>(std::move(meshes), probe, labels, settings.output_type);
  } else {
    const double voxel_size = mesh_voxel_size(f.voxel_size, true);
    VolumeGrid grid;
    try {
      grid = voxel_grid_around(meshes, voxel_size, voxel_size);
    } catch (const ParameterError& e) {  // both the spacing and the margin are --voxel-size
      throw InputError("--voxel-size " + e.detail());
    }
    const Volume v = voxelize(meshes, grid, labels);
    src.description += " at " + std::to_string(voxel_size) + " mm";
    src.slicer = std::make_unique<Slicer>(v, probe, settings, device);
  }
  return src;
}

void run_slice(const SliceFlags& f) {
  Stopwatch total;
  // Checked before the device is started, so the answer is the same with or without a GPU.
  if (f.surface_mode == "exact" && Device::parse(f.device).type != DeviceType::CPU)
    throw InputError("--surface-mode exact runs on the CPU (voxel mode runs on " + f.device + ")");
  const Device device = setup_device(f.device, f.threads);

  const int sources =
      !f.volume.path.empty() + !f.labels.empty() + !f.meshes.empty() + !f.mesh_dir.empty();
  if (sources != 1)
    throw InputError("slice: give exactly one of --volume, --labels, --meshes, --mesh-dir");
  const bool label_mode = f.volume.path.empty();
  if (f.surface_mode != "voxel" && f.surface_mode != "exact")
    throw InputError("--surface-mode " + f.surface_mode + ": expected voxel or exact");
  if (!label_mode && !f.colors.empty())
    throw InputError("--colors: colour images come from labels (--labels, --meshes, --mesh-dir)");
  const bool meshes = !f.meshes.empty() || !f.mesh_dir.empty();
  mesh_voxel_size(f.voxel_size, meshes && f.surface_mode == "voxel",
                  "--meshes or --mesh-dir, --surface-mode voxel");

  SliceSettings settings;
  settings.interpolation = parse_interpolation(f.interp);
  if (label_mode) {
    // Labels are sampled nearest and stay integers.
    if (f.interp_given && settings.interpolation != Interpolation::Nearest)
      throw InputError("--interp " + f.interp + ": label images are nearest-neighbour");
    settings.interpolation = Interpolation::Nearest;
  }
  const std::string dtype = f.dtype_given || !label_mode ? f.dtype : "uint8";
  if (dtype != "float32" && dtype != "int16" && dtype != "uint8" && dtype != "uint16")
    throw InputError("--dtype " + dtype + ": expected float32, int16, uint8 or uint16");
  if (label_mode && dtype != "uint8" && dtype != "uint16")
    throw InputError("--dtype " + dtype + ": label images are uint8 or uint16");
  settings.output_type = parse_pixel_type(dtype);
  settings.fill_value = f.fill;
  std::optional<std::pair<double, double>> window;
  if (!f.window.empty()) {
    const auto w = parse_numbers(f.window, 2, "--window");
    if (!(w[1] > 0)) throw InputError("--window " + f.window + ": the width must be > 0");
    window = std::make_pair(w[0], w[1]);
  }

  // Everything small and checkable first, so a typo fails in milliseconds, not after loading a CT.
  // Outputs on one path overwrite each other, an output on an input destroys it: refused here.
  std::vector<NamedPath> inputs = {
      {"--volume", f.volume.path}, {"--labels", f.labels}, {"--mesh-dir", f.mesh_dir},
      {"--probe", f.probe},        {"--poses", f.poses},   {"--npy-config", f.volume.npy_config}};
  for (const std::string& mesh : f.meshes) inputs.push_back({"--meshes", mesh});
  check_distinct_outputs({{"--out", f.out}, {"--mask", f.mask}, {"--colors", f.colors}}, inputs);
  const ProbeGeometry probe = read_probe(f.probe, f.downsampling);
  const std::vector<Pose> poses = read_poses(f.poses, parse_world_frame(f.world));
  const StackFormat format = stack_format(f.out);
  if (window && format != StackFormat::PngDirectory)
    warn("--window applies to PNG output only; ignored for '" + f.out + "'");
  check_output_path(f.out, format == StackFormat::PngDirectory);
  if (!f.mask.empty()) check_image_output(f.mask, "--mask");
  if (!f.colors.empty())
    check_output_path(f.colors, stack_format(f.colors) == StackFormat::PngDirectory);

  StackSpec spec = probe_stack_spec(probe, settings.output_type, poses);
  spec.window = window;
  StackSpec color_spec = spec;
  color_spec.type = PixelType::UInt8;
  color_spec.components = 3;
  color_spec.window.reset();
  const size_t image_bytes = size_t(probe.image.pixel_count()) * pixel_size(spec.type);
  const int64_t chunk = chunk_images(
      image_bytes + (f.colors.empty() ? 0 : 3 * size_t(probe.image.pixel_count())), spec.count);
  const uint64_t held = check_stack_resources(
      f.out, spec, chunk, f.colors.empty() ? 0 : stack_memory_bytes(f.colors, color_spec, chunk));

  double load_seconds = 0;
  const Source source = make_source(f, probe, settings, device, &load_seconds);
  if (held > available_memory_bytes())  // the volume now takes its share
    throw ResourceError("output '" + f.out + "' needs " + gib(held) +
                        " in memory beside the volume; write .npy or a PNG directory instead");

  spec.mask = source.mask().data();
  std::unique_ptr<StackWriter> writer = StackWriter::create(f.out, spec);
  std::unique_ptr<StackWriter> color_writer =
      f.colors.empty() ? nullptr : StackWriter::create(f.colors, color_spec);
  ProgressBar progress("slicing", spec.count, !f.quiet);
  double slice_seconds = 0, write_seconds = 0;
  for (int64_t first = 0; first < spec.count; first += chunk) {
    const int64_t count = std::min(chunk, spec.count - first);
    void* out = writer->buffer(first, count);
    Stopwatch s;
    source.slice(poses.data() + first, size_t(count), out, size_t(first));
    slice_seconds += s.seconds();
    Stopwatch w;
    if (color_writer) {
      colorize(out, spec.type, count, spec.width, spec.height, source.mask().data(), source.colors,
               static_cast<uint8_t*>(color_writer->buffer(first, count)));
      color_writer->write(first, count);
    }
    writer->write(first, count);
    write_seconds += w.seconds();
    progress.update(first + count);
  }
  Stopwatch commit_clock;
  // All outputs or none: a failure writing the last leaves the earlier ones' old files in place.
  OutputSet outputs;
  writer->finish(outputs);
  if (color_writer) color_writer->finish(outputs);
  if (!f.mask.empty()) write_mask(f.mask, probe, source.mask(), &outputs);
  outputs.commit();
  write_seconds += commit_clock.seconds();
  progress.finish();

  if (f.verbose) {
    std::fprintf(stderr,
                 "sonoslice: source %s\n"
                 "sonoslice: probe: %s\n"
                 "sonoslice: load %.3f s, slice %.3f s (%.0f images/s, %d threads), write %.3f s, "
                 "total %.3f s\n",
                 source.description.c_str(), probe.describe().c_str(), load_seconds, slice_seconds,
                 double(spec.count) / std::max(slice_seconds, 1e-9), cpu_threads(), write_seconds,
                 total.seconds());
  }
}

}  // namespace

void add_slice_command(CLI::App& app) {
  auto flags = std::make_shared<SliceFlags>();
  CLI::App* cmd =
      app.add_subcommand("slice", "Slice a batch of probe poses through a volume or meshes");
  flags->volume.add_to(*cmd, /*path_required=*/false);
  cmd->add_option("--labels", flags->labels,
                  "A label volume (uint8/uint16): label images, nearest");
  cmd->add_option("--meshes", flags->meshes, "Surface meshes (label k for the k-th): label images");
  cmd->add_option("--mesh-dir", flags->mesh_dir,
                  "Folder of the meshes a fan-slicer surface config (--probe) names: <name>.vtk");
  cmd->add_option(
      "--surface-mode", flags->surface_mode,
      "Meshes: voxel (voxelise at --voxel-size, then slice; default) or exact (plane cuts)");
  cmd->add_option("--voxel-size", flags->voxel_size,
                  "Meshes, voxel mode: voxel size (mm, default 0.5)");
  cmd->add_option("--colors", flags->colors, "Also write colour images of the labels (RGB) here");
  cmd->add_option("--probe", flags->probe, "Probe JSON (native or fan-slicer config)")->required();
  cmd->add_option("--poses", flags->poses, "Pose file: .npy, .txt/.csv, .json")->required();
  cmd->add_option("--out", flags->out,
                  "Output: .nii/.nii.gz/.mha/.nrrd stack, .npy (N,H,W), or a directory of PNGs")
      ->required();
  cmd->add_option("--interp", flags->interp, "linear (default) or nearest (always, for labels)")
      ->each([flags](const std::string&) { flags->interp_given = true; });
  cmd->add_option("--fill", flags->fill, "Value outside the fan or the volume (default 0)");
  cmd->add_option("--dtype", flags->dtype,
                  "Output type: float32 (default), int16, uint8, uint16 (labels: uint8 default)")
      ->each([flags](const std::string&) { flags->dtype_given = true; });
  cmd->add_option("--downsampling", flags->downsampling, "Divide the probe image size by K");
  cmd->add_option("--world", flags->world, "Frame of the poses and meshes: LPS (default) or RAS");
  add_threads_option(*cmd, flags->threads);
  cmd->add_option("--mask", flags->mask, "Also write the HxW fan mask here");
  cmd->add_option("--window", flags->window, "PNG window level,width (default: robust auto)");
  cmd->add_option("--device", flags->device, "cpu (default), cuda or cuda:K");
  cmd->add_flag("--quiet,-q", flags->quiet, "No progress bar");
  cmd->add_flag("--verbose,-v", flags->verbose, "Print time spent loading, slicing and writing");
  cmd->callback([flags] { run_slice(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
