#pragma once
/// @file The compounding kernels (docs/conventions.md §7): one source for every backend. CompoundCPU.cpp and
/// CompoundCUDA.cu include this file. Everything below the dispatch layer (Compounder.cpp)
/// takes pre-validated raw pointers and sizes.
///
/// A frame is a set of rows (image rows, or beams of a 3-D probe); sample u of a row lies at
/// c0 + u·dc in voxel-index space (for nearest splats the dispatch layer adds the 0.5 of
/// floor(c + 0.5) to c0, in double precision). A sample is splatted into the voxel nearest to it
/// (nearest: index floor(c + 0.5)) or into the eight voxels around it with trilinear weights
/// (linear).
///
/// CPU: owner computes. The batch's footprint is cut into slabs along one axis; a task owns a
/// slab and walks every row of every frame of the batch, in order, writing only its own voxels.
/// Each voxel therefore receives its samples in one fixed order whatever the number of threads,
/// and the result is the same bit for bit. Consecutive samples of a row that fall in the same
/// voxel (nearest) or cell (linear) are summed in registers first and written once: ultrasound
/// pixels are several times smaller than the voxels they go into.
///
/// CUDA: one thread per sample with atomic updates (mean sums then depend on the order in which
/// threads arrive, to float rounding; max and integer-valued nearest sums do not).
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

#include "../backend/Convert.h"
#include "CompoundTypes.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/core/Error.h"

#if defined(__CUDACC__)
#include "../backend/ParallelForCUDA.cuh"
#else
#include "../backend/ParallelFor.h"
#endif
#if !defined(__CUDACC__) && defined(__AVX2__)
#include <immintrin.h>
#define SONOSLICE_COMPOUND_AVX2 1
#endif

namespace sonoslice {
namespace compound_impl {
inline namespace SONOSLICE_KERNEL_ISA {

/// floor(x) as an int for |x| < 2^31, without a libm call (baseline x86-64 has no SSE4.1 round).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int floor_to_int(float x) {
  const int i = int(x);
  return i - (x < float(i) ? 1 : 0);
}

/// Whether a nearest splat at t = c + 0.5 lands in the grid (NaN: no).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool inside_nearest(const AccumulatorView& g, float tx,
                                                           float ty, float tz) {
  return tx >= 0.f && ty >= 0.f && tz >= 0.f && tx < float(g.nx) && ty < float(g.ny) &&
         tz < float(g.nz);
}

/// Whether a linear splat at c has a corner in the grid (NaN: no).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool inside_linear(const AccumulatorView& g, float cx,
                                                          float cy, float cz) {
  return cx > -1.f && cy > -1.f && cz > -1.f && cx < float(g.nx) && cy < float(g.ny) &&
         cz < float(g.nz);
}

/// The voxel nearest to a sample (docs/conventions.md §5 nearest: floor(c + 0.5)), given t = c + 0.5 (rows of
/// nearest splats carry the 0.5 in their origin); false outside the grid.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool nearest_voxel(const AccumulatorView& g, float tx,
                                                          float ty, float tz, int* i) {
  if (!inside_nearest(g, tx, ty, tz)) return false;
  // t >= 0, so truncation is floor.
  i[0] = int(tx);
  i[1] = int(ty);
  i[2] = int(tz);
  return true;
}

/// The cell (lower corner i, fractions f in [0, 1)) around continuous index c; false when no
/// corner of the cell is inside the grid.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool linear_cell(const AccumulatorView& g, float cx,
                                                        float cy, float cz, int* i, float* f) {
  if (!inside_linear(g, cx, cy, cz)) return false;
  i[0] = floor_to_int(cx);
  i[1] = floor_to_int(cy);
  i[2] = floor_to_int(cz);
  f[0] = cx - float(i[0]);
  f[1] = cy - float(i[1]);
  f[2] = cz - float(i[2]);
  return true;
}

/// Trilinear splat weight of corner k (bit 0: +x, bit 1: +y, bit 2: +z) of a cell.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float corner_weight(const float* f, int k) {
  const float wx = (k & 1) ? f[0] : 1.f - f[0];
  const float wy = (k & 2) ? f[1] : 1.f - f[1];
  const float wz = (k & 4) ? f[2] : 1.f - f[2];
  return (wx * wy) * wz;
}

