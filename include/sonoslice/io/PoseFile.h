#pragma once
/// @file Pose files (SPEC §2): .npy (N,4,4) or fan-slicer's (4,4N) strip, text .txt/.csv with
/// 16 or 12 row-major numbers per line, and .json {"poses": [[16 numbers], ...]}.
#include <string>
#include <vector>

#include "sonoslice/geometry/Pose.h"

namespace sonoslice {

/// Reads and validates the poses in `path`, converting them from `frame` to LPS. Errors name
/// the file and, where it applies, the line or pose index.
std::vector<Pose> read_poses(const std::string& path, WorldFrame frame = WorldFrame::LPS);

/// Writes poses as text, one row-major 4×4 per line (16 numbers), atomically.
void write_poses_text(const std::string& path, const std::vector<Pose>& poses);

/// Writes poses as a (N,4,4) float64 .npy, atomically.
void write_poses_npy(const std::string& path, const std::vector<Pose>& poses);

}  // namespace sonoslice
