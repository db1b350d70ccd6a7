// The viewer's parts that need no HTTP library: the planes' geometry, the live feed (its
// snapshot thread) and opening a browser. Built in every configuration, so the live commands
// link with or without cpp-httplib.
#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "ViewDetail.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace view_detail {

std::array<Vec3, 8> box_corners(const VolumeGrid& g) {
  std::array<Vec3, 8> c;
  for (int b = 0; b < 8; ++b)
    c[size_t(b)] =
        g.index_to_world({double((b & 1) ? g.dims[0] - 1 : 0), double((b & 2) ? g.dims[1] - 1 : 0),
                          double((b & 4) ? g.dims[2] - 1 : 0)});
  return c;
}

}  // namespace view_detail

using view_detail::box_corners;

// ----------------------------------------------------------------------------------- planes --

Pose ViewPlane::pose_at(double position) const {
  const Vec3 n = cross(u, v);
  Vec3 o = origin;
  o[size_t(axis)] = position;
  Pose t;
  for (int r = 0; r < 3; ++r) {
    t.m[r][0] = u[size_t(r)];
    t.m[r][1] = v[size_t(r)];
    t.m[r][2] = n[size_t(r)];
    t.m[r][3] = o[size_t(r)];
  }
  return t;
}

const char* ViewPlane::name() const {
  return axis == 0 ? "sagittal" : axis == 1 ? "coronal" : "axial";
}

std::array<ViewPlane, 3> view_planes(const VolumeGrid& grid, int max_pixels) {
  Vec3 lo{{1e300, 1e300, 1e300}}, hi{{-1e300, -1e300, -1e300}};
  for (const Vec3& c : box_corners(grid))
    for (size_t a = 0; a < 3; ++a) lo[a] = std::min(lo[a], c[a]), hi[a] = std::max(hi[a], c[a]);
  const Vec3 ext = hi - lo;
  double s = std::min({grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2]});
  const double widest = std::max({ext[0], ext[1], ext[2]});
  if (std::ceil(widest / s - 1e-9) + 1 > max_pixels) s = widest / (max_pixels - 1);
  // Enough pixels that the last one reaches the box's far side (an oblique box's extent is rarely
  // a whole number of pixels).
  const auto pixels = [&](double extent) { return int(std::ceil(extent / s - 1e-9)) + 1; };
  std::array<ViewPlane, 3> planes;
  for (int axis = 0; axis < 3; ++axis) {
    ViewPlane& p = planes[size_t(axis)];
    p.axis = axis;
    p.spacing = s;
    p.min = lo[size_t(axis)];
    p.max = hi[size_t(axis)];
    // The scroll step: the spacing of the index axis that runs most along this world axis.
    int best = 0;
    for (int c = 1; c < 3; ++c)
      if (std::fabs(grid.direction.m[axis][c]) > std::fabs(grid.direction.m[axis][best])) best = c;
    p.step = grid.spacing_mm[size_t(best)];
    // As 3D Slicer shows them (docs/view.md): axial right = +x (patient left), down = +y
    // (posterior); coronal and sagittal down = −z (inferior); sagittal right = +y (posterior).
    if (axis == 2) {
      p.u = {{1, 0, 0}}, p.v = {{0, 1, 0}}, p.origin = {{lo[0], lo[1], 0}};
      p.width = pixels(ext[0]), p.height = pixels(ext[1]);
    } else if (axis == 1) {
      p.u = {{1, 0, 0}}, p.v = {{0, 0, -1}}, p.origin = {{lo[0], 0, hi[2]}};
      p.width = pixels(ext[0]), p.height = pixels(ext[2]);
    } else {
      p.u = {{0, 1, 0}}, p.v = {{0, 0, -1}}, p.origin = {{0, lo[1], hi[2]}};
      p.width = pixels(ext[1]), p.height = pixels(ext[2]);
    }
  }
  return planes;
}

// -------------------------------------------------------------------------------- live feed --

LiveFeed::LiveFeed() : impl_(std::make_unique<Impl>()) {}
LiveFeed::~LiveFeed() {
  impl_->stop_refresher();
}

void LiveFeed::frame(const void* pixels, PixelType type, int width, int height,
                     const Mat4& to_world) {
  const size_t bytes = size_t(width) * size_t(height) * pixel_size(type);
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->pixels.assign(static_cast<const uint8_t*>(pixels),
                       static_cast<const uint8_t*>(pixels) + bytes);
  impl_->type = type;
  impl_->width = width;
  impl_->height = height;
  impl_->to_world = to_world;
  ++impl_->seq;
  impl_->wake.notify_all();
}

void LiveFeed::set_stats(std::function<std::string()> stats_json) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->stats = std::move(stats_json);
}

void LiveFeed::set_volume_source(std::function<Volume()> snapshot, double min_interval_s) {
  impl_->stop_refresher();
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->snapshot = std::move(snapshot);
  impl_->min_interval = min_interval_s;
  impl_->stopping = false;
  impl_->refresher = std::thread([im = impl_.get()] { im->refresh_loop(); });
}

void LiveFeed::finish(std::optional<Volume> final_volume) {
  impl_->stop_refresher();
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->running = false;
  if (final_volume) impl_->set_volume(std::make_shared<Volume>(std::move(*final_volume)));
}

bool open_in_browser(const std::string& url) {
#ifdef __APPLE__
  const std::string opener = "open";
#else
  const std::string opener = "xdg-open";
#endif
  if (!std::getenv("DISPLAY") && !std::getenv("WAYLAND_DISPLAY")) {
#ifndef __APPLE__
    return false;
#endif
  }
  const std::string command = opener + " '" + url + "' >/dev/null 2>&1 &";
  return std::system(command.c_str()) == 0;
}

}  // namespace sonoslice
