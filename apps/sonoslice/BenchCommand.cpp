// sonoslice bench: images per second of the slicing kernel on the benchmark workloads
// (W1: fan on the full phantom, W2: linear probe), or on a volume/probe/poses of your own;
// with --compound, frames per second of compounding (Jauer's workload and a 2D sweep); with
// --simulate, images per second of ultrasound simulation (W1 from the phantom CT).
// bench/peers.py runs the same workloads through torch, VTK and SciPy and calls this with
// --json to put sonoslice's figure in the same run.
#include <algorithm>
#include <cstdio>
#include <memory>

#include <nlohmann/json.hpp>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/simulate/Simulator.h"

namespace sonoslice {
namespace cli {
namespace {

struct BenchFlags {
  VolumeFlags volume;
  std::string probe, poses, as = "", interp = "linear", size = "full", device = "cpu";
  int downsampling = 1, count = 1000, repeat = 3;
  std::optional<int> threads;  // unset: all hardware threads
  bool json = false, compound = false, simulate = false;
};

// Compounding: the Jauer beam-space workload and a 1000-frame 2D sweep, nearest and
// linear splats into float accumulators (Workloads.h), splatting plus volume() (no hole filling).
void run_compound_bench(const BenchFlags& f, const Device& device) {
  struct Case {
    std::string name;
    bool beams;
  };
  const BeamSweepWorkload jauer = workload_jauer_beam_sweep();
  const ImageSweepWorkload sweep = workload_2d_sweep();
  const BeamGeometry& g = jauer.geometry;
  const int64_t beam_samples = int64_t(g.n_elevation) * g.n_azimuth * g.n_samples;
  const int64_t image_samples = int64_t(sweep.width) * sweep.height;
  const std::vector<uint8_t> beam_frames =
      workload_frames(int64_t(jauer.probe_to_reference.size()), beam_samples);
  const std::vector<uint8_t> image_frames =
      workload_frames(int64_t(sweep.image_to_reference.size()), image_samples);
  nlohmann::json j = nlohmann::json::array();
  if (!f.json)
    std::printf("sonoslice bench --compound: %s, best of %d\n%-44s %-8s %9s %10s %12s\n",
                device.type == DeviceType::CUDA
                    ? device.to_string().c_str()
                    : (std::to_string(cpu_threads()) + " threads").c_str(),
                f.repeat, "workload", "splats", "seconds", "frames/s", "Msamples/s");
  for (const Case& c : {Case{"Jauer 814 x 185x84x22 -> 300x1000x600", true},
                        Case{"2D sweep 1000 x 820x616 -> grid at 0.5 mm", false}})
    for (const bool linear : {false, true}) {
      CompoundSettings s;
      s.interpolation = linear ? Interpolation::Linear : Interpolation::Nearest;
      // End to end, and (of the best run) where the time went: making the compounder (its
      // accumulators), adding the frames, the finished volume (finishing and download).
      double best = 1e300, made = 0, added = 0, finished = 0;
      for (int r = 0; r < f.repeat; ++r) {
        Stopwatch clock;
        Compounder comp(c.beams ? jauer.grid : sweep.grid, s, device);
        const double t_made = clock.seconds();
        if (c.beams)
          comp.add_beams(beam_frames.data(), PixelType::UInt8, g,
                         int64_t(jauer.probe_to_reference.size()), jauer.probe_to_reference.data());
        else
          comp.add_images(image_frames.data(), PixelType::UInt8, sweep.width, sweep.height,
                          int64_t(sweep.image_to_reference.size()),
                          sweep.image_to_reference.data());
        const double t_added = clock.seconds();
        (void)comp.volume(PixelType::UInt8);
        const double t = clock.seconds();
        if (t < best) {
          best = t;
          made = t_made;
          added = t_added - t_made;
          finished = t - t_added;
        }
      }
      const double frames =
          double(c.beams ? jauer.probe_to_reference.size() : sweep.image_to_reference.size());
      const double samples = frames * double(c.beams ? beam_samples : image_samples);
      if (f.json)
        j.push_back({{"workload", c.name},
                     {"splats", linear ? "linear" : "nearest"},
                     {"device", device.to_string()},
                     {"threads", cpu_threads()},
                     {"best_seconds", best},
                     {"seconds_making", made},
                     {"seconds_adding", added},
                     {"seconds_finishing", finished},
                     {"frames_per_second", frames / best},
                     {"samples_per_second", samples / best}});
      else
        std::printf("%-44s %-8s %9.3f %10.0f %12.0f   (make %.3f + add %.3f + volume %.3f s)\n",
                    c.name.c_str(), linear ? "linear" : "nearest", best, frames / best,
                    samples / best / 1e6, made, added, finished);
    }
  if (f.json) std::printf("%s\n", j.dump(2).c_str());
}

// Simulation: W1 (the `lus` preset: fan-slicer's LUS fan at downsampling 2, 334×272, 6.5 MHz)
// from the phantom CT (int16, read in place) at random poses, B-mode into host memory.
void run_simulate_bench(const BenchFlags& f, const Device& device) {
  const Volume ct = f.volume.path.empty() ? make_phantom(parse_phantom_size(f.size)).ct
                                          : read_volume(f.volume.path, f.volume.options());
  const std::vector<Pose> poses =
      f.poses.empty() ? phantom_random_poses(size_t(f.count)) : read_poses(f.poses);
  SimulationSettings s;
  s.preset = "lus";
  s.device = device;
  const Simulator sim(ct, SimulationSource::HounsfieldUnits, std::nullopt, {}, s);
  std::vector<uint8_t> out(poses.size() * sim.image_bytes());
  sim.simulate(poses.data(), std::min<size_t>(poses.size(), 32), out.data());  // warm-up
  double best = 1e300;
  for (int r = 0; r < f.repeat; ++r) {
    Stopwatch clock;
    sim.simulate(poses.data(), poses.size(), out.data());
    best = std::min(best, clock.seconds());
  }
  const double ips = double(poses.size()) / best;
  if (f.json) {
    const nlohmann::json j = {{"workload", "W1 simulation 334x272"},
                              {"volume_type", to_string(ct.pixel_type())},
                              {"images", poses.size()},
                              {"device", device.to_string()},
                              {"threads", cpu_threads()},
                              {"best_seconds", best},
                              {"images_per_second", ips}};
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  std::printf(
      "sonoslice bench --simulate: %zu poses, %s, best of %d\n%-26s %-8s %12s\n", poses.size(),
      device.type == DeviceType::CUDA ? device.to_string().c_str()
                                      : (std::to_string(cpu_threads()) + " threads").c_str(),
      f.repeat, "workload", "volume", "images/s");
  std::printf("%-26s %-8s %12.0f\n", "W1 simulation 334x272", to_string(ct.pixel_type()).c_str(),
              ips);
}

struct Workload {
  std::string name;
  ProbeGeometry probe;
};

struct Result {
  std::string workload, volume_type, interp;
  int64_t images;
  double best_seconds, median_seconds;  // into host memory (end to end)
  double device_seconds = 0;            // CUDA: into GPU memory (best)
};

Result measure(const Workload& w, const Volume& volume, const std::vector<Pose>& poses,
               Interpolation interp, int repeat, const Device& device) {
  SliceSettings settings;
  settings.interpolation = interp;
  const Slicer slicer(volume, w.probe, settings, device);
  std::vector<float> out(poses.size() * size_t(w.probe.image.pixel_count()));
  // Warm-up: touches the output pages and the caches once.
  slicer.slice(poses.data(), std::min<size_t>(poses.size(), 32), out.data());
  std::vector<double> times;
  for (int r = 0; r < repeat; ++r) {
    Stopwatch s;
    slicer.slice(poses.data(), poses.size(), out.data());
    times.push_back(s.seconds());
  }
  std::sort(times.begin(), times.end());
  Result r{w.name,        to_string(volume.pixel_type()), to_string(interp), int64_t(poses.size()),
           times.front(), times[times.size() / 2]};
  if (device.type == DeviceType::CUDA) {
    // Images left on the GPU, as a training loop consumes them.
    slicer.slice_on_device(poses.data(), poses.size()).synchronize();
    r.device_seconds = 1e300;
    for (int k = 0; k < repeat; ++k) {
      Stopwatch s;
      slicer.slice_on_device(poses.data(), poses.size()).synchronize();
      r.device_seconds = std::min(r.device_seconds, s.seconds());
    }
  }
  return r;
}

void run_bench(const BenchFlags& f) {
  setup_threads(f.threads);
  if (f.count < 1 || f.repeat < 1) throw InputError("--count and --repeat must be >= 1");
  const Device device = Device::parse(f.device);
  if (f.compound && f.simulate) throw InputError("--compound and --simulate: give one");
  if (f.compound) {
    require_device(device);
    return run_compound_bench(f, device);
  }
  if (f.simulate) return run_simulate_bench(f, device);
  const Interpolation interp = parse_interpolation(f.interp);

  std::vector<Workload> workloads;
  if (!f.probe.empty())
    workloads.push_back({f.probe, read_probe(f.probe, f.downsampling)});
  else
    workloads = {{"W1 fan 334x272", workload_w1_fan_probe()},
                 {"W2 linear 400x500", workload_w2_linear_probe()}};

  const std::vector<Pose> poses =
      f.poses.empty() ? phantom_random_poses(size_t(f.count)) : read_poses(f.poses);

  Volume base = f.volume.path.empty() ? make_phantom(parse_phantom_size(f.size)).ct
                                      : read_volume(f.volume.path, f.volume.options());
  std::vector<Volume> volumes;
  if (!f.as.empty()) {
    const PixelType t = parse_pixel_type(f.as);
    volumes.push_back(t == base.pixel_type() ? base : base.converted(t));
  } else if (f.volume.path.empty()) {
    volumes = {base.converted(PixelType::Float32), base};  // the phantom as float32 and int16
  } else {
    volumes = {base};
  }

  std::vector<Result> results;
  for (const Workload& w : workloads)
    for (const Volume& v : volumes)
      results.push_back(measure(w, v, poses, interp, f.repeat, device));

  if (f.json) {
    nlohmann::json j = nlohmann::json::array();
    for (const Result& r : results)
      j.push_back({{"workload", r.workload},
                   {"volume_type", r.volume_type},
                   {"interp", r.interp},
                   {"images", r.images},
                   {"threads", cpu_threads()},
                   {"best_seconds", r.best_seconds},
                   {"median_seconds", r.median_seconds},
                   {"images_per_second", double(r.images) / r.best_seconds},
                   {"device", device.to_string()},
                   {"device_images_per_second",
                    r.device_seconds > 0 ? double(r.images) / r.device_seconds : 0.0}});
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  const bool gpu = device.type == DeviceType::CUDA;
  const std::string where = gpu ? device.to_string() : std::to_string(cpu_threads()) + " threads";
  std::printf("sonoslice bench: %zu poses, %s, %s, best of %d\n", poses.size(), where.c_str(),
              to_string(interp), f.repeat);
  std::printf("%-22s %-8s %12s %12s%s\n", "workload", "volume", "images/s", "Msamples/s",
              gpu ? "  images/s kept on the GPU" : "");
  for (const Result& r : results) {
    const Workload& w = *std::find_if(workloads.begin(), workloads.end(),
                                      [&](const Workload& x) { return x.name == r.workload; });
    const double ips = double(r.images) / r.best_seconds;
    std::printf("%-22s %-8s %12.0f %12.1f", r.workload.c_str(), r.volume_type.c_str(), ips,
                ips * double(w.probe.image.pixel_count()) / 1e6);
    if (gpu) std::printf("  %24.0f", double(r.images) / r.device_seconds);
    std::printf("\n");
  }
}

}  // namespace

void add_bench_command(CLI::App& app) {
  auto flags = std::make_shared<BenchFlags>();
  CLI::App* cmd = app.add_subcommand(
      "bench", "Measure slicing speed (default: W1 fan and W2 linear on the full phantom)");
  flags->volume.add_to(*cmd, /*path_required=*/false);
  cmd->add_option("--probe", flags->probe, "Probe JSON (default: the W1 and W2 probes)");
  cmd->add_option("--downsampling", flags->downsampling, "Divide the probe image size by K");
  cmd->add_option("--poses", flags->poses, "Pose file (default: --count random poses in the body)");
  cmd->add_option("--count", flags->count, "Random poses when no --poses (default 1000)");
  cmd->add_option("--as", flags->as, "Convert the volume to this pixel type first");
  cmd->add_option("--interp", flags->interp, "linear (default) or nearest");
  cmd->add_option("--size", flags->size, "Phantom size when no --volume: full (default) or small");
  cmd->add_option("--repeat", flags->repeat, "Timed repetitions; the best is reported (default 3)");
  add_threads_option(*cmd, flags->threads);
  cmd->add_option("--device", flags->device, "cpu (default), cuda or cuda:K");
  cmd->add_flag("--json", flags->json, "Machine-readable output");
  cmd->add_flag("--compound", flags->compound,
                "Measure compounding instead: the Jauer beam-space workload and a 2D sweep");
  cmd->add_flag("--simulate", flags->simulate,
                "Measure simulation instead: W1 B-mode images from the phantom CT");
  cmd->callback([flags] { run_bench(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
