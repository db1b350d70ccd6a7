#pragma once
/// @file The registration kernel (docs/registration.md §2): one image row of one frame at one
/// pose → the metric's sums and their pose derivatives, without materialising the slice. Plain
/// structs and pointers; the CPU driver (Registration.cpp) sums the rows in order, so the result
/// does not depend on the thread count.
#include <cmath>
#include <cstdint>

#include "../geometry/Sampling.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice {
namespace register_impl {

/// One frame at one pose, at one pyramid level.
struct TermsLaunch {
  const float* volume = nullptr;  // the level's volume, x fastest
  geometry::VolumeView grid;      // its extent
  IndexMap probe_to_index;        // probe mm → the level's continuous index
  double G[9];        // the level's index gradient → world gradient: ∇_w I = G · ∇_c I
  double P[9], p[3];  // probe mm → world mm (the pose)
  double centre[3];   // world point the rotation increments turn about
  const float* frame = nullptr;   // the level's frame, width × height
  const uint8_t* mask = nullptr;  // the level's mask (fan ∧ user ∧ finite frame)
  int width = 0, height = 0;
  double x0 = 0, y0 = 0, sx = 1, sy = 1;  // the level's pixel (u, v) → probe (x0 + u·sx, ...)
  bool gradients = false;
  // LC2 (lc2_row_terms): the beam direction at each pixel (curvilinear: from the apex at
  // probe (0, apex_y); linear: probe +y).
  bool curvilinear = false;
  double apex_y = 0;
};

/// LC2 terms per pixel, summed per patch: n, ΣU, Σp, Σg, ΣU², Σp², Σg², ΣUp, ΣUg, Σpg.
constexpr int kLc2Sums = 10;

/// The trilinear sample of the level's volume at probe point (x, y) and, with `gradient`, its
/// exact derivative along each index axis; false outside the volume. Registration's edge rule
/// (geometry/Sampling.h, conventions.md §5): 0 ≤ c ≤ n − 1 on every axis, whole cells only.
struct CellSample {
  double value = 0, gc[3] = {0, 0, 0};
};
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool sample_cell(const TermsLaunch& L, double x, double y,
                                                        bool gradient, CellSample& out) {
  using geometry::EdgeRule;
  double c[3];
  L.probe_to_index.apply(x, y, 0, c);
  if (!geometry::inside<EdgeRule::Interior>(L.grid, c[0], c[1], c[2])) return false;
  const auto cell = geometry::linear_cell<EdgeRule::Interior>(L.grid, c[0], c[1], c[2]);
  out.value = gradient ? geometry::linear_value_gradient<double>(L.volume, cell, out.gc)
                       : geometry::linear_value<double>(L.volume, cell);
  return true;
}

/// f(i, x, cs) for each pixel i of row v inside the mask whose sample lies inside the volume
/// (x: its probe x; cs: its sample, with derivatives when `gradient`).
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void for_each_row_sample(const TermsLaunch& L, int v,
                                                                bool gradient, const F& f) {
  const double y = L.y0 + v * L.sy;
  for (int u = 0; u < L.width; ++u) {
    const int64_t i = int64_t(v) * L.width + u;
    if (!L.mask[i]) continue;
    const double x = L.x0 + u * L.sx;
    CellSample cs;
    if (sample_cell(L, x, y, gradient, cs)) f(i, x, cs);
  }
}

/// Row v's compared pixels (inside the mask and the volume), packed into `x` (kRowArrays
/// arrays of L.width values): x[0..n) the volume's value I, x[w..w + n) the frame's F and,
/// with L.gradients, x[(2 + r)·w ..) the derivative J_r of I by the pose increment's r-th
/// component; returns n.
constexpr int kRowArrays = 8;
SONOSLICE_HOST_DEVICE inline int pack_row(const TermsLaunch& L, int v, double* x) {
  const int w = L.width;
  const double y = L.y0 + v * L.sy;
  int n = 0;
  for_each_row_sample(L, v, L.gradients, [&](int64_t i, double px, const CellSample& cs) {
    x[n] = cs.value;
    x[w + n] = L.frame[i];
    if (L.gradients) {
      const double* gc = cs.gc;
      double gw[3], r[3];
      for (int k = 0; k < 3; ++k) {
        gw[k] = L.G[3 * k] * gc[0] + L.G[3 * k + 1] * gc[1] + L.G[3 * k + 2] * gc[2];
        r[k] = L.P[3 * k] * px + L.P[3 * k + 1] * y + L.p[k] - L.centre[k];
      }
      // J = (∇I, r × ∇I), r = w − c: a translation v moves the sample by v, a rotation ω
      // about the centre by ω × r, and ∇I·(ω × r) = ω·(r × ∇I).
      double* J = x + 2 * w + n;
      J[0] = gw[0];
      J[w] = gw[1];
      J[2 * w] = gw[2];
      J[3 * w] = r[1] * gw[2] - r[2] * gw[1];
      J[4 * w] = r[2] * gw[0] - r[0] * gw[2];
      J[5 * w] = r[0] * gw[1] - r[1] * gw[0];
    }
    ++n;
  });
  return n;
}

/// out[m] += Σ_i a_i·b_m,i for m < M over n values (a = nullptr: Σ_i b_m,i), each as four
/// interleaved partial sums added in a fixed order: one pass over the row for M sums, whose
/// partial sums the compiler keeps in vector registers; the result does not depend on the
/// machine.
template <int M>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void row_dots(const double* a, const double* const* b, int n,
                                                     double* out) {
  double s[M][4] = {};
  int i = 0;
  for (; i + 4 <= n; i += 4)
    for (int m = 0; m < M; ++m)
      for (int l = 0; l < 4; ++l) s[m][l] += (a ? a[i + l] : 1.0) * b[m][i + l];
  for (int l = 0; i < n; ++i, ++l)
    for (int m = 0; m < M; ++m) s[m][l] += (a ? a[i] : 1.0) * b[m][i];
  for (int m = 0; m < M; ++m) out[m] += (s[m][0] + s[m][1]) + (s[m][2] + s[m][3]);
}

/// Adds row v's pixels to `t`: each pixel inside the mask whose sample lies inside the volume
/// (trilinear, 0 ≤ c ≤ n − 1 on every axis). `scratch`: kRowArrays · L.width doubles. The row is
/// packed first and its sums taken a few at a time over the packed arrays, as vector operations.
SONOSLICE_HOST_DEVICE inline void accumulate_row(const TermsLaunch& L, int v, double* scratch,
                                                 PoseTerms& t) {
  const int w = L.width;
  const int n = pack_row(L, v, scratch);
  if (n == 0) return;
  const double* x[kRowArrays];  // I, F, J0..J5
  for (int k = 0; k < kRowArrays; ++k) x[k] = scratch + size_t(k) * w;
  t.n += n;
  double plain[5] = {0, 0, 0, 0, 0};  // Σ I, Σ F, Σ I², Σ I·F, Σ F²
  row_dots<2>(nullptr, x, n, plain);
  row_dots<2>(x[0], x, n, plain + 2);
  row_dots<1>(x[1], x + 1, n, plain + 4);
  t.si += plain[0];
  t.sf += plain[1];
  t.sii += plain[2];
  t.sif += plain[3];
  t.sff += plain[4];
  if (!L.gradients) return;
  const double* const* J = x + 2;
  double sums[3][6] = {};  // Σ J, Σ I·J, Σ F·J
  row_dots<6>(nullptr, J, n, sums[0]);
  row_dots<6>(x[0], J, n, sums[1]);
  row_dots<6>(x[1], J, n, sums[2]);
  for (int r = 0; r < 6; ++r) {
    t.sj[r] += sums[0][r];
    t.sij[r] += sums[1][r];
    t.sfj[r] += sums[2][r];
  }
  // Σ J·Jᵀ, upper triangle row by row: row r is J_r against J_r..J_5.
  double jj[21] = {};
  row_dots<6>(J[0], J, n, jj);
  row_dots<5>(J[1], J + 1, n, jj + 6);
  row_dots<4>(J[2], J + 2, n, jj + 11);
  row_dots<3>(J[3], J + 3, n, jj + 15);
  row_dots<2>(J[4], J + 4, n, jj + 18);
  row_dots<1>(J[5], J + 5, n, jj + 20);
  for (int e = 0; e < 21; ++e) t.sjj[e] += jj[e];
}

/// Bins of the mutual information's joint histogram per axis.
constexpr int kMiBins = 32;

/// Mutual information, row v: each pixel inside the mask and the volume adds 1 to the joint
/// histogram (volume × frame, kMiBins²) split over the 2 × 2 bins around its (clipped, scaled)
/// intensities by bilinear weights, so that the histogram changes continuously with the pose.
SONOSLICE_HOST_DEVICE inline void accumulate_mi_row(const TermsLaunch& L, int v, double* joint,
                                                    double vol_lo, double vol_scale, double fr_lo,
                                                    double fr_scale) {
  for_each_row_sample(L, v, false, [&](int64_t i, double, const CellSample& cs) {
    const double p = cs.value;
    const auto bin = [](double value, double lo, double scale, int* at, double* frac) {
      double t = (value - lo) * scale;
      t = t < 0 ? 0 : (t > kMiBins - 1 ? kMiBins - 1 : t);
      int b = int(t);
      b = b > kMiBins - 2 ? kMiBins - 2 : b;
      *at = b;
      *frac = t - b;
    };
    int bi, bf;
    double ti, tf;
    bin(p, vol_lo, vol_scale, &bi, &ti);
    bin(double(L.frame[i]), fr_lo, fr_scale, &bf, &tf);
    double* h = joint + int64_t(bi) * kMiBins + bf;
    h[0] += (1 - ti) * (1 - tf);
    h[1] += (1 - ti) * tf;
    h[kMiBins] += ti * (1 - tf);
    h[kMiBins + 1] += ti * tf;
  });
}

/// LC2 (Wein et al. 2008), row v: for each pixel inside the mask and the volume, the frame's
/// value U, the volume's p and its gradient magnitude along the beam g = |∇I · beam|, written at
/// the pixel's place in `q` (kLc2Sums values a pixel: 1, U, p, g, U², p², g², Up, Ug, pg; the
/// other pixels are left as they are), the terms whose sums over a patch make the patch's fit.
SONOSLICE_HOST_DEVICE inline void lc2_row_terms(const TermsLaunch& L, int v, double* q) {
  const double y = L.y0 + v * L.sy;
  for_each_row_sample(L, v, true, [&](int64_t i, double x, const CellSample& cs) {
    const double p = cs.value;
    const double* gc = cs.gc;
    // The beam through this pixel, in the probe frame, then in world.
    double bx = 0, by = 1;
    if (L.curvilinear) {
      const double dy = y - L.apex_y, r = std::sqrt(x * x + dy * dy);
      bx = r > 0 ? x / r : 0;
      by = r > 0 ? dy / r : 1;
    }
    double g = 0;
    for (int k = 0; k < 3; ++k) {
      const double gw = L.G[3 * k] * gc[0] + L.G[3 * k + 1] * gc[1] + L.G[3 * k + 2] * gc[2];
      g += gw * (L.P[3 * k] * bx + L.P[3 * k + 1] * by);
    }
    g = g < 0 ? -g : g;
    const double U = L.frame[i];
    double* t = q + kLc2Sums * i;
    t[0] = 1;
    t[1] = U;
    t[2] = p;
    t[3] = g;
    t[4] = U * U;
    t[5] = p * p;
    t[6] = g * g;
    t[7] = U * p;
    t[8] = U * g;
    t[9] = p * g;
  });
}

}  // namespace register_impl
}  // namespace sonoslice
