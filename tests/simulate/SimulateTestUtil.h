#pragma once
// Helpers shared by the simulation tests (test_simulate.cpp, test_simulate_model.cpp): label
// phantoms, probes and poses in three orientations to the volume's axes, and the statistics the
// tests measure (correlations, speckle autocorrelation widths, FFTs). Public API only.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstdint>
#include <functional>
#include <numeric>
#include <ostream>
#include <string>
#include <vector>

#include "../common/TestUtil.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/simulate/Simulator.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {
namespace simtest {

constexpr double kVoxel = 0.5;  // mm
constexpr int kN = 100;         // today's phantoms: a 50 mm cube from the origin
constexpr double kDegree = kPi / 180;

/// A label as a function of a point (mm) in the phantom's own (probe-relative) frame.
using LabelFn = std::function<int(double, double, double)>;

/// Rotation by `degrees` about `axis` (any length).
inline Mat3 rotation_deg(const Vec3& axis, double degrees) {
  return rotation_about(normalized(axis), degrees * kDegree);
}

inline double angle_deg(const Vec3& a, const Vec3& b) {
  return std::acos(std::max(-1.0, std::min(1.0, dot(a, b) / (norm(a) * norm(b))))) / kDegree;
}

/// A probe orientation relative to the volume's axes: the phantom is voxelised rotated by R about
/// kCentre and every pose is rotated by the same R about kCentre, so the image sees the same
/// anatomy while the probe's axes (the columns of R, for an unrotated pose) cross the volume's
/// axes, and so the speckle lattice, obliquely.
struct Orientation {
  std::string name;
  Mat3 rotation;
};

/// The centre the phantoms and poses are rotated about: the middle of today's 50 mm cube.
inline const Vec3 kCentre = {25, 25, 25};

inline Orientation aligned() {
  return {"Aligned", Mat3::identity()};
}
/// Rz(20°)·Rx(30°)·Rz(40°): the elevation axis (probe z) is 30.0° from the volume's z, the
/// lateral axis (probe x) 38.3° from the volume's y and the beam (probe y) 33.8° from the
/// volume's x (each from its nearest volume axis); no probe axis lies in a volume plane.
inline Orientation oblique30() {
  return {"Oblique30",
          rotation_deg({0, 0, 1}, 20) * rotation_deg({1, 0, 0}, 30) * rotation_deg({0, 0, 1}, 40)};
}
/// Elevation (probe z) along the cube diagonal (1, 1, 1)/√3, lateral (1, −1, 0)/√2, beam
/// (1, 1, −2)/√6.
inline Orientation cube_diagonal() {
  return {"CubeDiagonal", Mat4::from_columns(normalized({1, -1, 0}), normalized({1, 1, -2}),
                                             normalized({1, 1, 1}), {0, 0, 0})
                              .linear()};
}
/// gtest's printer for the parameter: its name.
inline void PrintTo(const Orientation& o, std::ostream* os) {
  *os << o.name;
}
inline std::vector<Orientation> orientations() {
  return {aligned(), oblique30(), cube_diagonal()};
}
/// For INSTANTIATE_TEST_SUITE_P: the orientation's name.
struct OrientationName {
  std::string operator()(const ::testing::TestParamInfo<Orientation>& info) const {
    return info.param.name;
  }
};

/// The smallest angle (degrees) between direction d and a volume axis.
inline double angle_to_nearest_axis(const Vec3& d) {
  double best = 180;
  for (int k = 0; k < 3; ++k) {
    Vec3 e = {0, 0, 0};
    e[size_t(k)] = 1;
    best = std::min({best, angle_deg(d, e), 180 - angle_deg(d, e)});
  }
  return best;
}

inline bool is_identity(const Mat3& r) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (r.m[i][j] != (i == j ? 1.0 : 0.0)) return false;
  return true;
}

