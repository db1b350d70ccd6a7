// sonoslice register: ultrasound frames, their initial poses and a volume → refined poses
// (N, 4, 4) and a JSON report (docs/registration.md).
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>

#include <nlohmann/json.hpp>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TrackedFrames.h"
#include "sonoslice/register/PlusRegistration.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice {
namespace cli {
namespace {

struct RegisterFlags {
  VolumeFlags volume;
  std::string probe, frames, poses, out, report, user_mask, world = "LPS";
  std::string sequence, config;  // a PLUS sequence with its tracked poses, instead of the three
  int downsampling = 1;
  // The registration settings the user gave; the library has the defaults (RegistrationSettings).
  std::string metric, optimizer, mode, pyramid;
  std::optional<int> starts;
  std::optional<double> search_rot_deg, search_trans_mm, smoothness;
  std::optional<uint64_t> seed;
  std::optional<int> threads;
  bool verbose = false, quiet = false;
};

/// "8,4,2,1" → block sizes (the settings check their range).
std::vector<int> parse_pyramid(const std::string& text) {
  std::vector<int> levels;
  for (const std::string& item : split_commas(text)) {
    char* end = nullptr;
    const long level = std::strtol(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0' || level < std::numeric_limits<int>::min() ||
        level > std::numeric_limits<int>::max())
      throw InputError("--pyramid " + text +
                       ": expected block sizes from 1 to 64, coarse to fine, e.g. 8,4,2,1");
    levels.push_back(int(level));
  }
  return levels;
}

/// The settings the flags give; unset flags keep the library's defaults.
RegistrationSettings settings_of(const RegisterFlags& f) {
  RegistrationSettings s;
  if (!f.metric.empty()) s.metric = parse_registration_metric(f.metric, "--metric");
  if (!f.optimizer.empty()) s.optimizer = parse_registration_optimizer(f.optimizer, "--optimizer");
  if (!f.mode.empty()) s.mode = parse_registration_mode(f.mode, "--mode");
  if (f.starts) s.starts = *f.starts;
  if (f.search_rot_deg) s.search_rot_deg = *f.search_rot_deg;
  if (f.search_trans_mm) s.search_trans_mm = *f.search_trans_mm;
  if (f.seed) s.seed = *f.seed;
  if (f.smoothness) s.smoothness = *f.smoothness;
  if (!f.pyramid.empty()) s.pyramid = parse_pyramid(f.pyramid);
  s.validate(flag_named);  // every setting has the flag of its name
  return s;
}

/// What is registered: the probe, the frames (count × H × W floats), their initial poses and
/// the pixels compared from --probe/--frames/--poses/--mask, or a PLUS sequence's tracked frames.
struct Inputs {
  ProbeGeometry probe;
  std::vector<Pose> initial;
  const float* frames = nullptr;
  size_t count = 0;
  std::vector<uint8_t> user_mask;
  Volume stack;                           // --frames
  std::optional<PlusTrackedFrames> plus;  // --sequence
  std::optional<PlusSequence> sequence;   // --sequence, kept for a corrected sequence as --out
  PlusReconstructionConfig config;        // --config
  std::optional<Mat4> image_to_probe;     // --config's calibration, when it has one
};

Inputs read_frame_inputs(const RegisterFlags& f, WorldFrame world) {
  Inputs in;
  in.probe = read_probe(f.probe, f.downsampling);
  // FrameRegistration::run checks the poses again and warns once about non-orthonormal ones.
  in.initial = read_poses(f.poses, world, /*warn_non_orthonormal=*/false);
  const Volume stack = read_image_stack(f.frames, "--frames");
  const VolumeGrid& g = stack.grid();
  if (g.dims[0] != in.probe.image.width || g.dims[1] != in.probe.image.height)
    throw InputError("--frames '" + f.frames + "': frames of " + std::to_string(g.dims[0]) + "x" +
                     std::to_string(g.dims[1]) + " pixels, but the probe's image is " +
                     std::to_string(in.probe.image.width) + "x" +
                     std::to_string(in.probe.image.height) +
                     " (W x H; check --probe and --downsampling)");
  in.count = size_t(g.dims[2]);
  in.stack = stack.pixel_type() == PixelType::Float32 ? stack : stack.converted(PixelType::Float32);
  in.frames = in.stack.data_as<float>();
  if (in.initial.size() != in.count)
    throw InputError("--poses '" + f.poses + "': " + std::to_string(in.initial.size()) +
                     " poses for " + std::to_string(in.count) + " frames in '" + f.frames + "'");
  if (!f.user_mask.empty()) {
    const Volume m = read_image_stack(f.user_mask, "--mask");
    if (m.grid().dims[0] != in.probe.image.width || m.grid().dims[1] != in.probe.image.height ||
        m.grid().dims[2] != 1)
      throw InputError("--mask '" + f.user_mask + "': expected one " +
                       std::to_string(in.probe.image.width) + "x" +
                       std::to_string(in.probe.image.height) + " image");
    if (const int64_t nan = m.non_finite_count())
      throw InputError("--mask '" + f.user_mask + "': " + std::to_string(nan) +
                       " pixels are NaN or infinite (a mask is zero where pixels are left out, "
                       "non-zero where they are compared)");
    in.user_mask.resize(size_t(in.probe.image.pixel_count()));
    visit_pixel_type(m.pixel_type(), [&](auto zero) {
      using T = decltype(zero);
      for (size_t i = 0; i < in.user_mask.size(); ++i)
        in.user_mask[i] = m.data_as<T>()[i] != T(0) ? 1 : 0;
    });
  }
  return in;
}

// --out as a PLUS sequence (.mha/.nrrd, with --sequence): the corrected sequence.
bool sequence_out(const RegisterFlags& f) {
  const std::string ext = file_extension(f.out);
  return !f.sequence.empty() && (ext == ".mha" || ext == ".nrrd");
}

// A PLUS sequence: the frames compound would use, their ImageToReference split into rigid poses
// on the frames' pixel grid, the configuration's clip as the mask (register_tracked_frames takes
// them from here, after the volume is read).
Inputs read_sequence_inputs(const RegisterFlags& f) {
  Inputs in;
  if (!f.config.empty()) in.config = read_plus_config(f.config);
  in.sequence = read_plus_sequence(f.sequence);
  in.plus = plus_tracked_frames(*in.sequence, in.config);
  in.count = in.plus->frames.size();
  in.image_to_probe = plus_image_to_probe(in.config);
  if (!sequence_out(f)) in.sequence.reset();  // its pixels are in `plus` as well
  return in;
}

nlohmann::json matrix_json(const Mat4& m) {
  nlohmann::json rows = nlohmann::json::array();
  for (int r = 0; r < 4; ++r) rows.push_back({m.m[r][0], m.m[r][1], m.m[r][2], m.m[r][3]});
  return rows;
}

void run_register(const RegisterFlags& f) {
  Stopwatch total;
  if (f.volume.path.empty()) throw UsageError("register: --volume is required");
  const bool from_sequence = !f.sequence.empty();
  if (from_sequence) {
    for (const auto& [flag, value] :
         {std::pair<const char*, const std::string&>{"--probe", f.probe},
          {"--frames", f.frames},
          {"--poses", f.poses},
          {"--mask", f.user_mask}})
      if (!value.empty())
        throw InputError(std::string("register: ") + flag +
                         " is for frames given as files; --sequence brings its frames, their "
                         "tracked poses and (with --config) the clip");
    if (f.world != "LPS")
      throw InputError("--world " + f.world +
                       ": a PLUS sequence's poses are in its reference frame, which is the "
                       "volume's physical space");
  } else {
    if (!f.config.empty()) throw InputError("register: --config goes with --sequence");
    for (const auto& [flag, value] :
         {std::pair<const char*, const std::string&>{"--probe", f.probe},
          {"--frames", f.frames},
          {"--poses", f.poses}})
      if (value.empty())
        throw UsageError(std::string("register: ") + flag + " is required (or --sequence)");
  }
  if (f.out.empty()) throw UsageError("register: --out is required");
  setup_threads(f.threads);
  const RegistrationSettings settings = settings_of(f);
  if (file_extension(f.out) != ".npy" && !sequence_out(f))
    throw InputError("--out '" + f.out + "': refined poses are written as .npy (N, 4, 4)" +
                     (from_sequence ? "; a corrected sequence as .mha or .nrrd" : ""));
  if (!f.report.empty() && file_extension(f.report) != ".json")
    throw InputError("--report '" + f.report + "': the report is JSON (.json)");
  // The refined poses' .npy has no geometry sidecar: REFINED.npy beside REFINED.json is fine.
  check_distinct_outputs({{"--out", f.out, false}, {"--report", f.report}},
                         {{"--volume", f.volume.path},
                          {"--probe", f.probe},
                          {"--frames", f.frames},
                          {"--poses", f.poses, false},
                          {"--mask", f.user_mask},
                          {"--sequence", f.sequence},
                          {"--config", f.config}});
  check_output_path(f.out);
  if (!f.report.empty()) check_output_path(f.report);

  // Small inputs first, so that a typo fails before the volume is read.
  const WorldFrame world = parse_world_frame(f.world);
  const Inputs in = from_sequence ? read_sequence_inputs(f) : read_frame_inputs(f, world);
  const size_t count = in.count;
  Stopwatch load;
  const Volume volume = read_volume(f.volume.path, f.volume.options());
  const double load_seconds = load.seconds();

  // A sequence's refined ImageToReference matrices (PlusRegistration.h), else the refined poses
  // in the input's frame (pose_to_lps is its own inverse).
  RegistrationReport report;
  std::vector<Mat4> matrices;
  std::optional<Mat4> corrected_image_to_probe;
  std::optional<PlusSequence> corrected;
  if (from_sequence) {
    PlusRegistration r = register_tracked_frames(volume, *in.plus, settings, in.image_to_probe);
    if (in.sequence) corrected = corrected_plus_sequence(*in.sequence, in.config, r);
    matrices = std::move(r.image_to_reference);
    corrected_image_to_probe = r.image_to_probe;
    report = std::move(r.report);
  } else {
    const FrameRegistration reg(volume, in.probe, in.frames, count,
                                in.user_mask.empty() ? nullptr : in.user_mask.data());
    for (const Pose& p : reg.run(in.initial, settings, &report))
      matrices.push_back(pose_to_lps(p, world));
  }

  OutputSet outputs;  // both or neither
  std::vector<double> flat;
  for (const Mat4& p : matrices)
    for (int i = 0; i < 16; ++i) flat.push_back(p.m[i / 4][i % 4]);
  if (corrected)
    write_plus_sequence(f.out, *corrected, /*compress=*/true, &outputs);
  else
    write_npy(f.out, PixelType::Float64, {int64_t(matrices.size()), 4, 4}, flat.data(), &outputs);
  if (!f.report.empty()) {
    // The settings as the library resolved them (the optimiser chosen for the metric).
    const RegistrationSettings& ran = report.settings;
    nlohmann::json j;
    j["metric"] = to_string(ran.metric);
    j["optimizer"] = to_string(*ran.optimizer);
    j["mode"] = to_string(ran.mode);
    j["starts"] = ran.starts ? nlohmann::json(*ran.starts) : nlohmann::json("auto");
    if (ran.mode == RegistrationMode::SmoothSweep) j["smoothness"] = *ran.smoothness;
    j["frames"] = nlohmann::json::array();
    for (const FrameReport& r : report.frames)
      j["frames"].push_back({{"index", r.index},
                             {"metric", r.metric},
                             {"evaluations", r.evaluations},
                             {"iterations", r.iterations},
                             {"translation_change_mm", r.translation_change_mm},
                             {"rotation_change_deg", r.rotation_change_deg},
                             {"starts", r.starts},
                             {"agreeing_starts", r.agreeing_starts},
                             {"confidence", r.confidence()},
                             {"converged", r.converged},
                             {"uncertainty_mm", r.uncertainty_mm},
                             {"uncertainty_deg", r.uncertainty_deg}});
    size_t converged = 0;
    for (const FrameReport& r : report.frames) converged += r.converged;
    j["converged_frames"] = converged;
    if (report.correction) j["correction"] = matrix_json(*report.correction);
    if (report.sweep_metric) j["sweep_metric"] = *report.sweep_metric;  // +inf: null
    if (report.halves_mm) j["halves_mm"] = *report.halves_mm;
    if (report.sides_mm) j["sides_mm"] = *report.sides_mm;
    if (in.plus) {
      j["sequence"] = f.sequence;
      j["sequence_frames"] = in.plus->frames;
      if (!in.plus->skipped.empty()) j["skipped"] = in.plus->skipped;
      if (corrected_image_to_probe) j["image_to_probe"] = matrix_json(*corrected_image_to_probe);
    }
    j["evaluations"] = report.evaluations;
    j["seconds"] = report.seconds;
    write_text_file(f.report, j.dump(2) + "\n", &outputs);
  }
  outputs.commit();
  if (f.verbose && !f.quiet)
    std::fprintf(stderr,
                 "sonoslice: %zu frames, %s, %s; load %.3f s, register %.3f s (%lld pose "
                 "evaluations, %.0f per second, %d threads), total %.3f s\n",
                 count, to_string(report.settings.metric), to_string(report.settings.mode),
                 load_seconds, report.seconds, static_cast<long long>(report.evaluations),
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
  cmd->add_option(
      "--frames", flags->frames,
      "Frames: .npy (N,H,W), .nii/.mha/.nrrd stack, a multi-frame DICOM .dcm, or a folder "
      "of PNGs");
  cmd->add_option("--poses", flags->poses, "Initial poses, one per frame: .npy, .txt/.csv, .json");
  cmd->add_option("--out", flags->out,
                  "Refined poses: .npy (N,4,4); with --sequence, the refined ImageToReference "
                  "(pixels to reference mm) of each frame used as .npy, or the sequence with its "
                  "tracked transforms corrected (.mha/.nrrd; compound it with the same --config)");
  cmd->add_option("--sequence", flags->sequence,
                  "A PLUS sequence (.igs.mha/.nrrd): its frames and tracked poses, instead of "
                  "--probe, --frames and --poses");
  cmd->add_option("--config", flags->config,
                  "With --sequence: the PLUS configuration XML (calibration, frames, clip)");
  const RegistrationSettings defaults;
  cmd->add_option(
      "--metric", flags->metric,
      std::string("ncc, ssd, lncc, mi or lc2 (default ") + to_string(defaults.metric) + ")");
  // The library's choice per metric: "lm for ssd, ncc; bobyqa for lncc, mi, lc2".
  std::string chosen;
  for (RegistrationOptimizer o :
       {RegistrationOptimizer::LevenbergMarquardt, RegistrationOptimizer::GaussNewton,
        RegistrationOptimizer::Bobyqa, RegistrationOptimizer::NelderMead}) {
    std::string metrics;
    for (RegistrationMetric m :
         {RegistrationMetric::SSD, RegistrationMetric::NCC, RegistrationMetric::LNCC,
          RegistrationMetric::MI, RegistrationMetric::LC2})
      if (default_optimizer(m) == o)
        metrics += (metrics.empty() ? "" : ", ") + std::string(to_string(m));
    if (!metrics.empty())
      chosen += (chosen.empty() ? "" : "; ") + std::string(to_string(o)) + " for " + metrics;
  }
  cmd->add_option("--optimizer", flags->optimizer,
                  "lm, gn, bobyqa or nelder-mead (default: " + chosen + ")");
  cmd->add_option("--starts", flags->starts,
                  "Optimisations per frame (per sweep) from spread points (default: automatic, "
                  "until " +
                      std::to_string(kAgreeingStarts) + " reach the same pose, at most " +
                      std::to_string(default_max_starts(RegistrationMetric::NCC)) +
                      " for ssd and ncc, " +
                      std::to_string(default_max_starts(RegistrationMetric::MI)) +
                      " for the others; a sweep's shared correction: at most " +
                      std::to_string(kAutoMaxSweepStarts) + ")");
  cmd->add_option(
      "--search-rot-deg", flags->search_rot_deg,
      "Spread of the extra starts' rotations, degrees " + default_text(defaults.search_rot_deg));
  cmd->add_option(
      "--search-trans-mm", flags->search_trans_mm,
      "Spread of the extra starts' translations, mm " + default_text(defaults.search_trans_mm));
  add_seed_option(
      *cmd, [flags](uint64_t s) { flags->seed = s; },
      "Seed of the extra starts " + default_text(defaults.seed));
  // The library's pyramid per metric: "8,4,2,1 for ssd, ncc, lncc, mi; 2,1 for lc2".
  std::vector<std::pair<std::string, std::string>> pyramids;  // levels, metrics
  for (RegistrationMetric m :
       {RegistrationMetric::SSD, RegistrationMetric::NCC, RegistrationMetric::LNCC,
        RegistrationMetric::MI, RegistrationMetric::LC2}) {
    std::string levels;
    for (int level : default_pyramid(m))
      levels += (levels.empty() ? "" : ",") + std::to_string(level);
    auto same = std::find_if(pyramids.begin(), pyramids.end(),
                             [&](const auto& p) { return p.first == levels; });
    if (same == pyramids.end())
      pyramids.push_back({levels, to_string(m)});
    else
      same->second += std::string(", ") + to_string(m);
  }
  std::string pyramid;
  for (const auto& [levels, metrics] : pyramids)
    pyramid += (pyramid.empty() ? "" : "; ") + levels + " for " + metrics;
  cmd->add_option(
      "--pyramid", flags->pyramid,
      "Coarse-to-fine pixel block sizes (default: " + pyramid + "; docs/registration.md)");
  cmd->add_option("--mode", flags->mode,
                  std::string("per-frame, rigid-sweep (one world correction for all frames), "
                              "smooth-sweep (per frame, tied to the neighbours along the sweep) "
                              "or calibration (one probe-side correction); default ") +
                      to_string(defaults.mode));
  cmd->add_option("--smoothness", flags->smoothness,
                  "smooth-sweep: the prior's weight relative to the frames' curvature " +
                      default_text(RegistrationSettings::kDefaultSmoothness));
  cmd->add_option("--mask", flags->user_mask,
                  "An HxW image: compare only its non-zero pixels (with the fan mask)");
  cmd->add_option("--report", flags->report, "Write a JSON report here");
  cmd->add_option("--world", flags->world, "Frame of the poses: LPS (default) or RAS");
  add_threads_option(*cmd, flags->threads);
  cmd->add_flag("--verbose,-v", flags->verbose, "Print times and evaluation counts");
  cmd->add_flag("--quiet,-q", flags->quiet, "No summary (the default without -v)");
  cmd->callback([flags] { run_register(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
