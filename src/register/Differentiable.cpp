// Differentiable slicing: float64 linear slices and their exact backward pass
// (include/sonoslice/register/Differentiable.h).
#include "sonoslice/register/Differentiable.h"

#include <algorithm>
#include <vector>

#include "../backend/ParallelFor.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace {

/// One pixel's trilinear sample under docs/conventions.md §5 `linear`: its value, the eight
/// corners' offsets and weights, and the derivative along each index axis (0 along an axis
/// whose neighbours are clamped together).
struct Sample {
  double value = 0, dc[3] = {0, 0, 0};
  int64_t corner[8];
  double weight[8];
};

template <typename T>
bool sample(const T* v, const int64_t n[3], const double c[3], Sample& s) {
  for (int k = 0; k < 3; ++k)
    if (!(c[k] >= -0.5 && c[k] < double(n[k]) - 0.5)) return false;
  int64_t lo[3], hi[3];
  double f[3];
  for (int k = 0; k < 3; ++k) {
    const int64_t i = int64_t(c[k] + 1.0) - 1;  // floor: c ≥ −0.5
    f[k] = c[k] - double(i);
    lo[k] = i < 0 ? 0 : i;
    hi[k] = i + 1 < n[k] ? i + 1 : n[k] - 1;
  }
  const int64_t sy = n[0], sz = n[0] * n[1];
  for (int q = 0; q < 8; ++q)
    s.corner[q] =
        (q & 4 ? hi[2] : lo[2]) * sz + (q & 2 ? hi[1] : lo[1]) * sy + (q & 1 ? hi[0] : lo[0]);
  const double v000 = double(v[s.corner[0]]), v100 = double(v[s.corner[1]]),
               v010 = double(v[s.corner[2]]), v110 = double(v[s.corner[3]]),
               v001 = double(v[s.corner[4]]), v101 = double(v[s.corner[5]]),
               v011 = double(v[s.corner[6]]), v111 = double(v[s.corner[7]]);
  const double tx = f[0], ty = f[1], tz = f[2];
  // Value and exact derivatives along each index axis (clamped neighbours coincide: 0 there).
  const double a00 = v000 + tx * (v100 - v000), a10 = v010 + tx * (v110 - v010);
  const double a01 = v001 + tx * (v101 - v001), a11 = v011 + tx * (v111 - v011);
  const double b0 = a00 + ty * (a10 - a00), b1 = a01 + ty * (a11 - a01);
  s.value = b0 + tz * (b1 - b0);
  const double dx00 = v100 - v000, dx10 = v110 - v010, dx01 = v101 - v001, dx11 = v111 - v011;
  const double dx0 = dx00 + ty * (dx10 - dx00), dx1 = dx01 + ty * (dx11 - dx01);
  s.dc[0] = dx0 + tz * (dx1 - dx0);
  s.dc[1] = (a10 - a00) + tz * ((a11 - a01) - (a10 - a00));
  s.dc[2] = b1 - b0;
  for (int q = 0; q < 8; ++q)
    s.weight[q] = (q & 1 ? tx : 1 - tx) * (q & 2 ? ty : 1 - ty) * (q & 4 ? tz : 1 - tz);
  return true;
}

struct Geometry {
  Mat3 L;
  Vec3 o;
  int64_t n[3];
  std::vector<uint8_t> mask;
  int width, height;
  double x0, y0, sx, sy;
};

Geometry geometry(const Volume& volume, const ProbeGeometry& probe) {
  probe.validate("probe");
  Geometry g;
  const VolumeGrid& grid = volume.grid();
  g.L = grid.world_to_index_linear();
  g.o = grid.world_to_index_offset();
  for (int k = 0; k < 3; ++k) g.n[k] = grid.dims[k];
  g.mask = probe.mask();
  g.width = probe.image.width;
  g.height = probe.image.height;
  g.x0 = probe.image.origin_mm[0];
  g.y0 = probe.image.origin_mm[1];
  g.sx = probe.image.spacing_mm[0];
  g.sy = probe.image.spacing_mm[1];
  return g;
}

