#pragma once
// Internal: read-only memory maps of file regions, for zero-copy uncompressed volumes.
#include <cstdint>
#include <memory>
#include <string>

namespace sonoslice {

/// Maps bytes [offset, offset + length) of `path` read-only; the returned pointer (to the first
/// byte of the region) unmaps when the last owner goes. FileError when the file is shorter.
std::shared_ptr<void> map_file_region(const std::string& path, uint64_t offset, uint64_t length);

}  // namespace sonoslice
