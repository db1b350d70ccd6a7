#pragma once
// Internal: the plain structs the compounding kernels (CompoundImpl.h, the drivers) take, shared by
// the dispatch layer (Compounder.cpp) and every backend. No pointers are checked below this layer.
#include <cstdint>
#include <limits>

#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace compound_impl {

/// One accumulator per voxel: the running value (weighted sum for mean and latest, maximum for
/// max) and the summed splat weight (0: no sample yet). Interleaved so that a splat touches one
/// cache line per voxel.
// 8-byte aligned: the CUDA kernels add to value and weight with one float2 atomic (sm_90).
struct alignas(8) Accumulator {
  float value;
  float weight;
};
static_assert(sizeof(Accumulator) == 8, "value and weight side by side");

/// The accumulator grid: x fastest. `stamp` (latest mode only) holds the last frame that wrote
/// each voxel, so a newer frame replaces older samples instead of averaging with them.
struct AccumulatorView {
  int nx = 0, ny = 0, nz = 0;
  Accumulator* cells = nullptr;
  int32_t* stamp = nullptr;

  SONOSLICE_HOST_DEVICE bool contains(int x, int y, int z) const {
    return x >= 0 && y >= 0 && z >= 0 && x < nx && y < ny && z < nz;
  }
  SONOSLICE_HOST_DEVICE int64_t offset(int x, int y, int z) const {
    return (int64_t(z) * ny + y) * nx + x;
  }
};

enum class Mode : int { Mean = 0, Max = 1, Latest = 2 };

/// An accumulator's value before any sample: the sum 0, or -inf for a maximum.
SONOSLICE_HOST_DEVICE constexpr float empty_value(Mode mode) {
  return mode == Mode::Max ? -std::numeric_limits<float>::infinity() : 0.f;
}

/// A row of samples: a straight line in voxel-index space, sample u at c0 + u·dc. Image rows
/// and 3-D beams are both rows.
struct RowLine {
  float c0[3];
  float dc[3];
};

/// The samples of a row that go in: up to four runs [begin, end) (a fan of up to 180° cuts a
/// row at most twice, a wider one four times); unused runs have begin == end.
constexpr int kMaxSpans = 4;
struct RowSpans {
  int begin[kMaxSpans];
  int end[kMaxSpans];
};

/// A batch of frames: rows × width samples each, rows of all frames stored frame after frame.
struct FrameBatch {
  int frames = 0;
  int rows = 0;   ///< rows per frame (image height, or n_elevation × n_azimuth beams)
  int width = 0;  ///< samples per row
  PixelType type = PixelType::UInt8;
  const void* samples = nullptr;         ///< frames × rows × width
  const RowLine* lines = nullptr;        ///< frames × rows
  const RowSpans* spans = nullptr;       ///< rows (the same for every frame)
  int32_t first_frame_id = 0;            ///< frame ids (latest mode) are first_frame_id + f
  float rejection_threshold = -3.4e38f;  ///< samples below it are not inserted
};

/// Where a CPU task may write: voxels whose index along the slab axis (the kernels' Axis) is in
/// [lo, hi).
struct Slab {
  int lo = 0, hi = 0;
};

}  // namespace compound_impl
}  // namespace sonoslice
