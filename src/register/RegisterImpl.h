#pragma once
/// @file The registration kernel (docs/registration.md §2): one image row of one frame at one
/// pose → the metric's sums and their pose derivatives, without materialising the slice. Plain
/// structs and pointers; accumulate_rows sums a frame's rows in order (one frame per thread), so
/// the result does not depend on the thread count, nor, since the AVX2 build rounds as the
/// generic one does, on the CPU.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "../geometry/Sampling.h"
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define SONOSLICE_REGISTER_AVX2 1
#endif
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice {
namespace register_impl {

/// One frame at one pose, at one pyramid level.
struct TermsLaunch {
  const float* volume = nullptr;  // the level's volume, x fastest (nullptr: volume16)
  // or, for a full-resolution int16 volume (a CT's own type), its values as they are: read as
  // int16, exactly the floats a converted copy would hold, in half the memory and no copy.
  const int16_t* volume16 = nullptr;
  geometry::VolumeView grid;  // its extent
  IndexMap probe_to_index;    // probe mm → the level's continuous index
  double G[9];        // the level's index gradient → world gradient: ∇_w I = G · ∇_c I
  double P[9], p[3];  // probe mm → world mm (the pose)
  double centre[3];   // world point the rotation increments turn about
  const float* frame = nullptr;   // the level's frame, width × height
  const uint8_t* mask = nullptr;  // the level's mask (fan ∧ user ∧ finite frame)
  // Per row, the mask's columns [first, end) (2 values a row), so that the kernels skip the
  // rows' ends outside a fan (two fifths of a W1 frame); nullptr: every row whole.
  const int32_t* spans = nullptr;
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

/// The packed arrays of a row (pack_row): kRowArrays of them, each the row's width plus four
/// (a four-lane store may reach past the last packed pixel).
constexpr int kRowArrays = 8;
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int row_stride(int width) {
  return width + 4;
}

/// Bins of the mutual information's joint histogram per axis.
constexpr int kMiBins = 32;

// The functions below are compiled once per instruction set (RegisterCPU.cpp,
// RegisterCPUAvx2.cpp), like geometry/Sampling.h's.
inline namespace SONOSLICE_KERNEL_ISA {
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool sample_cell(const TermsLaunch& L, double x, double y,
                                                        bool gradient, CellSample& out) {
  using geometry::EdgeRule;
  double c[3];
  L.probe_to_index.apply(x, y, 0, c);
  if (!geometry::inside<EdgeRule::Interior>(L.grid, c[0], c[1], c[2])) return false;
  const auto cell = geometry::linear_cell<EdgeRule::Interior>(L.grid, c[0], c[1], c[2]);
  if (L.volume16)
    out.value = gradient ? geometry::linear_value_gradient<double>(L.volume16, cell, out.gc)
                         : geometry::linear_value<double>(L.volume16, cell);
  else
    out.value = gradient ? geometry::linear_value_gradient<double>(L.volume, cell, out.gc)
                         : geometry::linear_value<double>(L.volume, cell);
  return true;
}

/// Row v's columns that may hold mask pixels: [*first, *end).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void row_span(const TermsLaunch& L, int v, int* first,
                                                     int* end) {
  *first = L.spans ? L.spans[2 * v] : 0;
  *end = L.spans ? L.spans[2 * v + 1] : L.width;
}

/// f(i, x, cs) for each pixel i of row v in columns [first, end) inside the mask whose sample
/// lies inside the volume (x: its probe x; cs: its sample, with derivatives when `gradient`).
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void for_each_row_sample(const TermsLaunch& L, int v,
                                                                bool gradient, const F& f,
                                                                int first, int end) {
  const double y = L.y0 + v * L.sy;
  for (int u = first; u < end; ++u) {
    const int64_t i = int64_t(v) * L.width + u;
    if (!L.mask[i]) continue;
    const double x = L.x0 + u * L.sx;
    CellSample cs;
    if (sample_cell(L, x, y, gradient, cs)) f(i, x, cs);
  }
}

/// Pixel i (probe x = px, row y) with its sample cs, written at place n of the packed arrays
/// `x` (stride w): I, F and, with L.gradients, the derivatives J_r of I by the pose
/// increment's components.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void pack_pixel(const TermsLaunch& L, int64_t i, double px,
                                                       double y, const CellSample& cs, double* x,
                                                       int w, int n) {
  x[n] = cs.value;
  x[w + n] = L.frame[i];
  if (!L.gradients) return;
  const double* gc = cs.gc;
  double gw[3], r[3];
  for (int k = 0; k < 3; ++k) {
    gw[k] = L.G[3 * k] * gc[0] + L.G[3 * k + 1] * gc[1] + L.G[3 * k + 2] * gc[2];
    r[k] = L.P[3 * k] * px + L.P[3 * k + 1] * y + L.p[k] - L.centre[k];
  }
  // J = (∇I, r × ∇I), r = w − c: a translation v moves the sample by v, a rotation ω about the
  // centre by ω × r, and ∇I·(ω × r) = ω·(r × ∇I).
  double* J = x + 2 * w + n;
  J[0] = gw[0];
  J[w] = gw[1];
  J[2 * w] = gw[2];
  J[3 * w] = r[1] * gw[2] - r[2] * gw[1];
  J[4 * w] = r[2] * gw[0] - r[0] * gw[2];
  J[5 * w] = r[0] * gw[1] - r[1] * gw[0];
}

#if SONOSLICE_REGISTER_AVX2
/// Whether the level's volume is small enough for the four-pixel paths' 32-bit gather offsets.
SONOSLICE_INLINE bool gathers_reach(const TermsLaunch& L) {
  return int64_t(L.grid.nx) * L.grid.ny * L.grid.nz < (int64_t(1) << 31);
}

/// Writes the lanes of `valid` (a 4-bit mask) of each of `arrays` vectors, left-packed in lane
/// order, at x[k·w + n ..] (k = 0: *value, 1: *frame, then rest[k − 2]); returns their count.
SONOSLICE_INLINE int left_pack(int valid, const __m256d* value, const __m256d* frame, int arrays,
                               double* x, int w, int n, const __m256d* rest = nullptr) {
  // Per mask, the permutation of the eight 32-bit halves that moves the valid lanes first.
  alignas(32) static const int32_t kPack[16][8] = {
      {0, 1, 0, 1, 0, 1, 0, 1}, {0, 1, 0, 1, 0, 1, 0, 1}, {2, 3, 0, 1, 0, 1, 0, 1},
      {0, 1, 2, 3, 0, 1, 0, 1}, {4, 5, 0, 1, 0, 1, 0, 1}, {0, 1, 4, 5, 0, 1, 0, 1},
      {2, 3, 4, 5, 0, 1, 0, 1}, {0, 1, 2, 3, 4, 5, 0, 1}, {6, 7, 0, 1, 0, 1, 0, 1},
      {0, 1, 6, 7, 0, 1, 0, 1}, {2, 3, 6, 7, 0, 1, 0, 1}, {0, 1, 2, 3, 6, 7, 0, 1},
      {4, 5, 6, 7, 0, 1, 0, 1}, {0, 1, 4, 5, 6, 7, 0, 1}, {2, 3, 4, 5, 6, 7, 0, 1},
      {0, 1, 2, 3, 4, 5, 6, 7}};
  const __m256i perm = _mm256_load_si256(reinterpret_cast<const __m256i*>(kPack[valid]));
  for (int k = 0; k < arrays; ++k) {
    const __m256d v = k == 0 ? *value : (k == 1 ? *frame : rest[k - 2]);
    _mm256_storeu_pd(x + size_t(k) * w + n,
                     _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(v), perm)));
  }
  return __builtin_popcount(unsigned(valid));
}

