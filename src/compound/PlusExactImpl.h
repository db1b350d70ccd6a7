#pragma once
/// @file PLUS's insertion arithmetic, reproduced operation for operation (`--plus-exact`,
/// docs/compounding.md §4b): IGSIO's unoptimised paste path (vtkIGSIOPasteSliceIntoVolume with
/// Optimization="NONE": vtkUnoptimizedInsertSlice, vtkNearestNeighborInterpolation,
/// vtkTrilinearInterpolation), written from its source.
///
/// PLUS keeps the volume in the frames' type, rounded after every update, and a uint16
/// accumulation buffer (256 per unit of weight, saturating at 65535). Here a voxel's Accumulator
/// holds exactly those two numbers: `value` the voxel in the frames' type (exact in a float for
/// every type this path takes) and `weight` the buffer / 256 (exact too). Every update below does
/// what PLUS's does, in PLUS's types, so each voxel's sequence of updates gives PLUS's bytes; the
/// CPU driver (PlusExact.cpp) keeps that sequence for any thread count.
#include <cstdint>
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

/// vtkNearestNeighborInterpolation's update of one voxel with pixel `in`.
template <typename T>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void nearest_update(Accumulator& voxel, T in, Mode mode) {
  T out = voxel_value<T>(voxel);
  const int acc = buffer(voxel);
  switch (mode) {
    case Mode::Max: {
      if (in > out) out = in;
      store(voxel, out, saturated(acc + kMultiplier));
      return;
    }
    case Mode::Latest:
      store(voxel, in, saturated(acc + kMultiplier));
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
