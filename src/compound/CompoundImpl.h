#pragma once
/// @file The per-sample math of compounding (docs/conventions.md §7), the part of the kernels that
/// every backend compiles: where a sample lies, which voxel or cell it splats into and with which
/// weights, which samples stay out, and what a voxel's accumulator does with them in each mode.
/// How the samples are walked differs by backend and lives beside this file:
/// CompoundDriverCPU.h (owner computes; generic and AVX2) and CompoundDriverCUDA.cuh (one thread
/// per sample, atomic updates). Everything below the dispatch layer (Compounder.cpp) takes
/// pre-validated raw pointers and sizes.
///
/// A frame is a set of rows (image rows, or beams of a 3-D probe); sample u of a row lies at
/// c0 + u·dc in voxel-index space (for nearest splats the dispatch layer adds the 0.5 of
/// floor(c + 0.5) to c0, in double precision). A sample is splatted into the voxel nearest to it
/// (nearest: index floor(c + 0.5)) or into the eight voxels around it with trilinear weights
/// (linear).
///
/// NaN: a NaN coordinate is outside every grid (the inside tests compare false); a NaN sample is
/// not below any rejection threshold, so it goes in.
#include <cstdint>
#include <string>
#include <type_traits>

#include "../backend/Convert.h"
#include "CompoundTypes.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {
inline namespace SONOSLICE_KERNEL_ISA {

/// floor(x) as an int for |x| < 2^31, without a libm call (baseline x86-64 has no SSE4.1 round).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int floor_to_int(float x) {
  const int i = int(x);
  return i - (x < float(i) ? 1 : 0);
}

/// The coordinate of sample u along one axis of a row, c0 + u·d, never fused: every backend and
/// lane width then picks the same voxels. F: float, or the CPU's AVX2 lanes.
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F sample_coordinate(F c0, F u, F d) {
  return backend::add_product(c0, u, d);
}

/// Whether a sample stays out: below the rejection threshold (a NaN sample is not).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool rejected(float sample, float threshold) {
  return sample < threshold;
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

/// The voxel nearest to a sample (docs/conventions.md §5 nearest: floor(c + 0.5)), given
/// t = c + 0.5 (rows of nearest splats carry the 0.5 in their origin); false outside the grid.
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

/// The trilinear splat weight from the per-axis weights, (wx·wy)·wz in this order in every
/// backend (so the same bits). F: float, or the CPU's AVX2 lanes (all eight corners at once).
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F cell_weight(F wx, F wy, F wz) {
  return (wx * wy) * wz;
}

/// Trilinear splat weight of corner k (bit 0: +x, bit 1: +y, bit 2: +z) of a cell.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float corner_weight(const float* f, int k) {
  const float wx = (k & 1) ? f[0] : 1.f - f[0];
  const float wy = (k & 2) ? f[1] : 1.f - f[1];
  const float wz = (k & 4) ? f[2] : 1.f - f[2];
  return cell_weight(wx, wy, wz);
}

template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float sample_value(const T* row, int u) {
  return float(row[u]);
}

/// A sample counts for a voxel's maximum only with a splat weight of at least 1/8 (PLUS's rule):
/// a sample at the far corner of a cell says little about that voxel.
constexpr float kMaxModeMinimumWeight = 0.125f;
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool counts_for_max(float w) {
  return w >= kMaxModeMinimumWeight;
}

/// Running value of a group of samples before it is written: a weighted sum (mean, latest) or
/// a maximum (max).
template <Mode M>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void gather(float& value, float& weight, float sample,
                                                   float w) {
  if (M == Mode::Max) {
    if (counts_for_max(w)) {
      value = sample > value ? sample : value;
      weight += w;
    }
  } else {
    value += w * sample;
    weight += w;
  }
}

/// An accumulator's value with a group's value merged in: the larger (max) or the sum (mean,
/// latest). The CUDA driver does the same with atomics.
template <Mode M>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float merged(float accumulated, float value) {
  if (M == Mode::Max) return value > accumulated ? value : accumulated;
  return accumulated + value;
}

/// Latest mode: the first write of a newer frame into voxel i replaces what older frames left.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void restart_for_frame(const AccumulatorView& g, int64_t i,
                                                              int32_t frame) {
  if (g.stamp[i] != frame) {
    g.stamp[i] = frame;
    g.cells[i].value = 0.f;
    g.cells[i].weight = 0.f;
  }
}

/// Calls f(mode tag, interpolation tag) with compile-time constants for the run-time choice.
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

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace compound_impl
}  // namespace sonoslice
