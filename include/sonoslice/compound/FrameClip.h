#pragma once
/// @file Which pixels of a tracked 2D frame a reconstruction inserts (docs/compounding.md).
#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace sonoslice {

/// Which pixels of a 2D frame go in: a clip rectangle and, optionally, a fan (PLUS's
/// ClipRectangle*, FanAnglesDeg, FanOriginPixel, FanRadiusStart/StopPixel), in MF-oriented pixels.
/// The rectangle is width × height pixels from (x, y); PLUS's ClipRectangleSize w covers w + 1
/// pixels (its last pixel is x + w), which read_plus_config converts.
struct FrameClip {
  int x = 0, y = 0, width = -1, height = -1;  ///< width/height -1: to the frame's edge
  bool fan = false;
  double fan_angles_deg[2] = {-90, 90};  ///< from the axial direction (+y), x towards +
  double fan_origin_px[2] = {0, 0};
  double fan_radius_px[2] = {0, std::numeric_limits<double>::infinity()};
  /// An explicit H×W mask (1: inserted) instead of the rectangle and fan, e.g. a sonoslice
  /// probe's fan (ProbeGeometry::mask()) for frames the slicer made.
  std::vector<uint8_t> custom_mask;
  /// The H×W uint8 mask (1: inserted) of a frame's pixels that go in.
  std::vector<uint8_t> mask(int frame_width, int frame_height) const;
  /// The clip rectangle intersected with the frame (or the box around a custom mask's pixels):
  /// pixels [x0, x1) × [y0, y1).
  std::array<int, 4> rectangle(int frame_width, int frame_height) const;
  /// InputError naming `what` and the field for a negative x, y or size, NaN angles or radii,
  /// angles outside (-90°, 90°).
  void validate(const std::string& what) const;
  /// InputError when the rectangle leaves no pixel of `frames`' W×H frames: "<what> (origin x,y,
  /// size w×h) leaves no pixel of the W×H frames of '<frames>'" (without "of '…'" when `frames`
  /// is empty).
  void require_pixels(int frame_width, int frame_height, const std::string& what,
                      const std::string& frames = "") const;
};

}  // namespace sonoslice