template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float sample_value(const T* row, int u) {
  return float(row[u]);
}

/// A sample counts for a voxel's maximum only with a splat weight of at least 1/8 (PLUS's rule):
/// a sample at the far corner of a cell says little about that voxel.
constexpr float kMaxModeMinimumWeight = 0.125f;

/// Running value of a group of samples before it is written: a weighted sum (mean, latest) or
/// a maximum (max).
template <Mode M>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void gather(float& value, float& weight, float sample,
                                                   float w) {
  if (M == Mode::Max) {
    if (w >= kMaxModeMinimumWeight) {
      value = sample > value ? sample : value;
      weight += w;
    }
  } else {
    value += w * sample;
    weight += w;
  }
}

#if !defined(__CUDACC__)
/// Writes a group into voxel i (CPU: the calling task owns the voxel).
template <Mode M>
inline void apply(const AccumulatorView& g, int64_t i, float value, float weight, int32_t frame) {
  Accumulator& a = g.cells[i];
  if (M == Mode::Latest && g.stamp[i] != frame) {
    // A newer frame replaces what older frames left.
    g.stamp[i] = frame;
    a.value = 0.f;
    a.weight = 0.f;
  }
  if (M == Mode::Max)
    a.value = value > a.value ? value : a.value;
  else
    a.value += value;
  a.weight += weight;
}

/// floor and ceil without a libm call (baseline x86-64 has no SSE4.1 round); |x| is first
/// clamped to 2^40, far beyond any sample index.
inline double floor_fast(double x) {
  x = x < -1099511627776.0 ? -1099511627776.0 : (x > 1099511627776.0 ? 1099511627776.0 : x);
  const double t = double(int64_t(x));
  return t > x ? t - 1 : t;
}
inline double ceil_fast(double x) {
  return -floor_fast(-x);
}

/// Narrows [ub, ue) to the samples u of a row whose coordinate c0 + u·d along one axis lies in
/// [lo, hi] (`inv_d` = 1/d, 0 when the row is parallel to the axis's planes).
/// `outer`: conservatively (every such sample is kept, and up to two more at each end);
/// otherwise strictly (every sample kept is inside by 0.01 voxel and one sample), so that the
/// kernels can skip their per-sample tests there.
inline void clip_axis(double c0, double inv_d, double lo, double hi, bool outer, int& ub, int& ue) {
  if (ub >= ue) return;
  const double margin = outer ? 0.0 : 0.01;
  if (inv_d == 0) {
    if (!(c0 >= lo + margin && c0 <= hi - margin)) ue = ub;
    return;
  }
  double u0 = (lo - c0) * inv_d, u1 = (hi - c0) * inv_d;
  if (u0 > u1) std::swap(u0, u1);
  double b, e;  // [b, e) in samples
  if (outer) {
    b = floor_fast(u0) - 1;
    e = ceil_fast(u1) + 2;
  } else {
    const double shrink = margin * std::fabs(inv_d) + 1;
    b = ceil_fast(u0 + shrink);
    e = floor_fast(u1 - shrink) + 1;
  }
  if (b > double(ub)) ub = b < double(ue) ? int(b) : ue;
  if (e < double(ue)) ue = e > double(ub) ? int(e) : ub;
}

inline double inverse_step(float d) {
  return std::fabs(d) < 1e-9f ? 0.0 : 1.0 / double(d);
}

/// The samples of one run of a row that can reach the grid ([outer_b, outer_e)) and those that
/// certainly do ([inner_b, inner_e)), before the slab's own axis is considered.
struct RowClip {
  int outer_b, outer_e, inner_b, inner_e;
  double c0, inv_d;  ///< along the slab axis
};

