#pragma once
/// @file PLUS's transform repository (docs/conventions.md §7): named coordinate transforms with
/// PLUS's naming (`AToB` maps coordinates in A to B), from a configuration's
/// CoordinateDefinitions and a sequence frame's fields, chained and inverted on request.
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/plus/PlusSequence.h"

namespace sonoslice {

/// A set of named transforms (PLUS's transform repository): the configuration's
/// CoordinateDefinitions plus one frame's transforms. Any transform that is a chain of known
/// ones and their inverses can be asked for.
class TransformRepository {
 public:
  /// Adds or replaces `from`To`to` (e.g. set("Image", "Probe", m)); `valid` false records a
  /// transform whose status is not OK (a chain through it is invalid).
  void set(const std::string& from, const std::string& to, const Mat4& from_to_to,
           bool valid = true);
  /// Adds every transform of a sequence frame ("ProbeToTracker" → set("Probe", "Tracker", ...)),
  /// invalid ones marked as such.
  void set_frame(const PlusSequence& sequence, int frame);
  /// The transform from `from` to `to` through the shortest chain of known transforms;
  /// std::nullopt when a chain exists but passes through an invalid transform. Throws InputError
  /// naming both frames and the known transforms when no chain exists at all.
  std::optional<Mat4> get(const std::string& from, const std::string& to) const;
  /// One transform of a chain: the stored `from`To`to`, walked from `to` to `from` when
  /// `inverse`.
  struct Link {
    std::string from, to;
    bool inverse;
  };
  /// The transforms get(from, to) chains, in order from `from` (empty when from == to); the same
  /// errors as get, and std::nullopt where get gives it.
  std::optional<std::vector<Link>> chain(const std::string& from, const std::string& to) const;
  /// Splits "ImageToReference" into {"Image", "Reference"}; InputError when not of that form.
  static std::pair<std::string, std::string> split_name(const std::string& transform_name);

 private:
  struct Entry {
    Mat4 matrix;
    bool valid;
  };
  std::map<std::pair<std::string, std::string>, Entry> transforms_;
};

/// Why `m` cannot place image pixels (or probe points) in space, "" when it can: a non-finite
/// entry, a last row other than 0 0 0 1 (an all-zero matrix), or columns 0 and 1 (the image's x
/// and y axes) that are zero or parallel, which would put a frame's pixels on a line or a point.
std::string transform_problem(const Mat4& m);

}  // namespace sonoslice