/// Pixels u .. u + 3 of row v, four double lanes: the same operations in the same order as
/// sample_cell (this file is built without FMA contraction), so each lane is bit for bit the
/// scalar sample; the corners come by gathers. Needs a volume of fewer than 2^31 voxels (32-bit
/// gather offsets).
struct FourSamples {
  int valid = 0;  // 4-bit mask: the lanes inside the mask and the volume
  __m256d px;     // the pixels' probe x
  __m256d value;  // the volume's trilinear value
  __m256d gc[3];  // its derivatives along the index axes (when asked for)
  __m256d frame;  // the frame's pixels
};

SONOSLICE_INLINE bool sample_four(const TermsLaunch& L, int v, int u, bool gradient,
                                  FourSamples& out) {
  const double y = L.y0 + v * L.sy;
  const int64_t i = int64_t(v) * L.width + u;
  int32_t word;
  __builtin_memcpy(&word, L.mask + i, 4);
  const int in_mask =
      ~_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_cvtsi32_si128(word), _mm_setzero_si128())) & 0xf;
  const geometry::VolumeView& g = L.grid;
  if (!in_mask || g.nx < 2 || g.ny < 2 || g.nz < 2) return false;
  const __m256d px = _mm256_add_pd(
      _mm256_mul_pd(_mm256_add_pd(_mm256_set1_pd(double(u)), _mm256_setr_pd(0, 1, 2, 3)),
                    _mm256_set1_pd(L.sx)),
      _mm256_set1_pd(L.x0));
  // c = A·(x, y, 0) + a, as IndexMap::apply rounds it.
  __m256d c[3];
  const int n_axis[3] = {g.nx, g.ny, g.nz};
  __m256d inside = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
  for (int k = 0; k < 3; ++k) {
    const IndexMap& m = L.probe_to_index;
    c[k] = _mm256_add_pd(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(m.A[k][0]), px),
                                                     _mm256_set1_pd(m.A[k][1] * y)),
                                       _mm256_set1_pd(m.A[k][2] * 0.0)),
                         _mm256_set1_pd(m.a[k]));
    inside = _mm256_and_pd(inside, _mm256_cmp_pd(c[k], _mm256_setzero_pd(), _CMP_GE_OQ));
    inside = _mm256_and_pd(inside,
                           _mm256_cmp_pd(c[k], _mm256_set1_pd(double(n_axis[k] - 1)), _CMP_LE_OQ));
  }
  out.valid = in_mask & _mm256_movemask_pd(inside);
  if (!out.valid) return false;
  out.px = px;
  // The cell: int(c), or n − 2 at c = n − 1; lanes outside read voxel 0.
  __m128i cell[3];
  __m256d f[3];
  for (int k = 0; k < 3; ++k) {
    const __m256d last = _mm256_set1_pd(double(n_axis[k] - 1));
    const __m256d ck = _mm256_and_pd(c[k], inside);  // 0 in the lanes outside
    const __m128i below = _mm256_cvttpd_epi32(ck);
    const __m128i at_end = _mm256_castsi256_si128(
        _mm256_permutevar8x32_epi32(_mm256_castpd_si256(_mm256_cmp_pd(ck, last, _CMP_LT_OQ)),
                                    _mm256_setr_epi32(0, 2, 4, 6, 0, 0, 0, 0)));
    cell[k] = _mm_blendv_epi8(_mm_set1_epi32(n_axis[k] - 2), below, at_end);
    f[k] = _mm256_sub_pd(ck, _mm256_cvtepi32_pd(cell[k]));
  }
  const __m128i sy = _mm_set1_epi32(int32_t(g.stride_y)), sz = _mm_set1_epi32(int32_t(g.stride_z));
  const __m128i r00 = _mm_add_epi32(_mm_mullo_epi32(cell[2], sz), _mm_mullo_epi32(cell[1], sy));
  const __m128i o000 = _mm_add_epi32(r00, cell[0]);
  const __m128i o010 = _mm_add_epi32(o000, sy), o001 = _mm_add_epi32(o000, sz);
  const __m128i o011 = _mm_add_epi32(o001, sy);
  __m256d v000, v100, v010, v110, v001, v101, v011, v111;
  if (L.volume16) {
    // One 32-bit gather brings a voxel and its +x neighbour (little-endian: the voxel in the low
    // half), each sign-extended; the cell's x + 1 is always inside the row.
    const auto pair = [&](__m128i o, __m256d* at, __m256d* next) {
      const __m128i two = _mm_i32gather_epi32(reinterpret_cast<const int*>(L.volume16), o, 2);
      *at = _mm256_cvtepi32_pd(_mm_srai_epi32(_mm_slli_epi32(two, 16), 16));
      *next = _mm256_cvtepi32_pd(_mm_srai_epi32(two, 16));
    };
    pair(o000, &v000, &v100);
    pair(o010, &v010, &v110);
    pair(o001, &v001, &v101);
    pair(o011, &v011, &v111);
  } else {
    const auto voxels = [&](__m128i o) {
      return _mm256_cvtps_pd(_mm_i32gather_ps(L.volume, o, 4));
    };
    const auto next = [&](__m128i o) {
      return _mm256_cvtps_pd(_mm_i32gather_ps(L.volume + 1, o, 4));
    };
    v000 = voxels(o000), v100 = next(o000), v010 = voxels(o010), v110 = next(o010);
    v001 = voxels(o001), v101 = next(o001), v011 = voxels(o011), v111 = next(o011);
  }
  const auto lerp = [](__m256d a, __m256d b, __m256d t) {
    return _mm256_add_pd(a, _mm256_mul_pd(t, _mm256_sub_pd(b, a)));
  };
  // geometry::linear_value and linear_value_gradient (the same lerps), lane by lane.
  const __m256d a00 = lerp(v000, v100, f[0]), a10 = lerp(v010, v110, f[0]);
  const __m256d a01 = lerp(v001, v101, f[0]), a11 = lerp(v011, v111, f[0]);
  const __m256d b0 = lerp(a00, a10, f[1]), b1 = lerp(a01, a11, f[1]);
  out.value = lerp(b0, b1, f[2]);
  out.frame = _mm256_cvtps_pd(_mm_loadu_ps(L.frame + i));
  if (!gradient) return true;
  const __m256d dx00 = _mm256_sub_pd(v100, v000), dx10 = _mm256_sub_pd(v110, v010);
  const __m256d dx01 = _mm256_sub_pd(v101, v001), dx11 = _mm256_sub_pd(v111, v011);
  out.gc[0] = lerp(lerp(dx00, dx10, f[1]), lerp(dx01, dx11, f[1]), f[2]);
  out.gc[1] = lerp(_mm256_sub_pd(a10, a00), _mm256_sub_pd(a11, a01), f[2]);
  out.gc[2] = _mm256_sub_pd(b1, b0);
  return true;
}

