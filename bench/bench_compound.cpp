// Compounding throughput (issue 6), CPU threads and CUDA:
//   Jauer:   814 beam-space frames of 185×84×22 samples into 300×1000×600 voxels of 0.5 mm
//            (Jauer et al. 2015: 17.4 s on a GTX 980).
//   Sweep2D: 1000 frames of 820×616 pixels into the grid around them at 0.5 mm.
// Counters: frames/s, input samples/s (items_per_second). "finish" adds volume() (the division
// and, with holes=1, hole filling with one Gaussian 3³ element) to the splatting. The real PLUS
// sweeps (with their XML settings) are timed by `sonoslice compound --time` and bench/README.md.
//
//   build/bin/bench_compound --benchmark_filter=Jauer
#include <benchmark/benchmark.h>

#include "sonoslice/compound/Compounder.h"
#include "sonoslice/phantom/Workloads.h"

namespace sonoslice {
namespace {

const BeamSweepWorkload& jauer() {
  static const BeamSweepWorkload w = workload_jauer_beam_sweep();
  return w;
}
const std::vector<uint8_t>& jauer_frames() {
  const BeamGeometry& g = jauer().geometry;
  static const std::vector<uint8_t> f =
      workload_frames(int64_t(jauer().probe_to_reference.size()),
                      int64_t(g.n_elevation) * g.n_azimuth * g.n_samples);
  return f;
}
const ImageSweepWorkload& sweep() {
  static const ImageSweepWorkload w = workload_2d_sweep();
  return w;
}
const std::vector<uint8_t>& sweep_frames() {
  static const std::vector<uint8_t> f = workload_frames(int64_t(sweep().image_to_reference.size()),
                                                        int64_t(sweep().width) * sweep().height);
  return f;
}

CompoundSettings settings_for(const benchmark::State& state) {
  CompoundSettings s;
  s.interpolation = state.range(0) ? SplatInterpolation::Linear : SplatInterpolation::Nearest;
  s.mode = CompoundingMode::Mean;
  s.fill_holes = state.range(2) != 0;
  return s;
}

Device device_for(const benchmark::State& state) {
  return state.range(3) ? Device::parse("cuda") : Device::cpu();
}

// args: linear, threads, holes (finish + hole filling), cuda
void BM_Jauer(benchmark::State& state) {
  set_cpu_threads(int(state.range(1)));
  const BeamSweepWorkload& w = jauer();
  const auto& frames = jauer_frames();
  const int64_t n = int64_t(w.probe_to_reference.size());
  try {
    device_for(state);
    require_device(device_for(state));
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  for (auto _ : state) {
    Compounder c(w.grid, settings_for(state), device_for(state));
    c.add_beams(frames.data(), PixelType::UInt8, w.geometry, n, w.probe_to_reference.data());
    if (state.range(2) >= 0) {
      const Volume v = c.volume(PixelType::UInt8);
      benchmark::DoNotOptimize(v.data());
    }
  }
  const int64_t samples =
      int64_t(w.geometry.n_elevation) * w.geometry.n_azimuth * w.geometry.n_samples;
  state.SetItemsProcessed(int64_t(state.iterations()) * n * samples);
  state.counters["frames_per_s"] =
      benchmark::Counter(double(n) * double(state.iterations()), benchmark::Counter::kIsRate);
  set_cpu_threads(0);
}

void BM_Sweep2D(benchmark::State& state) {
  set_cpu_threads(int(state.range(1)));
  const ImageSweepWorkload& w = sweep();
  const auto& frames = sweep_frames();
  const int64_t n = int64_t(w.image_to_reference.size());
  try {
    require_device(device_for(state));
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  for (auto _ : state) {
    Compounder c(w.grid, settings_for(state), device_for(state));
    c.add_images(frames.data(), PixelType::UInt8, w.width, w.height, n,
                 w.image_to_reference.data());
    if (state.range(2) >= 0) {
      const Volume v = c.volume(PixelType::UInt8);
      benchmark::DoNotOptimize(v.data());
    }
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * n * w.width * w.height);
  state.counters["frames_per_s"] =
      benchmark::Counter(double(n) * double(state.iterations()), benchmark::Counter::kIsRate);
  set_cpu_threads(0);
}

// holes: -1 = splatting only (no volume()), 0 = + finish, 1 = + finish with hole filling.
void cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"linear", "threads", "holes", "cuda"})->Unit(benchmark::kMillisecond)->UseRealTime();
  for (int linear : {0, 1})
    for (int threads : {1, 2}) b->Args({linear, threads, -1, 0});
  for (int linear : {0, 1}) b->Args({linear, 2, 0, 0})->Args({linear, 2, 1, 0});
  for (int linear : {0, 1}) b->Args({linear, 0, -1, 1})->Args({linear, 0, 0, 1});
}

BENCHMARK(BM_Jauer)->Apply(cases)->Iterations(1)->Repetitions(1);
BENCHMARK(BM_Sweep2D)->Apply(cases)->Iterations(1)->Repetitions(1);

}  // namespace
}  // namespace sonoslice

BENCHMARK_MAIN();
