// sonoslice compound: tracked frames (a PLUS sequence, a stack of 2D frames with poses, or 3-D
// beam-space frames with poses) → one reconstructed volume (freehand 3D ultrasound).
#include <cmath>
#include <cstdio>
#include <memory>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/BeamGeometryFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PlusConfig.h"
#include "sonoslice/io/PlusSequence.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"

namespace sonoslice {
namespace cli {
namespace {

struct CompoundFlags {
  std::string sequence, config, frames, poses, image_to_probe, probe, beam_frames, beam_geometry;
  std::string out, weights;
  std::string spacing, interp, compounding, fill_holes, clip_rect, image_to_reference;
  std::string device = "cpu", max_memory, dtype, world = "LPS";
  double rejection_threshold = std::nan("");
  int threads = 0, skip = 0;
  bool quiet = false, verbose = false;
};

std::string on_off(bool b) {
  return b ? "on" : "off";
}

// "8G", "512M", "1.5GiB", "2000000000" → bytes.
uint64_t parse_bytes(const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  std::string unit(end);
  for (auto& c : unit) c = char(std::toupper(static_cast<unsigned char>(c)));
  double scale = 1;
  if (unit == "K" || unit == "KB" || unit == "KIB")
    scale = 1024.0;
  else if (unit == "M" || unit == "MB" || unit == "MIB")
    scale = 1024.0 * 1024;
  else if (unit == "G" || unit == "GB" || unit == "GIB")
    scale = 1024.0 * 1024 * 1024;
  else if (unit == "T" || unit == "TB" || unit == "TIB")
    scale = 1024.0 * 1024 * 1024 * 1024;
  else if (!unit.empty() && unit != "B")
    throw InputError("--max-memory " + text + ": expected a size such as 8G, 512M or 2000000000");
  if (end == text.c_str() || !(v > 0) || !std::isfinite(v))
    throw InputError("--max-memory " + text + ": expected a positive size such as 8G or 512M");
  return uint64_t(v * scale);
}

void check_volume_path(const std::string& flag, const std::string& path) {
  check_output_file(flag, path, {".nii", ".nii.gz", ".mha", ".mhd", ".nrrd", ".npy"},
                    "expected .nii, .nii.gz, .mha, .nrrd or .npy");
}

// Pixel (u, v) → probe mm for a sonoslice or fan-slicer probe's image grid.
Mat4 image_to_probe_of(const ProbeGeometry& p) {
  Mat4 m;
  m.m[0][0] = p.image.spacing_mm[0];
  m.m[1][1] = p.image.spacing_mm[1];
  m.m[0][3] = p.image.origin_mm[0];
  m.m[1][3] = p.image.origin_mm[1];
  return m;
}

// The frames, whichever way they came, ready for the Compounder.
struct Frames {
  std::string description;
  bool beams = false;
  int width = 0, height = 0;  // 2D frames
  BeamGeometry geometry;      // beam-space frames
  PixelType type = PixelType::UInt8;
  std::vector<const void*> data;   // one pointer per frame that goes in
  std::vector<Mat4> to_reference;  // image (or probe, for beams) → reference, per frame
  int64_t total = 0;               // frames in the input
  std::string skipped;             // why some did not go in
  // Owners of the pixel memory.
  std::shared_ptr<PlusSequence> sequence;
  Volume stack;
  NpyArray beam_array;

