#pragma once
/// @file Finishing a reconstruction, per voxel, for every backend: the value from the accumulator
/// (sum / weight for mean and latest, the maximum for max) and hole filling with PLUS's elements
/// and rules (IGSIO's vtkIGSIOFillHolesInVolume; docs/compounding.md §4a). Finish.cpp drives it
/// on CPU threads, CompoundCUDA.cu on the GPU. Sources are always the voxels samples reached,
/// never filled ones (as in PLUS), so the order of visits and the thread count do not matter.
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>

#include "../backend/Convert.h"
#include "CompoundTypes.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

/// One hole-filling element, ready for the kernels (Finish.cpp sets it up from a
/// HoleFillingKernel, with PLUS's float arithmetic): plain data, its kernel in the memory of the
/// backend that runs it.
struct FillElement {
  enum Type : int { NearestNeighbor, Gaussian, GaussianAccumulation, DistanceWeightInverse, Stick };
  Type type = Gaussian;
  int size = 3, range = 1;  // cube edge, (size - 1) / 2
  double min_ratio = 0;     // (double)(float)minimum_known_ratio, as PLUS compares it
  int stick_length_limit = 9, sticks_to_use = 1;
  const float* kernel = nullptr;  // size³ weights, index (z·size + y)·size + x (PLUS's)
};

/// What finishing reads: the accumulators, the mode, and the elements (none: no hole filling).
struct FinishInput {
  AccumulatorView g;
  Mode mode = Mode::Mean;
  const FillElement* elements = nullptr;
  int element_count = 0;
};

inline namespace SONOSLICE_KERNEL_ISA {

/// PLUS's accumulation buffer for a voxel of splat weight w: 256 per unit of weight, rounded,
/// saturating at 65535 (vtkIGSIOPasteSliceIntoVolume: ACCUMULATION_MULTIPLIER, _MAXIMUM).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE double plus_accumulation(float w) {
  const double a = floor(double(w) * 256.0 + 0.5);
  return a < 65535.0 ? a : 65535.0;
}

/// Whether a voxel of splat weight w was reached, with hole filling: exactly when PLUS's
/// accumulation buffer would not be 0 there, plus_accumulation(w) != 0, so a voxel reached only
/// by linear splat weights summing to less than 1/512 is a hole. Written without floor (a library
/// call on the CPU's baseline ISA) and in float, so that it vectorises: floor(256·w + 0.5) is 0
/// exactly when −1/512 <= w < 1/512 (256·w and the sum are exact in double for a float w; NaN:
/// known, as floor(NaN) != 0).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool reached_for_filling(float w) {
  return !(w >= -0x1p-9f && w < 0x1p-9f);
}

/// backend::saturate_cast<T>(v) for a double v written as selects rather than branches, so that
/// a loop of it vectorises: the same value for every v (the range of every integer T up to 32
/// bits is exact in double, so clamping before the conversion is the same as after).
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T saturate_select(double v) {
  if constexpr (std::is_floating_point<T>::value) {
    return static_cast<T>(v);
  } else {
    static_assert(sizeof(T) <= 4, "integer types of up to 32 bits");
    constexpr double lo = double(std::numeric_limits<T>::lowest());
    constexpr double hi = double(std::numeric_limits<T>::max());
    double r = floor(v + 0.5);
    r = r < lo ? lo : r;
    r = r > hi ? hi : r;
    return static_cast<T>(v == v ? r : 0.0);
  }
}

/// Whether a voxel of splat weight w was reached, without hole filling: any weight at all.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool reached(float w) {
  return w > 0.f;
}

/// Whether voxel i was reached.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool is_known(const FinishInput& in, int64_t i) {
  const float w = in.g.cells[i].weight;
  return in.element_count > 0 ? reached_for_filling(w) : reached(w);
}

/// The value of a reached voxel in modes mean and latest (max keeps the value itself).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE double mean_value(const Accumulator& a) {
  return double(a.value) / double(a.weight);
}

SONOSLICE_HOST_DEVICE SONOSLICE_INLINE double known_value(const FinishInput& in, int64_t i) {
  const Accumulator& a = in.g.cells[i];
  return in.mode == Mode::Max ? double(a.value) : mean_value(a);
}

/// A value converted to the output type T as PLUS's C casts do it (integers: toward zero,
/// saturated here where the cast would be undefined; float: rounded to float), and back.
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE double as_output_type(double v) {
  if constexpr (std::is_floating_point<T>::value)
    return double(static_cast<T>(v));
  else
    return double(backend::saturate_cast<T>(trunc(v)));
}

