#pragma once
/// @file The slicing kernel (docs/conventions.md §5): one source for every backend. SliceCPU.cpp
/// (generic x86-64), SliceCPUAvx2.cpp (AVX2 + FMA) and SliceCUDA.cu include this file. Everything
/// below the dispatch layer takes pre-validated raw pointers and sizes.
///
/// The sampling rule itself (inside test, trilinear, nearest) is geometry/Sampling.h, shared with
/// every other capability; its trilinear blend is a template over the lane type (float on CUDA
/// and in scalar code, eight AVX2 lanes in the CPU fast path).
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "../backend/Convert.h"
#include "../geometry/Sampling.h"
#include "SliceTypes.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/volume/PixelType.h"

#if defined(__CUDACC__)
#include "../backend/ParallelForCUDA.cuh"
#else
#include "../backend/ParallelFor.h"
#endif
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
#include "../backend/Avx2Lanes.h"
#define SONOSLICE_SLICE_AVX2 1
#endif

namespace sonoslice {
namespace slice_impl {
inline namespace SONOSLICE_KERNEL_ISA {

using geometry::inside;
using geometry::sample_linear;
using geometry::sample_nearest;
using geometry::trilinear;

/// One output image row at a time: row r of the batch is row v = r % H of image n = r / H.
/// `Index`: the type of flat voxel offsets (int32_t only for volumes under 2^31 voxels).
template <typename TIn, typename TOut, bool Linear, typename Index = int64_t>
struct SliceKernel {
  // Geometry in float except for float64 volumes (docs/conventions.md §5 allows float32 geometry).
  using Acc = typename std::conditional<std::is_same<TIn, double>::value, double, float>::type;
  // On CUDA a warp slices two rows at once, 16 pixels of each: W1 on an H200, 1 / 2 / 4 / 8 rows
  // per warp gave 1.82 / 2.06 / 1.92 / 1.19 M images/s (docs/cuda.md).
  static constexpr int kCudaRowsPerWarp = 2;

  const TIn* volume;
  VolumeView grid;
  const PixelToIndex* poses;  // one per image
  const uint8_t* mask;        // H × W
  TOut* out;                  // N × H × W
  int width;
  int height;
  TOut fill;

  struct Row {
    Acc c[3];  // continuous index of pixel (0, v)
    Acc d[3];  // step per column
    const uint8_t* mask;
    TOut* out;
  };

  SONOSLICE_HOST_DEVICE SONOSLICE_INLINE Row row(int64_t r) const {
    const int64_t n = r / height;
    const int v = int(r - n * height);
    const PixelToIndex& p = poses[n];
    Row s;
    for (int k = 0; k < 3; ++k) {
      s.c[k] = backend::add_product(Acc(p.origin[k]), Acc(v), Acc(p.per_row[k]));
      s.d[k] = Acc(p.per_column[k]);
    }
    s.mask = mask + int64_t(v) * width;
    s.out = out + r * width;
    return s;
  }

  /// The general per-element path: every backend, every pixel type, every position.
  SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void pixel(const Row& s, int u) const {
    if (!s.mask[u]) {
      s.out[u] = fill;
      return;
    }
    const Acc cx = backend::add_product(s.c[0], Acc(u), s.d[0]);
    const Acc cy = backend::add_product(s.c[1], Acc(u), s.d[1]);
    const Acc cz = backend::add_product(s.c[2], Acc(u), s.d[2]);
    if (!inside(grid, cx, cy, cz)) {
      s.out[u] = fill;
      return;
    }
    if (Linear) {
      s.out[u] = backend::saturate_cast<TOut>(sample_linear<Acc, Index>(volume, grid, cx, cy, cz));
    } else {
      s.out[u] = backend::saturate_cast<TOut>(Acc(sample_nearest<Index>(volume, grid, cx, cy, cz)));
    }
  }

#ifdef SONOSLICE_SLICE_AVX2
  /// CPU fast path: eight pixels at once where all eight are inside the probe mask and in the
  /// volume's interior (no clamping, every gathered byte in the buffer); any other block goes
  /// through pixel(). Needs int32 voxel offsets (the dispatcher checks the volume size).
  void pixels(const Row& s, int begin, int end) const {
    using namespace backend;
    if constexpr (!has_gather_pair<TIn>::value) {
      for (int u = begin; u < end; ++u) pixel(s, u);
    } else {
      // A pair gather at voxel i reads up to voxel i + reach along x (one-byte types load four
      // bytes), so the fast path keeps i + reach inside the row; linear also needs i + 1 in y
      // and z, and nearest rounds, so it stays half a voxel further from the x face.
      const float reach = sizeof(TIn) == 1 ? 3.0f : 1.0f;
      const float hx = float(grid.nx) - reach - (Linear ? 0.0f : 0.5f);
      const float hy = float(grid.ny) - 1.0f, hz = float(grid.nz) - 1.0f;
      const int32_t sy = int32_t(grid.stride_y), sz = int32_t(grid.stride_z);
      int u = begin;
      for (; u + 8 <= end; u += 8) {
        const int in_mask = lanes_set(s.mask + u);
        if (in_mask == 0) {
          for (int k = 0; k < 8; ++k) s.out[u + k] = fill;
          continue;
        }
        const Vec8f uu = Vec8f::iota(float(u));
        const Vec8f cx = Vec8f(s.c[0]) + uu * Vec8f(s.d[0]);
        const Vec8f cy = Vec8f(s.c[1]) + uu * Vec8f(s.d[1]);
        const Vec8f cz = Vec8f(s.c[2]) + uu * Vec8f(s.d[2]);
        const int interior = lanes_in_range(cx, 0.0f, hx) & lanes_in_range(cy, 0.0f, hy) &
                             lanes_in_range(cz, 0.0f, hz);
        if ((in_mask & interior) != 0xff) {
          for (int k = 0; k < 8; ++k) pixel(s, u + k);
          continue;
        }
        if constexpr (!Linear) {
          const Vec8f half(0.5f);
          const Vec8i o = offsets(floor_to_int(cx + half), floor_to_int(cy + half),
                                  floor_to_int(cz + half), sy, sz);
          if constexpr (std::is_same<TIn, float>::value)
            store_rounded(gather_float(volume, o), s.out + u);
          else  // integer volume: voxel values straight to the output, no float
            store_saturated(gather_value(volume, o), s.out + u);
        } else {
          const Vec8i ix = floor_to_int(cx), iy = floor_to_int(cy), iz = floor_to_int(cz);
          const Vec8i o00 = offsets(ix, iy, iz, sy, sz);
          Vec8f v000, v100, v010, v110, v001, v101, v011, v111;
          gather_pair(volume, o00, v000, v100);
          gather_pair(volume, o00 + sy, v010, v110);
          gather_pair(volume, o00 + sz, v001, v101);
          gather_pair(volume, o00 + (sz + sy), v011, v111);
          store_rounded(trilinear(cx - to_float(ix), cy - to_float(iy), cz - to_float(iz), v000,
                                  v100, v010, v110, v001, v101, v011, v111),
                        s.out + u);
        }
      }
      for (; u < end; ++u) pixel(s, u);
    }
  }
#endif
};

template <typename TIn, typename TOut, bool Linear, typename Index>
void run_slice_kernel(const SliceLaunch& launch) {
  SliceKernel<TIn, TOut, Linear, Index> k;
  k.volume = static_cast<const TIn*>(launch.volume);
  k.grid = launch.grid;
  k.poses = launch.poses;
  k.mask = launch.mask;
  k.out = static_cast<TOut*>(launch.out);
  k.width = launch.width;
  k.height = launch.height;
  k.fill = backend::saturate_cast<TOut>(launch.fill_value);
  backend::parallel_for_rows(launch.count * launch.height, launch.width, k, launch.stream);
}

template <typename TIn, typename TOut, bool Linear>
void run_slice_kernel(const SliceLaunch& launch) {
#if defined(__CUDACC__)
  // 32-bit voxel offsets where they suffice: on the GPU they save instructions and registers in
  // every gather. (The CPU's fast path already uses 32-bit lanes; its scalar edges stay 64-bit.)
  const int64_t voxels = launch.grid.stride_z * launch.grid.nz;
  if (voxels < (int64_t(1) << 31)) return run_slice_kernel<TIn, TOut, Linear, int32_t>(launch);
#endif
  run_slice_kernel<TIn, TOut, Linear, int64_t>(launch);
}

/// Type dispatch: volume type × output type × interpolation → one kernel instantiation.
inline void dispatch_slice(const SliceLaunch& launch) {
  visit_pixel_type(launch.volume_type, [&](auto in_zero) {
    using TIn = decltype(in_zero);
    // Slicer's constructor refuses other output types (is_slice_output_type).
    visit_pixel_type(
        KernelPixelTypes{}, launch.output_type,
        [&](auto out_zero) {
          using TOut = decltype(out_zero);
          if (launch.linear)
            run_slice_kernel<TIn, TOut, true>(launch);
          else
            run_slice_kernel<TIn, TOut, false>(launch);
        },
        "slicing kernels");
  });
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace slice_impl
}  // namespace sonoslice
