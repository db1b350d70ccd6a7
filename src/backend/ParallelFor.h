#pragma once
/// @file The one choke point through which every parallel loop of the CPU backend runs.
/// Kernels are functors of per-element SONOSLICE_HOST_DEVICE functions; the CPU threads are the
/// pool of ThreadPool.h (workers that sleep when idle, so a job shares the machine fairly). The
/// CUDA backend provides the same entry points as grid-stride kernels (ParallelForCUDA.cuh).
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <utility>

#include "ThreadPool.h"
#include "sonoslice/backend/HostDevice.h"

namespace sonoslice {
namespace backend {
inline namespace SONOSLICE_KERNEL_ISA {

/// f(i) for i in [0, n), spread over the CPU threads. Items should be coarse (a slice, a
/// chunk): each is scheduled separately.
template <typename F>
void parallel_for(int64_t n, const F& f) {
  run_parallel(
      n, 1,
      [](const void* context, int64_t begin, int64_t end) {
        const F& body = *static_cast<const F*>(context);
        for (int64_t i = begin; i < end; ++i) body(i);
      },
      &f);
}

/// The range [0, n) cut into chunks of `chunk` elements, spread over the CPU threads:
/// f(c, begin, end) for chunk c = [begin, end).
template <typename F>
void parallel_for_chunks(int64_t n, int64_t chunk, const F& f) {
  parallel_for((n + chunk - 1) / chunk, [&](int64_t c) {
    const int64_t begin = c * chunk, end = begin + chunk < n ? begin + chunk : n;
    f(c, begin, end);
  });
}

/// memcpy on every CPU thread, in 4 MiB pieces: one thread moves about 10 GB/s, a fraction of
/// what a GPU copy delivers into (or takes from) page-locked memory.
inline void parallel_memcpy(void* dst, const void* src, size_t bytes) {
  char* to = static_cast<char*>(dst);
  const char* from = static_cast<const char*>(src);
  parallel_for_chunks(int64_t(bytes), int64_t(4) << 20, [&](int64_t, int64_t begin, int64_t end) {
    std::memcpy(to + begin, from + begin, size_t(end - begin));
  });
}

namespace detail {
template <typename F, typename S, typename = void>
struct has_pixels : std::false_type {};
template <typename F, typename S>
struct has_pixels<F, S, decltype(std::declval<const F&>().pixels(std::declval<const S&>(), 0, 0))>
    : std::true_type {};
}  // namespace detail

/// A 2D index space of `rows` × `width` elements. The functor provides
///   State row(int64_t r) const;                   // per-row state (computed once per row)
///   void pixel(const State&, int u) const;        // one element
/// and, optionally, a CPU fast path for a run of elements (SIMD):
///   void pixels(const State&, int begin, int end) const;
/// On the CPU a thread takes whole rows, so per-row work (pose lookup, row base coordinates) is
/// paid once per row and stays in registers; on CUDA a warp takes a row, each lane computing
/// row() once for its pixels of that row.
template <typename F>
void parallel_for_rows(int64_t rows, int width, const F& f, void* /*stream*/ = nullptr) {
  struct Context {
    const F* f;
    int width;
  } context{&f, width};
  // Rows are handed out eight at a time.
  run_parallel(
      rows, 8,
      [](const void* c, int64_t begin, int64_t end) {
        const Context& ctx = *static_cast<const Context*>(c);
        for (int64_t r = begin; r < end; ++r) {
          const auto state = ctx.f->row(r);
          if constexpr (detail::has_pixels<F, decltype(state)>::value) {
            ctx.f->pixels(state, 0, ctx.width);
          } else {
            for (int u = 0; u < ctx.width; ++u) ctx.f->pixel(state, u);
          }
        }
      },
      &context);
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace backend
}  // namespace sonoslice