  size_t samples_per_frame() const {
    return beams ? size_t(geometry.n_elevation) * geometry.n_azimuth * geometry.n_samples
                 : size_t(width) * height;
  }
  size_t frame_bytes() const { return samples_per_frame() * pixel_size(type); }
};

// Reads --poses (one per frame of `frames_path`, given with `frames_flag`) and adds the
// fr->total frames stored one after the other at `pixels`, each with its pose followed by
// `*image_to_probe` (2D frames) or its pose alone (null: beam-space frames).
void add_posed_frames(const CompoundFlags& f, const std::string& frames_flag,
                      const std::string& frames_path, const void* pixels,
                      const Mat4* image_to_probe, Frames* fr) {
  const std::vector<Pose> poses = read_poses(f.poses, parse_world_frame(f.world));
  if (int64_t(poses.size()) != fr->total)
    throw InputError("--poses '" + f.poses + "' has " + std::to_string(poses.size()) +
                     " poses but " + frames_flag + " '" + frames_path + "' has " +
                     std::to_string(fr->total) + " frames");
  const size_t frame_bytes = fr->frame_bytes();
  for (int64_t k = 0; k < fr->total; ++k) {
    fr->data.push_back(static_cast<const char*>(pixels) + size_t(k) * frame_bytes);
    fr->to_reference.push_back(image_to_probe ? poses[size_t(k)] * *image_to_probe
                                              : poses[size_t(k)]);
  }
}

Frames read_sequence(const CompoundFlags& f, const PlusReconstructionConfig* config, int skip) {
  Frames fr;
  fr.sequence = std::make_shared<PlusSequence>(read_plus_sequence(f.sequence));
  const PlusSequence& s = *fr.sequence;
  fr.width = s.width;
  fr.height = s.height;
  fr.type = s.pixel_type;
  fr.total = s.frame_count;
  TransformRepository base = config ? config->coordinate_definitions : TransformRepository{};
  std::string from = config ? config->image_frame : "Image";
  std::string to = config ? config->reference_frame : "Reference";
  if (!f.image_to_reference.empty())
    std::tie(from, to) = TransformRepository::split_name(f.image_to_reference);
  if (!f.image_to_probe.empty())
    base.set("Image", "Probe", read_matrix(f.image_to_probe, "--image-to-probe"));
  const PlusFrameSelection sel =
      select_plus_frames(s, base, from, to, skip,
                         config ? "" : "; give the calibration with --config or --image-to-probe");
  for (size_t k = 0; k < sel.frames.size(); ++k) {
    fr.data.push_back(s.frame_pixels(sel.frames[k]));
    fr.to_reference.push_back(sel.to_reference[k]);
  }
  fr.skipped = sel.skipped_reason(from, to);
  const bool skipped_by_interval = skip > 1 && s.frame_count > 1;
  fr.description = f.sequence + ": " + std::to_string(s.frame_count) + " frames of " +
                   std::to_string(s.width) + "x" + std::to_string(s.height) + " " +
                   to_string(s.pixel_type) + " (orientation " + s.orientation + ")" +
                   (skipped_by_interval ? ", every " + std::to_string(skip) + "th used" : "");
  return fr;
}

Frames read_frame_stack(const CompoundFlags& f, Mat4* image_to_probe) {
  Frames fr;
  fr.stack = read_volume(f.frames);
  const auto& d = fr.stack.grid().dims;
  fr.width = int(d[0]);
  fr.height = int(d[1]);
  fr.type = fr.stack.pixel_type();
  fr.total = d[2];
  add_posed_frames(f, "--frames", f.frames, fr.stack.data(), image_to_probe, &fr);
  fr.description = f.frames + ": " + std::to_string(d[2]) + " frames of " + std::to_string(d[0]) +
                   "x" + std::to_string(d[1]) + " " + to_string(fr.type);
  return fr;
}

Frames read_beam_frames(const CompoundFlags& f) {
  Frames fr;
  fr.beams = true;
  if (file_extension(f.beam_frames) != ".npy")
    throw InputError("--beam-frames '" + f.beam_frames +
                     "': expected a .npy of shape (N, n_elevation, n_azimuth, n_samples)");
  fr.beam_array = read_npy(f.beam_frames);
  const auto& sh = fr.beam_array.shape;
  if ((sh.size() != 4 && sh.size() != 3) || fr.beam_array.fortran_order)
    throw InputError("--beam-frames '" + f.beam_frames +
                     "': expected a C-order array of shape (N, n_elevation, n_azimuth, n_samples)");
  const size_t o = sh.size() == 4 ? 1 : 0;
  fr.geometry = read_beam_geometry(f.beam_geometry);
  fr.geometry.n_elevation = int(sh[o]);
  fr.geometry.n_azimuth = int(sh[o + 1]);
  fr.geometry.n_samples = int(sh[o + 2]);
  fr.geometry.validate("--beam-geometry '" + f.beam_geometry + "'");
  fr.type = fr.beam_array.type;
  fr.total = sh.size() == 4 ? sh[0] : 1;
  add_posed_frames(f, "--beam-frames", f.beam_frames, fr.beam_array.data.get(), nullptr, &fr);
  fr.description = f.beam_frames + ": " + std::to_string(fr.total) + " beam-space frames of " +
                   std::to_string(sh[o]) + "x" + std::to_string(sh[o + 1]) + "x" +
                   std::to_string(sh[o + 2]) + " " + to_string(fr.type);
  return fr;
}

void run_compound(const CompoundFlags& f) {
  Stopwatch total;
  const Device device = setup_device(f.device, f.threads);
  const int inputs = !f.sequence.empty() + !f.frames.empty() + !f.beam_frames.empty();
  if (inputs != 1)
    throw InputError("compound: give exactly one of --sequence, --frames, --beam-frames");
  if (!f.config.empty() && f.sequence.empty())
    throw InputError("--config: a PLUS configuration goes with --sequence");
  if (!f.frames.empty() && (f.poses.empty() || (f.image_to_probe.empty() && f.probe.empty())))
    throw InputError(
        "--frames needs --poses and the pixel-to-probe mapping (--image-to-probe or --probe)");
  if (!f.beam_frames.empty() && (f.poses.empty() || f.beam_geometry.empty()))
    throw InputError("--beam-frames needs --poses and --beam-geometry");

  // Settings: PLUS XML first, then the flags.
  std::unique_ptr<PlusReconstructionConfig> config;
  if (!f.config.empty())
    config = std::make_unique<PlusReconstructionConfig>(read_plus_config(f.config));
  CompoundSettings settings = config ? config->settings : CompoundSettings{};
  FrameClip clip = config ? config->clip : FrameClip{};
  std::optional<Vec3> spacing = config ? config->output_spacing_mm : std::nullopt;
  int skip = config ? config->skip_interval : 1;
  if (!f.spacing.empty()) {
    const bool one = f.spacing.find(',') == std::string::npos;
    const auto v = parse_numbers(f.spacing, one ? 1 : 3, "--spacing");
    spacing = one ? Vec3{{v[0], v[0], v[0]}} : Vec3{{v[0], v[1], v[2]}};
    for (double s : *spacing)
      if (!(s > 0)) throw InputError("--spacing " + f.spacing + ": must be > 0 mm");
  }
  if (!spacing) throw InputError("compound: give --spacing (mm) or a --config with OutputSpacing");
  if (!f.interp.empty()) settings.interpolation = parse_interpolation(f.interp);
  if (!f.compounding.empty()) settings.mode = parse_compounding_mode(f.compounding);
  if (!f.fill_holes.empty()) {
    if (f.fill_holes != "on" && f.fill_holes != "off")
      throw InputError("--fill-holes " + f.fill_holes + ": expected on or off");
    settings.fill_holes = f.fill_holes == "on";
    if (settings.fill_holes && settings.hole_filling.empty())
      settings.hole_filling = CompoundSettings{}.hole_filling;
  }
  if (!std::isnan(f.rejection_threshold)) settings.rejection_threshold = f.rejection_threshold;
  if (f.skip < 0) throw InputError("--skip must be >= 1");
  if (f.skip > 0) skip = f.skip;
  if (!f.clip_rect.empty()) {
    const auto r = parse_numbers(f.clip_rect, 4, "--clip-rect");
    for (double x : r)
      if (x < 0 || x != std::floor(x))
        throw InputError("--clip-rect " + f.clip_rect +
                         ": expected four whole numbers X,Y,W,H >= 0");
    clip.x = int(r[0]);
    clip.y = int(r[1]);
    clip.width = int(r[2]);
    clip.height = int(r[3]);
  }
  const uint64_t max_memory = f.max_memory.empty() ? 0 : parse_bytes(f.max_memory);
  check_volume_path("--out", f.out);
  if (!f.weights.empty()) check_volume_path("--weights", f.weights);

  // Frames.
  Stopwatch read_clock;
  Frames frames;
  if (!f.sequence.empty()) {
    frames = read_sequence(f, config.get(), skip);
  } else if (!f.frames.empty()) {
    Mat4 image_to_probe;
    if (!f.probe.empty()) {
      const ProbeGeometry probe = read_probe(f.probe);
      image_to_probe = image_to_probe_of(probe);
      if (f.clip_rect.empty()) clip.custom_mask = probe.mask();
    }
    if (!f.image_to_probe.empty())
      image_to_probe = read_matrix(f.image_to_probe, "--image-to-probe");
    frames = read_frame_stack(f, &image_to_probe);
    if (!clip.custom_mask.empty() &&
        clip.custom_mask.size() != size_t(frames.width) * size_t(frames.height))
      throw InputError("--probe '" + f.probe + "': its image is not the size of the frames (" +
                       std::to_string(frames.width) + "x" + std::to_string(frames.height) + ")");
  } else {
    frames = read_beam_frames(f);
  }
  const double read_seconds = read_clock.seconds();
  if (!frames.skipped.empty())
    warn("skipped " + std::to_string(frames.total - int64_t(frames.data.size())) + " of " +
         std::to_string(frames.total) + " frames: " + frames.skipped);
  if (frames.data.empty())
    throw InputError("compound: no frame can be used (" + frames.skipped + ")");

  // Output grid: the PLUS XML's when it gives origin and extent (and, without --spacing, its
  // spacing is the one in use), else around the frames.
  const std::optional<VolumeGrid> config_grid =
      config && f.spacing.empty() ? config->output_grid() : std::nullopt;
  VolumeGrid grid;
  if (config_grid) {
    grid = *config_grid;
  } else if (frames.beams) {
    grid = Compounder::grid_around_beams(frames.to_reference, frames.geometry, *spacing);
  } else {
    grid =
        Compounder::grid_around(frames.to_reference, frames.width, frames.height, clip, *spacing);
  }
  PixelType out_type = frames.type;
  if (!f.dtype.empty()) out_type = parse_pixel_type(f.dtype);
  if (out_type == PixelType::Float64 || out_type == PixelType::Int8) out_type = PixelType::Float32;

  Compounder compounder(grid, settings, device, max_memory, out_type);
  if (f.verbose) {
    std::fprintf(stderr, "sonoslice: %s\n", frames.description.c_str());
    std::fprintf(stderr,
                 "sonoslice: grid %lldx%lldx%lld at %g,%g,%g mm, origin %g,%g,%g; %s splats, %s "
                 "compounding, hole filling %s, %s\n",
                 (long long)grid.dims[0], (long long)grid.dims[1], (long long)grid.dims[2],
                 grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2], grid.origin_mm[0],
                 grid.origin_mm[1], grid.origin_mm[2],
                 settings.interpolation == Interpolation::Linear ? "linear" : "nearest",
                 settings.mode == CompoundingMode::Mean  ? "mean"
                 : settings.mode == CompoundingMode::Max ? "max"
                                                         : "latest",
                 on_off(settings.fill_holes).c_str(), device.to_string().c_str());
  }