/// Visits the samples u in [ub, ue) in order: step(u, checked) one at a time, with
/// checked = false inside [ib, ie), where every sample is certainly inside the grid and the slab;
/// there blocks(u, ie) may first take whole blocks of samples (SIMD) and return where it stopped.
template <typename Step, typename Blocks>
SONOSLICE_INLINE void walk_row(int ub, int ue, int ib, int ie, const Step& step,
                               const Blocks& blocks) {
  ib = ib < ub ? ub : ib;
  ie = ie > ue ? ue : ie;
  if (ib >= ie) ib = ie = ue;
  for (int u = ub; u < ib; ++u) step(u, std::true_type{});
  for (int u = blocks(ib, ie); u < ie; ++u) step(u, std::false_type{});
  for (int u = ie; u < ue; ++u) step(u, std::true_type{});
}

#if defined(SONOSLICE_COMPOUND_AVX2)
/// Eight samples as floats.
inline __m256 load8(const uint8_t* p) {
  return _mm256_cvtepi32_ps(
      _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p))));
}
inline __m256 load8(const uint16_t* p) {
  return _mm256_cvtepi32_ps(
      _mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p))));
}
inline __m256 load8(const int16_t* p) {
  return _mm256_cvtepi32_ps(
      _mm256_cvtepi16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p))));
}
inline __m256 load8(const float* p) {
  return _mm256_loadu_ps(p);
}
#endif

/// One row's samples [ub, ue) into the slab (voxels with index in [lo, hi) along Axis), nearest
/// voxel (the row's c0 carries the +0.5 of floor(c + 0.5)). Runs of samples in the same voxel
/// are gathered first.
template <typename T, Mode M, int Axis>
void splat_row_nearest(const AccumulatorView& g, const Slab& slab, const RowLine& L, const T* row,
                       const RowClip& clip, float threshold, int32_t frame) {
  int ub = clip.outer_b, ue = clip.outer_e, ib = clip.inner_b, ie = clip.inner_e;
  clip_axis(clip.c0, clip.inv_d, slab.lo, slab.hi, true, ub, ue);
  if (ub >= ue) return;
  clip_axis(clip.c0, clip.inv_d, slab.lo, slab.hi, false, ib, ie);
  int64_t current = -1;
  float value = empty_value(M), weight = 0.f;
  const auto take = [&](int64_t v, float s) {
    if (v != current) {
      if (current >= 0) apply<M>(g, current, value, weight, frame);
      current = v;
      value = empty_value(M);
      weight = 0.f;
    }
    gather<M>(value, weight, s, 1.f);
  };
  const auto step = [&](int u, auto checked) {
    const float s = sample_value(row, u);
    if (s < threshold) return;
    const float fu = float(u);
    const float tx = L.c0[0] + fu * L.dc[0], ty = L.c0[1] + fu * L.dc[1],
                tz = L.c0[2] + fu * L.dc[2];
    if (decltype(checked)::value && !inside_nearest(g, tx, ty, tz)) return;
    // t >= 0: truncation is floor.
    const int ix = int(tx), iy = int(ty), iz = int(tz);
    if (decltype(checked)::value) {
      const int ia = Axis == 0 ? ix : (Axis == 1 ? iy : iz);
      if (ia < slab.lo || ia >= slab.hi) return;
    }
    take(g.offset(ix, iy, iz), s);
  };
  walk_row(ub, ue, ib, ie, step, [&](int u, [[maybe_unused]] int end) {
#if defined(SONOSLICE_COMPOUND_AVX2)
    // Eight samples' voxels at a time (the same float operations as step(), so the same bits);
    // the runs are then gathered lane by lane.
    if (int64_t(g.nx) * g.ny * g.nz >= (int64_t(1) << 31)) return u;
    const __m256 c0x = _mm256_set1_ps(L.c0[0]), c0y = _mm256_set1_ps(L.c0[1]),
                 c0z = _mm256_set1_ps(L.c0[2]);
    const __m256 dx = _mm256_set1_ps(L.dc[0]), dy = _mm256_set1_ps(L.dc[1]),
                 dz = _mm256_set1_ps(L.dc[2]);
    const __m256i vnx = _mm256_set1_epi32(g.nx), vny = _mm256_set1_epi32(g.ny);
    alignas(32) int32_t offsets[8];
    alignas(32) float samples[8];
    for (; u + 8 <= end; u += 8) {
      const __m256 fu =
          _mm256_add_ps(_mm256_set1_ps(float(u)), _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7));
      const __m256i ix = _mm256_cvttps_epi32(_mm256_add_ps(c0x, _mm256_mul_ps(fu, dx)));
      const __m256i iy = _mm256_cvttps_epi32(_mm256_add_ps(c0y, _mm256_mul_ps(fu, dy)));
      const __m256i iz = _mm256_cvttps_epi32(_mm256_add_ps(c0z, _mm256_mul_ps(fu, dz)));
      const __m256i off = _mm256_add_epi32(
          _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(iz, vny), iy), vnx), ix);
      _mm256_store_si256(reinterpret_cast<__m256i*>(offsets), off);
      _mm256_store_ps(samples, load8(row + u));
      for (int l = 0; l < 8; ++l)
        if (!(samples[l] < threshold)) take(offsets[l], samples[l]);
    }
