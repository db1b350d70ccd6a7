#pragma once
/// @file Live compounding (docs/live.md): tracked 2D frames arrive one at a time, from a network
/// stream or the caller's own acquisition code, and go into a volume that can be looked at any
/// time. The frames are compounded in arrival order by the library's Compounder with the settings
/// `sonoslice compound` resolves (plan_stream), so the final volume is byte-identical to an
/// offline reconstruction of the recorded frames on the same grid.
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/compound/Reconstruction.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"

namespace sonoslice {

/// What happens to frames that arrive faster than they are compounded.
enum class QueuePolicy {
  All,    ///< every frame is compounded; at `queue_size` waiting frames the sender waits
  Newest  ///< only the newest waiting frame is kept; the ones it replaces are counted as dropped
};
QueuePolicy parse_queue_policy(const std::string& text, const std::string& what);

struct LiveOptions {
  QueuePolicy queue = QueuePolicy::All;
  int queue_size = 16;  ///< QueuePolicy::All: frames that may wait (1 to 100000)
  /// Keep every compounded frame (for record()); a grid that grows keeps them anyway.
  bool keep_frames = false;
};

/// Latencies in milliseconds: nearest-rank percentiles and the maximum.
struct Latencies {
  double p50 = 0, p95 = 0, p99 = 0, max = 0;
  static Latencies of(std::vector<float> ms);
};

/// Counts since the start, and the latency from a frame's arrival to its being in the volume.
struct LiveStats {
  int64_t received = 0;    ///< frames offered (push), accepted or not
  int64_t compounded = 0;  ///< in the volume
  int64_t dropped = 0;     ///< replaced by a newer frame (QueuePolicy::Newest)
  int64_t suspended = 0;   ///< arrived while reconstruction was suspended
  int64_t rejected = 0;    ///< refused, by reason below
  std::map<std::string, int64_t> rejected_by_reason;
  int64_t waiting = 0;  ///< in the queue now
  uint64_t bytes = 0;   ///< pixel bytes of the frames received
  Latencies latency_ms;
  double seconds = 0;  ///< since the compounder was made
  std::optional<VolumeGrid> grid;
  /// One JSON object: these fields (latency under "latency_ms": p50, p95, p99, max) and the
  /// grid (origin, spacing, extent) when there is one.
  std::string json() const;
  /// "300 frames received, 300 compounded, 0 dropped, 0 rejected; latency p50 1.2 ms ..."
  std::string summary() const;
};

class LiveCompounder {
 public:
  /// `config` (may be null) and `options` as for Reconstruction (spacing, interpolation,
  /// compounding, hole filling, clip, output type, origin/extent, device, memory); errors for
  /// bad settings are thrown here, before any frame. Without a grid from the options or the
  /// configuration, the grid grows around the frames on the lattice of the spacing (origin a
  /// multiple of it), keeping the frames to re-insert them; finish() then fits it around them as
  /// `sonoslice compound` does (Compounder::grid_around).
  LiveCompounder(std::shared_ptr<const PlusReconstructionConfig> config,
                 ReconstructionOptions options, LiveOptions live = {});
  ~LiveCompounder();
  LiveCompounder(const LiveCompounder&) = delete;
  LiveCompounder& operator=(const LiveCompounder&) = delete;

  /// Offers a frame: H×W `pixels` (copied) of uint8, int8, uint16, int16 or float32, placed by
  /// `image_to_reference` (pixel (i, j, 0) → mm). Returns "" when it was queued, else why it was
  /// refused (also counted): a type or size other than the first frame's, a non-finite or
  /// singular matrix. QueuePolicy::All blocks while the queue is full. `arrival`: the
  /// steady-clock seconds the latency is measured from (default: now).
  std::string push(const void* pixels, PixelType type, int width, int height,
                   const Mat4& image_to_reference, double timestamp_s = 0,
                   std::optional<double> arrival = std::nullopt);
  /// QueuePolicy::All: the queue is full (a server stops reading its senders meanwhile).
  bool full() const;
  /// Waits until every queued frame is in the volume.
  void drain();

  /// PlusServer's Suspend/Resume: frames arriving while suspended are counted, not compounded.
  void suspend();
  void resume();
  bool is_suspended() const;
  /// PlusServer's Start: an empty volume (and record); counts and latencies go on. With
  /// `options`: those settings from now on (checked first; on error nothing changes).
  void reset();
  void reset(const ReconstructionOptions& options);
  const ReconstructionOptions& options() const;

  /// The volume of the frames compounded so far (holes filled when the settings say so), in
  /// the output type; an empty Volume before the first frame.
  Volume snapshot() const;
  /// drain(), then the final volume (a growing grid fitted around the frames as `compound` fits
  /// it).
  Volume finish();
  LiveStats stats() const;
  /// The compounded frames as a PLUS sequence (each with its `<Image>To<Reference>Transform`,
  /// Timestamp and ImageStatus OK): `sonoslice compound` of it reproduces the volume. Needs
  /// LiveOptions::keep_frames.
  PlusSequence recorded() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace sonoslice
