// sonoslice voxelize: surface meshes → one label volume (label k for the k-th mesh).
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <sstream>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/surface/Voxelize.h"

namespace sonoslice {
namespace cli {
namespace {

struct VoxelizeFlags {
  std::vector<std::string> meshes;
  std::string out, reference, world = "LPS";
  std::optional<double> spacing, margin;  // unset: from --reference (margin: one voxel)
  std::optional<int> threads;             // unset: all hardware threads
  bool quiet = false, verbose = false;
};

void run_voxelize(const VoxelizeFlags& f) {
  setup_threads(f.threads);
  const WorldFrame frame = parse_world_frame(f.world);
  if (f.reference.empty() && !f.spacing)
    throw InputError("voxelize: give --spacing S (mm) or --reference VOLUME");
  if (!f.reference.empty() && (f.spacing || f.margin))
    throw InputError("voxelize: --reference sets the grid; --spacing and --margin do not apply");
  const auto shown = [](double v) {
    std::ostringstream out;
    out << v;
    return out.str();
  };
  if (f.spacing && !(*f.spacing > 0 && std::isfinite(*f.spacing)))
    throw InputError("--spacing " + shown(*f.spacing) + ": must be > 0 mm");
  if (f.margin && !(*f.margin >= 0 && std::isfinite(*f.margin)))
    throw InputError("--margin " + shown(*f.margin) + ": must be >= 0 mm");
  check_output_path(f.out);
  Stopwatch load;
  std::vector<TriangleMesh> meshes;
  for (const std::string& path : f.meshes) meshes.push_back(read_mesh(path, frame));
  const double load_seconds = load.seconds();
  VolumeGrid grid;
  if (!f.reference.empty()) {
    grid = read_volume(f.reference).grid();
  } else {
    grid = voxel_grid_around(meshes, *f.spacing, f.margin ? *f.margin : *f.spacing);
  }
  const uint64_t bytes = uint64_t(grid.voxel_count()) * (meshes.size() > 255 ? 2 : 1);
  if (bytes > available_memory_bytes())
    throw ResourceError("voxelize: the label volume needs " + std::to_string(bytes >> 20) +
                        " MiB, more than the memory available; use a coarser --spacing");
  Stopwatch clock;
  const Volume labels = voxelize(meshes, grid);
  const double seconds = clock.seconds();
  Stopwatch write;
  write_volume(f.out, labels);
  if (!f.quiet) {
    std::fprintf(stderr,
                 "sonoslice: %zu mesh%s → %s: %lldx%lldx%lld %s labels at %g mm in %.3f s\n",
                 meshes.size(), meshes.size() == 1 ? "" : "es", f.out.c_str(),
                 static_cast<long long>(grid.dims[0]), static_cast<long long>(grid.dims[1]),
                 static_cast<long long>(grid.dims[2]), to_string(labels.pixel_type()).c_str(),
                 grid.spacing_mm[0], seconds);
    for (size_t k = 0; k < meshes.size(); ++k)
      std::fprintf(stderr, "sonoslice:   label %zu: %s (%zu triangles, %s)\n", k + 1,
                   meshes[k].name.c_str(), meshes[k].triangles.size(),
                   mesh_topology(meshes[k]).describe().c_str());
  }
  if (f.verbose)
    std::fprintf(stderr, "sonoslice: load %.3f s, voxelize %.3f s, write %.3f s\n", load_seconds,
                 seconds, write.seconds());
}

}  // namespace

void add_voxelize_command(CLI::App& app) {
  auto flags = std::make_shared<VoxelizeFlags>();
  CLI::App* cmd = app.add_subcommand(
      "voxelize",
      "Surface meshes → one label volume (label k for the k-th mesh; later meshes win)");
  cmd->add_option("meshes", flags->meshes, "Meshes: .vtk, .vtp, .stl, .obj, .ply")->required();
  cmd->add_option("--out", flags->out, "Label volume: .nii.gz, .mha, .nrrd, .npy ...")->required();
  cmd->add_option("--spacing", flags->spacing, "Isotropic voxel size (mm)");
  cmd->add_option("--margin", flags->margin,
                  "Margin around the meshes' bounds (mm; default: one voxel)");
  cmd->add_option("--reference", flags->reference, "Use this volume's grid (geometry) instead");
  cmd->add_option("--world", flags->world, "Frame of the mesh coordinates: LPS (default) or RAS");
  add_threads_option(*cmd, flags->threads);
  cmd->add_flag("--quiet,-q", flags->quiet, "No summary");
  cmd->add_flag("--verbose,-v", flags->verbose, "Print load/voxelize/write times");
  cmd->callback([flags] { run_voxelize(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
