#pragma once
// Internal: big scratch arrays (compounding accumulators, tens of MiB to GiB) backed by 2 MiB
// transparent huge pages where the OS offers them. A frame's splats land all over the grid: with
// 4 KiB pages each row touches a hundred pages and the CPU spends its time walking page tables
// (measured: about a third of the nearest-splat time on a 64 MiB grid, bench/README.md).
#include <cstddef>
#include <memory>

namespace sonoslice {
namespace backend {

struct LargeBufferFree {
  void operator()(void* p) const;
};

/// `bytes` of uninitialised memory, 2 MiB aligned and advised as huge pages when that is at
/// least one huge page (Linux; elsewhere plain aligned memory). Throws std::bad_alloc.
void* allocate_large(size_t bytes);

template <typename T>
using LargeArray = std::unique_ptr<T[], LargeBufferFree>;

/// n uninitialised T (trivially constructible types).
template <typename T>
LargeArray<T> make_large_array(size_t n) {
  return LargeArray<T>(static_cast<T*>(allocate_large(n * sizeof(T))));
}

}  // namespace backend
}  // namespace sonoslice
