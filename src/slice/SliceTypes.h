#pragma once
/// @file Plain structs that carry slicing geometry from the dispatch layer (Slicer.cpp) to the
/// kernels (SliceImpl.h). Trivially copyable, captured by value on every backend.
#include <cstdint>

#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace slice_impl {

/// Volume extent and memory strides (in voxels; x is contiguous).
struct VolumeView {
  int nx, ny, nz;
  int64_t stride_y;  // = nx
  int64_t stride_z;  // = nx * ny
};

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

/// Output pixel types the slicer writes.
template <typename F>
decltype(auto) visit_output_type(PixelType type, F&& f) {
  switch (type) {
    case PixelType::UInt8:
      return f(uint8_t{});
    case PixelType::Int16:
      return f(int16_t{});
    case PixelType::UInt16:
      return f(uint16_t{});
    case PixelType::Float32:
      return f(float{});
    case PixelType::Int8:
    case PixelType::UInt32:
    case PixelType::Int32:
    case PixelType::Float64:
      break;  // Slicer's constructor refuses these output types (is_slice_output_type)
  }
  throw Error("slicing kernels: no kernel writes " + to_string(type) + " images");
}

}  // namespace slice_impl
}  // namespace sonoslice