#endif
    return u;
  });
  if (current >= 0) apply<M>(g, current, value, weight, frame);
}

/// The eight corner sums (corner k: bit 0 +x, bit 1 +y, bit 2 +z) of a run of samples in one
/// cell. Every version computes corner_weight's (wx·wy)·wz and value += w·s without fusing, so
/// the generic and AVX2 kernels give the same bits.
template <Mode M, bool Summing = (M != Mode::Max)>
struct CornerSums {
  float value[8], weight[8];
  void reset() {
    for (int k = 0; k < 8; ++k) {
      value[k] = empty_value(M);
      weight[k] = 0.f;
    }
  }
  void add(float fx, float fy, float fz, float s) {
    if (!Summing) {
      const float f[3] = {fx, fy, fz};
      for (int k = 0; k < 8; ++k) gather<M>(value[k], weight[k], s, corner_weight(f, k));
      return;
    }
    // Laid out so that the compiler vectorises it.
    const float wx[2] = {1.f - fx, fx}, wy[2] = {1.f - fy, fy}, wz[2] = {1.f - fz, fz};
    const float wxy[4] = {wx[0] * wy[0], wx[1] * wy[0], wx[0] * wy[1], wx[1] * wy[1]};
    float w[8];
    for (int k = 0; k < 4; ++k) {
      w[k] = wxy[k] * wz[0];
      w[k + 4] = wxy[k] * wz[1];
    }
    for (int k = 0; k < 8; ++k) {
      value[k] += w[k] * s;
      weight[k] += w[k];
    }
  }
  void get(float* v, float* w) const {
    for (int k = 0; k < 8; ++k) {
      v[k] = value[k];
      w[k] = weight[k];
    }
  }
  /// Mean mode, every corner inside: adds the sums to the cell whose lower corner is `base`.
  void add_to(Accumulator* base, int64_t sy, int64_t sz) const {
    for (int k = 0; k < 8; ++k) {
      Accumulator& a = base[(k >> 2) * sz + ((k >> 1) & 1) * sy + (k & 1)];
      a.value += value[k];
      a.weight += weight[k];
    }
  }
};

#if defined(SONOSLICE_COMPOUND_AVX2)
/// The eight corners in one AVX register (mean and latest).
template <Mode M>
struct CornerSums<M, true> {
  __m256 value, weight;
  void reset() {
    value = _mm256_setzero_ps();
    weight = _mm256_setzero_ps();
  }
  void add(float fx, float fy, float fz, float s) {
    const __m256 one = _mm256_set1_ps(1.f);
    const __m256 x = _mm256_set1_ps(fx), y = _mm256_set1_ps(fy), z = _mm256_set1_ps(fz);
    // Lane k takes f where bit (0, 1, 2) of k is set, 1 - f elsewhere.
    const __m256 wx = _mm256_blend_ps(_mm256_sub_ps(one, x), x, 0xAA);
    const __m256 wy = _mm256_blend_ps(_mm256_sub_ps(one, y), y, 0xCC);
    const __m256 wz = _mm256_blend_ps(_mm256_sub_ps(one, z), z, 0xF0);
    const __m256 w = _mm256_mul_ps(_mm256_mul_ps(wx, wy), wz);
    value = _mm256_add_ps(value, _mm256_mul_ps(w, _mm256_set1_ps(s)));
    weight = _mm256_add_ps(weight, w);
  }
  void get(float* v, float* w) const {
    _mm256_storeu_ps(v, value);
    _mm256_storeu_ps(w, weight);
  }
  void add_to(Accumulator* base, int64_t sy, int64_t sz) const {
    // (value, weight) of corners 2j and 2j+1 are adjacent in memory: four 16-byte updates.
    const __m256 lo = _mm256_unpacklo_ps(value, weight);  // corners 0 1 | 4 5
    const __m256 hi = _mm256_unpackhi_ps(value, weight);  // corners 2 3 | 6 7
    float* p00 = &base[0].value;
    float* p10 = &base[sy].value;
    float* p01 = &base[sz].value;
    float* p11 = &base[sy + sz].value;
    _mm_storeu_ps(p00, _mm_add_ps(_mm_loadu_ps(p00), _mm256_castps256_ps128(lo)));
    _mm_storeu_ps(p10, _mm_add_ps(_mm_loadu_ps(p10), _mm256_castps256_ps128(hi)));
    _mm_storeu_ps(p01, _mm_add_ps(_mm_loadu_ps(p01), _mm256_extractf128_ps(lo, 1)));
    _mm_storeu_ps(p11, _mm_add_ps(_mm_loadu_ps(p11), _mm256_extractf128_ps(hi, 1)));
  }
};
#endif

