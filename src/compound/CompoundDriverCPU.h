#pragma once
/// @file The CPU driver of the compounding kernels: owner computes, over the per-sample math of
/// CompoundImpl.h. CompoundCPU.cpp (generic x86-64) and CompoundCPUAvx2.cpp (AVX2 + FMA, its
/// SIMD through backend/Avx2Lanes.h) include this file; both give the same bits.
///
/// The batch's footprint is cut into slabs along one axis; a task owns a slab and walks every row
/// of every frame of the batch, in order, writing only its own voxels. Each voxel therefore
/// receives its samples in one fixed order whatever the number of threads, and the result is the
/// same bit for bit. Consecutive samples of a row that fall in the same voxel (nearest) or cell
/// (linear) are summed in registers first and written once: ultrasound pixels are several times
/// smaller than the voxels they go into.
#if defined(__CUDACC__)
#error "CompoundDriverCPU.h is the CPU driver; CUDA builds use CompoundDriverCUDA.cuh"
#endif
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

#include "../backend/ParallelFor.h"
#include "CompoundImpl.h"
#include "CompoundTypes.h"
#include "sonoslice/backend/HostDevice.h"
#if defined(__AVX2__) && defined(__FMA__)
#include "../backend/Avx2Lanes.h"
#define SONOSLICE_COMPOUND_AVX2 1
#endif

