#pragma once
/// @file A PLUS configuration XML's volume-reconstruction settings and calibration.
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/compound/CompoundSettings.h"
#include "sonoslice/compound/FrameClip.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice {

/// What sonoslice uses from a PLUS configuration file.
struct PlusReconstructionConfig {
  std::string path;
  /// Every `CoordinateDefinitions/Transform` (From, To, Matrix), e.g. Image → Probe.
  TransformRepository coordinate_definitions;
  /// `VolumeReconstruction` attributes (PLUS defaults where absent).
  std::string image_frame = "Image", reference_frame = "Reference";
  std::optional<Vec3> output_spacing_mm, output_origin_mm;
  std::optional<std::array<int, 6>> output_extent;  ///< i0 i1 j0 j1 k0 k1, inclusive
  CompoundSettings settings;                        ///< interpolation, mode, threshold, holes
  FrameClip clip;                                   ///< clip rectangle and fan
  int skip_interval = 1;                            ///< use frames 0, k, 2k, ...
  /// The Optimization attribute (NONE, PARTIAL, FULL, GPU), upper case; empty when absent.
  /// Only --plus-exact acts on it (parse_plus_optimization, in the reconstruction recipe).
  std::string optimization;
  /// Attributes of `VolumeReconstruction` (and its hole-filling elements) that sonoslice read
  /// but does not act on (NumberOfThreads: sonoslice picks its own).
  std::vector<std::string> ignored_attributes;
  /// Attributes PLUS does not define (typos, newer PLUS versions); the reader also warns.
  std::vector<std::string> unknown_attributes;

  /// The output grid the XML fixes when it gives OutputSpacing, OutputOrigin and OutputExtent:
  /// voxel (0,0,0) at origin + (i0, j0, k0) * spacing, (i1 - i0 + 1) x (j1 - j0 + 1) x
  /// (k1 - k0 + 1) voxels; std::nullopt when any of the three is absent.
  std::optional<VolumeGrid> output_grid() const;
};

/// Reads `path`. Errors (FileError / InputError) name the file, the element and the attribute:
/// missing file, malformed XML, no VolumeReconstruction element, a value that does not parse, an
/// unknown enumerated value, IMPORTANCE_MASK compounding (not supported). Enumerated values are
/// case-insensitive as in PLUS. Where an attribute is absent PLUS's default applies:
/// Interpolation NEAREST_NEIGHBOR; CompoundingMode from the deprecated Calculation/Compounding,
/// else MEAN (with a warning); no clipping; no fan. Deprecated attributes, unknown ones (one
/// warning listing them all) and unsupported options that are switched on are reported through
/// sonoslice::warn. Throws Error in a build without pugixml.
PlusReconstructionConfig read_plus_config(const std::string& path);

/// The OutputSpacing, OutputOrigin and OutputExtent attributes of one XML element given as text
/// (a PlusServer command such as StartVolumeReconstruction carries them as a configuration's
/// VolumeReconstruction element does), each optional and checked as read_plus_config checks them;
/// only those three fields of the result are set. InputError "<source>: Command/@OutputExtent:
/// ..." for a value that does not parse.
PlusReconstructionConfig read_plus_output_grid(const std::string& element_xml,
                                               const std::string& source);

}  // namespace sonoslice
