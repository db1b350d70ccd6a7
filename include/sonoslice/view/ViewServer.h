#pragma once
/// @file The browser viewer (docs/view.md): a local HTTP server that shows volumes, labels,
/// meshes, probe poses and their images, and live runs, in a page that ships inside sonoslice.
/// The server owns no rendering: the page draws; the server answers with the library's own
/// slices (planes, images at poses) and the scene's geometry.
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/surface/Mesh.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// A world-axis-aligned plane through a volume's box, as 3D Slicer shows it: axial (normal z),
/// coronal (y) and sagittal (x), with square pixels of `spacing` mm. Pixel (i, j) of the plane
/// at axis coordinate p lies at origin + spacing·(i·u + j·v) + p·e_axis.
struct ViewPlane {
  int axis = 2;  ///< 0 sagittal, 1 coronal, 2 axial: the world axis normal to the plane
  int width = 0, height = 0;
  double spacing = 1.0;
  Vec3 origin{}, u{}, v{};  ///< origin has its axis coordinate 0; u: screen right, v: down
  double min = 0, max = 0;  ///< the box's range along the axis
  double step = 1.0;        ///< one scroll step (mm): the volume's spacing along the axis

  /// The pose (probe mm → world) of a linear probe whose pixel (i, j) is this plane's.
  Pose pose_at(double position) const;
  const char* name() const;
};

/// The three planes of `grid`'s box (corner voxel centres), at most `max_pixels` a side (the
/// spacing grows beyond).
std::array<ViewPlane, 3> view_planes(const VolumeGrid& grid, int max_pixels = 1024);

/// A mesh and its colour in the 3D scene.
struct ViewMesh {
  TriangleMesh mesh;
  std::array<uint8_t, 3> color{{200, 200, 200}};
};

/// What `sonoslice view` shows. Everything is optional; the page shows what is there.
struct ViewContent {
  std::string title;
  std::optional<Volume> volume;  ///< intensities in the planes (or a compounded volume)
  std::string volume_name;
  std::optional<Volume> labels;  ///< drawn over the volume (or alone)
  std::string labels_name;
  std::vector<std::array<uint8_t, 3>> label_colors;  ///< label k → label_colors[k − 1]
  std::vector<ViewMesh> meshes;
  std::optional<ProbeGeometry> probe;
  std::vector<Pose> poses;  ///< probe → world (LPS)
  /// The image at a pose, float32 H×W into `out`: sliced (or simulated) with the library's code.
  /// `index` is the pose's place in `poses`, or −1 for a pose the user dragged the probe to.
  std::function<void(const Pose& pose, int64_t index, float* out)> render;
  std::string image_source;  ///< "slice", "simulate" or "images" (with render)
  std::optional<std::pair<double, double>> image_window;  ///< level, width (default: auto)
};

/// What a live run hands the viewer: its newest frame, its statistics and its volume. Fed by
/// the run's thread, read by the server's; every member is safe to call from either.
class LiveFeed {
 public:
  LiveFeed();
  ~LiveFeed();
  /// The newest frame: `pixels` (w×h of `type`) placed by pixel (u, v, 0, 1) → world (LPS).
  void frame(const void* pixels, PixelType type, int width, int height, const Mat4& to_world);
  /// The run's statistics as a JSON object (LiveStats::json's keys), called when polled.
  void set_stats(std::function<std::string()> stats_json);
  /// Snapshots start at least this far apart (seconds), and at least three times their length.
  static constexpr double kMinSnapshotInterval = 0.04;
  /// The growing volume, taken on a thread of the feed's at most every `min_interval_s` while
  /// frames arrive (`snapshot` must stay callable until finish() or destruction).
  void set_volume_source(std::function<Volume()> snapshot,
                         double min_interval_s = kMinSnapshotInterval);
  /// The run ended: no more snapshots; `final_volume` (when given) is shown from now on.
  void finish(std::optional<Volume> final_volume);

  struct Impl;

 private:
  friend class ViewServer;
  std::unique_ptr<Impl> impl_;
};

/// Serves the page and its data on host:port (port 0: a free one) from construction until
/// stop() or destruction, on its own threads.
class ViewServer {
 public:
  ViewServer(ViewContent content, const std::string& host, int port,
             std::shared_ptr<LiveFeed> live = nullptr);
  ~ViewServer();
  ViewServer(const ViewServer&) = delete;
  ViewServer& operator=(const ViewServer&) = delete;

  int port() const;
  /// "http://127.0.0.1:PORT/"; on a network address "http://HOST:PORT/?token=KEY", the key
  /// without which the server answers 403.
  std::string url() const;
  void stop();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Opens `url` in the desktop's browser (xdg-open / open), without waiting; false when none.
bool open_in_browser(const std::string& url);

}  // namespace sonoslice