namespace sonoslice {
namespace compound_impl {
inline namespace SONOSLICE_KERNEL_ISA {

/// Writes a group into voxel i (the calling task owns the voxel).
template <Mode M>
inline void apply(const AccumulatorView& g, int64_t i, float value, float weight, int32_t frame) {
  if (M == Mode::Latest) restart_for_frame(g, i, frame);
  Accumulator& a = g.cells[i];
  a.value = merged<M>(a.value, value);
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

/// The run of consecutive samples of a row that fall in one voxel (nearest splats), gathered
/// before it is written once. Integer samples are summed exactly in integers and the sum is
/// rounded to float once, so the result does not depend on how a run is cut into pieces (SIMD
/// chunks, scalar head and tail); float samples are summed in row order.
template <typename T, Mode M>
struct NearestRun {
  using Sum = std::conditional_t<M != Mode::Max && std::is_integral<T>::value, int64_t, float>;
  int64_t voxel = -1;
  Sum value = Sum(empty_value(M));
  int32_t count = 0;

  void flush(const AccumulatorView& g, int32_t frame) const {
    if (voxel >= 0) apply<M>(g, voxel, float(value), float(count), frame);
  }
  void enter(const AccumulatorView& g, int64_t v, int32_t frame) {
    if (v == voxel) return;
    flush(g, frame);
    voxel = v;
    value = Sum(empty_value(M));
    count = 0;
  }
  void add_sample(const AccumulatorView& g, int64_t v, T s, int32_t frame) {
    enter(g, v, frame);
    if (M == Mode::Max) {
      const float f = float(s);
      value = f > value ? f : value;
    } else {
      value += Sum(s);
    }
    ++count;
  }
  /// n kept samples summing to `sum` (mean and latest, integer samples).
  void add_run(const AccumulatorView& g, int64_t v, int64_t sum, int32_t n, int32_t frame) {
    enter(g, v, frame);
    value += Sum(sum);
    count += n;
  }
};

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
  NearestRun<T, M> run;
  const auto step = [&](int u, auto checked) {
    const T s = row[u];
    if (rejected(float(s), threshold)) return;
    // Three scalars, not an array: GCC would pack an array loop into part-filled vectors.
    const float fu = float(u);
    const float tx = sample_coordinate(L.c0[0], fu, L.dc[0]),
                ty = sample_coordinate(L.c0[1], fu, L.dc[1]),
                tz = sample_coordinate(L.c0[2], fu, L.dc[2]);
    if (decltype(checked)::value && !inside_nearest(g, tx, ty, tz)) return;
    // t >= 0: truncation is floor.
    const int ix = int(tx), iy = int(ty), iz = int(tz);
    if (decltype(checked)::value) {
      const int ia = Axis == 0 ? ix : (Axis == 1 ? iy : iz);
      if (ia < slab.lo || ia >= slab.hi) return;
    }
    run.add_sample(g, g.offset(ix, iy, iz), s, frame);
  };
  walk_row(ub, ue, ib, ie, step, [&](int u, [[maybe_unused]] int end) {
#if defined(SONOSLICE_COMPOUND_AVX2)
    // Eight samples' voxels at a time (the same float operations as step(), so the same
    // voxels). Offsets are int32 lanes.
    if (int64_t(g.nx) * g.ny * g.nz >= (int64_t(1) << 31)) return u;
    using backend::Vec8f;
    using backend::Vec8i;
    const Vec8f c0x(L.c0[0]), c0y(L.c0[1]), c0z(L.c0[2]);
    const Vec8f dx(L.dc[0]), dy(L.dc[1]), dz(L.dc[2]);
    const int32_t sy = g.nx, sz = g.nx * g.ny;
    const auto voxels = [&](int at) {
      const Vec8f fu = Vec8f::iota(float(at));
      // In the inner run t >= 0: truncation is floor.
      return backend::offsets(backend::truncate_to_int(sample_coordinate(c0x, fu, dx)),
                              backend::truncate_to_int(sample_coordinate(c0y, fu, dy)),
                              backend::truncate_to_int(sample_coordinate(c0z, fu, dz)), sy, sz);
    };
    if constexpr (std::is_integral<T>::value && M != Mode::Max) {
      // Sums without a per-sample dependency chain: in chunks of up to 64 samples, the lanes
      // where the voxel changes mark where runs start, and a run's sum and count are the
      // difference of two running sums.
      constexpr int kChunk = 64;
      const bool keep_all = !(float(std::numeric_limits<T>::lowest()) < threshold);
      alignas(32) int32_t offsets[kChunk];
      int32_t sums[kChunk + 1], counts[kChunk + 1];
      sums[0] = counts[0] = 0;
      while (u + 8 <= end) {
        const int n = (end - u) < kChunk ? (end - u) & ~7 : kChunk;
        uint64_t starts = 1;
        int32_t sum = 0, kept = 0, before = 0;
        for (int j = 0; j < n; j += 8) {
          const Vec8i o = voxels(u + j);
          o.store(offsets + j);
          starts |= uint64_t(backend::lanes_changed(o, before)) << j;
          before = backend::last_lane(o);
          Vec8i s = backend::load_as_int(row + u + j);
          if (!keep_all) {
            const Vec8f sf = backend::to_float(s);
            const Vec8i c = backend::inclusive_sums(backend::ones_at_least(sf, threshold), kept);
            c.store(counts + j + 1);
            kept = backend::last_lane(c);
            s = backend::keep_at_least(s, sf, threshold);
          }
          const Vec8i p = backend::inclusive_sums(s, sum);
          p.store(sums + j + 1);
          sum = backend::last_lane(p);
        }
        // The runs' accumulators are fetched together rather than one miss after another.
        for (uint64_t m = starts; m; m &= m - 1)
          __builtin_prefetch(g.cells + offsets[__builtin_ctzll(m)], 1);
        while (starts) {
          const int b = __builtin_ctzll(starts);
          starts &= starts - 1;
          const int e = starts ? __builtin_ctzll(starts) : n;
          const int32_t k = keep_all ? e - b : counts[e] - counts[b];
          if (k > 0) run.add_run(g, offsets[b], sums[e] - sums[b], k, frame);
        }
        u += n;
      }
      return u;
    }
    alignas(32) int32_t offsets[8];
    for (; u + 8 <= end; u += 8) {
      voxels(u).store(offsets);
      for (int l = 0; l < 8; ++l)
        if (!rejected(float(row[u + l]), threshold))
          run.add_sample(g, offsets[l], row[u + l], frame);
    }
#endif
    return u;
  });
  run.flush(g, frame);
}

/// The eight corner sums (corner k: bit 0 +x, bit 1 +y, bit 2 +z) of a run of samples in one
/// cell. Every version computes the weights with cell_weight and value += w·s without fusing,
/// so the generic and AVX2 kernels give the same bits.
template <Mode M, bool Summing = (M != Mode::Max)>
struct CornerSums {
  float value[8], weight[8];
  SONOSLICE_INLINE void reset() {
    for (int k = 0; k < 8; ++k) {
      value[k] = empty_value(M);
      weight[k] = 0.f;
    }
  }
  SONOSLICE_INLINE void add(float fx, float fy, float fz, float s) {
    if (!Summing) {
      const float f[3] = {fx, fy, fz};
      for (int k = 0; k < 8; ++k) gather<M>(value[k], weight[k], s, corner_weight(f, k));
      return;
    }
    // cell_weight's (wx·wy)·wz, laid out so that the compiler vectorises it (a loop calling
    // cell_weight per corner made the generic linear kernel about 25% slower with GCC 12).
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
  SONOSLICE_INLINE void get(float* v, float* w) const {
    for (int k = 0; k < 8; ++k) {
      v[k] = value[k];
      w[k] = weight[k];
    }
  }
  /// Mean and latest modes, every corner inside: adds the sums to the cell whose lower corner is
  /// `base` (a corner of weight 0 adds +0, which changes no accumulator: they never hold -0).
  SONOSLICE_INLINE void add_to(Accumulator* base, int64_t sy, int64_t sz) const {
    for (int k = 0; k < 8; ++k) {
      Accumulator& a = base[(k >> 2) * sz + ((k >> 1) & 1) * sy + (k & 1)];
      a.value += value[k];
      a.weight += weight[k];
    }
  }
  /// Latest mode, every corner inside: add_to, each corner this frame reaches first restarted
  /// (restart_for_frame; `stamp`: the stamp of the cell's lower corner).
  SONOSLICE_INLINE void restart_add_to(Accumulator* base, int32_t* stamp, int64_t sy, int64_t sz,
                                       int32_t frame) const {
    for (int k = 0; k < 8; ++k) {
      const int64_t o = (k >> 2) * sz + ((k >> 1) & 1) * sy + (k & 1);
      if (weight[k] > 0.f && stamp[o] != frame) {
        stamp[o] = frame;
        base[o].value = 0.f;
        base[o].weight = 0.f;
      }
    }
    add_to(base, sy, sz);
  }
  /// Max mode, every corner inside: merges the maxima into that cell (a corner of weight 0 holds
  /// -inf and adds weight 0: no change).
  SONOSLICE_INLINE void merge_to(Accumulator* base, int64_t sy, int64_t sz) const {
    for (int k = 0; k < 8; ++k) {
      Accumulator& a = base[(k >> 2) * sz + ((k >> 1) & 1) * sy + (k & 1)];
      a.value = merged<M>(a.value, value[k]);
      a.weight += weight[k];
    }
  }
};

#if defined(SONOSLICE_COMPOUND_AVX2)
/// The eight corners' weights of a sample with fractions (x, y, z) (every lane the same):
/// corner_weight's products, lane k for corner k.
SONOSLICE_INLINE backend::Vec8f corner_weights(backend::Vec8f x, backend::Vec8f y,
                                               backend::Vec8f z) {
  using backend::blend;
  const backend::Vec8f one(1.f);
  // Lane k takes f where bit (0, 1, 2) of k is set, 1 - f elsewhere.
  return cell_weight(blend<0xAA>(one - x, x), blend<0xCC>(one - y, y), blend<0xF0>(one - z, z));
}

/// The eight corners' running values and weights, one AVX register each (lane k: corner k).
struct CornerLanes {
  backend::Vec8f value, weight;
  SONOSLICE_INLINE void get(float* v, float* w) const {
    value.store(v);
    weight.store(w);
  }
};

/// The eight corners' sums (mean and latest).
template <Mode M>
struct CornerSums<M, true> : CornerLanes {
  SONOSLICE_INLINE void reset() {
    value = backend::Vec8f(0.f);
    weight = backend::Vec8f(0.f);
  }
  SONOSLICE_INLINE void add(float fx, float fy, float fz, float s) {
    using backend::Vec8f;
    const Vec8f w = corner_weights(Vec8f(fx), Vec8f(fy), Vec8f(fz));
    value = value + w * Vec8f(s);
    weight = weight + w;
  }
  SONOSLICE_INLINE void add_to(Accumulator* base, int64_t sy, int64_t sz) const {
    // (value, weight) of corners 2j and 2j+1 are adjacent in memory: four 16-byte updates.
    backend::add_interleaved(value, weight, &base[0].value, &base[sy].value, &base[sz].value,
                             &base[sy + sz].value);
  }
  SONOSLICE_INLINE void restart_add_to(Accumulator* base, int32_t* stamp, int64_t sy, int64_t sz,
                                       int32_t frame) const {
    backend::restart_add_interleaved(value, weight, frame, &base[0].value, &base[sy].value,
                                     &base[sz].value, &base[sy + sz].value, stamp, stamp + sy,
                                     stamp + sz, stamp + sy + sz);
  }
};

/// The eight corners' maxima and weights (max mode): gather<Max> per lane.
template <>
struct CornerSums<Mode::Max, false> : CornerLanes {
  SONOSLICE_INLINE void reset() {
    value = backend::Vec8f(empty_value(Mode::Max));
    weight = backend::Vec8f(0.f);
  }
  /// Lanes whose weight w counts for the maximum take max(s, value) and add w.
  SONOSLICE_INLINE void gather(backend::Vec8f w, float s) {
    using backend::Vec8f;
    const Vec8f counted = backend::lanes_at_least(w, kMaxModeMinimumWeight);
    value = backend::select(counted, backend::maximum(Vec8f(s), value), value);
    weight = weight + (w & counted);
  }
  SONOSLICE_INLINE void add(float fx, float fy, float fz, float s) {
    using backend::Vec8f;
    gather(corner_weights(Vec8f(fx), Vec8f(fy), Vec8f(fz)), s);
  }
  SONOSLICE_INLINE void merge_to(Accumulator* base, int64_t sy, int64_t sz) const {
    backend::max_add_interleaved(value, weight, &base[0].value, &base[sy].value, &base[sz].value,
                                 &base[sy + sz].value);
  }
};
#endif

#if defined(SONOSLICE_COMPOUND_AVX2)
/// The inner samples [u, end) of a row, trilinear weights, mean and latest (summing) modes, every
/// sample kept: the AVX2 kernel without a branch per sample. Per chunk of up to 64 samples the
/// lanes first give each sample's cell, whether it continues the run of the sample before it
/// (same cell) and its run's number; then one pass over the samples adds each sample's eight
/// corner weights to its run's sums, cleared where a run starts (an AND with the mask, not a
/// branch: runs are a few samples long, so a branch on them mispredicts often), and stores the
/// sums in the run's slot. The same additions in the same order as CornerSums::add, hence the
/// same bits. `cell`, `sums` and `flush` are splat_row_linear's open run: it is continued on
/// entry, every run the chunk completes is flushed in order, and the run still open on return is
/// left there. Returns where the samples stop (a multiple of 8 from u).
template <typename T, Mode M, typename Flush>
SONOSLICE_INLINE int splat_runs_linear(const AccumulatorView& g, const RowLine& L, const T* row,
                                       int u, int end, int* cell, CornerSums<M>& sums,
                                       const Flush& flush) {
  using backend::Vec8f;
  using backend::Vec8i;
  constexpr int kChunk = 64;
  const Vec8f c0[3] = {Vec8f(L.c0[0]), Vec8f(L.c0[1]), Vec8f(L.c0[2])};
  const Vec8f d[3] = {Vec8f(L.dc[0]), Vec8f(L.dc[1]), Vec8f(L.dc[2])};
  const Vec8f one(1.f);
  alignas(32) int32_t idx[3][kChunk], run_of[kChunk];
  // Per sample: the four (x, y) corner weights (wx·wy for corners 0-3), the two z weights, the
  // sample, and the mask that keeps its run's sums (all ones) or clears them (a run starts).
  alignas(32) float wxy[kChunk][4], wz[2][kChunk], samples[kChunk], continues[kChunk];
  alignas(32) float run_value[kChunk + 1][8], run_weight[kChunk + 1][8];
  // In the inner run a cell's lower corner is in [-1, n - 1] on each axis, so the key
  // (x + 1) + kx·(y + 1) + kxy·(z + 1) names cells one to one (splat_row_linear checks that
  // it fits in int32).
  const int32_t kx = g.nx + 2, kxy = kx * (g.ny + 2);
  const int64_t sy = g.nx, sz = int64_t(g.nx) * g.ny;
  // The open run's cell, or -1 (no inner cell's key) when there is none or it lies outside.
  int32_t before = -1;
  if (cell[0] >= -1 && cell[1] >= -1 && cell[2] >= -1 && cell[0] <= g.nx && cell[1] <= g.ny &&
      cell[2] <= g.nz)
    before = (cell[0] + 1) + kx * (cell[1] + 1) + kxy * (cell[2] + 1);
  Vec8f value = sums.value, weight = sums.weight;
  while (u + 8 <= end) {
    const int n = (end - u) < kChunk ? (end - u) & ~7 : kChunk;
    int32_t runs = 0;     // run 0: the run open when the chunk starts
    uint64_t starts = 0;  // bit l: sample l starts a run
    for (int j = 0; j < n; j += 8) {
      const Vec8f fu = Vec8f::iota(float(u + j));
      Vec8i i[3];
      Vec8f f[3];
      for (int a = 0; a < 3; ++a) {
        const Vec8f c = sample_coordinate(c0[a], fu, d[a]);
        i[a] = backend::floor_to_int(c);
        i[a].store(idx[a] + j);
        f[a] = c - backend::to_float(i[a]);
      }
      // cell_weight's (wx·wy)·wz: the products wx·wy here, ·wz per sample below.
      const Vec8f wx0 = one - f[0], wy0 = one - f[1];
      backend::store_quads(wx0 * wy0, f[0] * wy0, wx0 * f[1], f[0] * f[1], wxy[j]);
      (one - f[2]).store(wz[0] + j);
      f[2].store(wz[1] + j);
      backend::load_as_float(row + u + j).store(samples + j);
      const Vec8i key = backend::offsets(i[0] + 1, i[1] + 1, i[2] + 1, kx, kxy);
      const Vec8i same = backend::lanes_same_as_before(key, before);
      backend::store_mask(same, continues + j);
      starts |= uint64_t(backend::lanes_changed(key, before)) << j;
      // The cells' accumulators are fetched while the samples are summed: cells of lanes 0
      // and 4 (runs are a few samples long, and a cache line holds eight voxels along x).
      for (int l = 0; l < 8; l += 4) {
        const int x = idx[0][j + l], y = idx[1][j + l], z = idx[2][j + l];
        if (x < 0 || y < 0 || z < 0) continue;
        const Accumulator* base = g.cells + g.offset(x, y, z);
        __builtin_prefetch(base, 1);
        __builtin_prefetch(base + sy, 1);
        __builtin_prefetch(base + sz, 1);
        __builtin_prefetch(base + sy + sz, 1);
        if constexpr (M == Mode::Latest) {  // and the voxels' frame stamps
          const int32_t* stamp = g.stamp + g.offset(x, y, z);
          __builtin_prefetch(stamp, 1);
          __builtin_prefetch(stamp + sy, 1);
          __builtin_prefetch(stamp + sz, 1);
          __builtin_prefetch(stamp + sy + sz, 1);
        }
      }
      // same is -1 or 0, so same + 1 counts the runs that start.
      const Vec8i r = backend::inclusive_sums(same + 1, runs);
      r.store(run_of + j);
      runs = backend::last_lane(r);
      before = backend::last_lane(key);
    }
    value.store(run_value[0]);
    weight.store(run_weight[0]);
    for (int l = 0; l < n; ++l) {
      const Vec8f w = backend::broadcast_quad(wxy[l]) * backend::halves(wz[0] + l, wz[1] + l);
      if constexpr (M == Mode::Max) {  // CornerSums<Max>::gather, restarted where a run starts
        value = backend::keep_or(value, continues + l, empty_value(M));
        weight = backend::keep_if(weight, continues + l);
        const Vec8f counted = backend::lanes_at_least(w, kMaxModeMinimumWeight);
        value = backend::select(counted, backend::maximum(Vec8f(samples[l]), value), value);
        weight = weight + (w & counted);
      } else {
        value = backend::keep_if(value, continues + l) + w * Vec8f(samples[l]);
        weight = backend::keep_if(weight, continues + l) + w;
      }
      value.store(run_value[run_of[l]]);
      weight.store(run_weight[run_of[l]]);
    }
    // Runs 0 .. runs - 1 are complete (run 0 may be empty: flush skips a cell it never had);
    // bit r - 1 of `starts`, counted from the lowest, is run r's first sample.
    for (int r = 0; r < runs; ++r) {
      if (r > 0) {
        const int l = __builtin_ctzll(starts);
        starts &= starts - 1;
        cell[0] = idx[0][l];
        cell[1] = idx[1][l];
        cell[2] = idx[2][l];
      }
      sums.value = _mm256_load_ps(run_value[r]);
      sums.weight = _mm256_load_ps(run_weight[r]);
      flush();
    }
    if (runs > 0) {
      const int l = __builtin_ctzll(starts);
      cell[0] = idx[0][l];
      cell[1] = idx[1][l];
      cell[2] = idx[2][l];
    }
    u += n;
  }
  sums.value = value;
  sums.weight = weight;
  return u;
}
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
    float value[8], weight[8];
    if (cell[0] >= 0 && cell[1] >= 0 && cell[2] >= 0 && cell[0] + 1 < g.nx && cell[1] + 1 < g.ny &&
        cell[2] + 1 < g.nz && ca >= slab.lo && ca + 1 < slab.hi) {
      // All eight corners are ours (zero weights change nothing).
      Accumulator* base = g.cells + g.offset(cell[0], cell[1], cell[2]);
      if constexpr (M == Mode::Max) {
        sums.merge_to(base, sy, sz);
      } else {
        if constexpr (M == Mode::Latest)  // this frame's first write restarts a voxel
          sums.restart_add_to(base, g.stamp + g.offset(cell[0], cell[1], cell[2]), sy, sz, frame);
        else
          sums.add_to(base, sy, sz);
      }
      return;
    }
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
    if (rejected(s, threshold)) return;
    const float fu = float(u);
    const float cx = sample_coordinate(L.c0[0], fu, L.dc[0]),
                cy = sample_coordinate(L.c0[1], fu, L.dc[1]),
                cz = sample_coordinate(L.c0[2], fu, L.dc[2]);
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
    // Eight samples' cells and fractions at a time (step()'s float operations, so its bits: in
    // the inner run |c| is far below 2^31, where the lanes' floor equals floor_to_int).
    using backend::Vec8f;
    const Vec8f c0[3] = {Vec8f(L.c0[0]), Vec8f(L.c0[1]), Vec8f(L.c0[2])};
    const Vec8f d[3] = {Vec8f(L.dc[0]), Vec8f(L.dc[1]), Vec8f(L.dc[2])};
    {
      const int64_t keys = (int64_t(g.nx) + 2) * (int64_t(g.ny) + 2) * (int64_t(g.nz) + 2);
      const bool keep_all = !(float(std::numeric_limits<T>::lowest()) < threshold);
      if (keep_all && keys < (int64_t(1) << 31))
        return splat_runs_linear(g, L, row, u, end, cell, sums, flush);
    }
    alignas(32) int32_t idx[3][8];
    alignas(32) float frac[3][8], samples[8];
    for (; u + 8 <= end; u += 8) {
      const Vec8f fu = Vec8f::iota(float(u));
      for (int a = 0; a < 3; ++a) {
        const Vec8f c = sample_coordinate(c0[a], fu, d[a]);
        const backend::Vec8i i = backend::floor_to_int(c);
        i.store(idx[a]);
        (c - backend::to_float(i)).store(frac[a]);
      }
      backend::load_as_float(row + u).store(samples);
      for (int l = 0; l < 8; ++l)
        if (!rejected(samples[l], threshold))
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

/// `slabs` tasks along `axis` over [lo, hi), each walking the whole batch.
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

/// The CPU entry point every CPU instruction set's translation unit exposes.
inline void dispatch_compound_cpu(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                                  bool linear, int axis, int lo, int hi, int slabs) {
  std::vector<RowClip> clips(size_t(batch.frames) * batch.rows * kMaxSpans);
  visit_pixel_type(
      KernelPixelTypes{}, batch.type,
      [&](auto sample_zero) {
        using T = decltype(sample_zero);
        visit_mode(mode, linear, [&](auto mode_tag, auto linear_tag) {
          compound_batch_cpu<T, decltype(mode_tag)::value, decltype(linear_tag)::value>(
              grid, batch, axis, lo, hi, slabs, clips.data());
        });
      },
      "compounding kernels");
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace compound_impl
}  // namespace sonoslice
