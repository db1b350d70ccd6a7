#include "CudaChecks.h"

#include <unistd.h>

#include <cstdlib>
#include <string>

#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace cuda {

std::string pointer_problem(PointerKind kind, int pointer_device, int slicer_device,
                            const std::string& what) {
  const std::string gpu = "cuda:" + std::to_string(slicer_device);
  switch (kind) {
    case PointerKind::Unregistered:
    case PointerKind::Host:
      return what + ": is host memory, not GPU memory of " + gpu +
             " (give a CUDA array, or slice into host memory with slice())";
    case PointerKind::Device:
      if (pointer_device != slicer_device)
        return what + ": is memory of cuda:" + std::to_string(pointer_device) +
               " but the slicer runs on " + gpu;
      return "";
    case PointerKind::Managed:
      return "";  // reachable from every GPU
  }
  return what + ": unknown kind of memory";
}

long current_process() {
  return long(::getpid());
}

void check_not_forked(long creator, const std::string& what) {
  if (creator == current_process()) return;
  throw Error(what + ": was created in process " + std::to_string(creator) +
              " and is used in process " + std::to_string(current_process()) +
              ", a fork of it: CUDA cannot be used across fork(). Create it in the child (for a "
              "torch DataLoader: in worker_init_fn or the dataset's first __getitem__), or use "
              "the 'spawn' start method");
}

bool debug_sync_enabled() {
  static const bool on = [] {
    const char* v = std::getenv("SONOSLICE_CUDA_DEBUG");
    return v && *v && std::string(v) != "0";
  }();
  return on;
}

int row_tile_shift(int rows_per_warp) {
  // -1: no override.
  static const int forced = [] {
    const char* v = std::getenv("SONOSLICE_CUDA_ROW_TILE");
    if (!v || !*v) return -1;
    for (int shift = 0; shift <= 5; ++shift)
      if (std::string(v) == std::to_string(1 << shift)) return shift;
    throw InputError(std::string("SONOSLICE_CUDA_ROW_TILE '") + v +
                     "': expected the rows per warp, 1, 2, 4, 8, 16 or 32");
  }();
  if (forced >= 0) return forced;
  int shift = 0;
  while (shift < 5 && (2 << shift) <= rows_per_warp) ++shift;
  return shift;
}

}  // namespace cuda
}  // namespace sonoslice
