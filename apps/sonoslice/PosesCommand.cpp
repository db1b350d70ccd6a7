// sonoslice poses: seeded probe poses from a sampler (skin, mesh, region, sweep) with rejection
// on the fan's content (docs/datasets.md §2), written as .npy (N, 4, 4), .txt or .csv.
#include <cstdio>
#include <filesystem>
#include <memory>

#include <nlohmann/json.hpp>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/sampling/PoseSampler.h"
#include "sonoslice/sampling/SamplerConfig.h"

namespace sonoslice {
namespace cli {
namespace {

struct PosesFlags {
  VolumeFlags volume;
  std::string sampler, probe, labels, mesh, out, world = "LPS";
  std::string tilt, heel_toe, rotation, depth;
  int downsampling = 1;
  int64_t count = 0;
  uint64_t seed = 0;
  std::optional<double> min_inside, min_body, min_label;
  std::optional<int> label, max_tries;
  bool no_gas = false, verbose = false, quiet = false;
  std::optional<int> threads;
};

/// The sampler's settings: a type name, a JSON file, or inline JSON, with the flags laid over
/// them by the library (parse_sampler_json's overrides).
SamplerSettings sampler_settings(const PosesFlags& f) {
  const std::string& s = f.sampler;
  const bool is_type = s == "skin" || s == "mesh" || s == "region" || s == "sweep";
  const bool is_file = !is_type && !s.empty() && s[0] != '{';
  std::error_code ec;
  if (is_file && !std::filesystem::exists(s, ec))
    throw InputError("--sampler '" + s +
                     "': expected skin, mesh, region, sweep, a JSON file or inline JSON");
  nlohmann::json overrides = nlohmann::json::object();
  const auto range = [](const std::string& text, const std::string& flag) {
    const std::vector<double> v = parse_numbers(text, 2, flag);
    if (!(v[0] <= v[1])) throw InputError(flag + " " + text + ": expected lo,hi with lo <= hi");
    return nlohmann::json::array({v[0], v[1]});
  };
  if (!f.tilt.empty()) overrides["tilt_deg"] = range(f.tilt, "--tilt-deg");
  if (!f.heel_toe.empty()) overrides["heel_toe_deg"] = range(f.heel_toe, "--heel-toe-deg");
  if (!f.rotation.empty()) overrides["rotation_deg"] = range(f.rotation, "--rotation-deg");
  if (!f.depth.empty()) overrides["depth_mm"] = range(f.depth, "--depth-mm");
  if (f.max_tries) overrides["max_tries"] = *f.max_tries;
  nlohmann::json reject = nlohmann::json::object();
  if (f.min_inside) reject["min_inside"] = *f.min_inside;
  if (f.min_body) reject["min_body"] = *f.min_body;
  if (f.label) reject["label"] = *f.label;
  if (f.min_label) reject["min_label"] = *f.min_label;
  if (f.no_gas) reject["no_gas"] = true;
  if (!reject.empty()) overrides["reject"] = reject;
  if (is_file) return read_sampler_json(s, "--sampler", overrides.dump());
  const std::string text = is_type ? nlohmann::json{{"type", s}}.dump() : s;
  return parse_sampler_json(text, "--sampler", overrides.dump());
}

void run_poses(const PosesFlags& f) {
  Stopwatch total;
  for (const auto& [flag, value] :
       {std::pair<const char*, const std::string&>{"--sampler", f.sampler},
        {"--probe", f.probe},
        {"--out", f.out}})
    if (value.empty()) throw UsageError(std::string("poses: ") + flag + " is required");
  if (f.count < 1 || f.count > 100000000)
    throw InputError("--count " + std::to_string(f.count) + ": must be from 1 to 100000000");
  const std::string ext = file_extension(f.out);
  if (ext != ".npy" && ext != ".txt" && ext != ".csv")
    throw InputError("--out '" + f.out + "': poses are written as .npy (N, 4, 4), .txt or .csv");
  setup_threads(f.threads);
  const SamplerSettings settings = sampler_settings(f);
  check_distinct_outputs({{"--out", f.out}}, {{"--volume", f.volume.path},
                                              {"--labels", f.labels},
                                              {"--mesh", f.mesh},
                                              {"--probe", f.probe},
                                              {"--sampler", f.sampler}});
  check_output_path(f.out);
  const ProbeGeometry probe = read_probe(f.probe, f.downsampling);
  const WorldFrame world = parse_world_frame(f.world);
  std::optional<TriangleMesh> mesh;
  if (!f.mesh.empty()) mesh = read_mesh(f.mesh, world);
  Stopwatch load;
  std::optional<Volume> volume, labels;
  if (!f.volume.path.empty()) volume = read_volume(f.volume.path, f.volume.options());
  if (!f.labels.empty()) {
    labels = read_volume(f.labels, {});
    check_label_values(*labels, "--labels '" + f.labels + "'");
  }
  const double load_seconds = load.seconds();

  Stopwatch build;
  const PoseSampler sampler(settings, probe, volume ? &*volume : nullptr,
                            labels ? &*labels : nullptr, mesh ? &*mesh : nullptr);
  const double build_seconds = build.seconds();
  const std::vector<uint64_t> seeds = sample_seeds(f.seed, 0, 0, size_t(f.count));
  Stopwatch draw;
  std::vector<Pose> poses = sampler.sample(seeds.data(), seeds.size());
  const double draw_seconds = draw.seconds();
  for (Pose& p : poses) p = pose_to_lps(p, world);  // to the caller's frame (its own inverse)
  if (ext == ".npy")
    write_poses_npy(f.out, poses);
  else
    write_poses_text(f.out, poses);
  if (f.verbose && !f.quiet)
    std::fprintf(stderr,
                 "sonoslice: %zu poses (%lld seeds): load %.3f s, sampler setup %.3f s, sampling "
                 "%.3f s (%.0f poses/s, %d threads), total %.3f s\n",
                 poses.size(), static_cast<long long>(f.count), load_seconds, build_seconds,
                 draw_seconds, double(poses.size()) / std::max(draw_seconds, 1e-9), cpu_threads(),
                 total.seconds());
}

}  // namespace

void add_poses_command(CLI::App& app) {
  auto flags = std::make_shared<PosesFlags>();
  CLI::App* cmd = app.add_subcommand(
      "poses", "Seeded probe poses on the skin, a mesh, in a region, or sweeps (docs/datasets.md)");
  flags->volume.add_to(*cmd, /*path_required=*/false);
  cmd->add_option("--sampler", flags->sampler,
                  "skin, mesh, region, sweep, or a sampler's JSON (a file or inline)");
  cmd->add_option("--probe", flags->probe, "Probe JSON (native or fan-slicer config)");
  cmd->add_option("--downsampling", flags->downsampling, "Divide the probe image size by K");
  cmd->add_option("--labels", flags->labels, "Label volume (region by label, --min-label)");
  cmd->add_option("--mesh", flags->mesh, "Mesh for the mesh sampler (.vtk/.vtp/.stl/.obj/.ply)");
  cmd->add_option("--count", flags->count, "Seeds to draw (sweeps: each gives its frames)");
  add_seed_option(
      *cmd, [flags](uint64_t s) { flags->seed = s; }, "Base seed (0)");
  cmd->add_option("--out", flags->out, "Poses: .npy (N, 4, 4), .txt or .csv");
  cmd->add_option("--tilt-deg", flags->tilt, "Fanning tilt range about the probe's x, lo,hi");
  cmd->add_option("--heel-toe-deg", flags->heel_toe, "Heel-toe range about the probe's z, lo,hi");
  cmd->add_option("--rotation-deg", flags->rotation, "Rotation range about the beam, lo,hi");
  cmd->add_option("--depth-mm", flags->depth, "Push into tissue along the beam, lo,hi");
  cmd->add_option("--min-inside", flags->min_inside,
                  "Reject: min fraction of the fan in the volume");
  cmd->add_option("--min-body", flags->min_body, "Reject: min fraction of the fan in the body");
  cmd->add_option("--label", flags->label, "Reject: the label of --min-label");
  cmd->add_option("--min-label", flags->min_label, "Reject: min fraction of the fan in --label");
  cmd->add_flag("--no-gas", flags->no_gas, "Reject: gas right under the face");
  cmd->add_option(
      "--max-tries", flags->max_tries,
      "Candidates per seed before giving up " + default_text(SamplerSettings().max_tries));
  cmd->add_option("--world", flags->world, "Frame of the written poses: LPS (default) or RAS");
  add_threads_option(*cmd, flags->threads);
  cmd->add_flag("--verbose,-v", flags->verbose, "Print times and rates");
  cmd->add_flag("--quiet,-q", flags->quiet, "No summary (the default without -v)");
  cmd->callback([flags] { run_poses(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
