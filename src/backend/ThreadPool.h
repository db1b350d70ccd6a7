#pragma once
/// @file The CPU backend's threads: one pool of workers behind parallel_for (ParallelFor.h).
///
/// Why not OpenMP: GCC's OpenMP runtime keeps idle threads spinning for a long while after every
/// parallel region (GOMP_SPINCOUNT, 300,000 rounds by default), and compounding runs two short
/// regions per batch. When another process wants the cores (a tracker, a viewer, a second job:
/// the normal case beside a live reconstruction) those spinning threads take its time and wait
/// for their own siblings, and two 2-thread compounding jobs on 2 cores each ran 6× slower than
/// alone instead of 2× (bench/concurrency.py). Here an idle worker spins for at most
/// kSpinMicroseconds, then sleeps on a condition variable; the caller never waits for a worker
/// that has not started (late workers find the job closed). The settings are not an environment
/// variable the user must know about (OMP_WAIT_POLICY), and the pool survives fork().
#include <cstdint>

namespace sonoslice {
namespace backend {

/// How long an idle worker (or a caller waiting for its workers) polls before it sleeps: long
/// enough to catch the next region of a loop of short ones, short against a scheduler time slice.
constexpr int kSpinMicroseconds = 50;

/// body(context, begin, end) over [0, n) in chunks of `grain` items handed out one at a time to
/// up to cpu_threads() threads, the calling thread among them. Returns when every chunk is done.
/// The first exception a chunk throws is rethrown here; chunks not yet started are skipped.
/// Called inside a chunk (a nested loop) it runs serially on the calling thread. Calls from
/// several threads at once take the pool in turn.
using RangeBody = void (*)(const void* context, int64_t begin, int64_t end);
void run_parallel(int64_t n, int64_t grain, RangeBody body, const void* context);

/// How many threads a parallel loop started here would run on: 1 inside a chunk (nested loops
/// run serially), else cpu_threads(). For work that is split only when it has the threads to
/// itself.
int parallel_width();

/// The number of CPUs this process may run on (its affinity mask), at least 1.
int available_cpus();

}  // namespace backend
}  // namespace sonoslice
