// The CPU backend of the slicing kernel for any x86-64 (or other) CPU: SliceImpl.h compiled
// with the thread pool's parallel_for and scalar lanes.
#include "SliceBackends.h"
#include "SliceImpl.h"

namespace sonoslice {
namespace slice_impl {
void slice_cpu_generic(const SliceLaunch& launch) {
  dispatch_slice(launch);
}
}  // namespace slice_impl
}  // namespace sonoslice