/// A uint8 label volume of dims voxels of `spacing` mm from `origin` (identity direction):
/// voxel (i, j, k) holds label(origin + spacing·(i, j, k)).
inline Volume label_volume(std::array<int64_t, 3> dims, double spacing, const Vec3& origin,
                           const LabelFn& label) {
  VolumeGrid g;
  g.dims = dims;
  g.spacing_mm = {spacing, spacing, spacing};
  g.origin_mm = origin;
  Volume v = Volume::allocate(PixelType::UInt8, g);
  uint8_t* p = v.data_as<uint8_t>();
  for (int64_t z = 0; z < dims[2]; ++z)
    for (int64_t y = 0; y < dims[1]; ++y)
      for (int64_t x = 0; x < dims[0]; ++x)
        p[(z * dims[1] + y) * dims[0] + x] =
            uint8_t(label(origin[0] + double(x) * spacing, origin[1] + double(y) * spacing,
                          origin[2] + double(z) * spacing));
  return v;
}

/// A homogeneous volume of label 1 (n³ voxels of `spacing` mm from `origin`). The speckle
/// lattice is in mm, so a homogeneous phantom may use coarse voxels.
inline Volume uniform_volume(int n, double spacing, const Vec3& origin = {0, 0, 0}) {
  VolumeGrid g;
  g.dims = {n, n, n};
  g.spacing_mm = {spacing, spacing, spacing};
  g.origin_mm = origin;
  Volume v = Volume::allocate(PixelType::UInt8, g);
  std::fill(v.data_as<uint8_t>(), v.data_as<uint8_t>() + g.voxel_count(), uint8_t(1));
  return v;
}

/// Today's phantom: kN³ voxels at 0.5 mm from the origin (a 50 mm cube), label(x, y, z) in mm.
inline Volume phantom(const LabelFn& label) {
  return label_volume({kN, kN, kN}, kVoxel, {0, 0, 0}, label);
}

/// Half the side (mm) of the rotated phantoms' cube about kCentre: every image of the
/// validation tests (pixels within 31.3 mm of kCentre) plus the slice thickness and the
/// impedance gradient's reach stays inside in any orientation.
constexpr double kRotatedHalfSide = 35;

/// The phantom `label` seen in orientation o: label(world) = label_fn(Rᵀ(world − c) + c), c =
/// kCentre. Aligned: exactly today's phantom(); rotated: a 140³ cube at 0.5 mm about kCentre.
inline Volume oriented_phantom(const LabelFn& label, const Orientation& o) {
  if (is_identity(o.rotation)) return phantom(label);
  const Mat3& r = o.rotation;
  const int n = int(std::lround(2 * kRotatedHalfSide / kVoxel));
  const double first = -kRotatedHalfSide + kVoxel / 2;
  const Vec3 origin = {kCentre[0] + first, kCentre[1] + first, kCentre[2] + first};
  return label_volume({n, n, n}, kVoxel, origin, [&](double x, double y, double z) {
    const Vec3 d = {x - kCentre[0], y - kCentre[1], z - kCentre[2]};
    // Rᵀ·d
    const Vec3 p = {r.m[0][0] * d[0] + r.m[1][0] * d[1] + r.m[2][0] * d[2],
                    r.m[0][1] * d[0] + r.m[1][1] * d[1] + r.m[2][1] * d[2],
                    r.m[0][2] * d[0] + r.m[1][2] * d[1] + r.m[2][2] * d[2]};
    return label(p[0] + kCentre[0], p[1] + kCentre[1], p[2] + kCentre[2]);
  });
}

/// `pose` rotated by R about c: T(c)·R·T(−c)·pose.
inline Pose rotated_about(const Pose& pose, const Mat3& r, const Vec3& c = kCentre) {
  const Vec3 t = c - r * c;
  return Mat4::from_rotation_translation(r, t) * pose;
}

/// `pose` rotated by R about its own axis through its origin: pose·R (R in probe coordinates).
inline Pose turned(const Pose& pose, const Mat3& r) {
  return pose * Mat4::from_rotation_translation(r, {0, 0, 0});
}

/// `pose` turned by r about the point p of its own frame (probe mm).
inline Pose turned_about(const Pose& pose, const Mat3& r, const Vec3& p) {
  return pose * Mat4::from_rotation_translation(r, p - r * p);
}

