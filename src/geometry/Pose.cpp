#include "sonoslice/geometry/Pose.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "../core/Text.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

WorldFrame parse_world_frame(const std::string& name) {
  const std::string upper = text::upper(name);
  if (upper == "LPS") return WorldFrame::LPS;
  if (upper == "RAS") return WorldFrame::RAS;
  throw InputError("world frame '" + name + "': expected LPS or RAS");
}

const char* to_string(WorldFrame frame) {
  switch (frame) {
    case WorldFrame::LPS:
      return "LPS";
    case WorldFrame::RAS:
      return "RAS";
  }
  return "?";
}

Pose pose_to_lps(const Pose& pose, WorldFrame frame) {
  if (frame == WorldFrame::LPS) return pose;
  Pose out = pose;  // diag(-1, -1, 1, 1) · pose
  for (int c = 0; c < 4; ++c) {
    out.m[0][c] = -pose.m[0][c];
    out.m[1][c] = -pose.m[1][c];
  }
  return out;
}

void validate_poses(const Pose* poses, size_t count, const std::string& source, size_t first_index,
                    bool warn_non_orthonormal) {
  double worst_deviation = 0.0;
  size_t worst_index = 0;
  for (size_t n = 0; n < count; ++n) {
    const Pose& p = poses[n];
    auto fail = [&](const std::string& why) {
      std::ostringstream s;
      s << source << ": pose " << (first_index + n) << ": " << why;
      throw InputError(s.str());
    };
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c)
        if (!std::isfinite(p.m[r][c])) fail("has a non-finite entry (NaN or inf)");
    for (int r = 0; r < 3; ++r)
      if (std::fabs(p.m[r][3]) > kMaxGeometryMm) {
        std::ostringstream t;
        t << "translation " << p.m[r][3] << " mm is beyond any scanner (at most 1e9 mm)";
        fail(t.str());
      }
    if (p.m[3][0] != 0 || p.m[3][1] != 0 || p.m[3][2] != 0 || p.m[3][3] != 1)
      fail("last row must be 0 0 0 1");
    const Vec3 x = p.column3(0), y = p.column3(1);
    const double nx = norm(x), ny = norm(y);
    if (nx < 0.5 || nx > 2.0) fail("lateral axis (column 0) has norm " + std::to_string(nx));
    if (ny < 0.5 || ny > 2.0) fail("axial axis (column 1) has norm " + std::to_string(ny));
    if (std::fabs(dot(x, y)) > 0.5 * nx * ny) fail("lateral and axial axes are nearly parallel");
    const double deviation = rigid_deviation(p);
    if (deviation > worst_deviation) {
      worst_deviation = deviation;
      worst_index = first_index + n;
    }
  }
  if (warn_non_orthonormal && worst_deviation > 1e-3) {
    std::ostringstream s;
    s << source << ": poses are not orthonormal (largest deviation " << worst_deviation
      << " at pose " << worst_index << "); they are used as given";
    warn(s.str());
  }
}

void require_rigid_pose(const Pose& pose, const std::string& what) {
  validate_poses(&pose, 1, what, 0, false);
  if (const double d = rigid_deviation(pose); d > 1e-3) {
    char deviation[32];
    std::snprintf(deviation, sizeof deviation, "%.3g", d);
    throw InputError(what + ": not a rigid frame (" +
                     (pose.linear().determinant() < 0 ? "a mirror image, " : "") + "deviation " +
                     deviation + " from orthonormal and right-handed)");
  }
}

}  // namespace sonoslice
