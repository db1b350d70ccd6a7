// sonoslice compound: tracked frames (a PLUS sequence, a stack of 2D frames with poses, or 3-D
// beam-space frames with poses) → one reconstructed volume (freehand 3D ultrasound).
#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>

#include "Commands.h"
#include "Common.h"
#include "ReconstructionFlags.h"
#include "sonoslice/compound/Reconstruction.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/plus/PlusConfig.h"

namespace sonoslice {
namespace cli {
namespace {

struct CompoundFlags {
  std::string sequence, config, frames, poses, image_to_probe, probe, beam_frames, beam_geometry;
  std::string out, weights;
  ReconstructionFlags recon;
  std::string image_to_reference, world = "LPS";
  std::optional<int> skip;
  int downsampling = 1;
  bool quiet = false, verbose = false, plus_exact = false;
  std::string plus_optimization;
  std::string plus_grid;
};

ReconstructionOptions options_of(const CompoundFlags& f) {
  ReconstructionOptions o;
  // Messages about the probe name its file too.
  o.names = [probe = f.probe](const std::string& parameter) {
    const std::string flag = flag_of(parameter);
    return parameter == "probe" && !probe.empty() ? flag + " '" + probe + "'" : flag;
  };
  f.recon.apply(o);
  if (f.skip) o.skip = *f.skip;
  if (!f.image_to_reference.empty()) o.transform = f.image_to_reference;
  if (!f.image_to_probe.empty())
    o.image_to_probe = read_matrix(f.image_to_probe, "--image-to-probe");
  o.plus_exact = f.plus_exact;
  if (!f.plus_optimization.empty()) {
    if (!f.plus_exact) throw InputError("--plus-optimization needs --plus-exact");
    o.plus_optimization = f.plus_optimization;
  }
  if (!f.plus_grid.empty()) {
    if (!f.plus_exact) throw InputError("--plus-grid needs --plus-exact");
    o.plus_grid = f.plus_grid;
  }
  return o;
}

void run_compound(const CompoundFlags& f) {
  Stopwatch total;
  ReconstructionOptions options = options_of(f);
  options.device = setup_device(f.recon.device, f.recon.threads);
  if (!f.config.empty() && f.sequence.empty())
    throw InputError("--config: a PLUS configuration goes with --sequence");
  // Refuse unwritable outputs before the (possibly long) reading and splatting, and outputs that
  // would overwrite each other or an input.
  check_distinct_outputs({{"--out", f.out}, {"--weights", f.weights}},
                         {{"--sequence", f.sequence},
                          {"--config", f.config},
                          {"--frames", f.frames},
                          {"--poses", f.poses},
                          {"--image-to-probe", f.image_to_probe},
                          {"--probe", f.probe},
                          {"--beam-frames", f.beam_frames},
                          {"--beam-geometry", f.beam_geometry}});
  check_volume_output(f.out, "--out");
  if (!f.weights.empty()) check_volume_output(f.weights, "--weights");

  FrameFiles files;
  files.sequence = f.sequence;
  files.frames = f.frames;
  files.poses = f.poses;
  files.probe = f.probe;
  files.probe_downsampling = f.downsampling;
  files.beam_frames = f.beam_frames;
  files.beam_geometry = f.beam_geometry;
  files.world = parse_world_frame(f.world);
  const LoadedFrames frames = read_frame_files(files, flag_of);
  std::optional<PlusReconstructionConfig> config;
  if (!f.config.empty()) config = read_plus_config(f.config);

  Reconstruction recon(frames.source, config ? &*config : nullptr, options);
  const ReconstructionReport& report = recon.report();
  const VolumeGrid& grid = recon.grid();
  const CompoundSettings& s = recon.settings();
  if (f.verbose) {
    std::fprintf(stderr, "sonoslice: %s\n", report.input.c_str());
    std::fprintf(stderr,
                 "sonoslice: grid %lldx%lldx%lld at %g,%g,%g mm, origin %g,%g,%g (%s); %s splats, "
                 "%s compounding, hole filling %s, output %s, %s\n",
                 (long long)grid.dims[0], (long long)grid.dims[1], (long long)grid.dims[2],
                 grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2], grid.origin_mm[0],
                 grid.origin_mm[1], grid.origin_mm[2],
                 report.grid_given         ? "given"
                 : report.grid_from_config ? "from the configuration"
                                           : "around the frames",
                 to_string(s.interpolation), to_string(s.mode), s.fill_holes ? "on" : "off",
                 to_string(recon.output_type()).c_str(), recon.device().to_string().c_str());
  }