/// The world gradient G·∇_c I of four samples, lane by lane as the scalar code sums it.
SONOSLICE_INLINE void world_gradient_four(const TermsLaunch& L, const __m256d gc[3],
                                          __m256d gw[3]) {
  const auto mul = [](double s, __m256d a) { return _mm256_mul_pd(_mm256_set1_pd(s), a); };
  for (int k = 0; k < 3; ++k)
    gw[k] = _mm256_add_pd(_mm256_add_pd(mul(L.G[3 * k], gc[0]), mul(L.G[3 * k + 1], gc[1])),
                          mul(L.G[3 * k + 2], gc[2]));
}

/// pack_pixel for pixels u .. u + 3 of row v (with derivatives when L.gradients), bit for bit:
/// packs the pixels inside the mask and the volume at x[n ..] (left-packed, in order); returns how
/// many.
SONOSLICE_INLINE int pack_four(const TermsLaunch& L, int v, int u, double* x, int w, int n) {
  FourSamples s;
  if (!sample_four(L, v, u, L.gradients, s)) return 0;
  if (!L.gradients) return left_pack(s.valid, &s.value, &s.frame, 2, x, w, n);
  const double y = L.y0 + v * L.sy;
  const auto mul = [](double c, __m256d a) { return _mm256_mul_pd(_mm256_set1_pd(c), a); };
  __m256d gw[3], r[3];
  world_gradient_four(L, s.gc, gw);
  for (int k = 0; k < 3; ++k)
    r[k] = _mm256_sub_pd(
        _mm256_add_pd(_mm256_add_pd(mul(L.P[3 * k], s.px), _mm256_set1_pd(L.P[3 * k + 1] * y)),
                      _mm256_set1_pd(L.p[k])),
        _mm256_set1_pd(L.centre[k]));
  const auto cross = [](__m256d a, __m256d b, __m256d c, __m256d d) {
    return _mm256_sub_pd(_mm256_mul_pd(a, b), _mm256_mul_pd(c, d));
  };
  const __m256d out[kRowArrays - 2] = {gw[0],
                                       gw[1],
                                       gw[2],
                                       cross(r[1], gw[2], r[2], gw[1]),
                                       cross(r[2], gw[0], r[0], gw[2]),
                                       cross(r[0], gw[1], r[1], gw[0])};
  return left_pack(s.valid, &s.value, &s.frame, kRowArrays, x, w, n, out);
}

