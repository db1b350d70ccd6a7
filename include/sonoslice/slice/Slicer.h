#pragma once
/// @file Slicing: a batch of probe poses through a volume → a batch of ultrasound-shaped images.
#include <cstdint>
#include <string>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

enum class Interpolation { Linear, Nearest };
Interpolation parse_interpolation(const std::string& name);  ///< "linear" / "nearest"
std::string interpolation_name(Interpolation interpolation);

struct SliceSettings {
  Interpolation interpolation = Interpolation::Linear;
  /// Value of pixels outside the probe shape or outside the volume (in output units).
  double fill_value = 0.0;
  /// float32 (default), int16, uint8 or uint16; integer outputs round and saturate.
  PixelType output_type = PixelType::Float32;
};

/// Bound to one volume, one probe and one device. The volume is shared, not copied.
class Slicer {
 public:
  Slicer(Volume volume, ProbeGeometry probe, SliceSettings settings = {},
         Device device = Device::cpu());

  const Volume& volume() const { return volume_; }
  const ProbeGeometry& probe() const { return probe_; }
  const SliceSettings& settings() const { return settings_; }
  int width() const { return probe_.image.width; }
  int height() const { return probe_.image.height; }
  /// The H×W fan mask (1 inside the probe shape), row-major.
  const std::vector<uint8_t>& mask() const { return mask_; }
  /// Bytes of one output image.
  size_t image_bytes() const;

  /// Slices `count` poses (probe mm → world mm, LPS) into `out`, a C-order (count, H, W) array
  /// of settings().output_type. Poses are checked first (InputError naming "pose <i>", with i
  /// counted from `first_index`); nothing is written when one is bad.
  void slice(const Pose* poses, size_t count, void* out, size_t first_index = 0) const;

  /// Convenience: slices into a new buffer of count·H·W elements of type T (T must match
  /// settings().output_type).
  template <typename T>
  std::vector<T> slice(const std::vector<Pose>& poses) const {
    std::vector<T> out(poses.size() * size_t(width()) * size_t(height()));
    check_output_type(PixelTypeOf<T>::value);
    slice(poses.data(), poses.size(), out.data());
    return out;
  }

 private:
  void check_output_type(PixelType type) const;

  Volume volume_;
  ProbeGeometry probe_;
  SliceSettings settings_;
  Device device_;
  std::vector<uint8_t> mask_;
};

}  // namespace sonoslice