  // Frames in chunks of about 64 MiB (frames of a sequence are not contiguous once some are
  // skipped: runs of consecutive frames go together).
  const size_t frame_bytes = frames.frame_bytes();
  const int64_t n = int64_t(frames.data.size());
  const int64_t chunk = chunk_images(frame_bytes, n);
  ProgressBar progress("compounding", n, !f.quiet);
  Stopwatch splat_clock;
  for (int64_t first = 0; first < n;) {
    int64_t count = 1;
    while (first + count < n && count < chunk &&
           static_cast<const char*>(frames.data[size_t(first + count)]) ==
               static_cast<const char*>(frames.data[size_t(first)]) + size_t(count) * frame_bytes)
      ++count;
    if (frames.beams)
      compounder.add_beams(frames.data[size_t(first)], frames.type, frames.geometry, count,
                           frames.to_reference.data() + first);
    else
      compounder.add_images(frames.data[size_t(first)], frames.type, frames.width, frames.height,
                            count, frames.to_reference.data() + first, clip);
    first += count;
    progress.update(first);
  }
  const double splat_seconds = splat_clock.seconds();
  Stopwatch finish_clock;
  const Volume volume = compounder.volume(out_type);
  const double finish_seconds = finish_clock.seconds();
  Stopwatch write_clock;
  write_volume(f.out, volume);
  if (!f.weights.empty()) write_volume(f.weights, compounder.weights());
  const double write_seconds = write_clock.seconds();
  progress.finish();

