#pragma once
/// @file Pose files (docs/conventions.md §2): .npy (N,4,4) or fan-slicer's (4,4N) strip, text
/// .txt/.csv with 16 or 12 row-major numbers per line, and .json {"poses": [[16 numbers], ...]}.
#include <string>
#include <vector>

#include "sonoslice/geometry/Pose.h"

namespace sonoslice {

/// Reads and validates the poses in `path`, converting them from `frame` to LPS. Errors name
/// the file and, where it applies, the line or pose index.
/// `warn_non_orthonormal` false: no warning for poses a little off orthonormal, for a caller
/// whose library call checks (and warns about) the same poses again.
std::vector<Pose> read_poses(const std::string& path, WorldFrame frame = WorldFrame::LPS,
                             bool warn_non_orthonormal = true);

/// The 4×4 matrices in a pose file, as written: no frame conversion, no pose checks (for
/// calibrations such as a pixel-to-probe matrix, whose axes are scaled).
std::vector<Mat4> read_matrices(const std::string& path);

/// One matrix: 16 (or 12) numbers separated by commas or spaces, or a pose file holding
/// exactly one. InputError naming `what` otherwise.
Mat4 read_matrix(const std::string& text_or_path, const std::string& what);

/// Writes poses as text, one row-major 4×4 per line (16 numbers), atomically.
void write_poses_text(const std::string& path, const std::vector<Pose>& poses);

/// Writes poses as a (N,4,4) float64 .npy, atomically.
void write_poses_npy(const std::string& path, const std::vector<Pose>& poses);

}  // namespace sonoslice
