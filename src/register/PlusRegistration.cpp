// A PLUS sequence's tracked frames registered to a volume, the result as PLUS's matrices
// (include/sonoslice/register/PlusRegistration.h).
#include "sonoslice/register/PlusRegistration.h"

#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {

std::optional<Mat4> plus_image_to_probe(const PlusReconstructionConfig& config) {
  try {
    return config.coordinate_definitions.get(config.image_frame, "Probe");
  } catch (const InputError&) {  // no Image → Probe calibration in the configuration
    return std::nullopt;
  }
}

PlusRegistration register_tracked_frames(const Volume& volume, const PlusTrackedFrames& tracked,
                                         const RegistrationSettings& settings,
                                         const std::optional<Mat4>& image_to_probe) {
  const size_t count = tracked.frames.size();
  const FrameRegistration reg(volume, tracked.probe, tracked.pixels.data(), count,
                              tracked.mask.empty() ? nullptr : tracked.mask.data());
  PlusRegistration out;
  const std::vector<Pose> refined = reg.run(tracked.poses, settings, &out.report);
  out.frames = tracked.frames;
  out.skipped = tracked.skipped;
  for (size_t k = 0; k < count; ++k)
    out.image_to_reference.push_back(refined[k] * *invert(tracked.poses[k]) *
                                     tracked.image_to_reference[k]);
  // Frame i's refined matrix is C_i·M_i (M_i = ProbeToReference_i · ImageToProbe); in calibration
  // mode C_i·M_i = ProbeToReference_i · ImageToProbe' for every i, with ImageToProbe' =
  // ImageToProbe · M_0⁻¹ · C_0 · M_0.
  if (out.report.settings.mode == RegistrationMode::Calibration && image_to_probe && count > 0) {
    const Mat4& M0 = tracked.image_to_reference[0];
    out.image_to_probe = *image_to_probe * *invert(M0) * out.image_to_reference[0];
  }
  return out;
}

PlusRegistration register_plus_sequence(const Volume& volume, const PlusSequence& sequence,
                                        const PlusReconstructionConfig& config,
                                        const RegistrationSettings& settings) {
  return register_tracked_frames(volume, plus_tracked_frames(sequence, config), settings,
                                 plus_image_to_probe(config));
}

}  // namespace sonoslice
