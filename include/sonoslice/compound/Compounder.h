#pragma once
/// @file Freehand 3D reconstruction (docs/conventions.md §7): tracked 2D frames and 3D beam-space
/// frames inserted ("compounded") into one voxel grid, as PLUS toolkit's volume reconstructor does.
#include <cstdint>
#include <memory>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/compound/BeamGeometry.h"
#include "sonoslice/compound/CompoundSettings.h"
#include "sonoslice/compound/FrameClip.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// Memory (bytes) a reconstruction on `grid` with `settings` holds: accumulators plus the result.
uint64_t compounding_memory_bytes(const VolumeGrid& grid, const CompoundSettings& settings,
                                  PixelType output_type);

/// Accepts frames one at a time (or in batches) and returns the volume at any point; the result
/// is bit-identical to a batch run over the same frames, for any thread count: each voxel is
/// owned by one thread per frame and receives its samples in a fixed order.
class Compounder {
 public:
  /// `grid`: the output voxel grid in the reference frame (world mm; any direction, though
  /// PLUS-style grids are axis-aligned). Throws ResourceError, before allocating anything, when
  /// the accumulators plus an `output_type` result do not fit in `max_memory_bytes` (0: what
  /// the machine has), naming the size and a spacing that fits.
  Compounder(const VolumeGrid& grid, CompoundSettings settings, Device device = Device::cpu(),
             uint64_t max_memory_bytes = 0, PixelType output_type = PixelType::UInt8);
  ~Compounder();
  Compounder(Compounder&&) noexcept;

  const VolumeGrid& grid() const;
  const CompoundSettings& settings() const;
  int64_t frames_added() const;

  /// A 2D frame: `pixels` (H×W, row-major, uint8/uint16/int16/float32) in MF orientation,
  /// `image_to_reference` maps pixel (i, j) at (i, j, 0) to reference mm.
  void add_image(const void* pixels, PixelType type, int width, int height,
                 const Mat4& image_to_reference, const FrameClip& clip = {});
  /// `count` frames stored one after the other, with one matrix each; the same result as
  /// `count` calls of add_image, faster (one pass over the output per batch).
  void add_images(const void* pixels, PixelType type, int width, int height, int64_t count,
                  const Mat4* image_to_reference, const FrameClip& clip = {});
  /// A 3D beam-space frame: (n_elevation, n_azimuth, n_samples), samples fastest;
  /// `probe_to_reference` maps probe mm to reference mm.
  void add_beams(const void* samples, PixelType type, const BeamGeometry& geometry,
                 const Mat4& probe_to_reference);
  void add_beams(const void* samples, PixelType type, const BeamGeometry& geometry, int64_t count,
                 const Mat4* probe_to_reference);

  /// The reconstruction so far: sample values combined by the compounding mode, empty voxels 0,
  /// holes filled when the settings say so; in `type` (rounded, saturated).
  Volume volume(PixelType type = PixelType::UInt8) const;
  /// The accumulated weight per voxel (float32): 0 where no sample arrived.
  Volume weights() const;

  /// How a grid is fitted to the box [min, max] around the frames, per axis (spacing s).
  enum class GridFit {
    Round,       ///< sonoslice: origin at min, round((max - min) / s) + 1 voxels
    PlusLegacy,  ///< PLUS up to 2.4 (its NWire reference): origin at min, int((max - min) / s) + 1
    PlusLattice  ///< current PLUS (IGSIO): origin floor(min / s)·s, ceil((max - origin) / s) + 1
  };
  /// Frames' footprints: the grid (axes parallel to the reference frame, `spacing_mm`) around the
  /// clipped frames, as PLUS computes it: the box around the clip rectangle's corner pixel centres
  /// over all frames, fitted by `fit`.
  static VolumeGrid grid_around(const std::vector<Mat4>& image_to_reference, int width, int height,
                                const FrameClip& clip, const Vec3& spacing_mm,
                                GridFit fit = GridFit::Round);
  /// The same for beam-space frames: the box around every beam's first and last sample.
  static VolumeGrid grid_around_beams(const std::vector<Mat4>& probe_to_reference,
                                      const BeamGeometry& geometry, const Vec3& spacing_mm);
  static VolumeGrid grid_around(const std::vector<Mat4>& image_to_reference, int width, int height,
                                const FrameClip& clip, double spacing_mm) {
    return grid_around(image_to_reference, width, height, clip,
                       Vec3{{spacing_mm, spacing_mm, spacing_mm}});
  }
  static VolumeGrid grid_around_beams(const std::vector<Mat4>& probe_to_reference,
                                      const BeamGeometry& geometry, double spacing_mm) {
    return grid_around_beams(probe_to_reference, geometry,
                             Vec3{{spacing_mm, spacing_mm, spacing_mm}});
  }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace sonoslice