/// lc2_row_terms for pixels u .. u + 3 of row v, lane by lane as the scalar code computes them.
SONOSLICE_INLINE void lc2_four(const TermsLaunch& L, int v, int u, double* q) {
  FourSamples s;
  if (!sample_four(L, v, u, true, s)) return;
  const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
  __m256d bx = zero, by = one;
  if (L.curvilinear) {
    const __m256d dy = _mm256_set1_pd(L.y0 + v * L.sy - L.apex_y);
    const __m256d r =
        _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(s.px, s.px), _mm256_mul_pd(dy, dy)));
    const __m256d positive = _mm256_cmp_pd(r, zero, _CMP_GT_OQ);
    bx = _mm256_blendv_pd(zero, _mm256_div_pd(s.px, r), positive);
    by = _mm256_blendv_pd(one, _mm256_div_pd(dy, r), positive);
  }
  __m256d gw[3];
  world_gradient_four(L, s.gc, gw);
  __m256d g = zero;
  for (int k = 0; k < 3; ++k)
    g = _mm256_add_pd(
        g, _mm256_mul_pd(gw[k], _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(L.P[3 * k]), bx),
                                              _mm256_mul_pd(_mm256_set1_pd(L.P[3 * k + 1]), by))));
  g = _mm256_blendv_pd(g, _mm256_sub_pd(zero, g), _mm256_cmp_pd(g, zero, _CMP_LT_OQ));
  const __m256d U = s.frame, p = s.value;
  alignas(32) double t[kLc2Sums][4];
  const __m256d terms[kLc2Sums] = {one,
                                   U,
                                   p,
                                   g,
                                   _mm256_mul_pd(U, U),
                                   _mm256_mul_pd(p, p),
                                   _mm256_mul_pd(g, g),
                                   _mm256_mul_pd(U, p),
                                   _mm256_mul_pd(U, g),
                                   _mm256_mul_pd(p, g)};
  for (int k = 0; k < kLc2Sums; ++k) _mm256_store_pd(t[k], terms[k]);
  for (int l = 0; l < 4; ++l) {
    if (!(s.valid >> l & 1)) continue;
    double* out = q + kLc2Sums * (u + l);
    for (int k = 0; k < kLc2Sums; ++k) out[k] = t[k][l];
  }
}
#endif