/// `pose` moved by d (mm) along its own axes (probe coordinates).
inline Pose moved(const Pose& pose, const Vec3& d) {
  Pose p = pose;
  const Vec3 w = pose.linear() * d;
  for (int i = 0; i < 3; ++i) p.m[i][3] += w[size_t(i)];
  return p;
}

/// `pose` moved by d (mm) in the world (the volume's axes).
inline Pose shifted(const Pose& pose, const Vec3& d) {
  Pose p = pose;
  for (int i = 0; i < 3; ++i) p.m[i][3] += d[size_t(i)];
  return p;
}

/// The probe face centred at (25, y0, z) mm, beams along world +y, lateral along world x.
inline Pose pose_at(double z, double y0 = 2.0) {
  Pose p = Pose::identity();
  p.m[0][3] = 25;
  p.m[1][3] = y0;
  p.m[2][3] = z;
  return p;
}

/// A linear probe of width × height pixels of `spacing` mm, face at y = 0, centred laterally.
inline ProbeGeometry linear_probe(int width = 100, int height = 130, double spacing = 0.3) {
  return test::linear_probe(width, height, spacing);
}

/// A pose of rotation r whose image (of `probe`) is centred on the point `centre`.
inline Pose centred_pose(const Mat3& r, const Vec3& centre, const ProbeGeometry& probe) {
  const double mid_y =
      probe.image.origin_mm[1] + 0.5 * (probe.image.height - 1) * probe.image.spacing_mm[1];
  const double mid_x =
      probe.image.origin_mm[0] + 0.5 * (probe.image.width - 1) * probe.image.spacing_mm[0];
  return Mat4::from_rotation_translation(r, centre - r * Vec3{mid_x, mid_y, 0});
}

/// Whether the image of `probe` at `pose`, grown by `margin` mm along each probe axis (the
/// slice thickness, the gradient's reach), lies inside the volume's voxel-centre box.
inline bool image_inside(const Volume& volume, const ProbeGeometry& probe, const Pose& pose,
                         double margin) {
  const ImageGrid& g = probe.image;
  const double x0 = g.origin_mm[0] - margin, x1 = g.origin_mm[0] + (g.width - 1) * g.spacing_mm[0];
  const double y0 = std::min(0.0, g.origin_mm[1]) - margin,
               y1 = g.origin_mm[1] + (g.height - 1) * g.spacing_mm[1];
  for (double x : {x0, x1 + margin})
    for (double y : {y0, y1 + margin})
      for (double z : {-margin, margin}) {
        const Vec3 c = volume.grid().world_to_index(pose.transform_point({x, y, z}));
        for (int k = 0; k < 3; ++k)
          if (!(c[size_t(k)] >= 0 && c[size_t(k)] <= double(volume.grid().dims[size_t(k)] - 1)))
            return false;
      }
  return true;
}

inline Tissue tissue(int label, double z, double alpha, double scatter) {
  Tissue t;
  t.name = "t" + std::to_string(label);
  t.label = label;
  t.impedance_mrayl = z;
  t.attenuation_db_cm_mhz = alpha;
  t.scatter_mean = scatter;
  return t;
}

inline std::vector<float> envelope(const Simulator& s, const std::vector<Pose>& poses) {
  std::vector<float> out(poses.size() * size_t(s.width()) * size_t(s.height()));
  s.simulate(poses.data(), poses.size(), out.data());
  return out;
}

inline std::vector<uint8_t> bmode(const Simulator& s, const std::vector<Pose>& poses) {
  std::vector<uint8_t> out(poses.size() * s.image_bytes());
  s.simulate(poses.data(), poses.size(), out.data());
  return out;
}

inline SimulationSettings envelope_settings(double f = 5.0) {
  SimulationSettings st;
  st.frequency_mhz = f;
  st.output = SimulationOutput::Envelope;
  st.tgc_auto = false;
  st.seed = 3;
  return st;
}

