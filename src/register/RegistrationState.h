#pragma once
// Internal: what a FrameRegistration holds (the probe, the float volume, the pyramid of frames
// and volume, each frame's centre, MI's intensity ranges), shared by its stages: the pyramid
// (Pyramid.cpp), the metrics (Metrics.cpp) and the driver (Registration.cpp).
#include <array>
#include <deque>
#include <string>
#include <vector>

#include "sonoslice/core/Error.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice {
namespace register_impl {

/// One pyramid level: every frame and the mask averaged over f² pixel blocks, the volume over
/// g³ voxel blocks, g the largest whole number of voxels within f pixels (at least 1): a volume
/// already coarser than the blocks is not averaged again.
struct Level {
  int f = 1, g = 1;
  std::vector<float> volume_copy;  // empty: the full-resolution volume, shared
  const float* volume = nullptr;
  const int16_t* volume16 = nullptr;  // instead of `volume`: the full-resolution int16 volume
  int nx = 0, ny = 0, nz = 0;
  std::vector<float> frames;   // count × w × h
  std::vector<uint8_t> masks;  // count × w × h (fan ∧ user ∧ finite)
  std::vector<int32_t> spans;  // count × h × 2: each row's mask columns [first, end)
  int width = 0, height = 0;
};

}  // namespace register_impl

struct FrameRegistration::State {
  ProbeGeometry probe;
  VolumeGrid grid;
  Mat3 L;  // world → index, linear (the gradients' chain rule)
  size_t count = 0;
  Volume volume;  // float32 or int16: the caller's (shared), else a float32 copy
  std::deque<register_impl::Level> levels;  // only added to: references to a level stay valid
  std::vector<Vec3> mask_centre;  // per frame: the centroid of its compared pixels (probe mm)
  // Pixels inside the fan and the user's mask, and how many of them are NaN or infinite (left out).
  size_t masked_pixels = 0, non_finite_pixels = 0;
  // MI's intensity ranges: the volume's and each frame's 1st and 99th percentiles.
  double volume_range[2] = {0, 1};
  std::vector<std::array<double, 2>> frame_range;

  /// Voxel i of `volume` (float32 or int16).
  double voxel(int64_t i) const {
    return volume.pixel_type() == PixelType::Int16 ? double(volume.data_as<int16_t>()[i])
                                                   : double(volume.data_as<float>()[i]);
  }
  const register_impl::Level& level(int f) const {
    for (const register_impl::Level& l : levels)
      if (l.f == f) return l;
    throw InputError("pyramid: level " + std::to_string(f) + " was not prepared");
  }
  /// Level f, made when first asked for: level 1 from the caller's frames and the H×W mask,
  /// the others from level 1.
  const register_impl::Level& make_level(int f, const float* frames = nullptr,
                                         const uint8_t* mask = nullptr);
};

}  // namespace sonoslice
