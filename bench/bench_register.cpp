// Registration's kernels, in pose evaluations per second (items_per_second), one thread, on W1
// (fan-slicer's LUS fan at downsampling 2, 334×272 px) over the full phantom CT as float32:
//   NccTerms: NCC's sums with their pose derivatives at full resolution (what every
//             Gauss–Newton/LM step evaluates; bench/register_speed.py times whole registrations
//             through the command, with torch's grid_sample + autograd as the peer);
//   Lc2:      LC2's patch score at level 2 (the ultrasound metric's default finest level).
// The frames are CT fans at 20 poses inside the body, each evaluated at 10 poses closing in on
// its own, as an optimiser's iterations do.
//
//   build/bin/bench_register --benchmark_min_time=2
#include <benchmark/benchmark.h>

#include <vector>

#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/register/Registration.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

constexpr int kSteps = 10;

struct Setup {
  Volume ct;
  ProbeGeometry probe = workload_w1_fan_probe();
  std::vector<Pose> truth, moved;
  std::vector<float> frames;
};

const Setup& setup() {
  static const Setup s = [] {
    Setup s;
    s.ct = make_phantom(PhantomSize::Full).ct.converted(PixelType::Float32);
    s.truth = phantom_random_poses(20);
    const Slicer slicer(s.ct, s.probe, {});
    s.frames.resize(s.truth.size() * size_t(slicer.width()) * size_t(slicer.height()));
    slicer.slice(s.truth.data(), s.truth.size(), s.frames.data());
    // As an optimiser evaluates: each frame at kSteps poses closing in on its own from about
    // 1 mm and 0.8° away (the same region of the volume, in cache after the first).
    for (const Pose& p : s.truth)
      for (int step = 0; step < kSteps; ++step) {
        const double t = 1.0 - double(step) / kSteps;
        const double xi[6] = {0.6 * t, -0.5 * t, 0.6 * t, 0.005 * t, -0.01 * t, 0.008 * t};
        s.moved.push_back(apply_increment(p, xi, Vec3{p.m[0][3], p.m[1][3], p.m[2][3]}));
      }
    return s;
  }();
  return s;
}

void BM_NccTerms(benchmark::State& state) {
  set_cpu_kernel_isa(state.range(0) ? "generic" : "auto");
  const Setup& s = setup();
  const FrameRegistration reg(s.ct, s.probe, s.frames.data(), s.truth.size());
  for (auto _ : state)
    for (size_t k = 0; k < s.moved.size(); ++k) {
      const size_t f = k / kSteps;
      const PoseTerms t = reg.terms(f, s.moved[k], 1, reg.centre(f, s.moved[k]), true);
      benchmark::DoNotOptimize(t.sjj[20]);
    }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(s.moved.size()));
  state.SetLabel(to_string(cpu_kernel_isa()));
  set_cpu_kernel_isa("auto");
}

void BM_Lc2(benchmark::State& state) {
  set_cpu_kernel_isa(state.range(0) ? "generic" : "auto");
  const Setup& s = setup();
  const FrameRegistration reg(s.ct, s.probe, s.frames.data(), s.truth.size());
  reg.prepare_level(2);
  for (auto _ : state)
    for (size_t k = 0; k < s.moved.size(); ++k)
      benchmark::DoNotOptimize(reg.cost(k / kSteps, s.moved[k], 2, RegistrationMetric::LC2));
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(s.moved.size()));
  state.SetLabel(to_string(cpu_kernel_isa()));
  set_cpu_kernel_isa("auto");
}

}  // namespace

// The kernels in their AVX2 (where the CPU has it) and generic builds.
BENCHMARK(BM_NccTerms)->ArgName("generic")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Lc2)->ArgName("generic")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace sonoslice

BENCHMARK_MAIN();