  ProgressBar progress("compounding", report.frames_used, !f.quiet);
  const ReconstructionResult result =
      recon.run(!f.weights.empty(), [&](int64_t done, int64_t) { progress.update(done); });
  Stopwatch write_clock;
  // Both or neither: a failure writing --weights leaves the old --out in place.
  OutputSet outputs;
  write_volume(f.out, result.volume, &outputs);
  if (!f.weights.empty()) write_volume(f.weights, result.weights, &outputs);
  outputs.commit();
  const double write_seconds = write_clock.seconds();
  progress.finish();

  if (!f.quiet) {
    const double n = double(report.frames_used);
    const double samples = n * double(frames.source.samples_per_frame());
    const double splat = std::max(report.splat_seconds, 1e-9);
    std::fprintf(
        stderr,
        "sonoslice: %lld of %lld frames into %lldx%lldx%lld voxels: read %.3f s, "
        "splatting %.3f s (%.0f frames/s, %.0f M samples/s, %d threads), finishing %.3f s, "
        "writing %.3f s, total %.3f s\n",
        (long long)report.frames_used, (long long)report.frames_in_input, (long long)grid.dims[0],
        (long long)grid.dims[1], (long long)grid.dims[2], frames.read_seconds, report.splat_seconds,
        n / splat, samples / splat / 1e6,
        recon.device().type == DeviceType::CPU ? cpu_threads() : 0, report.finish_seconds,
        write_seconds, total.seconds());
  }
}

}  // namespace

void add_compound_command(CLI::App& app) {
  auto flags = std::make_shared<CompoundFlags>();
  CLI::App* cmd = app.add_subcommand(
      "compound", "Reconstruct a volume from tracked frames (freehand 3D ultrasound)");
  cmd->add_option("--sequence", flags->sequence,
                  "PLUS sequence: .igs.mha/.seq.mha/.mha or .igs.nrrd/.seq.nrrd/.nrrd");
  cmd->add_option(
      "--config", flags->config,
      "PLUS configuration XML: calibration (Image->Probe) and VolumeReconstruction settings");
  cmd->add_option("--frames", flags->frames,
                  "A stack of 2D frames (.nii/.mha/.nrrd/.npy (N,H,W), a multi-frame DICOM .dcm, a "
                  "folder of PNGs), with --poses and --image-to-probe or --probe");
  cmd->add_option("--poses", flags->poses,
                  "Probe-to-reference poses, one per frame (.npy/.txt/.json)");
  cmd->add_option("--image-to-probe", flags->image_to_probe,
                  "Pixel (i,j) -> probe mm: 16 numbers, or a file with one 4x4 matrix");
  cmd->add_option("--probe", flags->probe,
                  "--frames from `sonoslice slice`: its probe file (pixel grid and fan)");
  cmd->add_option("--downsampling", flags->downsampling,
                  "The --downsampling the frames were sliced at (divides --probe's image size)");
  cmd->add_option("--beam-frames", flags->beam_frames,
                  "3-D beam-space frames: .npy (N, n_elevation, n_azimuth, n_samples)");
  cmd->add_option("--beam-geometry", flags->beam_geometry,
                  "Their geometry JSON (docs/conventions.md §7)");
  cmd->add_option("--out", flags->out, "Output volume: .nii/.nii.gz/.mha/.nrrd/.npy")->required();
  cmd->add_option("--weights", flags->weights, "Also write the splat weight per voxel (float32)");
  flags->recon.add_to(*cmd);
  cmd->add_option("--skip", flags->skip,
                  "Use every K-th frame (default: the XML's SkipInterval, else 1)");
  cmd->add_option("--image-to-reference", flags->image_to_reference,
                  "Transform to reconstruct in, e.g. ImageToReference (default) or ImageToTracker");
  cmd->add_flag("--plus-exact", flags->plus_exact,
                "PLUS's arithmetic bit for bit: output in the frames' type rounded after every "
                "update, PLUS's uint16 weights (docs/compounding.md 4b); CPU, 2D frames");
  cmd->add_option("--plus-optimization", flags->plus_optimization,
                  "With --plus-exact: PLUS's insertion path none, partial or full (default: the "
                  "XML's Optimization, else full as in PLUS)");
  cmd->add_option("--plus-grid", flags->plus_grid,
                  "With --plus-exact and no grid in the XML: legacy (default; PLUS 2.x, origin at "
                  "the frames' minimum) or lattice (current PLUS/IGSIO, origin on a multiple of "
                  "the spacing)");
  cmd->add_option("--world", flags->world, "Frame of --poses: LPS (default) or RAS");
  cmd->add_flag("--quiet,-q", flags->quiet, "No progress bar or summary");
  cmd->add_flag("--verbose,-v", flags->verbose, "Print the input and the settings used");
  cmd->callback([flags] { run_compound(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
