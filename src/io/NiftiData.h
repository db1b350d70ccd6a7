#pragma once
// Internal: NIfTI voxel data read by sonoslice itself, with ITK still reading the header and the
// geometry. ITK 5.2's NiftiImageIO holds two copies of the voxels while reading (its own buffer,
// then a copy into the image: 2× a CT's memory), and zero-fills the voxels of a truncated file
// without an error; this path reads once into the volume's buffer (or maps an uncompressed file)
// and treats a short file as the error it is.
#include <cstdint>
#include <optional>
#include <string>

#include "sonoslice/volume/Volume.h"

namespace sonoslice {
namespace itk_io {

/// Checks the header of a NIfTI-1/2 (or Analyze 7.5) file, .nii, .nii.gz or a .hdr/.img pair,
/// before ITK and the NIfTI C library see it: FileError for a corrupt header (dimensions, data
/// type) or an uncompressed file shorter than its voxels, InputError for sizes whose byte count
/// overflows, a zero, negative or NaN spacing (pixdim), a NaN slope with an intercept (or a slope
/// of 0 with one), and non-finite qform/sform fields. The NIfTI library would print a line to
/// stderr, turn the spacing into 1 mm or abort inside ITK's matrix code instead.
void check_nifti_header(const std::string& path);

/// Reads the voxels of the .nii / .nii.gz at `path` into a volume with geometry `grid`, when the
/// file stores exactly `type` (no scl_slope/scl_inter rescale, which ITK applies by converting
/// to float: then std::nullopt, and the caller lets ITK read). FileError for a truncated file.
std::optional<Volume> read_nifti_voxels(const std::string& path, const VolumeGrid& grid,
                                        PixelType type);

}  // namespace itk_io
}  // namespace sonoslice
