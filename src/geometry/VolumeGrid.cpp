#include "sonoslice/geometry/VolumeGrid.h"

#include <cmath>
#include <sstream>

#include "sonoslice/core/Error.h"

namespace sonoslice {

void VolumeGrid::validate(const std::string& what) const {
  std::ostringstream why;
  for (int a = 0; a < 3; ++a) {
    if (dims[a] <= 0)
      why << "size along axis " << a << " is " << dims[a] << " (must be > 0)";
    else if (!(std::isfinite(spacing_mm[a]) && spacing_mm[a] > 0))
      why << "spacing along axis " << a << " is " << spacing_mm[a] << " mm (must be > 0)";
    else if (!std::isfinite(origin_mm[a]))
      why << "origin is not finite";
    else if (spacing_mm[a] < kMinSpacingMm)
      why << "spacing along axis " << a << " is " << spacing_mm[a]
          << " mm: below any scanner's resolution (at least 1e-6 mm)";
    else if (spacing_mm[a] > kMaxGeometryMm || std::fabs(origin_mm[a]) > kMaxGeometryMm)
      why << (spacing_mm[a] > kMaxGeometryMm ? "spacing" : "origin") << " along axis " << a
          << " is " << (spacing_mm[a] > kMaxGeometryMm ? spacing_mm[a] : origin_mm[a])
          << " mm: beyond any scanner's extent (at most 1e9 mm)";
    if (!why.str().empty()) break;
  }
  if (why.str().empty()) {
    bool finite = true;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) finite = finite && std::isfinite(direction.m[r][c]);
    if (!finite)
      why << "direction matrix is not finite";
    else if (std::fabs(direction.determinant()) < 1e-6)
      why << "direction matrix is singular";
  }
  if (!why.str().empty()) throw InputError(what + ": " + why.str());
}

Vec3 VolumeGrid::index_to_world(const Vec3& c) const {
  const Vec3 scaled{c[0] * spacing_mm[0], c[1] * spacing_mm[1], c[2] * spacing_mm[2]};
  return origin_mm + direction * scaled;
}

Mat3 VolumeGrid::world_to_index_linear() const {
  const Vec3 inv_spacing{1.0 / spacing_mm[0], 1.0 / spacing_mm[1], 1.0 / spacing_mm[2]};
  return Mat3::diagonal(inv_spacing) * direction.inverse();
}

Vec3 VolumeGrid::world_to_index_offset() const {
  const Vec3 t = world_to_index_linear() * origin_mm;
  return {-t[0], -t[1], -t[2]};
}

Vec3 VolumeGrid::world_to_index(const Vec3& p) const {
  return world_to_index_linear() * (p - origin_mm);
}

IndexMap VolumeGrid::index_map(const Mat4& frame_to_world) const {
  const Mat3 w = world_to_index_linear();
  const Vec3 o = world_to_index_offset();
  IndexMap r;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double s = 0;
      for (int k = 0; k < 3; ++k) s += w.m[i][k] * frame_to_world.m[k][j];
      r.A[i][j] = s;
    }
    double t = 0;
    for (int k = 0; k < 3; ++k) t += w.m[i][k] * frame_to_world.m[k][3];
    r.a[i] = t + o[size_t(i)];
  }
  return r;
}

}  // namespace sonoslice
