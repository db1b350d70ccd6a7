#pragma once
/// @file Small fixed-size double-precision vectors and matrices for host-side geometry.
/// Kernels never see these: the dispatch layer reduces them to float structs (see slice/).
#include <array>
#include <cmath>
#include <optional>

namespace sonoslice {

constexpr double kPi = 3.14159265358979323846;

/// Lengths beyond this (1000 km, in mm) are no scanner's or probe's: volumes, probes and files
/// with spacing, origin or sizes beyond it are refused as absurd (a header field near FLT_MAX
/// once made ITK's orientation SVD loop without end; one beyond it makes ITK abort).
constexpr double kMaxGeometryMm = 1e9;
/// And a voxel or pixel below a nanometre is a typo (a grid of it overflows any size).
constexpr double kMinSpacingMm = 1e-6;

using Vec3 = std::array<double, 3>;

/// 3×3 matrix, row-major: m[r][c].
struct Mat3 {
  double m[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};

  static Mat3 identity() { return Mat3{}; }
  static Mat3 diagonal(const Vec3& d) {
    Mat3 r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r.m[i][j] = i == j ? d[i] : 0.0;
    return r;
  }
  Vec3 column(int c) const { return {m[0][c], m[1][c], m[2][c]}; }
  std::array<double, 9> row_major() const {
    return {m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2]};
  }
  Vec3 operator*(const Vec3& v) const {
    return {m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
            m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2]};
  }
  Mat3 operator*(const Mat3& b) const {
    Mat3 r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        r.m[i][j] = m[i][0] * b.m[0][j] + m[i][1] * b.m[1][j] + m[i][2] * b.m[2][j];
    return r;
  }
  double determinant() const {
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
           m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  }
  /// Inverse by cofactors; the caller checks the determinant first.
  Mat3 inverse() const {
    const double inv_det = 1.0 / determinant();
    Mat3 r;
    r.m[0][0] = (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv_det;
    r.m[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv_det;
    r.m[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv_det;
    r.m[1][0] = (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv_det;
    r.m[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv_det;
    r.m[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv_det;
    r.m[2][0] = (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv_det;
    r.m[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv_det;
    r.m[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv_det;
    return r;
  }
};

/// 4×4 homogeneous matrix, row-major: m[r][c]. A probe pose maps probe mm to world mm.
struct Mat4 {
  double m[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};

  static Mat4 identity() { return Mat4{}; }
  /// From 16 numbers in row-major order.
  static Mat4 from_row_major(const double* v) {
    Mat4 r;
    for (int i = 0; i < 16; ++i) r.m[i / 4][i % 4] = v[i];
    return r;
  }
  static Mat4 from_rotation_translation(const Mat3& rotation, const Vec3& translation) {
    Mat4 r;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) r.m[i][j] = rotation.m[i][j];
      r.m[i][3] = translation[i];
    }
    return r;
  }
  /// Columns x, y, z and the translation: a frame whose point (a, b, c) is at
  /// origin + a·x + b·y + c·z (axes need not be unit: pixel-to-mm matrices scale them).
  static Mat4 from_columns(const Vec3& x, const Vec3& y, const Vec3& z, const Vec3& origin) {
    Mat4 r;
    for (int i = 0; i < 3; ++i) {
      r.m[i][0] = x[i];
      r.m[i][1] = y[i];
      r.m[i][2] = z[i];
      r.m[i][3] = origin[i];
    }
    return r;
  }
  Vec3 column3(int c) const { return {m[0][c], m[1][c], m[2][c]}; }
  Mat3 linear() const {
    Mat3 r;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r.m[i][j] = m[i][j];
    return r;
  }
  /// Apply to the point p (w = 1).
  Vec3 transform_point(const Vec3& p) const {
    return {m[0][0] * p[0] + m[0][1] * p[1] + m[0][2] * p[2] + m[0][3],
            m[1][0] * p[0] + m[1][1] * p[1] + m[1][2] * p[2] + m[1][3],
            m[2][0] * p[0] + m[2][1] * p[1] + m[2][2] * p[2] + m[2][3]};
  }
  Mat4 operator*(const Mat4& b) const {
    Mat4 r;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        double s = 0;
        for (int k = 0; k < 4; ++k) s += m[i][k] * b.m[k][j];
        r.m[i][j] = s;
      }
    return r;
  }
};

/// Rotation by `angle` (rad) about the unit vector `axis` (Rodrigues).
Mat3 rotation_about(const Vec3& axis, double angle);
/// The rotation of rotation vector `w` (unit axis × angle, rad); the identity for w = 0.
Mat3 rotation_from_vector(const Vec3& w);
/// The rotation vector of R (its inverse for angles below π).
Vec3 rotation_vector(const Mat3& R);
/// A uniformly distributed rotation from three numbers uniform in [0, 1) (Shoemake's unit
/// quaternion): the phantom's random poses and the region sampler's.
Mat3 uniform_rotation(double u1, double u2, double u3);

/// The inverse of a 4×4 matrix (Gauss-Jordan elimination with partial pivoting); std::nullopt
/// when it is singular (a pivot below 1e-12 of the matrix's largest entry) or not finite.
std::optional<Mat4> invert(const Mat4& m);

/// How far m's 3×3 part is from a rotation: the largest of |‖x‖ − 1|, |‖y‖ − 1|, |x·y| and
/// ‖z − x × y‖ over its columns x, y, z (0 for a rigid transform).
double rigid_deviation(const Mat4& m);
/// How far m's 3×3 part is from a rotation whose axes may be scaled and mirrored (an image's
/// pixel → mm map: spacing per column, a flip): the largest |cosine| between two of its columns
/// (0 when they are orthogonal; 1 when one is zero or not finite).
double scaled_rigid_deviation(const Mat4& m);

inline Vec3 operator+(const Vec3& a, const Vec3& b) {
  return {a[0] + b[0], a[1] + b[1], a[2] + b[2]};
}
inline Vec3 operator-(const Vec3& a, const Vec3& b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
inline Vec3 operator*(double s, const Vec3& a) {
  return {s * a[0], s * a[1], s * a[2]};
}
inline double dot(const Vec3& a, const Vec3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline double norm(const Vec3& a) {
  return std::sqrt(dot(a, a));
}
inline Vec3 normalized(const Vec3& a) {
  return (1.0 / norm(a)) * a;
}

}  // namespace sonoslice