/// One row's samples [ub, ue) into the slab, trilinear weights. Runs of samples in the same
/// cell are gathered per corner first (corner k: bit 0 +x, bit 1 +y, bit 2 +z).
template <typename T, Mode M, int Axis>
void splat_row_linear(const AccumulatorView& g, const Slab& slab, const RowLine& L, const T* row,
                      const RowClip& clip, float threshold, int32_t frame) {
  // A cell touches the slab when its coordinate along Axis is in (lo - 1, hi).
  int ub = clip.outer_b, ue = clip.outer_e, ib = clip.inner_b, ie = clip.inner_e;
  clip_axis(clip.c0, clip.inv_d, slab.lo - 1.0, slab.hi, true, ub, ue);
  if (ub >= ue) return;
  clip_axis(clip.c0, clip.inv_d, slab.lo - 1.0, slab.hi, false, ib, ie);
  int cell[3] = {std::numeric_limits<int>::min(), 0, 0};
  CornerSums<M> sums;
  sums.reset();
  const int64_t sy = g.nx, sz = int64_t(g.nx) * g.ny;
  const auto flush = [&] {
    if (cell[0] == std::numeric_limits<int>::min()) return;
    const int ca = Axis == 0 ? cell[0] : (Axis == 1 ? cell[1] : cell[2]);
    if (M == Mode::Mean && cell[0] >= 0 && cell[1] >= 0 && cell[2] >= 0 && cell[0] + 1 < g.nx &&
        cell[1] + 1 < g.ny && cell[2] + 1 < g.nz && ca >= slab.lo && ca + 1 < slab.hi) {
      // All eight corners are ours (zero weights add nothing).
      sums.add_to(g.cells + g.offset(cell[0], cell[1], cell[2]), sy, sz);
      return;
    }
    float value[8], weight[8];
    sums.get(value, weight);
    for (int k = 0; k < 8; ++k) {
      const int x = cell[0] + (k & 1), y = cell[1] + ((k >> 1) & 1), z = cell[2] + (k >> 2);
      const int ia = Axis == 0 ? x : (Axis == 1 ? y : z);
      if (!(weight[k] > 0.f) || !g.contains(x, y, z) || ia < slab.lo || ia >= slab.hi) continue;
      apply<M>(g, g.offset(x, y, z), value[k], weight[k], frame);
    }
  };
  const auto take = [&](int ix, int iy, int iz, float fx, float fy, float fz, float s) {
    if (ix != cell[0] || iy != cell[1] || iz != cell[2]) {
      flush();
      cell[0] = ix;
      cell[1] = iy;
      cell[2] = iz;
      sums.reset();
    }
    sums.add(fx, fy, fz, s);
  };
  const auto step = [&](int u, auto checked) {
    const float s = sample_value(row, u);
    if (s < threshold) return;
    const float fu = float(u);
    const float cx = L.c0[0] + fu * L.dc[0], cy = L.c0[1] + fu * L.dc[1],
                cz = L.c0[2] + fu * L.dc[2];
    if (decltype(checked)::value && !inside_linear(g, cx, cy, cz)) return;
    const int ix = floor_to_int(cx), iy = floor_to_int(cy), iz = floor_to_int(cz);
    if (decltype(checked)::value) {
      const int ia = Axis == 0 ? ix : (Axis == 1 ? iy : iz);
      if (ia + 1 < slab.lo || ia >= slab.hi) return;
    }
    take(ix, iy, iz, cx - float(ix), cy - float(iy), cz - float(iz), s);
  };
  walk_row(ub, ue, ib, ie, step, [&](int u, [[maybe_unused]] int end) {
#if defined(SONOSLICE_COMPOUND_AVX2)
    // Eight samples' cells and fractions at a time (step()'s float operations, so its bits).
    const __m256 c0[3] = {_mm256_set1_ps(L.c0[0]), _mm256_set1_ps(L.c0[1]),
                          _mm256_set1_ps(L.c0[2])};
    const __m256 d[3] = {_mm256_set1_ps(L.dc[0]), _mm256_set1_ps(L.dc[1]), _mm256_set1_ps(L.dc[2])};
    alignas(32) int32_t idx[3][8];
    alignas(32) float frac[3][8], samples[8];
    for (; u + 8 <= end; u += 8) {
      const __m256 fu =
          _mm256_add_ps(_mm256_set1_ps(float(u)), _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7));
      for (int a = 0; a < 3; ++a) {
        const __m256 c = _mm256_add_ps(c0[a], _mm256_mul_ps(fu, d[a]));
        // floor_to_int: truncate, then one less where truncation went up.
        __m256i i = _mm256_cvttps_epi32(c);
        const __m256 up = _mm256_cmp_ps(c, _mm256_cvtepi32_ps(i), _CMP_LT_OQ);
        i = _mm256_add_epi32(i, _mm256_castps_si256(up));  // mask lanes are -1
        _mm256_store_si256(reinterpret_cast<__m256i*>(idx[a]), i);
        _mm256_store_ps(frac[a], _mm256_sub_ps(c, _mm256_cvtepi32_ps(i)));
      }
      _mm256_store_ps(samples, load8(row + u));
      for (int l = 0; l < 8; ++l)
        if (!(samples[l] < threshold))
          take(idx[0][l], idx[1][l], idx[2][l], frac[0][l], frac[1][l], frac[2][l], samples[l]);
    }
#endif
    return u;
  });
  flush();
}

