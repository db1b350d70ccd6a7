#pragma once
// Internal: the ITK side of the IO library (compiled only when ITK is found).
#include <cstdint>
#include <string>
#include <vector>

#include "sonoslice/io/VolumeFile.h"

namespace sonoslice {
namespace itk_io {

/// How an image of several components is read: refused (volumes are scalar), or, for images that
/// are frames, an RGB/RGBA image as its first component (as PLUS reconstructs colour frames).
enum class ImageChannels { ScalarOnly, FirstOfColour };

/// With FirstOfColour, a warning says how many pixels of a colour image have colour (R, G and B
/// differ: not grey stored as colour), or that count is added to `*colour_pixels` if given.
Volume read_image_file(const std::string& path, ImageChannels channels = ImageChannels::ScalarOnly,
                       int64_t* colour_pixels = nullptr);
Volume read_dicom_directory(const std::string& directory, const std::string& series_uid);
std::vector<DicomSeriesInfo> list_dicom_series(const std::string& directory);
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
