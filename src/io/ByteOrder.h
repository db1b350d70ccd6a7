#pragma once
// Internal: byte-order helpers for the binary readers (.npy, NIfTI voxel data).
#include <algorithm>
#include <cstddef>

namespace sonoslice {

/// Reverses the bytes of each of the `count` items of `size` bytes at `data`, in place.
inline void byteswap(void* data, size_t count, size_t size) {
  auto* p = static_cast<unsigned char*>(data);
  for (size_t i = 0; i < count; ++i, p += size) std::reverse(p, p + size);
}

}  // namespace sonoslice
