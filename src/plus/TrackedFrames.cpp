// A PLUS sequence's tracked frames as rigid poses on one pixel grid (TrackedFrames.h).
#include "sonoslice/plus/TrackedFrames.h"

#include <algorithm>
#include <cmath>

#include "sonoslice/core/Error.h"
#include "sonoslice/plus/FrameSelection.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

namespace {

// A calibration's pixel axes are rarely exactly perpendicular (the NWire phantom's, fitted and
// written with 4 digits, are 89.1° apart). Up to this many degrees off they are registered as
// perpendicular; beyond it the matrix is not an image plane with a pixel spacing.
constexpr double kMaxShearDeg = 5;
// Above this, say that the axes were made perpendicular.
constexpr double kNoticeShearDeg = 0.1;
// Every frame's pixel spacing is the first one's within this (relative): the calibration is
// one, and the tracker's poses are rigid.
constexpr double kSpacingTolerance = 1e-2;

}  // namespace

PlusTrackedFrames plus_tracked_frames(const PlusSequence& sequence,
                                      const PlusReconstructionConfig& config) {
  const PlusFrameSelection sel =
      select_plus_frames(sequence, config.coordinate_definitions, config.image_frame,
                         config.reference_frame, config.skip_interval);
  const std::string transform = config.image_frame + "To" + config.reference_frame;
  PlusTrackedFrames out;
  out.frames = sel.frames;
  out.skipped = sel.skipped_reason(config.image_frame, config.reference_frame);
  double spacing[2] = {0, 0}, worst_shear_deg = 0;
  for (size_t n = 0; n < sel.frames.size(); ++n) {
    const Mat4& m = sel.to_reference[n];
    const std::string where =
        sequence.path + ": frame " + std::to_string(sel.frames[n]) + "'s " + transform + " ";
    const Vec3 column[2] = {{m.m[0][0], m.m[1][0], m.m[2][0]}, {m.m[0][1], m.m[1][1], m.m[2][1]}};
    const Vec3 x = normalized(column[0]), y = normalized(column[1]);
    const double cosine = dot(x, y);
    const double shear_deg = std::fabs(90 - std::acos(cosine) * 180 / kPi);
    if (shear_deg > kMaxShearDeg)
      throw InputError(where + "shears the image: its pixel axes are " +
                       std::to_string(std::acos(cosine) * 180 / kPi) +
                       " degrees apart, not 90 (registration needs an image plane with a pixel "
                       "spacing)");
    worst_shear_deg = std::max(worst_shear_deg, shear_deg);
    for (int c = 0; c < 2; ++c) {
      const double l = norm(column[c]);
      if (n == 0)
        spacing[c] = l;
      else if (std::fabs(l - spacing[c]) > kSpacingTolerance * spacing[c])
        throw InputError(where + "has a pixel spacing of " + std::to_string(l) +
                         " mm along image " + (c ? "y" : "x") + ", frame " +
                         std::to_string(sel.frames[0]) + "'s " + std::to_string(spacing[c]) +
                         " mm: the calibration changes within the sweep");
    }
    // Perpendicular axes, the shear split evenly between them (about their bisector), and a
    // right-handed third axis: a 2D image has no extent along it, so a calibration that mirrors
    // the image (negative determinant) still gives a rotation.
    const Vec3 b = normalized(x + y), d = normalized(x - y);
    const double h = std::sqrt(0.5);
    const Vec3 px = h * (b + d), py = h * (b - d), pz = cross(px, py);
    Pose pose;
    for (int r = 0; r < 3; ++r) {
      pose.m[r][0] = px[r];
      pose.m[r][1] = py[r];
      pose.m[r][2] = pz[r];
      pose.m[r][3] = m.m[r][3];
    }
    out.poses.push_back(pose);
    out.image_to_reference.push_back(m);
  }
  if (worst_shear_deg > kNoticeShearDeg)
    warn(sequence.path + ": the " + transform + " pixel axes are up to " +
         std::to_string(worst_shear_deg) +
         " degrees from perpendicular (the calibration's shear); registered as perpendicular");
  ImageGrid grid;
  grid.width = sequence.width;
  grid.height = sequence.height;
  grid.spacing_mm[0] = spacing[0];
  grid.spacing_mm[1] = spacing[1];
  grid.origin_mm[0] = grid.origin_mm[1] = 0;
  out.probe = ProbeGeometry::linear(grid);
  config.clip.require_pixels(sequence.width, sequence.height, "the configuration's clip rectangle",
                             sequence.path);
  out.mask = config.clip.mask(sequence.width, sequence.height);
  const size_t frame_pixels = size_t(sequence.width) * size_t(sequence.height);
  out.pixels.resize(out.frames.size() * frame_pixels);
  for (size_t n = 0; n < out.frames.size(); ++n)
    visit_pixel_type(sequence.pixel_type, [&](auto zero) {
      using T = decltype(zero);
      const T* p = static_cast<const T*>(sequence.frame_pixels(out.frames[n]));
      for (size_t i = 0; i < frame_pixels; ++i) out.pixels[n * frame_pixels + i] = float(p[i]);
    });
  return out;
}

}  // namespace sonoslice
