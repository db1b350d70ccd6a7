#pragma once
/// @file Registration of a PLUS sequence's tracked frames (docs/registration.md §4): the frames
/// and poses `compound` would use (plus_tracked_frames), registered to a volume, and the result
/// as PLUS's own matrices: each frame's refined ImageToReference and, in calibration mode, the
/// corrected ImageToProbe. `sonoslice register --sequence` and Python's `register_sequence` are
/// thin callers of these.
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TrackedFrames.h"
#include "sonoslice/register/Registration.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// What registering a sequence found.
struct PlusRegistration {
  std::vector<int> frames;               ///< the sequence's frames used (plus_tracked_frames)
  std::vector<Mat4> image_to_reference;  ///< refined, one per used frame: PLUS's pixels → mm
  /// Calibration mode, when the configuration has an Image → Probe calibration: that calibration
  /// corrected, so that ProbeToReference_i · image_to_probe is every frame's refined matrix.
  std::optional<Mat4> image_to_probe;
  std::string skipped;  ///< why frames were left out ("" when none were)
  RegistrationReport report;
};

/// The configuration's Image → Probe calibration (its image frame to "Probe"), when it has one.
std::optional<Mat4> plus_image_to_probe(const PlusReconstructionConfig& config);

/// Registers `tracked` to `volume` with `settings` (the frames' rigid poses, the configuration's
/// clip as the mask). Frame i's refined ImageToReference is its own matrix moved by the
/// correction found, C_i · M_i with C_i = refined_i · initial_i⁻¹ (so a calibration's scale and
/// shear stay). `image_to_probe`: the calibration that calibration mode corrects.
PlusRegistration register_tracked_frames(const Volume& volume, const PlusTrackedFrames& tracked,
                                         const RegistrationSettings& settings,
                                         const std::optional<Mat4>& image_to_probe = std::nullopt);

/// plus_tracked_frames(sequence, config), then register_tracked_frames with the configuration's
/// calibration.
PlusRegistration register_plus_sequence(const Volume& volume, const PlusSequence& sequence,
                                        const PlusReconstructionConfig& config,
                                        const RegistrationSettings& settings);

}  // namespace sonoslice
