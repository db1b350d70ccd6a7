#pragma once
/// @file Freehand 3D reconstruction (docs/conventions.md §7): tracked 2D frames and 3D beam-space
/// frames inserted ("compounded") into one voxel grid, as PLUS toolkit's volume reconstructor does.
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Interpolation.h"
#include "sonoslice/core/Memory.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// How samples that land in one voxel combine.
enum class CompoundingMode {
  Mean,   ///< the splat-weighted mean of the samples
  Max,    ///< their maximum (samples with a splat weight >= 1/8)
  Latest  ///< the newest frame that reached the voxel
};
const char* to_string(CompoundingMode mode);                      ///< "mean", "max", "latest"
CompoundingMode parse_compounding_mode(const std::string& name);  ///< also "maximum"; any case

/// One hole-filling element (PLUS's HoleFillingElement), with PLUS's rules (docs/compounding.md
/// §4a). A hole is a voxel where PLUS's accumulation buffer would be 0 (no sample, or linear
/// splat weights below 1/512); holes are filled from the voxels samples did reach (never from
/// other filled holes), by the first element of the list that can.
struct HoleFillingKernel {
  enum Type {
    NearestNeighbor,        ///< mean of the known voxels in the smallest cube around the hole
                            ///< (radius 1 .. (size-1)/2) that has any
    Gaussian,               ///< Gaussian-weighted mean of the known voxels in the size³ cube
    GaussianAccumulation,   ///< the same, each voxel's weight also scaled by its splat weight
    DistanceWeightInverse,  ///< 1/distance-weighted mean of the known voxels in the size³ cube
    Stick                   ///< PLUS's weighted ends of the shortest of 13 lines through the
                            ///< hole with known voxels at both ends
  } type = Gaussian;
  int size = 3;           ///< cube edge in voxels (odd)
  double stdev = 0.6667;  ///< Gaussian, in voxels
  /// The element applies only when more than this fraction of the size³ cube's voxels are known
  /// (voxels outside the grid count as unknown; nearest neighbour: those of the first radius with
  /// any, still over size³).
  double minimum_known_ratio = 0.5;
  int stick_length_limit = 9;  ///< Stick: the longest stick, in voxels, ends included
  int sticks_to_use = 1;       ///< Stick: how many of the shortest sticks are averaged
  /// The farthest voxel (in voxels along an axis) this element reads around a hole.
  int reach() const;
  void validate(const std::string& what) const;
};
/// "nearest_neighbor", "gaussian", "gaussian_accumulation", "distance_weight_inverse", "stick".
const char* to_string(HoleFillingKernel::Type type);
/// The names above or PLUS's (NEAREST_NEIGHBOR, GAUSSIAN, ...), any case.
HoleFillingKernel::Type parse_hole_filling_type(const std::string& name);

/// PLUS's Optimization attribute: which insertion arithmetic PLUS uses (docs/compounding.md §4b).
/// None: positions in double, pixel by pixel with bounds tests. Partial: per row, the pixels
/// that land inside the volume (vtkUltraFindExtent), positions in double. Full (PLUS's
/// default): the same with positions and trilinear weights in 14-bit fixed point.
enum class PlusOptimization { None, Partial, Full };
/// PLUS's names NONE, PARTIAL, FULL, any case (also the CLI's none/partial/full). InputError for
/// GPU (PLUS's OpenCL path, not reproduced) and anything else; `what` names the input.
PlusOptimization parse_plus_optimization(const std::string& name, const std::string& what);

struct CompoundSettings {
  Interpolation interpolation = Interpolation::Linear;  ///< how a sample splats into voxels
  CompoundingMode mode = CompoundingMode::Mean;
  /// Samples below this value are not inserted (PLUS's PixelRejectionThreshold).
  double rejection_threshold = -std::numeric_limits<double>::infinity();
  bool fill_holes = false;
  /// Applied in order; a hole takes the first kernel that can fill it from the samples.
  std::vector<HoleFillingKernel> hole_filling{HoleFillingKernel{}};
  /// PLUS's arithmetic bit for bit (docs/compounding.md §4b): the volume kept in the frames'
  /// type and rounded after every update, PLUS's uint16 accumulation buffer, its nearest and
  /// trilinear update rules, its clip extent and fan test, on the path `plus_optimization`
  /// names. 2D frames of uint8, int16, uint16 or float32 on the CPU; volume() must be asked for
  /// the frames' type. Deterministic for any thread count (the single-threaded PLUS result).
  bool plus_exact = false;
  /// Which of PLUS's insertion paths plus_exact follows (PLUS's Optimization attribute).
  PlusOptimization plus_optimization = PlusOptimization::Full;
};

/// Which pixels of a 2D frame go in: a clip rectangle and, optionally, a fan (PLUS's
/// ClipRectangle*, FanAnglesDeg, FanOriginPixel, FanRadiusStart/StopPixel), in MF-oriented pixels.
/// The rectangle is width × height pixels from (x, y); PLUS's ClipRectangleSize w covers w + 1
/// pixels (its last pixel is x + w), which read_plus_config converts.
struct FrameClip {
  int x = 0, y = 0, width = -1, height = -1;  ///< width/height -1: to the frame's edge
  bool fan = false;
  double fan_angles_deg[2] = {-90, 90};  ///< from the axial direction (+y), x towards +
  double fan_origin_px[2] = {0, 0};
  double fan_radius_px[2] = {0, std::numeric_limits<double>::infinity()};
  /// An explicit H×W mask (1: inserted) instead of the rectangle and fan, e.g. a sonoslice
  /// probe's fan (ProbeGeometry::mask()) for frames the slicer made.
  std::vector<uint8_t> custom_mask;
  /// The H×W uint8 mask (1: inserted) of a frame's pixels that go in.
  std::vector<uint8_t> mask(int frame_width, int frame_height) const;
  /// The clip rectangle intersected with the frame (or the box around a custom mask's pixels):
  /// pixels [x0, x1) × [y0, y1).
  std::array<int, 4> rectangle(int frame_width, int frame_height) const;
  /// InputError naming `what` and the field for a negative x, y or size, NaN angles or radii,
  /// angles outside (-90°, 90°).
  void validate(const std::string& what) const;
};

/// A 3D beam-space frame's geometry (docs/conventions.md §7): sample s of the beam at azimuth
/// α = α0 + a·dα and elevation β = β0 + e·dβ lies at probe coordinates
/// apex + (r0 + s·dr)·(sin α, cos α·cos β, cos α·sin β), apex = (0, -apex_offset_mm, 0).
struct BeamGeometry {
  int n_elevation = 0, n_azimuth = 0, n_samples = 0;
  double r0_mm = 0, dr_mm = 1;
  double azimuth0_deg = 0, dazimuth_deg = 1;
  double elevation0_deg = 0, delevation_deg = 1;
  double apex_offset_mm = 0;
  void validate(const std::string& what) const;
};

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
