#pragma once
/// @file A 3D volume in its native pixel type with its world geometry.
#include <cstdint>
#include <memory>
#include <string>

#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

/// A cheap, shareable handle to voxel data (x fastest, then y, then z) plus its geometry.
/// The buffer is owned by `owner` (an ITK image, a std::vector, a NumPy array...), so readers
/// hand their buffers over without copying.
class Volume {
 public:
  Volume() = default;

  /// Allocates a zero-filled volume. Throws ResourceError when the memory is not available.
  static Volume allocate(PixelType type, const VolumeGrid& grid);

  /// Wraps existing memory; `owner` keeps it alive (may be null for caller-managed memory).
  static Volume wrap(void* data, PixelType type, const VolumeGrid& grid,
                     std::shared_ptr<void> owner);

  bool empty() const { return data_ == nullptr; }
  PixelType pixel_type() const { return type_; }
  const VolumeGrid& grid() const { return grid_; }
  VolumeGrid& grid() { return grid_; }
  const void* data() const { return data_; }
  void* data() { return data_; }
  size_t byte_size() const { return size_t(grid_.voxel_count()) * pixel_size(type_); }

  template <typename T>
  const T* data_as() const {
    return static_cast<const T*>(data_);
  }
  template <typename T>
  T* data_as() {
    return static_cast<T*>(data_);
  }

  /// Minimum and maximum voxel value (NaNs ignored), computed in parallel.
  std::pair<double, double> value_range() const;

  /// How many voxels are NaN or infinite (0 for integer types), counted in parallel.
  int64_t non_finite_count() const;

  /// A copy converted to another pixel type (saturating, rounding to nearest).
  Volume converted(PixelType type) const;

 private:
  PixelType type_ = PixelType::Float32;
  VolumeGrid grid_;
  void* data_ = nullptr;
  std::shared_ptr<void> owner_;
};

/// Throws InputError "<what>: a label volume is uint8 or uint16, this one is <type>" unless
/// `labels` holds one of the two label types (a CT given as labels would otherwise be read as
/// thousands of labels).
void check_label_volume(const Volume& labels, const std::string& what);

/// Throws InputError naming `what` unless `labels` holds integers in 0..65535 (any integer
/// type: segmentations exported as int16 are common; a CT's negative HU are refused).
void check_label_values(const Volume& labels, const std::string& what);

/// How many of the `count` values of `type` at `data` are NaN or infinite (0 for integer types).
int64_t count_non_finite(const void* data, PixelType type, int64_t count);

}  // namespace sonoslice