template <typename T, Mode M, bool Linear, int Axis>
void compound_slab(const AccumulatorView& g, const FrameBatch& b, const RowClip* clips,
                   const Slab& slab) {
  const T* samples = static_cast<const T*>(b.samples);
  for (int f = 0; f < b.frames; ++f)
    for (int r = 0; r < b.rows; ++r) {
      const int64_t fr = int64_t(f) * b.rows + r;
      const RowLine& line = b.lines[fr];
      const T* row = samples + fr * b.width;
      for (int k = 0; k < kMaxSpans; ++k) {
        const RowClip& clip = clips[fr * kMaxSpans + k];
        if (clip.outer_b >= clip.outer_e) continue;
        if (Linear)
          splat_row_linear<T, M, Axis>(g, slab, line, row, clip, b.rejection_threshold,
                                       b.first_frame_id + f);
        else
          splat_row_nearest<T, M, Axis>(g, slab, line, row, clip, b.rejection_threshold,
                                        b.first_frame_id + f);
      }
    }
}

/// Each row's runs clipped to the grid on the axes other than the slab axis (done once per
/// batch rather than once per slab).
inline void clip_rows(const AccumulatorView& g, const FrameBatch& b, bool linear, int axis,
                      RowClip* clips) {
  const double n[3] = {double(g.nx), double(g.ny), double(g.nz)};
  const double lo = linear ? -1.0 : 0.0;
  backend::parallel_for(b.frames, [&](int64_t f) {
    for (int r = 0; r < b.rows; ++r) {
      const int64_t fr = f * b.rows + r;
      const RowLine& line = b.lines[fr];
      double inv[3];
      for (int a = 0; a < 3; ++a) inv[a] = inverse_step(line.dc[a]);
      for (int k = 0; k < kMaxSpans; ++k) {
        RowClip& c = clips[fr * kMaxSpans + k];
        c.outer_b = c.inner_b = b.spans[r].begin[k];
        c.outer_e = c.inner_e = b.spans[r].end[k];
        c.c0 = line.c0[axis];
        c.inv_d = inv[axis];
        for (int a = 0; a < 3; ++a) {
          if (a == axis) continue;
          clip_axis(line.c0[a], inv[a], lo, n[a], true, c.outer_b, c.outer_e);
          clip_axis(line.c0[a], inv[a], lo, n[a], false, c.inner_b, c.inner_e);
        }
      }
    }
  });
}

