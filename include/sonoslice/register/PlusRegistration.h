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
  /// The rigid correction C_i of each used frame, reference mm → reference mm:
  /// image_to_reference[i] = C_i · the frame's own ImageToReference.
  std::vector<Mat4> corrections;
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

/// `sequence` with the tracked transforms of the frames `registration` used corrected, so that
/// the configuration's chain from its image frame to its reference frame gives each one its
/// refined matrix: `compound` of it with the same configuration puts the frames where
/// registration did. In each such frame the first transform of the frame's own (a
/// `<A>To<B>Transform` field, typically ProbeToTracker) on that chain from the image is replaced:
/// with A the chain after it (to the reference), L' = A⁻¹ · C · A · L (walked forwards), so the
/// configuration's calibration and the other transforms stay as they are; the field's status,
/// the images and the other frames are kept. PLUS refuses a sequence that adds a transform
/// between frames a chain already joins, so the correction cannot be a field of its own.
/// InputError naming the sequence and the frame when the chain holds none of the frame's own
/// transforms or A cannot be inverted.
PlusSequence corrected_plus_sequence(const PlusSequence& sequence,
                                     const PlusReconstructionConfig& config,
                                     const PlusRegistration& registration);

/// plus_tracked_frames(sequence, config), then register_tracked_frames with the configuration's
/// calibration.
PlusRegistration register_plus_sequence(const Volume& volume, const PlusSequence& sequence,
                                        const PlusReconstructionConfig& config,
                                        const RegistrationSettings& settings);

}  // namespace sonoslice