/// Rows [r0, r1) and columns [c0, c1) of image k (w × h) of `img`, as doubles.
inline std::vector<double> region(const std::vector<float>& img, int w, int h, int k, int r0,
                                  int r1, int c0, int c1) {
  std::vector<double> v;
  v.reserve(size_t(std::max(0, (r1 - r0) * (c1 - c0))));
  for (int r = r0; r < r1; ++r)
    for (int c = c0; c < c1; ++c) v.push_back(img[(size_t(k) * size_t(h) + size_t(r)) * w + c]);
  return v;
}
inline std::vector<double> squared(std::vector<double> v) {
  for (double& x : v) x *= x;
  return v;
}
inline double mean(const std::vector<double>& v) {
  return std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
}
inline double stdev(const std::vector<double>& v) {
  const double m = mean(v);
  double s = 0;
  for (double x : v) s += (x - m) * (x - m);
  return std::sqrt(s / double(v.size()));
}
/// Pearson correlation of two samples of equal size.
inline double correlation(const std::vector<double>& a, const std::vector<double>& b) {
  const double ma = mean(a), mb = mean(b);
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

/// Full width at half maximum (in pixels, linear between lags) of the autocorrelation of the
/// image's fluctuation along rows (dx = 1) or columns (dy = 1) of a w × h image.
inline double acf_fwhm(const std::vector<float>& img, int w, int h, int dx, int dy) {
  double mean = 0;
  for (float v : img) mean += v;
  mean /= double(img.size());
  std::vector<double> acf;
  for (int lag = 0; lag < 40; ++lag) {
    double s = 0;
    int n = 0;
    for (int y = 0; y + lag * dy < h; ++y)
      for (int x = 0; x + lag * dx < w; ++x) {
        s +=
            (img[size_t(y) * w + x] - mean) * (img[size_t(y + lag * dy) * w + x + lag * dx] - mean);
        ++n;
      }
    acf.push_back(s / n);
  }
  for (int lag = 1; lag < 40; ++lag)
    if (acf[size_t(lag)] < 0.5 * acf[0]) {
      const double a = acf[size_t(lag - 1)] / acf[0], b = acf[size_t(lag)] / acf[0];
      return 2 * (lag - 1 + (a - 0.5) / (a - b));
    }
  return 80;
}

/// In-place radix-2 FFT of v (size a power of two); inverse: the conjugate transform, unscaled.
inline void fft(std::vector<std::complex<double>>& v, bool inverse = false) {
  const size_t n = v.size();
  for (size_t i = 1, j = 0; i < n; ++i) {
    size_t bit = n >> 1;
    for (; j & bit; bit >>= 1) j ^= bit;
    j ^= bit;
    if (i < j) std::swap(v[i], v[j]);
  }
  for (size_t len = 2; len <= n; len <<= 1) {
    const double a = 2 * kPi / double(len) * (inverse ? 1 : -1);
    const std::complex<double> wl(std::cos(a), std::sin(a));
    for (size_t i = 0; i < n; i += len) {
      std::complex<double> w(1);
      for (size_t k = 0; k < len / 2; ++k) {
        const std::complex<double> u = v[i + k], t = w * v[i + k + len / 2];
        v[i + k] = u + t;
        v[i + k + len / 2] = u - t;
        w *= wl;
      }
    }
  }
}

/// 2-D FFT of an nx × ny row-major array (both powers of two), in place.
inline void fft2(std::vector<std::complex<double>>& a, int nx, int ny, bool inverse = false) {
  std::vector<std::complex<double>> line(size_t(std::max(nx, ny)));
  line.resize(size_t(nx));
  for (int y = 0; y < ny; ++y) {
    std::copy(a.begin() + size_t(y) * nx, a.begin() + size_t(y + 1) * nx, line.begin());
    fft(line, inverse);
    std::copy(line.begin(), line.end(), a.begin() + size_t(y) * nx);
  }
  line.resize(size_t(ny));
  for (int x = 0; x < nx; ++x) {
    for (int y = 0; y < ny; ++y) line[size_t(y)] = a[size_t(y) * nx + x];
    fft(line, inverse);
    for (int y = 0; y < ny; ++y) a[size_t(y) * nx + x] = line[size_t(y)];
  }
}

}  // namespace simtest
}  // namespace sonoslice
