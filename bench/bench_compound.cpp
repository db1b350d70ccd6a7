// Compounding throughput, CPU threads and CUDA:
//   Jauer:   814 beam-space frames of 185×84×22 samples into 300×1000×600 voxels of 0.5 mm
//            (Jauer et al. 2015: 17.4 s on a GTX 980).
//   Sweep2D: 1000 frames of 820×616 pixels into the grid around them at 0.5 mm.
// Counters: frames/s, input samples/s (items_per_second). "finish" adds volume() (the division
// and, with holes=1, hole filling with one Gaussian 3³ element) to the splatting. The real PLUS
// sweeps (with their XML settings) are timed by `sonoslice compound --time` and bench/README.md.
//
//   build/bin/bench_compound --benchmark_filter=Jauer
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <random>

#include "sonoslice/compound/Compounder.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

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
  s.interpolation = state.range(0) ? Interpolation::Linear : Interpolation::Nearest;
  s.mode = CompoundingMode::Mean;
  s.fill_holes = state.range(2) != 0;
  return s;
}

Device device_for(const benchmark::State& state) {
  return state.range(3) ? Device::parse("cuda") : Device::cpu();
}

// One synthetic workload: `add(compounder)` inserts every frame. args: linear, threads, holes
// (-1 splatting only, 0 + volume(), 1 + volume() with hole filling), cuda.
template <typename Add>
void run_synthetic(benchmark::State& state, const VolumeGrid& grid, int64_t frames,
                   int64_t samples_per_frame, const Add& add) {
  try {
    require_device(device_for(state));
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
    return;
  }
  set_cpu_threads(int(state.range(1)));
  for (auto _ : state) {
    Compounder c(grid, settings_for(state), device_for(state));
    add(c);
    if (state.range(2) >= 0) {
      const Volume v = c.volume(PixelType::UInt8);
      benchmark::DoNotOptimize(v.data());
    }
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * frames * samples_per_frame);
  state.counters["frames_per_s"] =
      benchmark::Counter(double(frames) * double(state.iterations()), benchmark::Counter::kIsRate);
  reset_cpu_threads();
}

void BM_Jauer(benchmark::State& state) {
  const BeamSweepWorkload& w = jauer();
  const auto& frames = jauer_frames();
  const int64_t n = int64_t(w.probe_to_reference.size());
  const int64_t samples =
      int64_t(w.geometry.n_elevation) * w.geometry.n_azimuth * w.geometry.n_samples;
  run_synthetic(state, w.grid, n, samples, [&](Compounder& c) {
    c.add_beams(frames.data(), PixelType::UInt8, w.geometry, n, w.probe_to_reference.data());
  });
}

void BM_Sweep2D(benchmark::State& state) {
  const ImageSweepWorkload& w = sweep();
  const auto& frames = sweep_frames();
  const int64_t n = int64_t(w.image_to_reference.size());
  run_synthetic(state, w.grid, n, int64_t(w.width) * w.height, [&](Compounder& c) {
    c.add_images(frames.data(), PixelType::UInt8, w.width, w.height, n,
                 w.image_to_reference.data());
  });
}

// The real PLUS sweeps of data/plus with their XML settings (clip rectangle, spacing);
// the valid frames copied next to each other once, outside the timing.
struct RealSweep {
  std::vector<uint8_t> pixels;
  std::vector<Mat4> image_to_reference;
  int width = 0, height = 0;
  PlusReconstructionConfig config;
  VolumeGrid grid;
  std::string error;
};

// BoneLong (the 500-frame workload, as bench/splat_speed.py builds it for the CLI): the
// 21 Bone frames cycled to 500 along a 60 mm sweep in the recorded sweep's direction, each pose
// jittered by up to ±1 mm and ±2° about a random axis through the image origin (seeded).
void lengthen(RealSweep& r) {
  const int recorded = int(r.image_to_reference.size());
  const size_t frame_bytes = size_t(r.width) * r.height;
  const Mat4 first = r.image_to_reference.front();
  Vec3 direction = r.image_to_reference.back().column3(3) - first.column3(3);
  direction = (1.0 / norm(direction)) * direction;
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::normal_distribution<double> gauss;
  std::vector<uint8_t> pixels(500 * frame_bytes);
  std::vector<Mat4> poses;
  for (int k = 0; k < 500; ++k) {
    std::memcpy(pixels.data() + k * frame_bytes, r.pixels.data() + (k % recorded) * frame_bytes,
                frame_bytes);
    Vec3 axis{gauss(rng), gauss(rng), gauss(rng)};
    axis = (1.0 / norm(axis)) * axis;
    const double angle = unit(rng) * 2.0 * M_PI / 180.0, c = std::cos(angle), sn = std::sin(angle);
    Mat3 rot;  // Rodrigues
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) rot.m[i][j] = (i == j ? c : 0.0) + (1 - c) * axis[i] * axis[j];
    rot.m[0][1] -= sn * axis[2], rot.m[0][2] += sn * axis[1], rot.m[1][2] -= sn * axis[0];
    rot.m[1][0] += sn * axis[2], rot.m[2][0] -= sn * axis[1], rot.m[2][1] += sn * axis[0];
    Mat4 pose = Mat4::from_rotation_translation(rot, {0, 0, 0}) * first;
    const Vec3 shift = (60.0 * k / 500) * direction;
    for (int i = 0; i < 3; ++i) pose.m[i][3] = first.m[i][3] + shift[i] + unit(rng);
    poses.push_back(pose);
  }
  r.pixels = std::move(pixels);
  r.image_to_reference = std::move(poses);
}

