#pragma once
/// @file A PLUS sequence's tracked frames as sonoslice's poses: rigid probe → reference poses on
/// one pixel grid, what registration takes (and what slicing would make).
#include <string>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"

namespace sonoslice {

/// The frames of a sequence that `compound` would use (select_plus_frames with the
/// configuration's calibration, frames and skip interval), each PLUS ImageToReference (pixels →
/// reference mm, its column lengths the pixel spacing) split into a rigid pose and the grid:
/// ImageToReference ≈ pose · diag(sx, sy, 1, 1). A calibration's pixel axes are rarely exactly
/// perpendicular: up to 5° off they are made so (the shear split evenly between them, one
/// warning above 0.1°); image_to_reference keeps each frame's own matrix, so that a correction
/// found on the rigid poses can be applied to it.
struct PlusTrackedFrames {
  std::vector<int> frames;  ///< the sequence's frames used
  /// A linear probe on the frames' grid: pixel (i, j) at probe (i·sx, j·sy, 0) mm, every pixel
  /// inside; `mask` is the configuration's clip rectangle and fan (1: compared).
  ProbeGeometry probe;
  std::vector<uint8_t> mask;
  std::vector<Pose> poses;               ///< rigid, probe mm → reference mm, one per used frame
  std::vector<Mat4> image_to_reference;  ///< PLUS's own pixels → reference mm, per used frame
  std::vector<float> pixels;             ///< frames.size() × height × width, MF orientation
  std::string skipped;                   ///< why frames were left out ("" when none were)
};

/// Reads the tracked frames of `sequence` with `config` (its CoordinateDefinitions, its
/// ImageCoordinateFrame/ReferenceCoordinateFrame and skip interval, its clip). InputError naming
/// the sequence and the frame when a frame's ImageToReference is not an image plane with a pixel
/// spacing (axes more than 5° from perpendicular, a spacing 1 % off the first frame's), and as
/// select_plus_frames when no frame has a usable chain.
PlusTrackedFrames plus_tracked_frames(const PlusSequence& sequence,
                                      const PlusReconstructionConfig& config);

}  // namespace sonoslice
