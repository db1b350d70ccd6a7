#pragma once
/// @file The CUDA driver of the compounding kernels: one thread per sample with atomic updates,
/// over the per-sample math of CompoundImpl.h. CompoundCUDA.cu includes this file.
///
/// Mean sums depend on the order in which threads arrive, to float rounding; max and
/// integer-valued nearest sums do not.
#include <cstdint>

#include "../backend/AtomicsCUDA.cuh"
#include "../backend/ParallelForCUDA.cuh"
#include "CompoundImpl.h"
#include "CompoundTypes.h"

namespace sonoslice {
namespace compound_impl {
inline namespace SONOSLICE_KERNEL_ISA {

/// Writes one sample's share into voxel i (any thread may touch any voxel): the atomic form of
/// gather() and merged().
template <Mode M>
__device__ __forceinline__ void apply_atomic(const AccumulatorView& g, int64_t i, float sample,
                                             float w) {
  Accumulator& a = g.cells[i];
  if (M == Mode::Max) {
    if (!counts_for_max(w)) return;
    // As gather() on the CPU: a NaN sample never wins the maximum (its bits would, as integers),
    // but its weight counts.
    if (sample == sample) backend::atomic_max_float(&a.value, sample);
    atomicAdd(&a.weight, w);
  } else {
    // value and weight side by side (Accumulator is 8-byte aligned): one atomic on sm_90.
    backend::atomic_add_pair(&a.value, w * sample, w);
  }
}

/// One thread per sample: row() finds the row's line and values, pixel() splats one sample.
/// Latest mode takes two passes over the whole batch. `claim_latest`, the first, stamps each voxel
/// with the newest frame that reaches it (atomicMax) and clears a voxel that still holds an
/// earlier batch's frame (every thread that clears writes the same zeros, and nothing adds in
/// this pass); the second adds only the samples of the frame the voxel is stamped with. The
/// result is the CPU's frame-by-frame "newest frame replaces", in two launches per batch.
template <typename T, Mode M, bool Linear>
struct SplatSamples {
  AccumulatorView g;
  FrameBatch b;
  int64_t first_row;  // rows first_row, first_row + 1, ... of the batch (all frames' rows)
  bool claim_latest;

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
    if (M != Mode::Latest) {
      apply_atomic<M>(g, i, s, w);
    } else if (claim_latest) {
      const int32_t before = atomicMax(&g.stamp[i], row.frame_id);
      if (before < b.first_frame_id && before < row.frame_id) {
        g.cells[i].value = 0.f;
        g.cells[i].weight = 0.f;
      }
    } else if (g.stamp[i] == row.frame_id) {
      apply_atomic<M>(g, i, s, w);
    }
  }
  __device__ void pixel(const Row& row, int u) const {
    const RowSpans& sp = *row.spans;
    bool inside = false;
    for (int k = 0; k < kMaxSpans; ++k) inside = inside || (u >= sp.begin[k] && u < sp.end[k]);
    if (!inside) return;
    const float s = sample_value(row.samples, u);
    if (rejected(s, b.rejection_threshold)) return;
    const RowLine& L = *row.line;
    const float fu = float(u);
    const float cx = sample_coordinate(L.c0[0], fu, L.dc[0]),
                cy = sample_coordinate(L.c0[1], fu, L.dc[1]),
                cz = sample_coordinate(L.c0[2], fu, L.dc[2]);
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

/// Mean and max do not depend on the order of the samples (to float rounding, for the mean):
/// one launch for the whole batch. Latest: two launches for the whole batch (SplatSamples).
template <typename T, Mode M, bool Linear>
void compound_batch_cuda(const AccumulatorView& g, const FrameBatch& b, void* stream) {
  using Kernel = SplatSamples<T, M, Linear>;
  const int64_t rows = int64_t(b.frames) * b.rows;
  if constexpr (M == Mode::Latest)
    backend::parallel_for_rows(rows, b.width, Kernel{g, b, 0, true}, stream);
  backend::parallel_for_rows(rows, b.width, Kernel{g, b, 0, false}, stream);
}

/// Calls the driver instantiated for the batch's sample type, mode and interpolation.
inline void dispatch_compound_cuda(const AccumulatorView& grid, const FrameBatch& batch, Mode mode,
                                   bool linear, void* stream) {
  visit_pixel_type(
      KernelPixelTypes{}, batch.type,
      [&](auto sample_zero) {
        using T = decltype(sample_zero);
        visit_mode(mode, linear, [&](auto mode_tag, auto linear_tag) {
          compound_batch_cuda<T, decltype(mode_tag)::value, decltype(linear_tag)::value>(
              grid, batch, stream);
        });
      },
      "compounding kernels");
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace compound_impl
}  // namespace sonoslice
