#pragma once
/// @file How a reconstruction combines its samples (docs/compounding.md): the compounding mode,
/// hole filling, PLUS's insertion arithmetic, and the settings that hold them.
#include <limits>
#include <string>
#include <vector>

#include "sonoslice/core/Interpolation.h"

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
  void validate(const std::string& what) const;
};
/// Every hole-filling element (PLUS's documentation order): the one list both readers (PLUS's
/// XML, the bindings) take their names from.
constexpr HoleFillingKernel::Type kHoleFillingTypes[] = {
    HoleFillingKernel::Gaussian, HoleFillingKernel::GaussianAccumulation, HoleFillingKernel::Stick,
    HoleFillingKernel::NearestNeighbor, HoleFillingKernel::DistanceWeightInverse};
/// "nearest_neighbor", "gaussian", "gaussian_accumulation", "distance_weight_inverse", "stick";
/// PLUS spells them in upper case.
const char* to_string(HoleFillingKernel::Type type);
/// PLUS's spellings of kHoleFillingTypes for a message: "GAUSSIAN, ... or DISTANCE_WEIGHT_INVERSE".
std::string plus_hole_filling_names();
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
  std::vector<HoleFillingKernel> hole_filling = std::vector<HoleFillingKernel>(1);
  /// PLUS's arithmetic bit for bit (docs/compounding.md §4b): the volume kept in the frames'
  /// type and rounded after every update, PLUS's uint16 accumulation buffer, its nearest and
  /// trilinear update rules, its clip extent and fan test, on the path `plus_optimization`
  /// names. 2D frames of uint8, int16, uint16 or float32 on the CPU; volume() must be asked for
  /// the frames' type. Deterministic for any thread count (the single-threaded PLUS result).
  bool plus_exact = false;
  /// Which of PLUS's insertion paths plus_exact follows (PLUS's Optimization attribute).
  PlusOptimization plus_optimization = PlusOptimization::Full;
};

}  // namespace sonoslice
