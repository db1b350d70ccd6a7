#include "LargeBuffer.h"

#include <cstdlib>
#include <new>
#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace sonoslice {
namespace backend {

namespace {
constexpr size_t kHugePage = size_t(2) << 20;
}

void* allocate_large(size_t bytes) {
  const size_t align = bytes >= kHugePage ? kHugePage : 64;
  const size_t rounded = (bytes + align - 1) / align * align;
  void* p = std::aligned_alloc(align, rounded == 0 ? align : rounded);
  if (!p) throw std::bad_alloc();
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  // Advice only: where transparent huge pages are off this changes nothing.
  if (align == kHugePage) ::madvise(p, rounded, MADV_HUGEPAGE);
#endif
  return p;
}

void LargeBufferFree::operator()(void* p) const {
  std::free(p);
}

}  // namespace backend
}  // namespace sonoslice
