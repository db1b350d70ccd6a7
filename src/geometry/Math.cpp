// The general 4×4 inverse of Math.h (affine or not).
#include "sonoslice/geometry/Math.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace sonoslice {

std::optional<Mat4> invert(const Mat4& m) {
  double a[4][8];
  double scale = 0;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(m.m[r][c])) return std::nullopt;
      scale = std::max(scale, std::fabs(m.m[r][c]));
    }
  if (scale == 0) return std::nullopt;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 8; ++c) a[r][c] = c < 4 ? m.m[r][c] : (c - 4 == r ? 1.0 : 0.0);
  for (int col = 0; col < 4; ++col) {
    int pivot = col;
    for (int r = col + 1; r < 4; ++r)
      if (std::fabs(a[r][col]) > std::fabs(a[pivot][col])) pivot = r;
    if (std::fabs(a[pivot][col]) <= 1e-12 * scale) return std::nullopt;
    if (pivot != col)
      for (int c = 0; c < 8; ++c) std::swap(a[pivot][c], a[col][c]);
    const double inv = 1.0 / a[col][col];
    for (int c = 0; c < 8; ++c) a[col][c] *= inv;
    for (int r = 0; r < 4; ++r) {
      if (r == col || a[r][col] == 0) continue;
      const double f = a[r][col];
      for (int c = 0; c < 8; ++c) a[r][c] -= f * a[col][c];
    }
  }
  Mat4 out;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out.m[r][c] = a[r][c + 4];
  return out;
}

}  // namespace sonoslice
