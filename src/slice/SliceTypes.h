#pragma once
/// @file Plain structs that carry slicing geometry from the dispatch layer (Slicer.cpp) to the
/// kernels (SliceImpl.h). Trivially copyable, captured by value on every backend.
#include <cstdint>

#include "../geometry/Sampling.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace slice_impl {

using geometry::VolumeView;

/// Per image: the continuous volume index of pixel (0, 0)'s centre and its change per image
/// column (u) and per image row (v). c(u, v) = origin + u·per_column + v·per_row.
struct PixelToIndex {
  float origin[3];
  float per_column[3];
  float per_row[3];
};

/// Everything one kernel launch needs; pointers are device-accessible for the chosen backend.
struct SliceLaunch {
  const void* volume;
  PixelType volume_type;
  VolumeView grid;
  const PixelToIndex* poses;
  int64_t count;  // images
  const uint8_t* mask;
  void* out;
  PixelType output_type;
  int width, height;
  double fill_value;
  bool linear;
  void* stream;  // CUDA stream (cudaStream_t) or null
};

}  // namespace slice_impl
}  // namespace sonoslice
