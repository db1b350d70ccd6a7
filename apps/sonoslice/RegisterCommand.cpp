// sonoslice register: ultrasound frames, their initial poses and a volume → refined poses
// (N, 4, 4) and a JSON report (docs/registration.md).
#include <cstdio>
#include <cstdlib>
#include <memory>

#include <nlohmann/json.hpp>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice {
namespace cli {
namespace {

struct RegisterFlags {
  VolumeFlags volume;
  std::string probe, frames, poses, out, report, user_mask, world = "LPS";
  std::string metric = "ncc", optimizer, mode = "per-frame", pyramid;
  int downsampling = 1, starts = 1;
  double search_rot_deg = 10, search_trans_mm = 10, smoothness = 0.3;
  uint64_t seed = 0;
  std::optional<int> threads;
  bool verbose = false;
};

/// The frames as a float32 stack (W, H, N), checked against the probe's image size.
Volume read_frames(const std::string& path, const ProbeGeometry& probe, size_t* count) {
  const Volume stack = read_image_stack(path, "--frames");
  const VolumeGrid& g = stack.grid();
  if (g.dims[0] != probe.image.width || g.dims[1] != probe.image.height)
    throw InputError("--frames '" + path + "': frames of " + std::to_string(g.dims[0]) + "x" +
                     std::to_string(g.dims[1]) + " pixels, but the probe's image is " +
                     std::to_string(probe.image.width) + "x" + std::to_string(probe.image.height) +
                     " (W x H; check --probe and --downsampling)");
  *count = size_t(g.dims[2]);
  return stack.pixel_type() == PixelType::Float32 ? stack : stack.converted(PixelType::Float32);
}

void run_register(const RegisterFlags& f) {
  Stopwatch total;
  if (f.volume.path.empty()) throw InputError("register: --volume is required");
  for (const auto& [flag, value] : {std::pair<const char*, const std::string&>{"--probe", f.probe},
                                    {"--frames", f.frames},
                                    {"--poses", f.poses},
                                    {"--out", f.out}})
    if (value.empty()) throw InputError(std::string("register: ") + flag + " is required");
  setup_threads(f.threads);
  RegistrationSettings settings;
  settings.metric = parse_registration_metric(f.metric);
  // Default: LM for the metrics with derivatives (ssd, ncc), BOBYQA for lncc, mi and lc2.
  const std::string optimizer = !f.optimizer.empty()                      ? f.optimizer
                                : metric_has_derivatives(settings.metric) ? "lm"
                                                                          : "bobyqa";
  settings.optimizer = parse_registration_optimizer(optimizer);
  settings.mode = parse_registration_mode(f.mode);
  settings.starts = f.starts;
  settings.search_rot_deg = f.search_rot_deg;
  settings.search_trans_mm = f.search_trans_mm;
  settings.seed = f.seed;
  settings.smoothness = f.smoothness;
  if (!f.pyramid.empty()) {
    settings.pyramid.clear();
    size_t start = 0;
    while (start <= f.pyramid.size()) {
      const size_t comma = std::min(f.pyramid.find(',', start), f.pyramid.size());
      const std::string item = f.pyramid.substr(start, comma - start);
      char* end = nullptr;
      const long level = std::strtol(item.c_str(), &end, 10);
      if (item.empty() || *end != '\0' || level < 1 || level > 64)
        throw InputError("--pyramid " + f.pyramid +
                         ": expected block sizes from 1 to 64, coarse to fine, e.g. 8,4,2,1");
      settings.pyramid.push_back(int(level));
      start = comma + 1;
    }
  }
  settings.validate();
  if (file_extension(f.out) != ".npy")
    throw InputError("--out '" + f.out + "': refined poses are written as .npy (N, 4, 4)");
  if (!f.report.empty() && file_extension(f.report) != ".json")
    throw InputError("--report '" + f.report + "': the report is JSON (.json)");
  // The refined poses' .npy has no geometry sidecar: REFINED.npy beside REFINED.json is fine.
  check_distinct_outputs({{"--out", f.out, false}, {"--report", f.report}},
                         {{"--volume", f.volume.path},
                          {"--probe", f.probe},
                          {"--frames", f.frames},
                          {"--poses", f.poses, false},
                          {"--mask", f.user_mask}});
  check_output_path(f.out);
  if (!f.report.empty()) check_output_path(f.report);

  // Small inputs first, so that a typo fails before the volume is read.
  const ProbeGeometry probe = read_probe(f.probe, f.downsampling);
  const WorldFrame world = parse_world_frame(f.world);
  const std::vector<Pose> initial = read_poses(f.poses, world);
  size_t count = 0;
  const Volume frames = read_frames(f.frames, probe, &count);
  if (initial.size() != count)
    throw InputError("--poses '" + f.poses + "': " + std::to_string(initial.size()) +
                     " poses for " + std::to_string(count) + " frames in '" + f.frames + "'");
  std::vector<uint8_t> user_mask;
  if (!f.user_mask.empty()) {
    const Volume m = read_image_stack(f.user_mask, "--mask");
    if (m.grid().dims[0] != probe.image.width || m.grid().dims[1] != probe.image.height ||
        m.grid().dims[2] != 1)
      throw InputError("--mask '" + f.user_mask + "': expected one " +
                       std::to_string(probe.image.width) + "x" +
                       std::to_string(probe.image.height) + " image");
    user_mask.resize(size_t(probe.image.pixel_count()));
    visit_pixel_type(m.pixel_type(), [&](auto zero) {
      using T = decltype(zero);
      for (size_t i = 0; i < user_mask.size(); ++i)
        user_mask[i] = m.data_as<T>()[i] != T(0) ? 1 : 0;
    });
  }
  Stopwatch load;
  const Volume volume = read_volume(f.volume.path, f.volume.options());
  const double load_seconds = load.seconds();

  const FrameRegistration reg(volume, probe, frames.data_as<float>(), count,
                              user_mask.empty() ? nullptr : user_mask.data());
  RegistrationReport report;
  const std::vector<Pose> refined = reg.run(initial, settings, &report);

  OutputSet outputs;  // both or neither
  std::vector<double> flat;
  for (const Pose& lps : refined) {
    const Pose p = pose_to_lps(lps, world);  // back to the input's frame (its own inverse)
    for (int i = 0; i < 16; ++i) flat.push_back(p.m[i / 4][i % 4]);
  }
  write_npy(f.out, PixelType::Float64, {int64_t(refined.size()), 4, 4}, flat.data(), &outputs);
  if (!f.report.empty()) {
    nlohmann::json j;
    j["metric"] = f.metric;
    j["optimizer"] = optimizer;
    j["mode"] = f.mode;
    j["starts"] = f.starts;
    if (settings.mode == RegistrationMode::SmoothSweep) j["smoothness"] = f.smoothness;
    j["frames"] = nlohmann::json::array();
    for (const FrameReport& r : report.frames)
      j["frames"].push_back({{"index", r.index},
                             {"metric", r.metric},
                             {"evaluations", r.evaluations},
                             {"iterations", r.iterations},
                             {"translation_change_mm", r.translation_change_mm},
                             {"rotation_change_deg", r.rotation_change_deg}});
    j["evaluations"] = report.evaluations;
    j["seconds"] = report.seconds;
    write_text_file(f.report, j.dump(2) + "\n", &outputs);
  }
  outputs.commit();
  if (f.verbose)
    std::fprintf(stderr,
                 "sonoslice: %zu frames, %s, %s; load %.3f s, register %.3f s (%lld pose "
                 "evaluations, %.0f per second, %d threads), total %.3f s\n",
                 count, f.metric.c_str(), f.mode.c_str(), load_seconds, report.seconds,
                 static_cast<long long>(report.evaluations),
                 double(report.evaluations) / std::max(report.seconds, 1e-9), cpu_threads(),
                 total.seconds());
}

}  // namespace

void add_register_command(CLI::App& app) {
  auto flags = std::make_shared<RegisterFlags>();
  CLI::App* cmd =
      app.add_subcommand("register", "Refine frame poses against a volume (docs/registration.md)");
  flags->volume.add_to(*cmd, /*path_required=*/false);
  cmd->add_option("--probe", flags->probe, "Probe JSON (native or fan-slicer config)");
  cmd->add_option("--downsampling", flags->downsampling, "Divide the probe image size by K");
  cmd->add_option("--frames", flags->frames,
                  "Frames: .npy (N,H,W), .nii/.mha/.nrrd stack, or a folder of PNGs");
  cmd->add_option("--poses", flags->poses, "Initial poses, one per frame: .npy, .txt/.csv, .json");
  cmd->add_option("--out", flags->out, "Refined poses: .npy (N,4,4)");
  cmd->add_option("--metric", flags->metric, "ncc (default), ssd, lncc, mi or lc2");
  cmd->add_option(
      "--optimizer", flags->optimizer,
      "lm (default for ssd, ncc), gn, bobyqa (default for lncc, mi, lc2) or nelder-mead");
  cmd->add_option("--starts", flags->starts, "Optimisations per frame from spread points (1)");
  cmd->add_option("--search-rot-deg", flags->search_rot_deg,
                  "Spread of the extra starts' rotations, degrees (10)");
  cmd->add_option("--search-trans-mm", flags->search_trans_mm,
                  "Spread of the extra starts' translations, mm (10)");
  cmd->add_option("--seed", flags->seed, "Seed of the extra starts (0)");
  cmd->add_option("--pyramid", flags->pyramid,
                  "Coarse-to-fine pixel block sizes (default 8,4,2,1; docs/registration.md)");
  cmd->add_option("--mode", flags->mode,
                  "per-frame (default), rigid-sweep (one world correction for all frames) or "
                  "smooth-sweep (per frame, tied to the neighbours along the sweep)");
  cmd->add_option("--smoothness", flags->smoothness,
                  "smooth-sweep: the prior's weight relative to the frames' curvature (0.3)");
  cmd->add_option("--mask", flags->user_mask,
                  "An HxW image: compare only its non-zero pixels (with the fan mask)");
  cmd->add_option("--report", flags->report, "Write a JSON report here");
  cmd->add_option("--world", flags->world, "Frame of the poses: LPS (default) or RAS");
  add_threads_option(*cmd, flags->threads);
  cmd->add_flag("--verbose,-v", flags->verbose, "Print times and evaluation counts");
  cmd->callback([flags] { run_register(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