const RealSweep& real_sweep(const std::string& name) {
  static std::map<std::string, std::unique_ptr<RealSweep>> cache;
  auto& entry = cache[name];
  if (entry) return *entry;
  entry = std::make_unique<RealSweep>();
  RealSweep& r = *entry;
  try {
    const std::string dir = SONOSLICE_DATA_DIR "/plus/";
    const bool nwire = name == "Nwire";  // else BoneUltrasound_L14 (Bone, BoneLong)
    const PlusSequence s = read_plus_sequence(
        dir + (nwire ? "NwirePhantomFreehand.igs.mha" : "BoneUltrasound_L14.igs.mha"));
    r.config = read_plus_config(
        dir + (nwire ? "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"
                     : "BoneUltrasound_L14_config.xml"));
    r.width = s.width;
    r.height = s.height;
    for (int f = 0; f < s.frame_count; ++f) {
      TransformRepository repo = r.config.coordinate_definitions;
      repo.set_frame(s, f);
      const auto m = repo.get(r.config.image_frame, r.config.reference_frame);
      if (!m || !s.image_ok(f)) continue;
      r.image_to_reference.push_back(*m);
      const auto* p = static_cast<const uint8_t*>(s.frame_pixels(f));
      r.pixels.insert(r.pixels.end(), p, p + s.frame_bytes());
    }
    if (name == "BoneLong") lengthen(r);
    r.grid = Compounder::grid_around(r.image_to_reference, r.width, r.height, r.config.clip,
                                     *r.config.output_spacing_mm);
  } catch (const std::exception& e) {
    r.error = e.what();
  }
  return r;
}

// args: linear, threads
void BM_PlusSweep(benchmark::State& state, const std::string& name) {
  const RealSweep& r = real_sweep(name);
  if (!r.error.empty()) {
    state.SkipWithError(r.error.c_str());
    return;
  }
  set_cpu_threads(int(state.range(1)));
  CompoundSettings s = r.config.settings;
  s.interpolation = state.range(0) ? Interpolation::Linear : Interpolation::Nearest;
  s.fill_holes = false;
  const int64_t n = int64_t(r.image_to_reference.size());
  for (auto _ : state) {
    Compounder c(r.grid, s);
    c.add_images(r.pixels.data(), PixelType::UInt8, r.width, r.height, n,
                 r.image_to_reference.data(), r.config.clip);
    benchmark::DoNotOptimize(&c);
  }
  const auto rect = r.config.clip.rectangle(r.width, r.height);
  const double inserted = double(rect[2] - rect[0]) * (rect[3] - rect[1]);
  state.SetItemsProcessed(int64_t(state.iterations()) * n * r.width * r.height);  // frame pixels
  state.counters["frames_per_s"] =
      benchmark::Counter(double(n) * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["inserted_px_per_s"] = benchmark::Counter(
      double(n) * inserted * double(state.iterations()), benchmark::Counter::kIsRate);
  reset_cpu_threads();
}

void real_cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"linear", "threads"})->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
  for (int linear : {0, 1})
    for (int threads : {1, 2}) b->Args({linear, threads});
}

BENCHMARK_CAPTURE(BM_PlusSweep, Nwire, std::string("Nwire"))->Apply(real_cases);
BENCHMARK_CAPTURE(BM_PlusSweep, BoneL14, std::string("Bone"))->Apply(real_cases);
BENCHMARK_CAPTURE(BM_PlusSweep, BoneLong, std::string("BoneLong"))->Apply(real_cases);

// holes: -1 = splatting only (no volume()), 0 = + finish, 1 = + finish with hole filling.
void cases(benchmark::internal::Benchmark* b) {
  b->ArgNames({"linear", "threads", "holes", "cuda"})->Unit(benchmark::kMillisecond)->UseRealTime();
  for (int linear : {0, 1})
    for (int threads : {1, 2}) b->Args({linear, threads, -1, 0});
  for (int linear : {0, 1}) b->Args({linear, 2, 0, 0})->Args({linear, 2, 1, 0});
  for (int linear : {0, 1}) b->Args({linear, 0, -1, 1})->Args({linear, 0, 0, 1});
}

BENCHMARK(BM_Jauer)->Apply(cases)->Iterations(1)->Repetitions(3)->ReportAggregatesOnly(true);
BENCHMARK(BM_Sweep2D)->Apply(cases)->Iterations(1)->Repetitions(3)->ReportAggregatesOnly(true);

}  // namespace
}  // namespace sonoslice

BENCHMARK_MAIN();