/// Row v's compared pixels (inside the mask and the volume), packed into `x` (kRowArrays
/// arrays, row_stride(L.width) apart): I, F and, with L.gradients, the six derivatives J_r, in
/// pixel order; returns how many.
SONOSLICE_HOST_DEVICE inline int pack_row(const TermsLaunch& L, int v, double* x) {
  const int w = row_stride(L.width);
  const double y = L.y0 + v * L.sy;
  int n = 0, u, end;
  row_span(L, v, &u, &end);
#if SONOSLICE_REGISTER_AVX2
  if (gathers_reach(L))
    for (; u + 4 <= end; u += 4) n += pack_four(L, v, u, x, w, n);
#endif
  for_each_row_sample(
      L, v, L.gradients,
      [&](int64_t i, double px, const CellSample& cs) { pack_pixel(L, i, px, y, cs, x, w, n++); },
      u, end);
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
/// (trilinear, 0 ≤ c ≤ n − 1 on every axis). `scratch`: kRowArrays · row_stride(L.width)
/// doubles. The row is packed first and its sums taken a few at a time over the packed arrays, as
/// vector operations.
SONOSLICE_HOST_DEVICE inline void accumulate_row(const TermsLaunch& L, int v, double* scratch,
                                                 PoseTerms& t) {
  const int w = row_stride(L.width);
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

/// Adds the rows of L, in order, to `total`: the terms of one frame at one pose (host code: one
/// scratch row buffer per thread, kept from call to call).
inline void accumulate_rows(const TermsLaunch& L, PoseTerms& total) {
  thread_local std::vector<double> scratch;
  scratch.resize(size_t(kRowArrays) * size_t(row_stride(L.width)));
  for (int v = 0; v < L.height; ++v) {
    PoseTerms row;
    accumulate_row(L, v, scratch.data(), row);
    total.add(row);
  }
}

/// Mutual information, row v: each pixel inside the mask and the volume adds 1 to the joint
/// histogram (volume × frame, kMiBins²) split over the 2 × 2 bins around its (clipped, scaled)
/// intensities by bilinear weights, so that the histogram changes continuously with the pose.
SONOSLICE_HOST_DEVICE inline void accumulate_mi_row(const TermsLaunch& L, int v, double* joint,
                                                    double vol_lo, double vol_scale, double fr_lo,
                                                    double fr_scale) {
  int first, end;
  row_span(L, v, &first, &end);
  for_each_row_sample(
      L, v, false,
      [&](int64_t i, double, const CellSample& cs) {
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
      },
      first, end);
}

/// LC2 (Wein et al. 2008), row v: for each pixel inside the mask and the volume, the frame's
/// value U, the volume's p and its gradient magnitude along the beam g = |∇I · beam|, written at
/// the pixel's place u in the row's `q` (kLc2Sums values a pixel: 1, U, p, g, U², p², g², Up, Ug,
/// pg; the other pixels are left as they are), the terms whose sums over a patch make the
/// patch's fit.
SONOSLICE_HOST_DEVICE inline void lc2_row_terms(const TermsLaunch& L, int v, double* q) {
  const double y = L.y0 + v * L.sy;
  int first, end;
  row_span(L, v, &first, &end);
#if SONOSLICE_REGISTER_AVX2
  if (gathers_reach(L))
    for (; first + 4 <= end; first += 4) lc2_four(L, v, first, q);
#endif
  const auto pixel = [&](int64_t i, double x, const CellSample& cs) {
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
    double* t = q + kLc2Sums * (i - int64_t(v) * L.width);
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
  };
  for_each_row_sample(L, v, true, pixel, first, end);
}

/// One patch's score from its window sums t (kLc2Sums values; n = t[0] compared pixels), when it
/// counts (at least `least` pixels, and a frame patch that is not flat): LC2's fit R² weighted by
/// the frame patch's σ (contribution σ·R², weight σ), or local NCC (its correlation, weight 1).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool score_patch(const double* t, double least, bool lncc,
                                                        double* contribution, double* weight) {
  const double n = t[0];
  if (n < least) return false;
  // Variances from running sums carry their round-off (about 1e-16 of the mean square, times the
  // steps they ran): a variance below 1e-10 of the mean square is a flat patch, and its
  // covariances are round-off too.
  const auto spread = [n](double sum, double sum_sq) {
    const double mean = sum / n, v = sum_sq / n - mean * mean;
    return v > 1e-10 * (sum_sq / n) + 1e-300 ? v : 0.0;
  };
  const double mu = t[1] / n, mp = t[2] / n, mg = t[3] / n;
  const double vu = spread(t[1], t[4]);
  if (!(vu > 0)) return false;  // flat frame patch: nothing to explain
  double cpp = spread(t[2], t[5]), cgg = spread(t[3], t[6]);
  const double bup = cpp > 0 ? t[7] / n - mu * mp : 0;
  if (lncc) {
    // The patch's NCC of frame and volume, every patch alike; a flat volume patch scores 0.
    *contribution = cpp > 0 ? bup / std::sqrt(vu * cpp) : 0;
    *weight = 1;
    return true;
  }
  // LC2: the least-squares fit U ≈ α·p + β·g + γ, R² = bᵀ·C⁻¹·b / var U with C the covariance
  // of (p, g) and b their covariances with U (a small ridge keeps a flat p or g solvable).
  const double cpg = cpp > 0 && cgg > 0 ? t[9] / n - mp * mg : 0;
  const double bug = cgg > 0 ? t[8] / n - mu * mg : 0;
  const double ridge = 1e-9 * (cpp + cgg) + 1e-12;
  cpp += ridge;
  cgg += ridge;
  const double det = cpp * cgg - cpg * cpg;
  double r2 =
      det > 0 ? (bup * (cgg * bup - cpg * bug) + bug * (cpp * bug - cpg * bup)) / det / vu : 0;
  r2 = r2 > 0 ? r2 : 0;  // also a NaN fit
  r2 = r2 < 1 ? r2 : 1;
  const double sigma = std::sqrt(vu);
  *contribution = sigma * r2;
  *weight = sigma;
  return true;
}

#if SONOSLICE_REGISTER_AVX2
/// score_patch for the patches of pixels u .. u + 3 (window sums at t, kLc2Sums apart), lane by
/// lane with the same operations (IEEE division and square root round as the scalar ones do);
/// returns the 4-bit mask of the patches that count.
SONOSLICE_INLINE int score_four(const double* t, double least, bool lncc, double* contribution,
                                double* weight) {
  const auto at = [t](int k) {
    return _mm256_setr_pd(t[k], t[kLc2Sums + k], t[2 * kLc2Sums + k], t[3 * kLc2Sums + k]);
  };
  const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
  const __m256d n = at(0);
  __m256d counts = _mm256_cmp_pd(n, _mm256_set1_pd(least), _CMP_NLT_UQ);
  if (!_mm256_movemask_pd(counts)) return 0;
  const auto spread = [&](__m256d sum, __m256d sum_sq) {
    const __m256d mean = _mm256_div_pd(sum, n), square = _mm256_div_pd(sum_sq, n);
    const __m256d v = _mm256_sub_pd(square, _mm256_mul_pd(mean, mean));
    const __m256d floor =
        _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(1e-10), square), _mm256_set1_pd(1e-300));
    return _mm256_and_pd(v, _mm256_cmp_pd(v, floor, _CMP_GT_OQ));
  };
  const __m256d s1 = at(1), s2 = at(2), s3 = at(3);
  const __m256d mu = _mm256_div_pd(s1, n), mp = _mm256_div_pd(s2, n), mg = _mm256_div_pd(s3, n);
  const __m256d vu = spread(s1, at(4));
  counts = _mm256_and_pd(counts, _mm256_cmp_pd(vu, zero, _CMP_GT_OQ));
  const int mask = _mm256_movemask_pd(counts);
  if (!mask) return 0;
  __m256d cpp = spread(s2, at(5)), cgg = spread(s3, at(6));
  const __m256d p_varies = _mm256_cmp_pd(cpp, zero, _CMP_GT_OQ);
  const __m256d g_varies = _mm256_cmp_pd(cgg, zero, _CMP_GT_OQ);
  const auto cov = [&](int k, __m256d a, __m256d b) {
    return _mm256_sub_pd(_mm256_div_pd(at(k), n), _mm256_mul_pd(a, b));
  };
  const __m256d bup = _mm256_and_pd(cov(7, mu, mp), p_varies);
  if (lncc) {
    const __m256d r = _mm256_div_pd(bup, _mm256_sqrt_pd(_mm256_mul_pd(vu, cpp)));
    _mm256_storeu_pd(contribution, _mm256_and_pd(r, p_varies));
    _mm256_storeu_pd(weight, one);
    return mask;
  }
  const __m256d cpg = _mm256_and_pd(cov(9, mp, mg), _mm256_and_pd(p_varies, g_varies));
  const __m256d bug = _mm256_and_pd(cov(8, mu, mg), g_varies);
  const __m256d ridge = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(1e-9), _mm256_add_pd(cpp, cgg)),
                                      _mm256_set1_pd(1e-12));
  cpp = _mm256_add_pd(cpp, ridge);
  cgg = _mm256_add_pd(cgg, ridge);
  const __m256d det = _mm256_sub_pd(_mm256_mul_pd(cpp, cgg), _mm256_mul_pd(cpg, cpg));
  const __m256d num = _mm256_add_pd(
      _mm256_mul_pd(bup, _mm256_sub_pd(_mm256_mul_pd(cgg, bup), _mm256_mul_pd(cpg, bug))),
      _mm256_mul_pd(bug, _mm256_sub_pd(_mm256_mul_pd(cpp, bug), _mm256_mul_pd(cpg, bup))));
  __m256d r2 = _mm256_div_pd(_mm256_div_pd(num, det), vu);
  r2 = _mm256_and_pd(r2, _mm256_cmp_pd(det, zero, _CMP_GT_OQ));
  r2 = _mm256_and_pd(r2, _mm256_cmp_pd(r2, zero, _CMP_GT_OQ));  // also a NaN fit
  r2 = _mm256_blendv_pd(one, r2, _mm256_cmp_pd(r2, one, _CMP_LT_OQ));
  const __m256d sigma = _mm256_sqrt_pd(vu);
  _mm256_storeu_pd(contribution, _mm256_mul_pd(sigma, r2));
  _mm256_storeu_pd(weight, sigma);
  return mask;
}
#endif