  if (!f.quiet) {
    const double samples = double(n) * double(frames.samples_per_frame());
    std::fprintf(
        stderr,
        "sonoslice: %lld of %lld frames into %lldx%lldx%lld voxels: read %.3f s, "
        "splatting %.3f s (%.0f frames/s, %.0f M samples/s, %d threads), finishing %.3f s, "
        "writing %.3f s, total %.3f s\n",
        (long long)n, (long long)frames.total, (long long)grid.dims[0], (long long)grid.dims[1],
        (long long)grid.dims[2], read_seconds, splat_seconds,
        double(n) / std::max(splat_seconds, 1e-9), samples / std::max(splat_seconds, 1e-9) / 1e6,
        device.type == DeviceType::CPU ? cpu_threads() : 0, finish_seconds, write_seconds,
        total.seconds());
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
                  "A stack of 2D frames (.nii/.mha/.nrrd/.npy (N,H,W)), with --poses and "
                  "--image-to-probe or --probe");
  cmd->add_option("--poses", flags->poses,
                  "Probe-to-reference poses, one per frame (.npy/.txt/.json)");
  cmd->add_option("--image-to-probe", flags->image_to_probe,
                  "Pixel (i,j) -> probe mm: 16 numbers, or a file with one 4x4 matrix");
  cmd->add_option("--probe", flags->probe,
                  "--frames from `sonoslice slice`: its probe file (pixel grid and fan)");
  cmd->add_option("--beam-frames", flags->beam_frames,
                  "3-D beam-space frames: .npy (N, n_elevation, n_azimuth, n_samples)");
  cmd->add_option("--beam-geometry", flags->beam_geometry, "Their geometry JSON (docs/conventions.md §7)");
  cmd->add_option("--out", flags->out, "Output volume: .nii/.nii.gz/.mha/.nrrd/.npy")->required();
  cmd->add_option("--weights", flags->weights, "Also write the splat weight per voxel (float32)");
  cmd->add_option("--spacing", flags->spacing,
                  "Voxel size in mm: S or SX,SY,SZ (default: the XML's)");
  cmd->add_option("--interp", flags->interp,
                  "nearest or linear splats (default: the XML's, else linear)");
  cmd->add_option("--compounding", flags->compounding, "mean (default), max or latest");
  cmd->add_option("--fill-holes", flags->fill_holes, "on or off (default: the XML's, else off)");
  cmd->add_option("--clip-rect", flags->clip_rect, "X,Y,W,H: the W x H pixels from (X,Y) go in");
  cmd->add_option("--rejection-threshold", flags->rejection_threshold,
                  "Pixels below this value are not inserted");
  cmd->add_option("--skip", flags->skip,
                  "Use every K-th frame (default: the XML's SkipInterval, else 1)");
  cmd->add_option("--image-to-reference", flags->image_to_reference,
                  "Transform to reconstruct in, e.g. ImageToReference (default) or ImageToTracker");
  cmd->add_option("--dtype", flags->dtype, "Output type (default: the frames' type)");
  cmd->add_option("--max-memory", flags->max_memory,
                  "Memory the reconstruction may use, e.g. 8G (default: what is available)");
  cmd->add_option("--world", flags->world, "Frame of --poses: LPS (default) or RAS");
  cmd->add_option("--device", flags->device, "cpu (default), cuda or cuda:K");
  cmd->add_option("--threads", flags->threads, "CPU threads (default: all)");
  cmd->add_flag("--quiet,-q", flags->quiet, "No progress bar or summary");
  cmd->add_flag("--verbose,-v", flags->verbose, "Print the input and the settings used");
  cmd->callback([flags] { run_compound(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
