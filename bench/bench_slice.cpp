// Slicing throughput on the benchmark workloads, in images per second (items_per_second):
//   W1: fan-slicer's LUS fan (models_intensity_LUS_config.json, downsampling 2): 334×272 px at
//       0.247 mm, on the full phantom (512×512×400) as float32 and int16.
//   W2: fan-slicer's linear probe (linear_config.json): 400×500 px at 0.1235 mm.
// Poses: 1000 random poses inside the body (phantom_random_poses). The peers' figures come from
// bench/peers.py, which runs them in the same process session as `sonoslice bench`.
//
//   build/bin/bench_slice --benchmark_filter=W1 --benchmark_min_time=2
#include <benchmark/benchmark.h>

#include <memory>

#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

const Phantom& phantom() {
  static const Phantom p = make_phantom(PhantomSize::Full);
  return p;
}

const Volume& volume(PixelType t) {
  static const Volume f32 = phantom().ct.converted(PixelType::Float32);
  if (t == PixelType::UInt8) return phantom().labels;  // the phantom's label map
  return t == PixelType::Float32 ? f32 : phantom().ct;
}

// args: 0 = W1 / 1 = W2, volume type, 0 = linear / 1 = nearest, threads, kernel set (0 auto, 1
// generic)
void BM_Slice(benchmark::State& state, int workload, PixelType type, Interpolation interp) {
  set_cpu_threads(int(state.range(0)));
  set_cpu_kernel_isa(state.range(1) ? "generic" : "auto");
  const auto poses = phantom_random_poses(1000);
  SliceSettings s;
  s.interpolation = interp;
  const Slicer slicer(volume(type),
                      workload == 1 ? workload_w1_fan_probe() : workload_w2_linear_probe(), s);
  std::vector<float> out(poses.size() * size_t(slicer.width()) * size_t(slicer.height()));
  for (auto _ : state) {
    slicer.slice(poses.data(), poses.size(), out.data());
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(poses.size()));
  state.counters["threads"] = double(cpu_threads());
  state.SetLabel(to_string(cpu_kernel_isa()));
  set_cpu_kernel_isa("auto");
  reset_cpu_threads();
}

void threads_and_kernels(benchmark::internal::Benchmark* b) {
  b->Unit(benchmark::kMillisecond)->UseRealTime()->ArgNames({"threads", "generic"});
  for (int generic : {0, 1})
    for (int threads : {1, 2}) b->Args({threads, generic});
}

// CUDA: images left in GPU memory (device=0) or copied into host memory (device=1).
void BM_SliceCuda(benchmark::State& state, int workload, PixelType type) {
  const Device gpu{DeviceType::CUDA, 0};
  try {
    require_device(gpu);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  const auto poses = phantom_random_poses(1000);
  const Slicer slicer(
      volume(type), workload == 1 ? workload_w1_fan_probe() : workload_w2_linear_probe(), {}, gpu);
  const bool to_host = state.range(0) == 1;
  std::vector<float> out(to_host ? poses.size() * size_t(slicer.width()) * size_t(slicer.height())
                                 : 0);
  for (auto _ : state) {
    if (to_host)
      slicer.slice(poses.data(), poses.size(), out.data());
    else
      slicer.slice_on_device(poses.data(), poses.size()).synchronize();
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(poses.size()));
}
BENCHMARK_CAPTURE(BM_SliceCuda, W1_float32, 1, PixelType::Float32)
    ->ArgName("to_host")
    ->Arg(0)
    ->Arg(1)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_SliceCuda, W1_int16, 1, PixelType::Int16)
    ->ArgName("to_host")
    ->Arg(0)
    ->Arg(1)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_SliceCuda, W2_float32, 2, PixelType::Float32)
    ->ArgName("to_host")
    ->Arg(0)
    ->Arg(1)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_SliceCuda, W2_int16, 2, PixelType::Int16)
    ->ArgName("to_host")
    ->Arg(0)
    ->Arg(1)
    ->UseRealTime();

BENCHMARK_CAPTURE(BM_Slice, W1_float32_linear, 1, PixelType::Float32, Interpolation::Linear)
    ->Apply(threads_and_kernels);
BENCHMARK_CAPTURE(BM_Slice, W1_int16_linear, 1, PixelType::Int16, Interpolation::Linear)
    ->Apply(threads_and_kernels);
BENCHMARK_CAPTURE(BM_Slice, W1_int16_nearest, 1, PixelType::Int16, Interpolation::Nearest)
    ->Apply(threads_and_kernels);
// Label slicing (uint8 labels, nearest, uint8 out) against intensity slicing above.
void BM_SliceLabels(benchmark::State& state) {
  set_cpu_threads(int(state.range(0)));
  const auto poses = phantom_random_poses(1000);
  SliceSettings s;
  s.interpolation = Interpolation::Nearest;
  s.output_type = PixelType::UInt8;
  const Slicer slicer(volume(PixelType::UInt8), workload_w1_fan_probe(), s);
  std::vector<uint8_t> out(poses.size() * size_t(slicer.width()) * size_t(slicer.height()));
  for (auto _ : state) slicer.slice(poses.data(), poses.size(), out.data());
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(poses.size()));
  reset_cpu_threads();
}
BENCHMARK(BM_SliceLabels)
    ->Name("BM_Slice/W1_uint8_labels_nearest")
    ->ArgName("threads")
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_CAPTURE(BM_Slice, W2_float32_linear, 2, PixelType::Float32, Interpolation::Linear)
    ->Apply(threads_and_kernels);
BENCHMARK_CAPTURE(BM_Slice, W2_int16_linear, 2, PixelType::Int16, Interpolation::Linear)
    ->Apply(threads_and_kernels);

}  // namespace
}  // namespace sonoslice

BENCHMARK_MAIN();