/// Adds the patches of one row (window sums `sums`, kLc2Sums a pixel; centre[u]: whether pixel
/// u itself is compared) to `weighted` and `weight`, in pixel order (score_patch).
SONOSLICE_HOST_DEVICE inline void score_patch_row(const double* sums, const uint8_t* centre, int W,
                                                  double least, bool lncc, double& weighted,
                                                  double& weight) {
  int u = 0;
#if SONOSLICE_REGISTER_AVX2
  for (; u + 4 <= W; u += 4) {
    int32_t word;
    __builtin_memcpy(&word, centre + u, 4);
    if (!word) continue;  // no compared centre among the four
    double c[4], w[4];
    const int counts = score_four(sums + size_t(u) * kLc2Sums, least, lncc, c, w);
    for (int l = 0; l < 4; ++l)
      if (centre[u + l] && (counts >> l & 1)) {
        weighted += c[l];
        weight += w[l];
      }
  }
#endif
  for (; u < W; ++u) {
    double c, w;
    if (centre[u] && score_patch(sums + size_t(u) * kLc2Sums, least, lncc, &c, &w)) {
      weighted += c;
      weight += w;
    }
  }
}

/// The sums of the per-pixel terms (K values a pixel, W × H pixels) over the (2·half + 1)² window
/// around each pixel, pixels outside the image counting 0, streamed row by row: row v's terms are
/// made by `make_row(v, row)` (W·K values, zero beforehand; it writes only the columns
/// `span(v, &first, &end)` gives), summed along the row (running sums), and the window's column
/// sums kept as a running sum of those row sums, so a pixel costs O(K) whatever the window, and
/// only 2·half + 2 rows of row sums are held (a few hundred KB at full W1 resolution, in cache;
/// the whole frame's terms would be tens of MB an evaluation). Each pass covers only the columns
/// a row's span can reach (a W1 fan fills three fifths of its rectangle); the row sums beyond them
/// are zeros, not the running sums' round-off. `use(sums, centre, first, end)`, row by row in
/// order: the row's window sums (W·K values, meaningful in [first, end), the row's span) and
/// whether each pixel itself was compared (its count term, centre[u] = row[u·K] ≠ 0). Per-thread
/// buffers, reused across calls and left all zero between them.
template <int K, typename Span, typename MakeRow, typename Use>
inline void window_sums(int W, int H, int half, const Span& span, const MakeRow& make_row,
                        const Use& use) {
  const int rows_held = 2 * half + 2;  // rows v − half − 1 .. v + half
  const size_t line = size_t(W) * K;
  struct Columns {
    int first = 0, end = 0;
  };
  thread_local std::vector<double> row, row_sums, run;
  thread_local std::vector<uint8_t> centres;
  // Per slot of the ring: the columns of its row sums that may be non-zero.
  thread_local std::vector<Columns> written;
  const size_t held = size_t(rows_held);
  if (row.size() != line) row.assign(line, 0.0);
  if (row_sums.size() != line * held) row_sums.assign(line * held, 0.0);
  run.assign(line, 0.0);
  centres.resize(size_t(W) * held);
  written.assign(held, Columns{});
  const auto slot_of = [&](int v) { return size_t(v % rows_held); };
  const auto clear = [&](size_t slot) {
    double* b = row_sums.data() + slot * line;
    std::fill(b + size_t(written[slot].first) * K, b + size_t(written[slot].end) * K, 0.0);
    written[slot] = {};
  };
  // Row v's terms into its slot of the ring: the running sums along the row, and its centres.
  const auto add_row = [&](int v) {
    const size_t slot = slot_of(v);
    clear(slot);
    Columns s;
    span(v, &s.first, &s.end);
    if (s.first >= s.end) return;
    make_row(v, row.data());
    double* b = row_sums.data() + slot * line;
    uint8_t* c = centres.data() + slot * size_t(W);
    const double* a = row.data();
    // Column u's sum covers columns u − half .. u + half: zero left of first − half, and
    // constant (zero up to round-off) right of end + half.
    const int from = std::max(0, s.first - half), to = std::min(W, s.end + half);
    double sum[K] = {};
    if (from == 0)
      for (int u = 0; u < std::min(half, W); ++u)
        for (int k = 0; k < K; ++k) sum[k] += a[u * K + k];
    for (int u = from; u < to; ++u) {
      if (u + half < W)
        for (int k = 0; k < K; ++k) sum[k] += a[(u + half) * K + k];
      if (u - half - 1 >= 0)
        for (int k = 0; k < K; ++k) sum[k] -= a[(u - half - 1) * K + k];
      for (int k = 0; k < K; ++k) b[u * K + k] = sum[k];
    }
    written[slot] = {from, to};
    for (int u = s.first; u < s.end; ++u) c[u] = a[u * K] != 0;
    std::fill(row.begin() + ptrdiff_t(s.first) * K, row.begin() + ptrdiff_t(s.end) * K, 0.0);
  };
  const auto sums_of = [&](int v) { return row_sums.data() + slot_of(v) * line; };
  for (int v = 0; v < std::min(half, H); ++v) {
    add_row(v);
    const double* r = sums_of(v);
    const Columns& w = written[slot_of(v)];
    for (size_t j = size_t(w.first) * K; j < size_t(w.end) * K; ++j) run[j] += r[j];
  }
  for (int v = 0; v < H; ++v) {
    // The row entering the window is added and the row leaving it taken away in one pass (each
    // element as (run + in) − out, the order two passes would take), over the columns either
    // may reach: elsewhere both are zero.
    const bool enters = v + half < H, leaves = v - half - 1 >= 0;
    if (enters) add_row(v + half);
    const double* in = enters ? sums_of(v + half) : nullptr;
    const double* out = leaves ? sums_of(v - half - 1) : nullptr;
    const Columns none{W, 0};
    const Columns& wi = enters ? written[slot_of(v + half)] : none;
    const Columns& wo = leaves ? written[slot_of(v - half - 1)] : none;
    const auto reach = [](const Columns& w) { return w.first < w.end; };
    const size_t j0 = size_t(std::min(reach(wi) ? wi.first : W, reach(wo) ? wo.first : W)) * K;
    const size_t j1 = size_t(std::max(reach(wi) ? wi.end : 0, reach(wo) ? wo.end : 0)) * K;
    if (in && out)
      for (size_t j = j0; j < j1; ++j) run[j] = (run[j] + in[j]) - out[j];
    else if (in)
      for (size_t j = j0; j < j1; ++j) run[j] += in[j];
    else if (out)
      for (size_t j = j0; j < j1; ++j) run[j] -= out[j];
    Columns s;
    span(v, &s.first, &s.end);
    if (s.first < s.end)
      use(static_cast<const double*>(run.data()),
          static_cast<const uint8_t*>(centres.data() + slot_of(v) * size_t(W)), s.first, s.end);
  }
  for (size_t slot = 0; slot < held; ++slot) clear(slot);
}

/// LC2's (local NCC's) patches of one frame at one pose (the launch L), one centred on each
/// compared pixel, 2·half + 1 pixels a side (Wein's LC2 is a patch per pixel: a grid of patches
/// would make the cost jump as structures cross its lines): adds each patch that counts (at least
/// `least` compared pixels, score_patch) to `weighted` and `weight`, in pixel order. Host code
/// (per-thread buffers, window_sums).
inline void patch_score(const TermsLaunch& L, int half, double least, bool lncc, double& weighted,
                        double& weight) {
  constexpr int K = kLc2Sums;
  const auto span = [&](int v, int* first, int* end) { row_span(L, v, first, end); };
  const auto make_row = [&](int v, double* row) { lc2_row_terms(L, v, row); };
  const auto use = [&](const double* sums, const uint8_t* centre, int first, int end) {
    score_patch_row(sums + size_t(first) * K, centre + first, end - first, least, lncc, weighted,
                    weight);
  };
  window_sums<K>(L.width, L.height, half, span, make_row, use);
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace register_impl
}  // namespace sonoslice
