// Surfaces: voxelising the real fan-slicer meshes, and label slicing in voxel and exact modes.
//   build/bin/bench_surface  (needs data/fanslicer; skips otherwise)
#include <benchmark/benchmark.h>

#include <filesystem>

#include "sonoslice/io/MeshFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/slice/Slicer.h"
#include "sonoslice/surface/SurfaceSlicer.h"
#include "sonoslice/surface/Voxelize.h"

namespace sonoslice {
namespace {

const std::string kData = SONOSLICE_DATA_DIR "/fanslicer/";

const std::vector<TriangleMesh>* meshes(bool all) {
  static std::vector<TriangleMesh> four, veins;
  if (four.empty() && std::filesystem::exists(kData + "liver.vtk")) {
    for (const char* n : {"liver", "hepatic veins", "portal vein", "arteries"})
      four.push_back(read_mesh(kData + n + ".vtk"));
    veins = {four[1]};
  }
  if (four.empty()) return nullptr;
  return all ? &four : &veins;
}

// fan-slicer's grid (20 mm margins): hepatic veins at 0.5 mm is 374×364×348.
void BM_Voxelize(benchmark::State& state, bool all) {
  const auto* m = meshes(all);
  if (!m) return state.SkipWithError("data/fanslicer not found");
  const VolumeGrid grid = voxel_grid_around(*m, 0.5, 20.0);
  for (auto _ : state) benchmark::DoNotOptimize(voxelize(*m, grid).data());
  state.counters["voxels"] = double(grid.voxel_count());
  state.SetLabel(std::to_string(grid.dims[0]) + "x" + std::to_string(grid.dims[1]) + "x" +
                 std::to_string(grid.dims[2]));
}
BENCHMARK_CAPTURE(BM_Voxelize, hepatic_veins_0_5mm, false)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_Voxelize, four_meshes_0_5mm, true)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// 1000 W1 fans through the liver (random poses inside its bounding box's middle).
std::vector<Pose> liver_poses() {
  std::vector<Pose> poses = phantom_random_poses(1000, 5);
  for (Pose& p : poses) {  // move the phantom's poses into the meshes' region
    p.m[0][3] = -17 + 0.25 * p.m[0][3];
    p.m[1][3] = 0 + 0.25 * p.m[1][3];
    p.m[2][3] = -314 + 0.25 * p.m[2][3];
  }
  return poses;
}

void BM_LabelSlicing(benchmark::State& state, bool exact) {
  const auto* m = meshes(true);
  if (!m) return state.SkipWithError("data/fanslicer not found");
  const ProbeGeometry probe = workload_w1_fan_probe();
  const auto poses = liver_poses();
  std::vector<uint8_t> out(poses.size() * size_t(probe.image.pixel_count()));
  if (exact) {
    const SurfaceSlicer slicer(*m, probe);
    for (auto _ : state) slicer.slice(poses.data(), poses.size(), out.data());
  } else {
    static const Volume labels = voxelize(*m, voxel_grid_around(*m, 0.5, 1.0));
    SliceSettings s;
    s.interpolation = Interpolation::Nearest;
    s.output_type = PixelType::UInt8;
    const Slicer slicer(labels, probe, s);
    for (auto _ : state) slicer.slice(poses.data(), poses.size(), out.data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(poses.size()));
}
BENCHMARK_CAPTURE(BM_LabelSlicing, W1_exact_four_meshes, true)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_LabelSlicing, W1_voxel_0_5mm, false)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace sonoslice

BENCHMARK_MAIN();
