// sonoslice slice: a volume, a probe and a pose file → a stack of ultrasound-shaped images.
#include <cstdio>
#include <memory>
#include <sstream>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"

namespace sonoslice {
namespace cli {
namespace {

struct SliceFlags {
  VolumeFlags volume;
  std::string probe, poses, out, mask;
  std::string interp = "linear", dtype = "float32", world = "LPS", device = "cpu", window;
  double fill = 0.0;
  int downsampling = 1, threads = 0;
  bool quiet = false, verbose = false;
};

std::string gib(uint64_t bytes) {
  std::ostringstream s;
  s.precision(3);
  s << double(bytes) / double(1ull << 30) << " GiB";
  return s.str();
}

void run_slice(const SliceFlags& f) {
  Stopwatch total;
  set_cpu_threads(f.threads);
  const Device device = Device::parse(f.device);
  require_device(device);
  SliceSettings settings;
  settings.interpolation = parse_interpolation(f.interp);
  if (f.dtype != "float32" && f.dtype != "int16" && f.dtype != "uint8" && f.dtype != "uint16")
    throw InputError("--dtype " + f.dtype + ": expected float32, int16, uint8 or uint16");
  settings.output_type = parse_pixel_type(f.dtype);
  settings.fill_value = f.fill;
  std::optional<std::pair<double, double>> window;
  if (!f.window.empty()) {
    const auto w = parse_numbers(f.window, 2, "--window");
    if (!(w[1] > 0)) throw InputError("--window " + f.window + ": the width must be > 0");
    window = std::make_pair(w[0], w[1]);
  }

  // Everything small and checkable first, so a typo fails in milliseconds, not after loading a CT.
  const ProbeGeometry probe = read_probe(f.probe, f.downsampling);
  const std::vector<Pose> poses = read_poses(f.poses, parse_world_frame(f.world));
  const StackFormat format = stack_format(f.out);
  if (window && format != StackFormat::PngDirectory)
    warn("--window applies to PNG output only; ignored for '" + f.out + "'");
  check_output_path(f.out, format == StackFormat::PngDirectory);
  if (!f.mask.empty()) {
    const std::string ext = file_extension(f.mask);
    if (ext != ".png" && ext != ".npy" && ext != ".nii" && ext != ".nii.gz" && ext != ".mha" &&
        ext != ".nrrd")
      throw InputError("--mask '" + f.mask +
                       "': expected .png, .npy, .nii, .nii.gz, .mha or .nrrd");
    check_output_path(f.mask);
  }

  StackSpec spec;
  spec.type = settings.output_type;
  spec.width = probe.image.width;
  spec.height = probe.image.height;
  spec.count = int64_t(poses.size());
  spec.spacing_mm[0] = probe.image.spacing_mm[0];
  spec.spacing_mm[1] = probe.image.spacing_mm[1];
  spec.window = window;
  spec.poses = poses;
  const size_t image_bytes = size_t(probe.image.pixel_count()) * pixel_size(spec.type);
  const int64_t chunk = chunk_images(image_bytes, spec.count);
  const uint64_t total_bytes = uint64_t(image_bytes) * uint64_t(spec.count);
  const uint64_t held = stack_memory_bytes(f.out, spec, chunk);
  const uint64_t available = available_memory_bytes();
  if (held > available)
    throw ResourceError("output '" + f.out + "' needs " + gib(held) + " in memory (" +
                        std::to_string(spec.count) + " images of " + std::to_string(spec.width) +
                        "x" + std::to_string(spec.height) + " " + f.dtype + ") but only " +
                        gib(available) +
                        " is available; write .npy or a PNG directory (streamed) instead");
  if (format == StackFormat::Npy && total_bytes > free_disk_bytes(f.out))
    throw ResourceError("output '" + f.out + "' needs " + gib(total_bytes) + " on disk but only " +
                        gib(free_disk_bytes(f.out)) + " is free");

  Stopwatch load_clock;
  Volume volume = read_volume(f.volume.path, f.volume.options());
  const double load_seconds = load_clock.seconds();
  if (held > available_memory_bytes())  // the volume now takes its share
    throw ResourceError("output '" + f.out + "' needs " + gib(held) +
                        " in memory beside the volume; write .npy or a PNG directory instead");

  Slicer slicer(volume, probe, settings, device);
  spec.mask = slicer.mask().data();
  std::unique_ptr<StackWriter> writer = StackWriter::create(f.out, spec);
  ProgressBar progress("slicing", spec.count, !f.quiet);
  double write_seconds = 0;
  const double slice_seconds = slice_into(slicer, poses, *writer, chunk, progress, &write_seconds);
  Stopwatch commit_clock;
  writer->commit();
  if (!f.mask.empty()) write_mask(f.mask, probe, slicer.mask());
  write_seconds += commit_clock.seconds();
  progress.finish();

  if (f.verbose) {
    std::fprintf(stderr,
                 "sonoslice: volume %s: %lldx%lldx%lld %s\n"
                 "sonoslice: probe: %s\n"
                 "sonoslice: load %.3f s, slice %.3f s (%.0f images/s, %d threads), write %.3f s, "
                 "total %.3f s\n",
                 f.volume.path.c_str(), static_cast<long long>(volume.grid().dims[0]),
                 static_cast<long long>(volume.grid().dims[1]),
                 static_cast<long long>(volume.grid().dims[2]),
                 pixel_type_name(volume.pixel_type()).c_str(), probe.describe().c_str(),
                 load_seconds, slice_seconds, double(spec.count) / std::max(slice_seconds, 1e-9),
                 cpu_threads(), write_seconds, total.seconds());
  }
}

}  // namespace

void add_slice_command(CLI::App& app) {
  auto flags = std::make_shared<SliceFlags>();
  CLI::App* cmd = app.add_subcommand("slice", "Slice a batch of probe poses through a volume");
  flags->volume.add_to(*cmd, /*path_required=*/true);
  cmd->add_option("--probe", flags->probe, "Probe JSON (native or fan-slicer config)")->required();
  cmd->add_option("--poses", flags->poses, "Pose file: .npy, .txt/.csv, .json")->required();
  cmd->add_option("--out", flags->out,
                  "Output: .nii/.nii.gz/.mha/.nrrd stack, .npy (N,H,W), or a directory of PNGs")
      ->required();
  cmd->add_option("--interp", flags->interp, "linear (default) or nearest");
  cmd->add_option("--fill", flags->fill, "Value outside the fan or the volume (default 0)");
  cmd->add_option("--dtype", flags->dtype, "Output type: float32 (default), int16, uint8, uint16");
  cmd->add_option("--downsampling", flags->downsampling, "Divide the probe image size by K");
  cmd->add_option("--world", flags->world, "Frame of the poses: LPS (default) or RAS");
  cmd->add_option("--threads", flags->threads, "CPU threads (default: all)");
  cmd->add_option("--mask", flags->mask, "Also write the HxW fan mask here");
  cmd->add_option("--window", flags->window, "PNG window level,width (default: robust auto)");
  cmd->add_option("--device", flags->device, "cpu (default), cuda or cuda:K");
  cmd->add_flag("--quiet,-q", flags->quiet, "No progress bar");
  cmd->add_flag("--verbose,-v", flags->verbose, "Print time spent loading, slicing and writing");
  cmd->callback([flags] { run_slice(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
