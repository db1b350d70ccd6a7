// sonoslice live: OpenIGTLink in and out (docs/live.md). `live compound`: tracked frames in, a
// growing volume out, driven by PlusServer's reconstruction commands; `live slice` and `live
// simulate`: a virtual probe answering each pose with the image `slice` / `simulate` makes there.
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <mutex>

#include <unistd.h>

#include "Commands.h"
#include "Common.h"
#include "ReconstructionFlags.h"
#include "SimulationFlags.h"
#include "ViewFlags.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/live/LiveServers.h"
#include "sonoslice/plus/PlusConfig.h"

namespace sonoslice {
namespace cli {
namespace {

struct Endpoint {
  std::string listen, connect;
  void add_to(CLI::App& cmd) {
    cmd.add_option("--listen", listen,
                   "[HOST:]PORT: wait for OpenIGTLink clients (host 127.0.0.1 unless given; "
                   "port 0: a free one, printed)");
    cmd.add_option("--connect", connect, "HOST:PORT: be a client of an OpenIGTLink server");
  }
  IgtlEndpointOptions options() const {
    if (listen.empty() == connect.empty()) throw UsageError("give one of --listen or --connect");
    IgtlEndpointOptions o;
    o.listen = !listen.empty();
    parse_host_port(o.listen ? listen : connect, o.listen ? "--listen" : "--connect", o.host,
                    o.port);
    return o;
  }
};

void announce(const char* command, const IgtlEndpoint& e) {
  // One line on stdout, flushed: scripts and tests read the port from it.
  std::printf("sonoslice live %s: %s %s:%d\n", command,
              e.options().listen ? "listening on" : "connecting to", e.options().host.c_str(),
              e.port());
  std::fflush(stdout);
}

// --view after a run: the page keeps showing its end until Ctrl-C (at once when a Ctrl-C ended
// the run).
void keep_serving(const char* command, const ViewServer& view) {
  if (StopOnSignals::stop_requested().load()) return;
  std::fprintf(stderr, "sonoslice live %s: the run ended; %s shows it until Ctrl-C\n", command,
               view.url().c_str());
  wait_for_interrupt();
}

void write_text_file(const std::string& path, const std::string& text) {
  AtomicFile f(path);
  std::FILE* out = fdopen(dup(f.fd()), "w");
  if (!out || std::fputs(text.c_str(), out) < 0 || std::fclose(out) != 0)
    throw FileError("cannot write '" + path + "'");
  f.commit();
}

// --view's [HOST:]PORT, checked before the endpoint listens (the viewer starts after it, so
// that the endpoint's line comes first on stdout).
void check_view_option(const std::string& view) {
  if (view.empty()) return;
  std::string host = "127.0.0.1";
  int port = 0;
  parse_host_port(view, "--view", host, port);
}

void add_view_option(CLI::App& cmd, std::string& view) {
  cmd.add_option("--view", view,
                 "[HOST:]PORT: also serve the browser viewer there (docs/view.md; port 0: a free "
                 "one); it stays up after the run until Ctrl-C");
}

struct LiveCompoundFlags {
  Endpoint endpoint;
  std::string config;
  ReconstructionFlags recon;
  std::string image_device, queue = "all", out, record, stats, view;
  int queue_size = 16;
  int64_t max_frames = 0;
  double max_seconds = 0;
  bool quiet = false;
};

// --max-frames and --max-seconds of every live command: 0 is no limit.
void check_stop_limits(int64_t max_frames, double max_seconds) {
  if (max_frames < 0)
    throw InputError("--max-frames " + std::to_string(max_frames) + ": must be >= 0 (0: no limit)");
  if (!(max_seconds >= 0) || std::isinf(max_seconds)) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", max_seconds);
    throw InputError("--max-seconds " + std::string(text) +
                     ": must be a finite number >= 0 (0: no limit)");
  }
}

void run_live_compound_command(const LiveCompoundFlags& f) {
  const IgtlEndpointOptions endpoint = f.endpoint.options();
  ReconstructionOptions options;
  options.names = flag_of;
  f.recon.apply(options);
  options.device = setup_device(f.recon.device, f.recon.threads);
  check_stop_limits(f.max_frames, f.max_seconds);
  check_view_option(f.view);
  check_distinct_outputs({{"--out", f.out}, {"--record", f.record}, {"--stats", f.stats}},
                         {{"--config", f.config}});
  check_volume_output(f.out, "--out");
  if (!f.record.empty()) {
    check_plus_sequence_name(f.record);
    check_output_path(f.record);
  }
  if (!f.stats.empty()) check_output_path(f.stats);
  std::shared_ptr<const PlusReconstructionConfig> config;
  if (!f.config.empty())
    config = std::make_shared<PlusReconstructionConfig>(read_plus_config(f.config));
  LiveOptions live;
  live.queue = parse_queue_policy(f.queue, "--queue");
  live.queue_size = f.queue_size;
  live.keep_frames = !f.record.empty();
  LiveCompounder compounder(config, options, live);

  LiveCompoundRun run;
  run.endpoint = endpoint;
  run.image_device = f.image_device;
  run.limits.max_frames = f.max_frames;
  run.limits.max_seconds = f.max_seconds;
  run.limits.stop = &StopOnSignals::stop_requested();
  run.on_ready = [](const IgtlEndpoint& e) { announce("compound", e); };
  if (!f.quiet)
    run.log = [](const std::string& line) {
      std::fprintf(stderr, "sonoslice live compound: %s\n", line.c_str());
    };
  // --view: the page shows the newest frame, the statistics and the growing volume.
  std::shared_ptr<LiveFeed> feed;
  std::unique_ptr<ViewServer> view;
  if (!f.view.empty()) {
    feed = std::make_shared<LiveFeed>();
    feed->set_stats([&compounder] { return compounder.stats().json(); });
    feed->set_volume_source([&compounder] { return compounder.snapshot(); });
    // Started once the endpoint listens, so the endpoint's line comes first on stdout.
    run.on_ready = [&view, &f, feed](const IgtlEndpoint& e) {
      announce("compound", e);
      ViewContent content;
      content.title = "live compound";
      view = start_view("sonoslice live compound", std::move(content), f.view, feed);
    };
    run.on_frame = [feed](const void* pixels, PixelType type, int w, int h, const Mat4& m) {
      feed->frame(pixels, type, w, h, m);
    };
  }
  LiveCompoundResult result;
  {
    // The feed's snapshots stop before the compounder goes, whichever way this scope is left.
    const std::unique_ptr<LiveFeed, void (*)(LiveFeed*)> snapshots(
        feed.get(), [](LiveFeed* fd) { fd->finish(std::nullopt); });
    StopOnSignals signals;
    result = run_live_compound(compounder, run);
  }
  if (feed) feed->finish(result.volume);
  // Why frames were turned away, for the summary line and the error of a run without a volume.
  std::string why;
  for (const auto& [reason, n] : result.stats.rejected_by_reason)
    why += "; " + std::to_string(n) + " rejected: " + reason;
  for (const auto& [key, n] : result.network)
    if (key.rfind("rejected: ", 0) == 0 || key.rfind("ignored: ", 0) == 0 ||
        key.rfind("connect failed: ", 0) == 0)
      why += "; " + std::to_string(n) + " " + key;
  if (result.volume.grid().voxel_count() == 0) {
    // One line, the error's, with the counts; the statistics alone say more.
    if (!f.stats.empty()) write_text_file(f.stats, result.json() + "\n");
    throw InputError("live compound: stopped by " + result.stopped_by +
                     " with no frame compounded, nothing written to '" + f.out + "' (" +
                     std::to_string(result.stats.received) + " frames received" + why + ")");
  }
  std::fprintf(stderr, "sonoslice live compound: stopped by %s: %s%s\n", result.stopped_by.c_str(),
               result.stats.summary().c_str(), why.c_str());
  OutputSet outputs;  // the volume, the recording and the statistics: all of them or none
  write_volume(f.out, result.volume, &outputs);
  if (!f.record.empty()) write_plus_sequence(f.record, compounder.recorded(), true, &outputs);
  if (!f.stats.empty()) write_text_file(f.stats, result.json() + "\n", &outputs);
  outputs.commit();
  if (!f.quiet && result.stats.grid) {
    const VolumeGrid& g = *result.stats.grid;
    std::fprintf(stderr,
                 "sonoslice live compound: %s: %lldx%lldx%lld voxels, origin %.17g,%.17g,%.17g\n",
                 f.out.c_str(), (long long)g.dims[0], (long long)g.dims[1], (long long)g.dims[2],
                 g.origin_mm[0], g.origin_mm[1], g.origin_mm[2]);
  }
  if (view) keep_serving("compound", *view);
}

// What `live slice` and `live simulate` share: the endpoint, device names, limits, statistics.
struct VirtualProbeFlags {
  Endpoint endpoint;
  std::string pose_device, image_device = "Image", stats, view;
  int64_t max_frames = 0;
  double max_seconds = 0;
  void add_to(CLI::App& cmd) {
    endpoint.add_to(cmd);
    cmd.add_option("--pose-device", pose_device,
                   "Only TRANSFORM messages of this device name (default: every one)");
    cmd.add_option("--image-device", image_device, "Device name of the images sent (Image)");
    cmd.add_option("--max-frames", max_frames, "Stop after N images (default 0: no limit)");
    cmd.add_option("--max-seconds", max_seconds, "Stop after S seconds (default 0: no limit)");
    cmd.add_option("--stats", stats, "Write the counts and latencies here (JSON)");
    add_view_option(cmd, view);
  }
};

// Serves `renderer` until a limit or a signal; the summary line and --stats.
void serve_virtual_probe(const char* command, const VirtualProbeFlags& f,
                         const IgtlEndpointOptions& endpoint, WorldFrame world,
                         const ProbeRenderer& renderer, ViewContent content) {
  VirtualProbeRun run;
  run.endpoint = endpoint;
  run.pose_device = f.pose_device;
  run.image_device = f.image_device;
  run.world = world;
  run.limits.max_frames = f.max_frames;
  run.limits.max_seconds = f.max_seconds;
  run.limits.stop = &StopOnSignals::stop_requested();
  run.on_ready = [command](const IgtlEndpoint& e) { announce(command, e); };
  // --view: the page shows the volume's planes, each image sent in its place and the counts.
  std::unique_ptr<ViewServer> view;
  std::shared_ptr<LiveFeed> feed;
  if (!f.view.empty()) {
    feed = std::make_shared<LiveFeed>();
    struct Counts {
      std::mutex mutex;
      int64_t images = 0;
      std::vector<float> latency_ms;
    };
    auto counts = std::make_shared<Counts>();
    feed->set_stats([counts] {
      std::lock_guard<std::mutex> lock(counts->mutex);
      LiveStats s;  // the keys the page reads, as live compound's
      s.received = s.compounded = counts->images;
      s.latency_ms = Latencies::of(counts->latency_ms);
      return s.json();
    });
    run.on_image = [feed, counts, &renderer](const Pose& pose, const void* image, double ms) {
      feed->frame(image, renderer.type, renderer.width, renderer.height,
                  pose * renderer.pixel_to_probe);
      std::lock_guard<std::mutex> lock(counts->mutex);
      ++counts->images;
      counts->latency_ms.push_back(float(ms));
    };
    content.title = std::string("live ") + command;
    // Started once the endpoint listens, so the endpoint's line comes first on stdout.
    run.on_ready = [&view, &f, feed, command, &content](const IgtlEndpoint& e) {
      announce(command, e);
      view = start_view(std::string("sonoslice live ") + command, std::move(content), f.view, feed);
    };
  }
  VirtualProbeResult result;
  {
    StopOnSignals signals;
    result = run_virtual_probe(renderer, run);
  }
  if (feed) feed->finish(std::nullopt);
  std::fprintf(stderr,
               "sonoslice live %s: stopped by %s: %lld poses, %lld images (%.0f/s), %lld "
               "rejected; latency p50 %.2f ms, p99 %.2f ms\n",
               command, result.stopped_by.c_str(), (long long)result.poses,
               (long long)result.images, result.seconds > 0 ? result.images / result.seconds : 0.0,
               (long long)result.rejected, result.latency_ms.p50, result.latency_ms.p99);
  if (!f.stats.empty()) write_text_file(f.stats, result.json() + "\n");
  if (view) keep_serving(command, *view);
}

void check_probe_flags(const VirtualProbeFlags& f) {
  check_stop_limits(f.max_frames, f.max_seconds);
  if (!f.stats.empty()) check_output_path(f.stats);
  check_view_option(f.view);
}

struct LiveSliceFlags {
  VirtualProbeFlags probe_flags;
  VolumeFlags volume;
  std::string labels, probe, interp = "linear", dtype = "float32", world = "LPS";
  std::string device = "cpu";
  double fill = 0;
  int downsampling = 1;
  std::optional<int> threads;
};

void run_live_slice_command(const LiveSliceFlags& f) {
  const IgtlEndpointOptions endpoint = f.probe_flags.endpoint.options();
  if (f.volume.path.empty() == f.labels.empty())
    throw UsageError("live slice: give one of --volume or --labels");
  check_probe_flags(f.probe_flags);
  const Device device = setup_device(f.device, f.threads);
  SliceSettings settings;
  settings.interpolation = parse_interpolation(f.interp);
  settings.output_type = parse_pixel_type(f.dtype);
  settings.fill_value = f.fill;
  if (!f.labels.empty()) settings.interpolation = Interpolation::Nearest;
  const WorldFrame world = parse_world_frame(f.world);
  const ProbeGeometry probe = read_probe(f.probe, f.downsampling);
  const std::string path = f.volume.path.empty() ? f.labels : f.volume.path;
  const Volume v = read_volume(path, f.volume.options());
  const Slicer slicer(v, probe, settings, device);

  ProbeRenderer renderer;
  renderer.width = probe.image.width;
  renderer.height = probe.image.height;
  renderer.type = settings.output_type;
  renderer.pixel_to_probe = probe.pixel_to_probe();
  renderer.render = [&slicer](const Pose& pose, void* out) { slicer.slice(&pose, 1, out, 0); };
  ViewContent content;
  content.volume = v;
  content.volume_name = path;
  content.probe = probe;
  serve_virtual_probe("slice", f.probe_flags, endpoint, world, renderer, std::move(content));
}

struct LiveSimulateFlags {
  VirtualProbeFlags probe_flags;
  SimulateFlags simulation;
};

void run_live_simulate_command(const LiveSimulateFlags& f) {
  const IgtlEndpointOptions endpoint = f.probe_flags.endpoint.options();
  const SimulateFlags& s = f.simulation;
  check_simulation_flags(s, "live simulate");
  check_probe_flags(f.probe_flags);
  setup_threads(s.threads);
  const SimulationSettings settings = settings_of(s);
  const std::optional<ProbeGeometry> probe = probe_of(s);
  const WorldFrame world = parse_world_frame(s.world);
  const std::vector<Tissue> tissues = tissues_of(s);
  const SimulationInput input = read_simulation_input(s);
  const Simulator sim = simulator_of(s, input, probe, tissues, settings);

  ProbeRenderer renderer;
  renderer.width = sim.width();
  renderer.height = sim.height();
  renderer.type =
      settings.output == SimulationOutput::BMode ? PixelType::UInt8 : PixelType::Float32;
  renderer.pixel_to_probe = sim.probe().pixel_to_probe();
  renderer.render = [&sim](const Pose& pose, void* out) { sim.simulate(&pose, 1, out, 0); };
  ViewContent content;
  content.volume = input.volume;
  content.volume_name = s.volume.path.empty() ? s.labels : s.volume.path;
  content.probe = sim.probe();
  if (renderer.type == PixelType::UInt8) content.image_window = std::make_pair(127.5, 255.0);
  serve_virtual_probe("simulate", f.probe_flags, endpoint, world, renderer, std::move(content));
}

}  // namespace

void add_live_command(CLI::App& app) {
  CLI::App* live = app.add_subcommand(
      "live", "OpenIGTLink in and out: live compounding and a virtual probe (docs/live.md)");
  live->require_subcommand(1);

  auto c = std::make_shared<LiveCompoundFlags>();
  CLI::App* cmd =
      live->add_subcommand("compound",
                           "Tracked frames (IMAGE messages) in, a growing volume out; PlusServer's "
                           "volume reconstruction commands");
  c->endpoint.add_to(*cmd);
  cmd->add_option("--config", c->config,
                  "PLUS configuration XML: its VolumeReconstruction settings and grid");
  c->recon.add_to(*cmd);
  cmd->add_option("--image-device", c->image_device,
                  "Only IMAGE messages of this device name (default: every IMAGE)");
  cmd->add_option("--queue", c->queue,
                  "all (default: every frame, the sender waits while --queue-size frames are "
                  "waiting) or newest "
                  "(only the newest waiting frame; the others are dropped and counted)");
  cmd->add_option("--queue-size", c->queue_size, "Frames that may wait with --queue all (16)");
  cmd->add_option("--max-frames", c->max_frames, "Stop after N frames (default 0: no limit)");
  cmd->add_option("--max-seconds", c->max_seconds, "Stop after S seconds (default 0: no limit)");
  cmd->add_option("--out", c->out, "The volume: .nii/.nii.gz/.mha/.nrrd/.npy")->required();
  cmd->add_option("--record", c->record,
                  "Also write the compounded frames as a PLUS sequence (.igs.mha/.igs.nrrd)");
  cmd->add_option("--stats", c->stats, "Write the counts and latencies here (JSON)");
  add_view_option(*cmd, c->view);
  cmd->add_flag("--quiet,-q", c->quiet, "Only the summary line");
  cmd->callback([c] { run_live_compound_command(*c); });

  auto s = std::make_shared<LiveSliceFlags>();
  cmd = live->add_subcommand("slice",
                             "A virtual probe: each TRANSFORM (probe pose) gets the IMAGE "
                             "`sonoslice slice` makes there");
  s->probe_flags.add_to(*cmd);
  s->volume.add_to(*cmd, /*path_required=*/false);
  cmd->add_option("--labels", s->labels, "A label volume (uint8/uint16): label images, nearest");
  cmd->add_option("--probe", s->probe, "Probe JSON (native or fan-slicer config)")->required();
  cmd->add_option("--downsampling", s->downsampling, "Divide the probe image size by K");
  cmd->add_option("--interp", s->interp, "linear (default) or nearest");
  cmd->add_option("--dtype", s->dtype, "float32 (default), int16, uint8 or uint16");
  cmd->add_option("--fill", s->fill, "Value outside the fan or the volume (default 0)");
  cmd->add_option("--world", s->world, "Frame of the poses and images: LPS (default) or RAS");
  cmd->add_option("--device", s->device, "cpu (default), cuda or cuda:K");
  add_threads_option(*cmd, s->threads);
  cmd->callback([s] { run_live_slice_command(*s); });

  auto m = std::make_shared<LiveSimulateFlags>();
  cmd = live->add_subcommand("simulate",
                             "A virtual probe: each TRANSFORM (probe pose) gets the IMAGE "
                             "`sonoslice simulate` makes there");
  m->probe_flags.add_to(*cmd);
  add_simulation_flags(*cmd, m->simulation);
  cmd->callback([m] { run_live_simulate_command(*m); });
}

}  // namespace cli
}  // namespace sonoslice
