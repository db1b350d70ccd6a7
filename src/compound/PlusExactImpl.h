#pragma once
/// @file PLUS's insertion arithmetic, reproduced operation for operation (`--plus-exact`,
/// docs/compounding.md §4b), written from IGSIO's source (vtkIGSIOPasteSliceIntoVolume and its
/// helpers) for its three CPU paths: Optimization="NONE" (vtkUnoptimizedInsertSlice,
/// vtkNearestNeighborInterpolation, vtkTrilinearInterpolation), "PARTIAL" (vtkOptimizedInsertSlice
/// in double: vtkUltraFindExtent's row extent, its own fan clip, incremental positions) and
/// "FULL" (the same in IGSIO's `fixed`, 14-bit fixed point: Fixed below).
///
/// PLUS keeps the volume in the frames' type, rounded after every update, and a uint16
/// accumulation buffer (256 per unit of weight, saturating at 65535). Here a voxel's Accumulator
/// holds exactly those two numbers: `value` the voxel in the frames' type (exact in a float for
/// every type this path takes) and `weight` the buffer / 256 (exact too). Every update below does
/// what PLUS's does, in PLUS's types, so each voxel's sequence of updates gives PLUS's bytes; the
/// CPU driver (PlusExact.cpp) keeps that sequence for any thread count.
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "CompoundTypes.h"
#include "sonoslice/backend/HostDevice.h"

namespace sonoslice {
namespace compound_impl {
namespace plus_exact {

constexpr int kMultiplier = 256;   // ACCUMULATION_MULTIPLIER: one pixel of full weight
constexpr int kMaximum = 65535;    // ACCUMULATION_MAXIMUM: uint16 saturation
constexpr int kThreshold = 65279;  // ACCUMULATION_THRESHOLD = maximum - multiplier

/// igsioMath::Floor on x86-64: a large offset quantises x to 2^-16 (with a 2^-17 tolerance
/// upwards) before truncation, so values just below an integer floor to it.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int floor_(double x) {
  x += 103079215104.0 + 7.62939453125e-06;
  return int(static_cast<long long>(x) - 103079215104LL);
}
/// igsioMath::Round on x86-64: the same with 0.5 added.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int round_(double x) {
  x += 103079215104.5 + 7.62939453125e-06;
  return int(static_cast<long long>(x) - 103079215104LL);
}

/// A product PLUS computes in int, with the wrap-around of two's complement where it overflows
/// (uint16 voxels × a large buffer).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int wrapping_product(int a, int b) {
  return int(uint32_t(a) * uint32_t(b));
}