/// Pixel (u, v) of pose T: its probe point (x, y, 0) and continuous index.
void index_of(const Geometry& g, const Pose& T, int u, int v, double p[2], double c[3]) {
  p[0] = g.x0 + u * g.sx;
  p[1] = g.y0 + v * g.sy;
  double w[3];
  for (int i = 0; i < 3; ++i) w[i] = T.m[i][0] * p[0] + T.m[i][1] * p[1] + T.m[i][3];
  for (int k = 0; k < 3; ++k)
    c[k] = g.L.m[k][0] * w[0] + g.L.m[k][1] * w[1] + g.L.m[k][2] * w[2] + g.o[k];
}

/// f(i, p, s) for every pixel i of pose T inside the fan and the volume (p: its probe point,
/// s: its sample), row by row; `skip(i)` leaves a pixel out before it is sampled.
template <typename T, typename Skip, typename F>
void for_each_sample(const Geometry& g, const T* v, const Pose& pose, const Skip& skip,
                     const F& f) {
  for (int row = 0; row < g.height; ++row)
    for (int u = 0; u < g.width; ++u) {
      const int64_t i = int64_t(row) * g.width + u;
      if (!g.mask[size_t(i)] || skip(i)) continue;
      double p[2], c[3];
      index_of(g, pose, u, row, p, c);
      Sample s;
      if (sample(v, g.n, c, s)) f(i, p, s);
    }
}

}  // namespace

void slice_linear_f64(const Volume& volume, const ProbeGeometry& probe, const Pose* poses,
                      size_t count, double fill, double* out) {
  if (count == 0) return;
  validate_poses(poses, count, "poses", 0, /*warn_non_orthonormal=*/false);
  const Geometry g = geometry(volume, probe);
  const int64_t plane = int64_t(g.width) * g.height;
  visit_pixel_type(volume.pixel_type(), [&](auto zero) {
    using T = decltype(zero);
    const T* v = volume.data_as<T>();
    backend::parallel_for(int64_t(count), [&](int64_t k) {
      double* img = out + k * plane;
      std::fill(img, img + plane, fill);
      for_each_sample(
          g, v, poses[k], [](int64_t) { return false; },
          [&](int64_t i, const double*, const Sample& s) { img[i] = s.value; });
    });
  });
}

void slice_linear_backward(const Volume& volume, const ProbeGeometry& probe, const Pose* poses,
                           size_t count, const double* grad_images, double* grad_poses,
                           double* grad_volume) {
  if (count == 0) return;
  validate_poses(poses, count, "poses", 0, /*warn_non_orthonormal=*/false);
  const Geometry g = geometry(volume, probe);
  const int64_t plane = int64_t(g.width) * g.height;
  visit_pixel_type(volume.pixel_type(), [&](auto zero) {
    using T = decltype(zero);
    const T* v = volume.data_as<T>();
    // dL/dT_ij = Σ dL/dI · (∇_w I)_i · p̃_j with ∇_w I = Lᵀ·∇_c I and p̃ = (x, y, 0, 1); with a
    // volume gradient, each sample's dL/dI is also spread over its eight corners by their
    // weights (clamped corners coincide and add up). Without it, poses run in parallel; with it,
    // one pass pose by pose in order, so the sums are the same on any thread count.
    const auto pose = [&](int64_t k) {
      double G[12] = {};
      const double* go = grad_images + k * plane;
      for_each_sample(
          g, v, poses[k], [&](int64_t i) { return go[i] == 0; },
          [&](int64_t i, const double* p, const Sample& s) {
            for (int a = 0; a < 3; ++a) {
              const double gw =
                  go[i] * (g.L.m[0][a] * s.dc[0] + g.L.m[1][a] * s.dc[1] + g.L.m[2][a] * s.dc[2]);
              G[4 * a] += gw * p[0];
              G[4 * a + 1] += gw * p[1];
              G[4 * a + 3] += gw;
            }
            if (grad_volume)
              for (int q = 0; q < 8; ++q) grad_volume[s.corner[q]] += go[i] * s.weight[q];
          });
      double* out = grad_poses + 16 * k;
      for (int e = 0; e < 16; ++e) out[e] = e < 12 ? G[e] : 0.0;
    };
    if (grad_volume)
      for (int64_t k = 0; k < int64_t(count); ++k) pose(k);
    else
      backend::parallel_for(int64_t(count), pose);
  });
}

}  // namespace sonoslice