/// f(i, kx, ky, kz) for the known voxels of the cube of `range` around (x, y, z), inside the
/// grid, in PLUS's order (x outer, then y, then z); returns how many there were.
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int for_known_in_cube(const FinishInput& in, int x, int y,
                                                             int z, int range, F&& f) {
  const AccumulatorView& g = in.g;
  const int x0 = x - range < 0 ? 0 : x - range, x1 = x + range < g.nx ? x + range : g.nx - 1;
  const int y0 = y - range < 0 ? 0 : y - range, y1 = y + range < g.ny ? y + range : g.ny - 1;
  const int z0 = z - range < 0 ? 0 : z - range, z1 = z + range < g.nz ? z + range : g.nz - 1;
  const int64_t slice = int64_t(g.nx) * g.ny;
  int known = 0;
  for (int xx = x0; xx <= x1; ++xx)
    for (int yy = y0; yy <= y1; ++yy) {
      int64_t i = g.offset(xx, yy, z0);
      for (int zz = z0; zz <= z1; ++zz, i += slice) {
        if (!is_known(in, i)) continue;
        ++known;
        f(i, xx - (x - range), yy - (y - range), zz - (z - range));
      }
    }
  return known;
}

/// The ratio test of every element but the stick: the known voxels found over the whole size³
/// cube (voxels outside the grid and the hole itself count in the denominator), strictly greater.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool enough_known(const FillElement& e, int known) {
  return double(known) / double(e.size * e.size * e.size) > e.min_ratio;
}

/// Gaussian, Gaussian × accumulation, inverse distance: the kernel-weighted mean of the known
/// voxels of the cube (PLUS's applyGaussian, applyGaussianAccumulation,
/// applyDistanceWeightInverse).
template <typename T>
SONOSLICE_HOST_DEVICE bool fill_weighted(const FinishInput& in, const FillElement& e, int x, int y,
                                         int z, double* result) {
  double sum = 0, wsum = 0;
  const int known = for_known_in_cube(in, x, y, z, e.range, [&](int64_t i, int kx, int ky, int kz) {
    const float g = e.kernel[(kz * e.size + ky) * e.size + kx];
    // PLUS: `double weight = currentAccumulation * kernel[...]`, an int times a float: float.
    const double w = e.type == FillElement::GaussianAccumulation
                         ? double(float(plus_accumulation(in.g.cells[i].weight)) * g)
                         : double(g);
    sum += known_value(in, i) * w;
    wsum += w;
  });
  if (wsum == 0 || !enough_known(e, known)) return false;
  *result = as_output_type<T>(sum / wsum);
  return true;
}

/// Nearest neighbour: the plain mean of the known voxels in the smallest cube (radius 1, 2, ...,
/// (size-1)/2) that has any; the ratio test counts those against the whole size³ cube.
template <typename T>
SONOSLICE_HOST_DEVICE bool fill_nearest(const FinishInput& in, const FillElement& e, int x, int y,
                                        int z, double* result) {
  for (int radius = 1; radius <= e.range; ++radius) {
    double sum = 0;
    const int known = for_known_in_cube(
        in, x, y, z, radius, [&](int64_t i, int, int, int) { sum += known_value(in, i); });
    if (known == 0) continue;
    if (!enough_known(e, known)) return false;
    *result = as_output_type<T>(sum / known);
    return true;
  }
  return false;
}

/// PLUS's 13 stick directions, in PLUS's order.
constexpr int kStickDirections = 13;
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void stick_direction(int s, int* d) {
  constexpr int kDirections[kStickDirections][3] = {
      {1, 0, 0},  {0, 1, 0},  {0, 0, 1}, {1, 1, 0},  {1, 0, 1},  {0, 1, 1},  {1, -1, 0},
      {1, 0, -1}, {0, 1, -1}, {1, 1, 1}, {-1, 1, 1}, {1, -1, 1}, {-1, -1, 1}};
  d[0] = kDirections[s][0];
  d[1] = kDirections[s][1];
  d[2] = kDirections[s][2];
}

/// Walks from (x, y, z) along d for at most `limit` steps; the steps to the first known voxel
/// (0: none before the limit or the grid's edge).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int walk_to_known(const FinishInput& in, int x, int y, int z,
                                                         const int* d, int sign, int limit) {
  for (int j = 1; j <= limit; ++j) {
    const int px = x + sign * j * d[0], py = y + sign * j * d[1], pz = z + sign * j * d[2];
    if (!in.g.contains(px, py, pz)) return 0;
    if (is_known(in, in.g.offset(px, py, pz))) return j;
  }
  return 0;
}