template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T voxel_value(const Accumulator& a) {
  return static_cast<T>(a.value);
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int buffer(const Accumulator& a) {
  return int(a.weight * 256.f);
}
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void store(Accumulator& a, T value, int buffer) {
  a.value = float(value);
  a.weight = float(buffer) * (1.f / 256.f);
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int saturated(int newa) {
  return newa < kMaximum ? newa : kMaximum;
}

/// vtkNearestNeighborInterpolation's update of one voxel with pixel `in`; `optimized`:
/// vtkFreehand2OptimizedNNHelper's instead, which sets the buffer to 256 for MAXIMUM and LATEST
/// where the unoptimised path adds 256.
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void nearest_update(Accumulator& voxel, T in, Mode mode,
                                                           bool optimized = false) {
  T out = voxel_value<T>(voxel);
  const int acc = buffer(voxel);
  const int max_latest_buffer = optimized ? kMultiplier : saturated(acc + kMultiplier);
  switch (mode) {
    case Mode::Max: {
      if (in > out) out = in;
      store(voxel, out, max_latest_buffer);
      return;
    }
    case Mode::Latest:
      store(voxel, in, max_latest_buffer);
      return;
    case Mode::Mean:
      if (acc <= kThreshold) {
        const int newa = acc + kMultiplier;
        if constexpr (std::is_floating_point<T>::value) {
          out = (in * kMultiplier + out * acc) / newa;
        } else {
          // int arithmetic, truncating division
          const int sum =
              int(uint32_t(int(in) * kMultiplier) + uint32_t(wrapping_product(out, acc)));
          out = static_cast<T>(sum / newa);
        }
        store(voxel, out, saturated(newa));
      } else {
        // Past the threshold PLUS switches to a recursive filter and leaves the buffer.
        out = static_cast<T>(1.0 / 256 * double(in) + 255.0 / 256 * double(out));
        store(voxel, out, acc);
      }
      return;
  }
}

/// One corner's update in vtkTrilinearInterpolation (F = double), weight `f` > 0.
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void linear_update(Accumulator& voxel, T in, double f,
                                                          Mode mode) {
  T out = voxel_value<T>(voxel);
  const int acc = buffer(voxel);
  double a = double(acc);
  switch (mode) {
    case Mode::Max:
      if (f >= 0.125 && in > out) {
        out = in;
        a = f * kMultiplier;
      }
      break;
    case Mode::Latest:
      if (f >= 0.125) {
        out = in;
        a = f * kMultiplier;
      }
      break;
    case Mode::Mean: {
      const double r = double(acc) / double(kMultiplier);
      a = f + r;
      const double v = (f * double(in) + r * double(out)) / a;
      if constexpr (std::is_floating_point<T>::value)
        out = static_cast<T>(v);
      else
        out = static_cast<T>(round_(v));
      a *= kMultiplier;
      break;
    }
  }
  store(voxel, out, a < double(kMaximum) ? round_(a) : kMaximum);
}

/// IGSIO's `fixed` (fixed.h): an int holding value × 2^14. Only the operations PLUS's paste
/// path uses, each as fixed.h computes it; int products wrap as they do there.
struct Fixed {
  int32_t i = 0;
};
constexpr int kFixedPoint = 14;
/// fixed(double): adds 1.5 × 2^38 so the double's last mantissa bit is 2^-14, then takes the low
/// 32 bits: round half to even of x × 2^14, modulo 2^32.
inline Fixed fixed_from(double x) {
  const double d = x + 412316860416.0;
  uint64_t bits;
  std::memcpy(&bits, &d, sizeof bits);
  return Fixed{int32_t(uint32_t(bits))};
}
inline Fixed fixed_from_int(int x) {
  return Fixed{int32_t(uint32_t(x) << kFixedPoint)};
}
inline double to_double(Fixed x) {
  return x.i * (1.0 / (1 << kFixedPoint));
}
inline double to_double(double x) {
  return x;
}
inline Fixed operator+(Fixed a, Fixed b) {
  return Fixed{int32_t(uint32_t(a.i) + uint32_t(b.i))};
}
inline Fixed operator-(Fixed a, Fixed b) {
  return Fixed{int32_t(uint32_t(a.i) - uint32_t(b.i))};
}
/// int × fixed: the raw product, no rounding.
inline Fixed operator*(int k, Fixed a) {
  return Fixed{int32_t(uint32_t(k) * uint32_t(a.i))};
}
/// fixed × fixed (fast_multiply): rounded, assumes the product is below 2.
inline Fixed operator*(Fixed a, Fixed b) {
  return Fixed{int32_t(uint32_t(a.i) * uint32_t(b.i) + (1u << (kFixedPoint - 1))) >> kFixedPoint};
}
/// fixed / fixed: through a double quotient.
inline Fixed operator/(Fixed a, Fixed b) {
  return fixed_from(double(a.i) / b.i);
}
inline bool operator<(Fixed a, Fixed b) {
  return a.i < b.i;
}
inline bool operator<=(Fixed a, Fixed b) {
  return a.i <= b.i;
}
inline bool operator!=(Fixed a, Fixed b) {
  return a.i != b.i;
}
inline Fixed fixed_abs(Fixed a) {
  return a.i < 0 ? Fixed{-a.i} : a;
}
inline double fixed_abs(double a) {
  return a < 0 ? -a : a;
}
/// igsioMath::Round of a position (a fixed converts to double first).
inline int round_position(double x) {
  return round_(x);
}
inline int round_position(Fixed x) {
  return round_(to_double(x));
}

/// One corner's update in vtkTrilinearInterpolation with F = fixed (Optimization="FULL"):
/// weight `f` in fixed point, > 0.
template <typename T>
inline void linear_update_fixed(Accumulator& voxel, T in, Fixed f, Mode mode) {
  T out = voxel_value<T>(voxel);
  const int acc = buffer(voxel);
  Fixed a = fixed_from_int(acc);
  const Fixed min_weight = fixed_from(0.125);
  switch (mode) {
    case Mode::Max:
      if (!(f < min_weight) && in > out) {
        out = in;
        a = kMultiplier * f;
      }
      break;
    case Mode::Latest:
      if (!(f < min_weight)) {
        out = in;
        a = kMultiplier * f;
      }
      break;
    case Mode::Mean: {
      const Fixed r = fixed_from(acc / double(kMultiplier));
      a = f + r;
      if constexpr (std::is_floating_point<T>::value) {
        // fixed × float and float / fixed are float operations in fixed.h.
        out = (float(to_double(f)) * in + float(to_double(r)) * out) / float(to_double(a));
      } else {
        const Fixed sum = int(in) * f + int(out) * r;
        out = static_cast<T>(round_(to_double(sum / a)));
      }
      a = kMultiplier * a;
      break;
    }
  }
  store(voxel, out, a < fixed_from_int(kMaximum) ? round_(to_double(a)) : kMaximum);
}

/// vtkUltraFindExtent (Optimization PARTIAL and FULL): the pixels [start, end] of a row whose
/// rounded position lies inside the volume, found from the row's start `point` and per-pixel step
/// `axis` by IGSIO's own face-by-face search, so that the same pixels come out where rounding puts
/// a position on a face. F is double or Fixed.
template <typename F>
struct RowExtent {
  const F* point;
  const F* axis;
  const int* vmin;    // 0, 0, 0
  const int* vmax;    // nx - 1, ny - 1, nz - 1
  const int* pixels;  // the row's pixel range [first, last]
  int sign[3];

  int position(int r, int a) const { return round_position(point[a] + step(r, a)); }
  static double step_of(int r, double axis) { return r * axis; }
  static Fixed step_of(int r, Fixed axis) { return r * axis; }
  F step(int r, int a) const { return step_of(r, axis[a]); }

  // A first guess for the search below; its result does not depend on it (positions are
  // monotonic along the row), only its cost does. (IGSIO's guess reads past its point array.)
  int guess(int limit, int a) const {
    const double p = to_double(point[a]), d = to_double(axis[a]);
    double r = d != 0 ? (limit - p) / d : pixels[0];
    if (!(r >= pixels[0])) r = pixels[0];
    if (r > pixels[1]) r = pixels[1];
    return int(r);
  }
  // intersectionLow: the pixel just inside the face vmin[a] (or vmax via `limit`).
  int low(const int* limit, int a) const {
    int r = guess(limit[a], a);
    for (;;) {
      if (((sign[a] < 0 && r > pixels[0]) || (sign[a] > 0 && r < pixels[1])) &&
          position(r, a) < limit[a])
        r += sign[a];
      else
        break;
    }
    for (;;) {
      if (((sign[a] > 0 && r > pixels[0]) || (sign[a] < 0 && r < pixels[1])) &&
          position(r - sign[a], a) >= limit[a])
        r -= sign[a];
      else
        break;
    }
    return r;
  }
  // intersectionHigh
  int high(const int* limit, int a) const {
    int r = guess(limit[a], a);
    for (;;) {
      if (((sign[a] > 0 && r > pixels[0]) || (sign[a] < 0 && r < pixels[1])) &&
          position(r, a) > limit[a])
        r -= sign[a];
      else
        break;
    }
    for (;;) {
      if (((sign[a] < 0 && r > pixels[0]) || (sign[a] > 0 && r < pixels[1])) &&
          position(r + sign[a], a) <= limit[a])
        r += sign[a];
      else
        break;
    }
    return r;
  }
  bool bounded(int a, int r) const {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    const int bp = position(r, b), cp = position(r, c);
    return bp >= vmin[b] && bp <= vmax[b] && cp >= vmin[c] && cp <= vmax[c];
  }
  // vtkUltraFindExtentHelper
  void finish(int& start, int& end, int s) const {
    if (s < 0) {
      const int t = start;
      start = end;
      end = t;
    }
    if (start < pixels[0]) start = pixels[0];
    if (end > pixels[1]) end = pixels[1];
    if (start > end) {
      start = pixels[0];
      end = pixels[0] - 1;
    }
  }

  // vtkUltraFindExtent, branch for branch.
  void find(int& start, int& end) {
    for (int i = 0; i < 3; ++i) sign[i] = point[i] <= point[i] + axis[i] ? 1 : -1;
    int ix = 0;
    for (int i = 1; i < 3; ++i)
      if (fixed_abs(axis[ix]) < fixed_abs(axis[i])) ix = i;
    int iy = ix > 1 ? ix - 2 : ix + 1;
    int iz = ix > 0 ? ix - 1 : ix + 2;
    if (fixed_abs(axis[iz]) < fixed_abs(axis[iy])) {
      const int t = iy;
      iy = iz;
      iz = t;
    }
    start = low(vmin, ix);
    end = high(vmax, ix);
    int i1[3], i2[3];
    for (int i = 0; i < 3; ++i) {
      i1[i] = position(start, i);
      i2[i] = position(end, i);
    }
    // IGSIO's pair of tests per axis, iy then iz: where the row's end p lies outside the volume
    // on that axis, r moves onto the face it crosses; true once r lies inside on the others.
    const auto onto_face = [&](const int* p, int& r) {
      for (const int a : {iy, iz}) {
        if (p[a] < vmin[a])
          r = low(vmin, a);
        else if (p[a] > vmax[a])
          r = high(vmax, a);
        else
          continue;
        if (bounded(a, r)) return true;
      }
      return false;
    };
    if (bounded(ix, start)) {
      if (bounded(ix, end)) return finish(start, end, sign[ix]);
      if (onto_face(i2, end)) return finish(start, end, sign[ix]);
    }
    if (bounded(ix, end) && onto_face(i1, start)) return finish(start, end, sign[ix]);
    if ((i1[iy] >= vmin[iy] && i2[iy] < vmin[iy]) || (i1[iy] < vmin[iy] && i2[iy] >= vmin[iy])) {
      start = low(vmin, iy);
      if (bounded(iy, start)) {
        if ((i1[iy] <= vmax[iy] && i2[iy] > vmax[iy]) ||
            (i1[iy] > vmax[iy] && i2[iy] <= vmax[iy])) {
          end = high(vmax, iy);
          if (bounded(iy, end)) return finish(start, end, sign[iy]);
        }
        if ((i1[iz] < vmin[iz] && i2[iy] < vmin[iy]) || (i2[iz] < vmin[iz] && i1[iy] < vmin[iy])) {
          end = low(vmin, iz);
          if (bounded(iz, end)) return finish(start, end, sign[iy]);
        } else if ((i1[iz] > vmax[iz] && i2[iy] < vmin[iy]) ||
                   (i2[iz] > vmax[iz] && i1[iy] < vmin[iy])) {
          end = high(vmax, iz);
          if (bounded(iz, end)) return finish(start, end, sign[iy]);
        }
      }
    }
    if ((i1[iy] <= vmax[iy] && i2[iy] > vmax[iy]) || (i1[iy] > vmax[iy] && i2[iy] <= vmax[iy])) {
      end = high(vmax, iy);
      if (bounded(iy, end)) {
        if ((i1[iz] < vmin[iz] && i2[iy] > vmax[iy]) || (i2[iz] < vmin[iz] && i1[iy] > vmax[iy])) {
          start = low(vmin, iz);
          if (bounded(iz, start)) return finish(start, end, sign[iy]);
        } else if ((i1[iz] > vmax[iz] && i2[iy] > vmax[iy]) ||
                   (i2[iz] > vmax[iz] && i1[iy] > vmax[iy])) {
          start = high(vmax, iz);
          if (bounded(iz, start)) return finish(start, end, sign[iy]);
        }
      }
    }
    if ((i1[iz] >= vmin[iz] && i2[iz] < vmin[iz]) || (i1[iz] < vmin[iz] && i2[iz] >= vmin[iz])) {
      start = low(vmin, iz);
      if (bounded(iz, start)) {
        if (i1[iz] > vmax[iz] || i2[iz] > vmax[iz]) {
          end = high(vmax, iz);
          if (bounded(iz, end)) return finish(start, end, sign[iz]);
        }
      }
    }
    start = pixels[0];
    end = pixels[0] - 1;
  }
};

/// Which pixels of a frame go in, as PLUS decides it: the clip rectangle as an inclusive extent
/// (GetClipExtent), the fan test of vtkUnoptimizedInsertSlice, the pixel rejection threshold.
struct PixelFilter {
  int x0 = 0, x1 = -1, y0 = 0, y1 = -1;  // inclusive
  bool fan = false;
  double fan_origin[2] = {0, 0};
  double tan_left = 0, tan_right = 0;  // left <= right
  double radius2_start = 0, radius2_stop = 0;
  bool reject = false;
  double threshold = 0;

  SONOSLICE_HOST_DEVICE bool in_fan(int x_px, int y_px) const {
    if (!fan) return true;
    const double x = x_px - fan_origin[0], y = y_px - fan_origin[1];
    if (y < 0 || x / y < tan_left || x / y > tan_right) return false;
    const double d2 = x * x + y * y;
    return !(d2 < radius2_start || d2 > radius2_stop);
  }
};

}  // namespace plus_exact
}  // namespace compound_impl
}  // namespace sonoslice
