// Which pixels of a 2D frame go into a reconstruction: the clip rectangle, PLUS's fan test or a
// custom mask (FrameClip), and the runs of pixels the kernels take.
#include "sonoslice/compound/FrameClip.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include "ClipSpans.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {

namespace compound_impl {

std::vector<RowSpans> spans_from_mask(const std::vector<uint8_t>& mask, int width, int height) {
  std::vector<RowSpans> spans(static_cast<size_t>(height));
  for (int v = 0; v < height; ++v) {
    RowSpans& s = spans[size_t(v)];
    for (int k = 0; k < kMaxSpans; ++k) s.begin[k] = s.end[k] = 0;
    int k = 0;
    const uint8_t* row = mask.data() + size_t(v) * width;
    for (int u = 0; u < width;) {
      if (!row[u]) {
        ++u;
        continue;
      }
      int e = u;
      while (e < width && row[e]) ++e;
      if (k == kMaxSpans)
        throw InputError("frame clip: row " + std::to_string(v) + " of the fan has more than " +
                         std::to_string(kMaxSpans) + " runs of pixels");
      s.begin[k] = u;
      s.end[k] = e;
      ++k;
      u = e;
    }
  }
  return spans;
}

}  // namespace compound_impl

std::array<int, 4> FrameClip::rectangle(int frame_width, int frame_height) const {
  if (!custom_mask.empty() && custom_mask.size() == size_t(frame_width) * size_t(frame_height)) {
    // The box around the mask's pixels.
    std::array<int, 4> box{frame_width, frame_height, 0, 0};
    for (int v = 0; v < frame_height; ++v)
      for (int u = 0; u < frame_width; ++u)
        if (custom_mask[size_t(v) * frame_width + u]) {
          box = {std::min(box[0], u), std::min(box[1], v), std::max(box[2], u + 1),
                 std::max(box[3], v + 1)};
        }
    if (box[0] >= box[2]) box = {0, 0, 0, 0};
    return box;
  }
  const int x0 = std::max(0, x), y0 = std::max(0, y);
  const int x1 = width < 0 ? frame_width : std::min(frame_width, x + width);
  const int y1 = height < 0 ? frame_height : std::min(frame_height, y + height);
  return {x0, y0, std::max(x0, x1), std::max(y0, y1)};
}

void FrameClip::require_pixels(int frame_width, int frame_height, const std::string& what,
                               const std::string& frames) const {
  const auto r = rectangle(frame_width, frame_height);
  if (r[0] < r[2] && r[1] < r[3]) return;
  const auto size = [](int n) { return n < 0 ? std::string("to the edge") : std::to_string(n); };
  throw InputError(what + " (origin " + std::to_string(x) + "," + std::to_string(y) + ", size " +
                   size(width) + " x " + size(height) + ") leaves no pixel of the " +
                   std::to_string(frame_width) + "x" + std::to_string(frame_height) + " frames" +
                   (frames.empty() ? "" : " of '" + frames + "'"));
}

void FrameClip::validate(const std::string& what) const {
  if (x < 0 || y < 0)
    throw InputError(what + ": clip rectangle x, y = " + std::to_string(x) + ", " +
                     std::to_string(y) + " must not be negative");
  if (width < -1 || height < -1)
    throw InputError(what + ": clip rectangle width x height = " + std::to_string(width) + "x" +
                     std::to_string(height) + " is negative (-1: to the frame's edge)");
  if (!fan) return;
  for (double a : fan_angles_deg)
    if (!(a > -90 && a < 90))
      throw InputError(what +
                       ": fan angles (fan_angles_deg) must be strictly between -90 and 90 degrees");
  if (!(fan_angles_deg[0] <= fan_angles_deg[1]))
    throw InputError(what + ": fan angles (fan_angles_deg) must be given smallest first");
  if (!std::isfinite(fan_origin_px[0]) || !std::isfinite(fan_origin_px[1]))
    throw InputError(what + ": fan origin (fan_origin_px) must be finite");
  if (!(fan_radius_px[0] >= 0 && fan_radius_px[1] >= fan_radius_px[0]))
    throw InputError(what + ": fan radii (fan_radius_px) must satisfy 0 <= start <= stop");
}

std::vector<uint8_t> FrameClip::mask(int frame_width, int frame_height) const {
  validate("frame clip");
  if (!custom_mask.empty()) {
    if (custom_mask.size() != size_t(frame_width) * size_t(frame_height))
      throw InputError("frame clip: the mask has " + std::to_string(custom_mask.size()) +
                       " pixels, frames have " + std::to_string(frame_width) + "x" +
                       std::to_string(frame_height));
    return custom_mask;
  }
  std::vector<uint8_t> m(size_t(frame_width) * frame_height, 0);
  const auto r = rectangle(frame_width, frame_height);
  // PLUS's fan test (unoptimised path): below the origin, tan(a0) <= dx/dy <= tan(a1), and
  // start <= distance <= stop, all inclusive.
  const double deg = kPi / 180.0;
  const double tan0 = std::tan(fan_angles_deg[0] * deg), tan1 = std::tan(fan_angles_deg[1] * deg);
  for (int v = r[1]; v < r[3]; ++v)
    for (int u = r[0]; u < r[2]; ++u) {
      if (fan) {
        const double dx = u - fan_origin_px[0], dy = v - fan_origin_px[1];
        if (dy < 0) continue;
        if (dy == 0 ? dx != 0 : (dx / dy < tan0 || dx / dy > tan1)) continue;
        const double d2 = dx * dx + dy * dy;
        if (d2 < fan_radius_px[0] * fan_radius_px[0] || d2 > fan_radius_px[1] * fan_radius_px[1])
          continue;
      }
      m[size_t(v) * frame_width + u] = 1;
    }
  return m;
}

}  // namespace sonoslice
