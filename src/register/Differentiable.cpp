// Differentiable slicing: float64 linear slices and their exact backward pass
// (include/sonoslice/register/Differentiable.h).
#include "sonoslice/register/Differentiable.h"

#include <algorithm>
#include <vector>

#include "../backend/ParallelFor.h"
#include "../geometry/Sampling.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace {

/// One pixel's docs/conventions.md §5 `linear` sample (geometry/Sampling.h): its value, its
/// derivative along each index axis (0 along an axis whose neighbours are clamped together), and
/// the eight corners' offsets and weights for the backward pass into the volume.
struct Sample {
  double value = 0, dc[3] = {0, 0, 0};
  int64_t corner[8];
  double weight[8];
};

struct Geometry {
  VolumeGrid grid;
  Mat3 L;  // world → index, linear (the gradients' chain rule)
  geometry::VolumeView view;
  std::vector<uint8_t> mask;
  int width, height;
  double x0, y0, sx, sy;
};

Geometry geometry_of(const Volume& volume, const ProbeGeometry& probe) {
  probe.validate("probe");
  Geometry g;
  g.grid = volume.grid();
  g.L = g.grid.world_to_index_linear();
  g.view = geometry::VolumeView::of(g.grid.dims[0], g.grid.dims[1], g.grid.dims[2]);
  g.mask = probe.mask();
  g.width = probe.image.width;
  g.height = probe.image.height;
  g.x0 = probe.image.origin_mm[0];
  g.y0 = probe.image.origin_mm[1];
  g.sx = probe.image.spacing_mm[0];
  g.sy = probe.image.spacing_mm[1];
  return g;
}

/// f(i, p, s) for every pixel i of pose T inside the fan and the volume (p: its probe point,
/// s: its sample), row by row; `skip(i)` leaves a pixel out before it is sampled.
template <typename T, typename Skip, typename F>
void for_each_sample(const Geometry& g, const T* v, const Pose& pose, const Skip& skip,
                     const F& f) {
  const IndexMap to_index = g.grid.index_map(pose);
  for (int row = 0; row < g.height; ++row)
    for (int u = 0; u < g.width; ++u) {
      const int64_t i = int64_t(row) * g.width + u;
      if (!g.mask[size_t(i)] || skip(i)) continue;
      const double p[2] = {g.x0 + u * g.sx, g.y0 + row * g.sy};
      double c[3];
      to_index.apply(p[0], p[1], 0, c);
      if (!geometry::inside(g.view, c[0], c[1], c[2])) continue;
      const auto cell = geometry::linear_cell(g.view, c[0], c[1], c[2]);
      Sample s;
      s.value = geometry::linear_value_gradient<double>(v, cell, s.dc);
      geometry::linear_corners(cell, s.corner, s.weight);
      f(i, p, s);
    }
}

}  // namespace

void slice_linear_f64(const Volume& volume, const ProbeGeometry& probe, const Pose* poses,
                      size_t count, double fill, double* out) {
  if (count == 0) return;
  validate_poses(poses, count, "poses", 0, /*warn_non_orthonormal=*/false);
  const Geometry g = geometry_of(volume, probe);
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
  const Geometry g = geometry_of(volume, probe);
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
