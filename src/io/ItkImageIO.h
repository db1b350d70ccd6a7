#pragma once
// Internal: the ITK side of the IO library (compiled only when ITK is found).
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace itk_io {

/// `colour_pixels` null: a volume, of one component. Otherwise the image is a frame: an RGB/RGBA
/// image is read as its first component (as PLUS reconstructs colour frames) and the count of its
/// pixels whose R, G and B differ (not grey stored as colour) is added to `*colour_pixels`, for
/// the caller to say once.
Volume read_image_file(const std::string& path, int64_t* colour_pixels = nullptr);
Volume read_dicom_directory(const std::string& directory, const std::string& series_uid);
std::vector<DicomSeriesInfo> list_dicom_series(const std::string& directory);
/// The InstanceNumber (0020,0013) of a DICOM file, if it has one that is a whole number (its
/// structure is walked first, dicom::check_structure; `where` names it in errors).
std::optional<int64_t> dicom_instance_number(const std::string& file, const std::string& where);
/// Writes to exactly `path` (the caller handles temporary names). ITK's writers do not all report
/// failed writes (NIfTI and MetaImage print a line and carry on), so the caller must check the
/// file with verify_image_file(); returns what the libraries printed meanwhile, as one line.
std::string write_image(const std::string& path, const void* data, PixelType type,
                        const std::vector<int64_t>& dims, const std::vector<double>& spacing,
                        const std::vector<double>& origin, const std::vector<double>& direction,
                        int components = 1);
/// Reads `path` back in full: FileError unless it holds every voxel of an image of `dims`,
/// `type` and `components` (what a full disk or a file-size limit leaves is caught here).
void verify_image_file(const std::string& path, PixelType type, const std::vector<int64_t>& dims,
                       int components);

}  // namespace itk_io
}  // namespace sonoslice
