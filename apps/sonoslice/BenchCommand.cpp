// sonoslice bench: images per second of the slicing kernel on the benchmark workloads
// (W1: fan on the full phantom, W2: linear probe), or on a volume/probe/poses of your own.
// bench/peers.py runs the same workloads through torch, VTK and SciPy and calls this with
// --json to put sonoslice's figure in the same run.
#include <algorithm>
#include <cstdio>
#include <memory>

#include <nlohmann/json.hpp>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/phantom/Phantom.h"

namespace sonoslice {
namespace cli {
namespace {

struct BenchFlags {
  VolumeFlags volume;
  std::string probe, poses, as = "", interp = "linear", size = "full", device = "cpu";
  int downsampling = 1, count = 1000, repeat = 3, threads = 0;
  bool json = false;
};

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
  Result r{w.name, pixel_type_name(volume.pixel_type()), interpolation_name(interp),
           int64_t(poses.size()), times.front(), times[times.size() / 2]};
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
  set_cpu_threads(f.threads);
  if (f.count < 1 || f.repeat < 1) throw InputError("--count and --repeat must be >= 1");
  const Device device = Device::parse(f.device);
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
              interpolation_name(interp).c_str(), f.repeat);
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
  cmd->add_option("--threads", flags->threads, "CPU threads (default: all)");
  cmd->add_option("--device", flags->device, "cpu (default), cuda or cuda:K");
  cmd->add_flag("--json", flags->json, "Machine-readable output");
  cmd->callback([flags] { run_bench(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
