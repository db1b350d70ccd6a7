#pragma once
// Internal: the decisions behind the CUDA backend's safety checks, in plain C++ (no CUDA header),
// so that they are tested on every machine, GPU or not. CudaRuntime.cpp feeds them what the
// runtime reports.
#include <string>

namespace sonoslice {
namespace cuda {

/// What cudaPointerGetAttributes says a pointer is.
enum class PointerKind { Unregistered, Host, Device, Managed };

/// Why `kind` memory on `pointer_device` cannot be written by kernels on cuda:`slicer_device`
/// ("" when it can). `what` names the pointer (e.g. "out").
std::string pointer_problem(PointerKind kind, int pointer_device, int slicer_device,
                            const std::string& what);

/// The process id of the caller.
long current_process();

/// Throws Error when called in another process than `creator` (a fork of it): CUDA state does not
/// survive fork(), and a forked child (a torch DataLoader worker) that used it would crash or hang.
/// `what` names the object ("cuda:0 slicer").
void check_not_forked(long creator, const std::string& what);

/// SONOSLICE_CUDA_DEBUG=1: every launch is followed by a synchronisation and an error check, so a
/// faulting kernel is reported at its own launch (slow; for debugging).
bool debug_sync_enabled();

/// log2 of the rows a warp takes at once in a row kernel: log2(`rows_per_warp`), the kernel's own
/// measured choice, unless SONOSLICE_CUDA_ROW_TILE (1, 2, 4, 8, 16 or 32 rows) overrides it, for
/// tuning on other cards.
int row_tile_shift(int rows_per_warp);

}  // namespace cuda
}  // namespace sonoslice
