#pragma once
/// @file Which frames of a PLUS sequence go into a reconstruction, and their transforms, as PLUS
/// picks them.
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice {

/// The frames of a sequence that go into a reconstruction, as PLUS picks them.
struct PlusFrameSelection {
  std::vector<int> frames;         ///< indices into the sequence
  std::vector<Mat4> to_reference;  ///< their `from`→`to` transforms
  int bad_image = 0;               ///< frames whose image status is not OK
  int bad_transform = 0;           ///< frames whose chain passes through an invalid transform
  /// Frames left out because their own transforms cannot place them, with the reason: no chain
  /// (a transform missing from the frame), a link that cannot be inverted, or a `from`→`to`
  /// transform with a transform_problem() (an all-zero ProbeToTracker).
  std::vector<std::pair<int, std::string>> unusable;
  /// "2 with an invalid ImageToReference transform, 1 with an image status not OK" ("" if none).
  std::string skipped_reason(const std::string& from, const std::string& to) const;
};

/// Every `skip`-th frame (0, skip, 2·skip, ...) whose image status is OK and whose `from`→`to`
/// chain, through the frame's transforms and `calibration` (e.g. a configuration's
/// CoordinateDefinitions), has no invalid link and gives a usable transform; the others are
/// counted or listed (`unusable`, with the frame). InputError (prefixed with the sequence's path
/// and the first frame, followed by `hint`) when no considered frame has a chain at all.
PlusFrameSelection select_plus_frames(const PlusSequence& sequence,
                                      const TransformRepository& calibration,
                                      const std::string& from, const std::string& to, int skip = 1,
                                      const std::string& hint = "");

}  // namespace sonoslice