/// Sticks (PLUS's applySticks): along each of PLUS's 13 directions, in PLUS's order, the first
/// known voxel forward (at most L - 1 steps) and backward (at most L - 1 - forward steps), so a
/// stick spans at most L voxels, ends included. A stick's value weighs its forward end by
/// (back + 1) / (forward + back + 1), PLUS's formula (not the linear interpolation
/// back / (forward + back) it approximates), converted to the output type; its score is
/// 1 / ((forward + back + 1) · |d|). The best scores are taken until sticks_to_use are used,
/// every stick tied at a taken score with it, and averaged weighted by score (a stick's value is
/// computed only when it is taken).
template <typename T>
SONOSLICE_HOST_DEVICE bool fill_stick(const FinishInput& in, const FillElement& e, int x, int y,
                                      int z, double* result) {
  const int limit = e.stick_length_limit;
  double score[kStickDirections];
  int forward[kStickDirections], back[kStickDirections];
  for (int s = 0; s < kStickDirections; ++s) {
    score[s] = 0;
    int d[3];
    stick_direction(s, d);
    const int f = forward[s] = walk_to_known(in, x, y, z, d, 1, limit - 1);
    if (f == 0) continue;
    const int b = back[s] = walk_to_known(in, x, y, z, d, -1, limit - 1 - f);
    if (b == 0) continue;
    score[s] = 1.0 / (double(f + b + 1) * sqrt(double(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])));
  }
  // A taken stick's value: its ends' values weighed as PLUS does, in the output type.
  const auto value = [&](int s) {
    int d[3];
    stick_direction(s, d);
    const int f = forward[s], b = back[s];
    const double total = double(f + b + 1);
    const double weight_fwd = double(b + 1) / total;
    const double weight_back = 1.0 - weight_fwd;
    const int64_t fwd_i = in.g.offset(x + f * d[0], y + f * d[1], z + f * d[2]);
    const int64_t back_i = in.g.offset(x - b * d[0], y - b * d[1], z - b * d[2]);
    return as_output_type<T>(weight_back * known_value(in, back_i) +
                             weight_fwd * known_value(in, fwd_i));
  };
  double sum = 0, wsum = 0;
  int used = 0;
  while (used < e.sticks_to_use) {
    double best = 0;
    for (int s = 0; s < kStickDirections; ++s)
      if (score[s] > best) best = score[s];
    if (best == 0) break;
    for (int s = 0; s < kStickDirections; ++s)
      if (score[s] == best) {
        sum += value(s) * score[s];
        wsum += score[s];
        ++used;
        score[s] = 0;
      }
  }
  if (wsum == 0) return false;
  *result = as_output_type<T>(sum / wsum);
  return true;
}

template <typename T>
SONOSLICE_HOST_DEVICE bool fill(const FinishInput& in, const FillElement& e, int x, int y, int z,
                                double* result) {
  switch (e.type) {
    case FillElement::NearestNeighbor:
      return fill_nearest<T>(in, e, x, y, z, result);
    case FillElement::Stick:
      return fill_stick<T>(in, e, x, y, z, result);
    case FillElement::Gaussian:
    case FillElement::GaussianAccumulation:
    case FillElement::DistanceWeightInverse:
      return fill_weighted<T>(in, e, x, y, z, result);
  }
  return false;
}

/// Voxel (x, y, z) of the finished volume: its own value where samples reached it (rounded to
/// nearest for integer outputs), else the first element that can fill it (already in the output
/// type, as PLUS's casts give it), else 0 (PLUS writes 0 where no element fills).
/// `may_fill(k)`: false where element k cannot fill this hole, so it need not be tried (the CPU
/// driver's shortcut: no known voxel within the element's reach).
template <typename T, typename MayFill>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T finished_voxel(const FinishInput& in, int x, int y, int z,
                                                        const MayFill& may_fill) {
  const int64_t i = in.g.offset(x, y, z);
  double v = 0;
  if (is_known(in, i)) {
    v = known_value(in, i);
  } else {
    for (int k = 0; k < in.element_count; ++k)
      if (may_fill(k) && fill<T>(in, in.elements[k], x, y, z, &v)) break;
  }
  return backend::saturate_cast<T>(v);
}

/// The same, every element tried.
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T finished_voxel(const FinishInput& in, int x, int y,
                                                        int z) {
  return finished_voxel<T>(in, x, y, z, [](int) { return true; });
}

/// finished_voxel without hole filling, for voxels [begin, end) of the grid: the quotient is
/// computed for every voxel, also where it is then dropped (weight 0), and the mode is decided
/// outside the loops, so each loop has no branch and vectorises (CompoundCPUAvx2.cpp: four voxels
/// a step). A live view finishes the whole grid several times a second, offline `compound` once.
template <typename T>
SONOSLICE_INLINE void finished_values(const FinishInput& in, int64_t begin, int64_t end, T* out) {
  const Accumulator* c = in.g.cells;
  if (in.mode == Mode::Max) {
    for (int64_t i = begin; i < end; ++i) {
      const T v = saturate_select<T>(double(c[i].value));
      out[i] = reached(c[i].weight) ? v : T(0);
    }
  } else {
    for (int64_t i = begin; i < end; ++i) {
      const T v = saturate_select<T>(mean_value(c[i]));
      out[i] = reached(c[i].weight) ? v : T(0);
    }
  }
}

/// The same for an output of `type`: the CPU entry points of each instruction set.
inline void finished_values(const FinishInput& in, PixelType type, int64_t begin, int64_t end,
                            void* out) {
  visit_pixel_type(type, [&](auto zero) {
    using T = decltype(zero);
    finished_values<T>(in, begin, end, static_cast<T*>(out));
  });
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace compound_impl
}  // namespace sonoslice
