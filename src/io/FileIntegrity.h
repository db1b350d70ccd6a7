#pragma once
// Internal: checks that a volume file holds all the voxel bytes its header announces.
#include <cstdint>
#include <string>

namespace sonoslice {
namespace itk_io {

/// Throws FileError naming `path` when a .nii or .nii.gz holds fewer than `data_bytes` of voxel
/// data after its header (other formats: their readers report it; see ItkImageIO.cpp).
void check_complete(const std::string& path, uint64_t data_bytes);

}  // namespace itk_io
}  // namespace sonoslice
