#pragma once
/// @file Reading and writing volumes with their full geometry: NIfTI (.nii, .nii.gz), MetaImage
/// (.mha, .mhd), NRRD (.nrrd, .nhdr) and DICOM series through ITK; NumPy .npy natively.
/// Voxels stay in their native pixel type.
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

class OutputSet;

struct VolumeReadOptions {
  /// DICOM directory: the SeriesInstanceUID to read (default: the series with the most files).
  std::string series_uid;
  /// .npy geometry (docs/conventions.md §1); flags win over a sidecar `<name>.json` beside the
  /// .npy, which wins over the defaults (spacing 1 mm, origin 0, identity direction; with a
  /// warning).
  std::optional<Vec3> spacing_mm, origin_mm;
  std::optional<Mat3> direction;
  /// fan-slicer's `npy_config` JSON ("voxel size", "bounding box"): the .npy is then read with
  /// fan-slicer's axis order [Y, X, Z] (docs/conventions.md §4).
  std::string fanslicer_npy_config;
};

/// Reads a volume file or DICOM directory. Errors (FileError / InputError) name the path and
/// say why: missing, corrupt or truncated file, unsupported pixel type (RGB, complex, 64-bit
/// integers), 4-D data, bad geometry.
Volume read_volume(const std::string& path, const VolumeReadOptions& options = {});

/// One DICOM series found in a directory.
struct DicomSeriesInfo {
  std::string uid;
  size_t file_count = 0;
};
std::vector<DicomSeriesInfo> list_dicom_series(const std::string& directory);

/// A stack of 2-D images as a volume of (W, H, N): any volume file (.npy (N, H, W), .nii, .mha,
/// .nrrd: what `slice --out` writes), a 2-D .npy (H, W) as a stack of one (what `slice --mask`
/// writes), or a folder of .png images (read in name order, all of one size and type, as
/// `slice --out DIR/` writes them). FileError / InputError naming `what`.
Volume read_image_stack(const std::string& path, const std::string& what);

/// Writes a volume atomically: .npy (C order (nz, ny, nx), geometry in a sidecar .json) or any
/// ITK format chosen by extension. With `together`, the checked output waits for that set's
/// commit(), so that the outputs of one run go into place together or not at all.
void write_volume(const std::string& path, const Volume& volume, OutputSet* together = nullptr);

/// Writes an N-D (2 or 3) image atomically, through ITK or as .npy (C order, slowest axis
/// first): dims/spacing per axis, zero origin, identity direction. `components` = 3 writes RGB
/// (uint8; .npy gets a trailing axis of 3). Used for output stacks, masks and PNGs.
/// `together`: as for write_volume.
void write_image(const std::string& path, const void* data, PixelType type,
                 const std::vector<int64_t>& dims, const std::vector<double>& spacing,
                 int components = 1, OutputSet* together = nullptr);

/// True when this build reads and writes ITK formats (otherwise only .npy).
bool built_with_itk();

/// Lower-case file extension with compound endings kept whole (".nii.gz", ".seq.mha"... as
/// ".nii.gz", ".mha"); "" for none.
std::string file_extension(const std::string& path);

/// The image formats sonoslice reads and writes. Every reader and writer, and every front end,
/// asks image_format() rather than comparing extensions, so a new format is one enum value, one
/// line in image_format() and its reader/writer.
enum class ImageFormat {
  Npy,        ///< .npy (native)
  Nifti,      ///< .nii, .nii.gz (ITK)
  MetaImage,  ///< .mha, .mhd (ITK)
  Nrrd,       ///< .nrrd, .nhdr (ITK)
  Png,        ///< .png, 2-D only (ITK)
  Dicom,      ///< .dcm: one DICOM file (a multi-frame ultrasound clip, a slice), read only (ITK)
  Directory   ///< no extension: a DICOM series to read, or a folder of PNGs to write
};
const char* to_string(ImageFormat format);  ///< "npy", "NIfTI", "MetaImage", "NRRD", ...
/// The format of `path` from its extension (an existing directory, a path ending in '/' or one
/// without extension: Directory). InputError naming `what` and the path otherwise.
ImageFormat image_format(const std::string& path, const std::string& what = "file");
/// True for formats that need ITK (all but .npy and .png).
bool needs_itk(ImageFormat format);

/// Checks, before any work, that `path` names a volume file this build can write (a 3-D format)
/// in a writable folder; InputError / FileError naming `what` and the path.
void check_volume_output(const std::string& path, const std::string& what = "output");
/// The same for a single 2-D image (also .png).
void check_image_output(const std::string& path, const std::string& what = "output");

}  // namespace sonoslice
