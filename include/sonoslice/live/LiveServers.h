#pragma once
/// @file The live workflows (docs/live.md): frames in → a growing volume out (live compound, with
/// PlusServer's volume reconstruction commands), and poses in → images out (a virtual probe).
/// Both run until a stop condition and return what the caller writes.
#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/live/IgtlServer.h"
#include "sonoslice/live/LiveCompounder.h"

namespace sonoslice {

/// When a live run ends, besides its own commands: after `max_frames` frames or `max_seconds`
/// (0: no limit), or when `*stop` becomes true (a signal handler sets it).
struct LiveLimits {
  int64_t max_frames = 0;
  double max_seconds = 0;
  const std::atomic<bool>* stop = nullptr;
};

struct LiveCompoundRun {
  IgtlEndpointOptions endpoint;
  std::string image_device;  ///< only IMAGE messages of this device name ("": every one)
  LiveLimits limits;
  /// Called once the endpoint is bound (listen: with the port it got).
  std::function<void(const IgtlEndpoint&)> on_ready;
  /// Progress lines (commands received, snapshots sent); may be empty.
  std::function<void(const std::string&)> log;
  /// Each frame handed to the compounder (a viewer's newest frame): w×h pixels of `type`,
  /// pixel (u, v, 0, 1) → the reconstruction frame. May be empty.
  std::function<void(const void* pixels, PixelType type, int width, int height,
                     const Mat4& to_reference)>
      on_frame;
};

struct LiveCompoundResult {
  Volume volume;  ///< finish(): every compounded frame
  LiveStats stats;
  std::map<std::string, int64_t> network;  ///< IgtlEndpoint::counts() and ignored messages
  std::string stopped_by;                  ///< "--max-frames", "StopVolumeReconstruction", ...
  /// The statistics (LiveStats::json) with "peak_memory_mb" (the process's), "stopped_by" and
  /// "network" added.
  std::string json() const;
};

/// Serves `compounder` until a limit or a StopVolumeReconstruction command. IMAGE messages are
/// frames; STRING `CMD_<uid>` and (header v2) COMMAND messages are PlusServer's commands
/// (StartVolumeReconstruction, Suspend..., Resume..., GetVolumeReconstructionSnapshot,
/// StopVolumeReconstruction), answered as PlusServer answers; GET_STATUS gets a STATUS holding
/// the statistics. Anything else is ignored and counted.
LiveCompoundResult run_live_compound(LiveCompounder& compounder, const LiveCompoundRun& run);

/// A virtual probe's renderer: the image at `pose` (probe → world, LPS) into `out`.
struct ProbeRenderer {
  int width = 0, height = 0;
  PixelType type = PixelType::Float32;
  Mat4 pixel_to_probe;
  std::function<void(const Pose& pose, void* out)> render;
};

struct VirtualProbeRun {
  IgtlEndpointOptions endpoint;
  std::string pose_device;  ///< only TRANSFORMs of this device name ("": every one)
  std::string image_device = "Image";
  WorldFrame world = WorldFrame::LPS;  ///< the frame of the poses received and images sent
  LiveLimits limits;                   ///< max_frames counts images sent
  std::function<void(const IgtlEndpoint&)> on_ready;
  /// Each image sent (a viewer's newest frame): the renderer's pixels at `pose` (LPS), and the
  /// time from its TRANSFORM's arrival. May be empty.
  std::function<void(const Pose& pose, const void* image, double latency_ms)> on_image;
};

struct VirtualProbeResult {
  int64_t poses = 0, images = 0, rejected = 0;
  std::map<std::string, int64_t> network;
  double seconds = 0;
  Latencies latency_ms;  ///< a TRANSFORM read → its IMAGE queued
  std::string stopped_by;
  std::string json() const;
};

/// Answers each TRANSFORM with one IMAGE: the renderer's image at that pose, placed by
/// pose · pixel_to_probe, with the TRANSFORM's timestamp, to the client that sent it.
VirtualProbeResult run_virtual_probe(const ProbeRenderer& renderer, const VirtualProbeRun& run);

}  // namespace sonoslice
