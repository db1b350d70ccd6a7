// A PLUS sequence's tracked frames registered to a volume, the result as PLUS's matrices
// (include/sonoslice/register/PlusRegistration.h).
#include "sonoslice/register/PlusRegistration.h"

#include <algorithm>
#include <map>
#include <string>

#include "../io/TextParse.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/plus/TransformRepository.h"

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
  for (size_t k = 0; k < count; ++k) {
    out.corrections.push_back(refined[k] * *invert(tracked.poses[k]));
    out.image_to_reference.push_back(out.corrections[k] * tracked.image_to_reference[k]);
  }
  // Frame i's refined matrix is C_i·M_i (M_i = ProbeToReference_i · ImageToProbe); in calibration
  // mode C_i·M_i = ProbeToReference_i · ImageToProbe' for every i, with ImageToProbe' =
  // ImageToProbe · M_0⁻¹ · C_0 · M_0.
  if (out.report.settings.mode == RegistrationMode::Calibration && image_to_probe && count > 0) {
    const Mat4& M0 = tracked.image_to_reference[0];
    out.image_to_probe = *image_to_probe * *invert(M0) * out.image_to_reference[0];
  }
  return out;
}

PlusSequence corrected_plus_sequence(const PlusSequence& sequence,
                                     const PlusReconstructionConfig& config,
                                     const PlusRegistration& registration) {
  PlusSequence out = sequence;
  for (size_t k = 0; k < registration.frames.size(); ++k) {
    const int frame = registration.frames[k];
    const std::string where = sequence.path + ": frame " + std::to_string(frame) + ": ";
    TransformRepository chain_of_frame = config.coordinate_definitions;
    chain_of_frame.set_frame(sequence, frame);
    const std::optional<std::vector<TransformRepository::Link>> links =
        chain_of_frame.chain(config.image_frame, config.reference_frame);
    std::map<std::string, std::string>& fields = out.frame_fields[size_t(frame)];
    const auto own = [&](const TransformRepository::Link& l) {
      return fields.count(l.from + "To" + l.to + "Transform") > 0;
    };
    if (!links)  // a used frame's chain is valid (plus_tracked_frames)
      throw InputError(where + "its chain passes through an invalid transform");
    const auto link = std::find_if(links->begin(), links->end(), own);
    if (link == links->end())
      throw InputError(where + "its " + config.image_frame + "To" + config.reference_frame +
                       " holds none of the frame's own transforms to correct");
    const std::string name = link->from + "To" + link->to;
    // A: the chain after the link, from the frame the link walks to, on to the reference.
    const std::string after_from = link->inverse ? link->from : link->to;
    Mat4 A = Mat4::identity(), A_inverse = Mat4::identity(), stored = Mat4::identity();
    bool usable = false;
    if (const std::optional<Mat4> a = chain_of_frame.get(after_from, config.reference_frame))
      if (const std::optional<Mat4> a_inverse = invert(*a)) {
        A = *a;
        A_inverse = *a_inverse;
        usable = text::parse_matrix16(fields.at(name + "Transform"), &stored);
      }
    if (!usable)
      throw InputError(where + "cannot correct its " + name + " (" + after_from + "To" +
                       config.reference_frame + " cannot be inverted)");
    const Mat4& C = registration.corrections[k];
    // Walked forwards: M = A·L·B, so A·L'·B = C·M gives L' = A⁻¹·C·A·L. Walked backwards
    // (M = A·S⁻¹·B): S' = S·A⁻¹·C⁻¹·A. C is rigid, so its inverse exists.
    const Mat4 corrected =
        link->inverse ? stored * A_inverse * *invert(C) * A : A_inverse * C * A * stored;
    fields[name + "Transform"] = text::format_matrix16(corrected);
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