/// The CPU driver: `slabs` tasks along `axis` over [lo, hi), each walking the whole batch.
template <typename T, Mode M, bool Linear>
void compound_batch_cpu(const AccumulatorView& g, const FrameBatch& b, int axis, int lo, int hi,
                        int slabs, RowClip* clips) {
  clip_rows(g, b, Linear, axis, clips);
  backend::parallel_for(slabs, [&](int64_t s) {
    Slab slab;
    slab.lo = int(lo + (int64_t(hi) - lo) * s / slabs);
    slab.hi = int(lo + (int64_t(hi) - lo) * (s + 1) / slabs);
    if (slab.lo >= slab.hi) return;
    if (axis == 0)
      compound_slab<T, M, Linear, 0>(g, b, clips, slab);
    else if (axis == 1)
      compound_slab<T, M, Linear, 1>(g, b, clips, slab);
    else
      compound_slab<T, M, Linear, 2>(g, b, clips, slab);
  });
}

#endif  // !__CUDACC__

#if defined(__CUDACC__)
__device__ __forceinline__ void atomic_max_float(float* address, float value) {
  // Floats order like sign-magnitude integers: positive values as ints, negative ones reversed.
  if (value >= 0.f)
    atomicMax(reinterpret_cast<int*>(address), __float_as_int(value));
  else
    atomicMin(reinterpret_cast<unsigned int*>(address), __float_as_uint(value));
}

/// Writes one sample's share into voxel i (CUDA: any thread may touch any voxel).
template <Mode M>
__device__ __forceinline__ void apply_atomic(const AccumulatorView& g, int64_t i, float sample,
                                             float w) {
  Accumulator& a = g.cells[i];
  if (M == Mode::Max) {
    if (w < kMaxModeMinimumWeight) return;
    atomic_max_float(&a.value, sample);
  } else {
    atomicAdd(&a.value, w * sample);
  }
  atomicAdd(&a.weight, w);
}

/// One thread per sample: row() finds the row's line and values, pixel() splats one sample.
/// `reset_latest` is the first of latest mode's two passes per frame: it clears the voxels this
/// frame will write (all threads write the same values), the second pass accumulates.
template <typename T, Mode M, bool Linear>
struct SplatSamples {
  AccumulatorView g;
  FrameBatch b;
  int64_t first_row;  // rows first_row, first_row + 1, ... of the batch (all frames' rows)
  bool reset_latest;

