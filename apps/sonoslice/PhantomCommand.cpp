// sonoslice phantom: writes the built-in CT-like abdominal phantom and its label map.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/simulate/TissueFile.h"

namespace sonoslice {
namespace cli {
namespace {

struct PhantomFlags {
  std::string out_dir, size = "small", format = "nii.gz";
  int poses = 0;
  std::optional<int> threads;  // unset: all hardware threads
  bool quiet = false;
};

void run_phantom(const PhantomFlags& f) {
  setup_threads(f.threads);
  const PhantomSize size = parse_phantom_size(f.size);
  if (f.format != "nii.gz" && f.format != "nii" && f.format != "mha" && f.format != "nrrd" &&
      f.format != "npy")
    throw InputError("--format " + f.format + ": expected nii.gz, nii, mha, nrrd or npy");
  // poses.npy holds 128 bytes a pose: ten million (1.3 GB) is beyond any benchmark's need.
  constexpr int kMaxPoses = 10000000;
  if (f.poses < 0 || f.poses > kMaxPoses)
    throw InputError("--poses " + std::to_string(f.poses) + ": expected 0 to " +
                     std::to_string(kMaxPoses));
  std::error_code ec;
  std::filesystem::create_directories(f.out_dir, ec);
  if (ec) throw FileError("cannot create directory '" + f.out_dir + "': " + ec.message());
  Stopwatch clock;
  const Phantom phantom = make_phantom(size);
  const double generate = clock.seconds();
  const std::string ct = (std::filesystem::path(f.out_dir) / ("ct." + f.format)).string();
  const std::string labels = (std::filesystem::path(f.out_dir) / ("labels." + f.format)).string();
  // The benchmark's poses (random, inside the body) and probes on the skin, to slice with: made
  // before anything is written, so that a failure leaves no partial folder.
  const std::vector<Pose> random_poses = phantom_random_poses(size_t(f.poses));
  const std::vector<Pose> surface_poses =
      f.poses > 0
          ? phantom_surface_poses(size_t(std::min(f.poses, 64)), workload_w1_fan_probe().face_y_mm)
          : std::vector<Pose>{};
  write_volume(ct, phantom.ct);
  write_volume(labels, phantom.labels);
  // The labels' acoustic properties, for `sonoslice simulate --labels ... --tissues`.
  const std::string tissues = (std::filesystem::path(f.out_dir) / "tissues.json").string();
  write_text_file(tissues, tissue_table_json(phantom_tissues()));
  if (f.poses > 0) {
    write_poses_npy((std::filesystem::path(f.out_dir) / "poses.npy").string(), random_poses);
    write_poses_text((std::filesystem::path(f.out_dir) / "surface_poses.txt").string(),
                     surface_poses);
  }
  if (!f.quiet) {
    const auto& g = phantom.ct.grid();
    std::fprintf(stderr,
                 "sonoslice: phantom %lldx%lldx%lld at %.2gx%.2gx%.2g mm: %s (int16 HU), %s "
                 "(uint8 labels) in %.1f s (generated in %.1f s)\n",
                 static_cast<long long>(g.dims[0]), static_cast<long long>(g.dims[1]),
                 static_cast<long long>(g.dims[2]), g.spacing_mm[0], g.spacing_mm[1],
                 g.spacing_mm[2], ct.c_str(), labels.c_str(), clock.seconds(), generate);
    std::fprintf(stderr, "sonoslice: labels:");
    for (int l = 0; l < kPhantomLabelCount; ++l)
      std::fprintf(stderr, " %d=%s", l, phantom_label_name(l));
    std::fprintf(stderr, "\n");
  }
}

}  // namespace

void add_phantom_command(CLI::App& app) {
  auto flags = std::make_shared<PhantomFlags>();
  CLI::App* cmd = app.add_subcommand(
      "phantom", "Write a deterministic CT-like abdominal phantom (ct + labels)");
  cmd->add_option("out_dir", flags->out_dir, "Output directory (created if missing)")->required();
  cmd->add_option("--size", flags->size, "small (128x128x100, default) or full (512x512x400)");
  cmd->add_option("--format", flags->format, "nii.gz (default), nii, mha, nrrd or npy");
  cmd->add_option(
      "--poses", flags->poses,
      "Also write N random poses inside the body (poses.npy, the benchmark's) and up to "
      "64 poses on the skin (surface_poses.txt)");
  add_threads_option(*cmd, flags->threads);
  cmd->add_flag("--quiet,-q", flags->quiet, "No summary");
  cmd->callback([flags] { run_phantom(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
