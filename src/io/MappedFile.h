#pragma once
// Internal: read-only memory maps of file regions, for zero-copy uncompressed volumes.
#include <cstdint>
#include <memory>
#include <string>

namespace sonoslice {

/// Maps bytes [offset, offset + length) of `path` read-only; the returned pointer (to the first
/// byte of the region) unmaps when the last owner goes. FileError when the file is shorter.
/// `alignment` (the size of the values there): when the region would start at an address that is
/// not a multiple of it, the bytes are read into aligned memory instead (a misaligned double is
/// undefined behaviour, and the kernels' vector loads assume natural alignment).
std::shared_ptr<void> map_file_region(const std::string& path, uint64_t offset, uint64_t length,
                                      size_t alignment = 1);

}  // namespace sonoslice