  struct Row {
    const RowLine* line;
    const T* samples;
    const RowSpans* spans;
    int32_t frame_id;
  };
  __device__ Row row(int64_t r) const {
    const int64_t fr = first_row + r;
    return Row{b.lines + fr, static_cast<const T*>(b.samples) + fr * b.width, b.spans + fr % b.rows,
               b.first_frame_id + int32_t(fr / b.rows)};
  }
  __device__ void touch(const Row& row, int64_t i, float s, float w) const {
    if (reset_latest) {
      const int32_t id = row.frame_id;
      if (g.stamp[i] != id) {
        g.stamp[i] = id;
        g.cells[i].value = 0.f;
        g.cells[i].weight = 0.f;
      }
    } else {
      apply_atomic<M>(g, i, s, w);
    }
  }
  __device__ void pixel(const Row& row, int u) const {
    const RowSpans& sp = *row.spans;
    bool inside = false;
    for (int k = 0; k < kMaxSpans; ++k) inside = inside || (u >= sp.begin[k] && u < sp.end[k]);
    if (!inside) return;
    const float s = sample_value(row.samples, u);
    if (s < b.rejection_threshold) return;
    const RowLine& L = *row.line;
    const float fu = float(u);
    // Unfused, as on the CPU: the same coordinates, so the same voxels.
    const float cx = backend::add_product(L.c0[0], fu, L.dc[0]),
                cy = backend::add_product(L.c0[1], fu, L.dc[1]),
                cz = backend::add_product(L.c0[2], fu, L.dc[2]);
    int i[3];
    if (!Linear) {
      if (nearest_voxel(g, cx, cy, cz, i)) touch(row, g.offset(i[0], i[1], i[2]), s, 1.f);
      return;
    }
    float f[3];
    if (!linear_cell(g, cx, cy, cz, i, f)) return;
    for (int k = 0; k < 8; ++k) {
      const int x = i[0] + (k & 1), y = i[1] + ((k >> 1) & 1), z = i[2] + (k >> 2);
      if (!g.contains(x, y, z)) continue;
      const float w = corner_weight(f, k);
      if (w > 0.f) touch(row, g.offset(x, y, z), s, w);
    }
  }
};

/// The CUDA driver. Mean and max do not depend on the order of the samples (to float rounding,
/// for the mean): one launch for the whole batch. Latest goes frame by frame, each frame first
/// clearing the voxels it reaches, then accumulating into them.
template <typename T, Mode M, bool Linear>
void compound_batch_cuda(const AccumulatorView& g, const FrameBatch& b, void* stream) {
  using Kernel = SplatSamples<T, M, Linear>;
  if constexpr (M != Mode::Latest) {
    backend::parallel_for_rows(int64_t(b.frames) * b.rows, b.width, Kernel{g, b, 0, false}, stream);
  } else {
    for (int f = 0; f < b.frames; ++f) {
      const int64_t first = int64_t(f) * b.rows;
      backend::parallel_for_rows(b.rows, b.width, Kernel{g, b, first, true}, stream);
      backend::parallel_for_rows(b.rows, b.width, Kernel{g, b, first, false}, stream);
    }
  }
}
#endif  // __CUDACC__

/// Calls f(T{}) for the sample types the kernels are built for.
template <typename F>
void visit_sample_type(PixelType type, F&& f) {
  switch (type) {
    case PixelType::UInt8:
      return f(uint8_t{});
    case PixelType::UInt16:
      return f(uint16_t{});
    case PixelType::Int16:
      return f(int16_t{});
    case PixelType::Float32:
      return f(float{});
    case PixelType::Int8:
    case PixelType::UInt32:
    case PixelType::Int32:
    case PixelType::Float64:
      break;  // the Compounder converts these to float32 before they reach a kernel
  }
  throw Error(std::string("compounding kernels: no kernel for ") + to_string(type) + " samples");
}

template <typename F>
void visit_mode(Mode mode, bool linear, F&& f) {
  const auto with_interp = [&](auto mode_tag) {
    if (linear)
      f(mode_tag, std::true_type{});
    else
      f(mode_tag, std::false_type{});
  };
  switch (mode) {
    case Mode::Mean:
      return with_interp(std::integral_constant<Mode, Mode::Mean>{});
    case Mode::Max:
      return with_interp(std::integral_constant<Mode, Mode::Max>{});
    case Mode::Latest:
      return with_interp(std::integral_constant<Mode, Mode::Latest>{});
  }
}

#if !defined(__CUDACC__)
/// The CPU entry point every CPU instruction set's translation unit exposes.
inline void dispatch_compound_cpu(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                                  bool linear, int axis, int lo, int hi, int slabs) {
  std::vector<RowClip> clips(size_t(batch.frames) * batch.rows * kMaxSpans);
  visit_sample_type(batch.type, [&](auto sample_zero) {
    using T = decltype(sample_zero);
    visit_mode(mode, linear, [&](auto mode_tag, auto linear_tag) {
      compound_batch_cpu<T, decltype(mode_tag)::value, decltype(linear_tag)::value>(
          grid, batch, axis, lo, hi, slabs, clips.data());
    });
  });
}
#endif

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace compound_impl
}  // namespace sonoslice
