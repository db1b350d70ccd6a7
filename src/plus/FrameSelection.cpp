// The selection of a sequence's frames for a reconstruction, as PLUS picks them.
#include "sonoslice/plus/FrameSelection.h"

#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "sonoslice/core/Error.h"

namespace sonoslice {

std::string PlusFrameSelection::skipped_reason(const std::string& from,
                                               const std::string& to) const {
  std::string why;
  if (bad_transform)
    why += std::to_string(bad_transform) + " with an invalid " + from + "To" + to + " transform";
  if (!unusable.empty())
    why += (why.empty() ? "" : ", ") + std::to_string(unusable.size()) +
           " whose transforms cannot place them (frame " + std::to_string(unusable[0].first) +
           ": " + unusable[0].second + (unusable.size() > 1 ? "; ..." : "") + ")";
  if (bad_image)
    why += (why.empty() ? "" : ", ") + std::to_string(bad_image) + " with an image status not OK";
  return why;
}

PlusFrameSelection select_plus_frames(const PlusSequence& sequence,
                                      const TransformRepository& calibration,
                                      const std::string& from, const std::string& to, int skip,
                                      const std::string& hint) {
  if (skip < 1) throw InputError("skip interval " + std::to_string(skip) + ": must be >= 1");
  PlusFrameSelection sel;
  // A frame whose own transforms cannot place it (one missing, zero or non-invertible) is left
  // out and named; a tracker writes such frames when it loses a tool. When no frame has a chain
  // at all, the calibration is what is missing: that is an error.
  int considered = 0, without_chain = 0;
  struct {
    double deviation = 0;
    int frame = 0;
    std::string name;
    bool from_image = false;
  } worst;
  std::string first_without_chain;
  for (int k = 0; k < sequence.frame_count; k += skip) {
    if (!sequence.image_ok(k)) {
      ++sel.bad_image;
      continue;
    }
    ++considered;
    TransformRepository repo = calibration;
    repo.set_frame(sequence, k);
    std::optional<Mat4> m;
    try {
      m = repo.get(from, to);
    } catch (const InputError& e) {
      if (without_chain++ == 0)
        first_without_chain = sequence.path + ": frame " + std::to_string(k) + ": " + e.what();
      sel.unusable.emplace_back(k, e.what());
      continue;
    }
    if (!m) {
      ++sel.bad_transform;
      continue;
    }
    const std::string problem = transform_problem(*m);
    if (!problem.empty()) {
      sel.unusable.emplace_back(k, "its " + from + "To" + to + " " + problem);
      continue;
    }
    sel.frames.push_back(k);
    sel.to_reference.push_back(*m);
    // A tracker's transforms are rigid; one that scales or shears (a corrupt or hand-edited
    // file) stretches the volume. PLUS uses it as given, and so does this, but says so. A
    // transform from the image's own frame (ImageToReference, as PlusServer and `live compound
    // --record` write it) maps pixels, so its axes carry the spacing and may be mirrored: only a
    // shear is wrong there.
    for (const std::string& name : sequence.transform_names(k)) {
      const std::optional<Mat4> t = sequence.transform(k, name);
      const bool from_image = name.rfind("ImageTo", 0) == 0;
      const double deviation = !t           ? 0.0
                               : from_image ? scaled_rigid_deviation(*t)
                                            : rigid_deviation(*t);
      if (deviation > worst.deviation) worst = {deviation, k, name, from_image};
    }
  }
  if (considered > 0 && without_chain == considered) throw InputError(first_without_chain + hint);
  if (worst.deviation > 1e-3) {
    std::ostringstream s;
    s << sequence.path << ": frame " << worst.frame << "'s " << worst.name
      << (worst.from_image ? "Transform shears (axes " : "Transform is not rigid (")
      << worst.deviation << (worst.from_image ? " from orthogonal" : " from a rotation")
      << ", the largest of the frames'); tracking transforms are used as given";
    warn(s.str());
  }
  return sel;
}

}  // namespace sonoslice
