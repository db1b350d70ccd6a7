// The general 4×4 inverse of Math.h (affine or not).
#include "sonoslice/geometry/Math.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace sonoslice {

double rigid_deviation(const Mat4& m) {
  const Vec3 x = m.column3(0), y = m.column3(1), z = m.column3(2);
  return std::max({std::fabs(norm(x) - 1), std::fabs(norm(y) - 1), std::fabs(dot(x, y)),
                   norm(z - cross(x, y))});
}

double scaled_rigid_deviation(const Mat4& m) {
  const Vec3 c[3] = {m.column3(0), m.column3(1), m.column3(2)};
  double worst = 0;
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b) {
      const double cosine = std::fabs(dot(c[a], c[b])) / (norm(c[a]) * norm(c[b]));
      worst = std::isfinite(cosine) ? std::max(worst, cosine) : 1.0;
    }
  return worst;
}

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

Mat3 rotation_about(const Vec3& k, double angle) {
  // R = I + sin θ·K + (1 − cos θ)·K², K the cross-product matrix of k.
  const double s = std::sin(angle), one_c = 1 - std::cos(angle);
  const double K[3][3] = {{0, -k[2], k[1]}, {k[2], 0, -k[0]}, {-k[1], k[0], 0}};
  Mat3 R;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double kk = 0;
      for (int m = 0; m < 3; ++m) kk += K[i][m] * K[m][j];
      R.m[i][j] = (i == j ? 1.0 : 0.0) + s * K[i][j] + one_c * kk;
    }
  return R;
}

Mat3 rotation_from_vector(const Vec3& w) {
  const double angle = norm(w);
  return angle > 0 ? rotation_about((1.0 / angle) * w, angle) : Mat3::identity();
}

Vec3 rotation_vector(const Mat3& R) {
  const double trace = R.m[0][0] + R.m[1][1] + R.m[2][2];
  const double angle = std::acos(std::max(-1.0, std::min(1.0, (trace - 1) / 2)));
  const double s = std::sin(angle);
  const double k = s > 1e-9 ? angle / (2 * s) : 0.5;  // angle/(2 sin angle) → 1/2 at 0
  return {k * (R.m[2][1] - R.m[1][2]), k * (R.m[0][2] - R.m[2][0]), k * (R.m[1][0] - R.m[0][1])};
}

Mat3 uniform_rotation(double u1, double u2, double u3) {
  const double t2 = 2 * kPi * u2, t3 = 2 * kPi * u3;
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  const double w = a * std::sin(t2), x = a * std::cos(t2), y = b * std::sin(t3),
               z = b * std::cos(t3);
  Mat3 r;
  r.m[0][0] = 1 - 2 * (y * y + z * z);
  r.m[0][1] = 2 * (x * y - z * w);
  r.m[0][2] = 2 * (x * z + y * w);
  r.m[1][0] = 2 * (x * y + z * w);
  r.m[1][1] = 1 - 2 * (x * x + z * z);
  r.m[1][2] = 2 * (y * z - x * w);
  r.m[2][0] = 2 * (x * z - y * w);
  r.m[2][1] = 2 * (y * z + x * w);
  r.m[2][2] = 1 - 2 * (x * x + y * y);
  return r;
}

}  // namespace sonoslice
