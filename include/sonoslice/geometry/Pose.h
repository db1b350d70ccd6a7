#pragma once
/// @file Probe poses (docs/conventions.md §2): 4×4 matrices mapping probe mm to world mm. Column 0
/// is the lateral axis x̂, column 1 the axial (depth) axis ŷ, column 2 the elevation, column 3 the
/// probe origin in world.
#include <cstddef>
#include <string>
#include <vector>

#include "sonoslice/geometry/Math.h"

namespace sonoslice {

using Pose = Mat4;

/// The world frame poses are given in. Volumes live in ITK's LPS; RAS poses (3D Slicer,
/// nibabel) are converted by negating world x and y.
enum class WorldFrame { LPS, RAS };

WorldFrame parse_world_frame(const std::string& name);  ///< "LPS" / "RAS" (any case)
const char* to_string(WorldFrame frame);                ///< "LPS" / "RAS"

/// Converts a pose given in `frame` to LPS (identity for LPS).
Pose pose_to_lps(const Pose& pose, WorldFrame frame);

/// Checks poses as docs/conventions.md §2 says; throws InputError "<source>: pose <i>: <why>" for a
/// pose with non-finite entries, a wrong last row, or degenerate x̂/ŷ (norm outside [0.5, 2] or
/// |x̂·ŷ| > 0.5·|x̂||ŷ|). Emits one warning for the whole set when any pose deviates from
/// orthonormal by more than 1e-3 (unless `warn_non_orthonormal` is false: callers that check
/// chunks of an already-validated file). `first_index` numbers the poses in messages.
void validate_poses(const Pose* poses, size_t count, const std::string& source,
                    size_t first_index = 0, bool warn_non_orthonormal = true);

/// For a pose a probe is placed at live (a tracker's TRANSFORM, a viewer's drag), where nothing
/// says to use it as given: validate_poses, and InputError "<what>: not a rigid frame (...)" for a
/// mirror image, a scale or a shear (deviation from orthonormal and right-handed above 1e-3; a
/// float32 matrix deviates ~1e-7).
void require_rigid_pose(const Pose& pose, const std::string& what);

inline void validate_poses(const std::vector<Pose>& poses, const std::string& source) {
  validate_poses(poses.data(), poses.size(), source);
}

}  // namespace sonoslice
