#include "ThreadPool.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

#if defined(__linux__)
#include <pthread.h>
#include <sched.h>
#endif
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

#include "sonoslice/backend/Device.h"

namespace sonoslice {
namespace backend {
namespace {

void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
  _mm_pause();
#else
  std::this_thread::yield();
#endif
}

/// Polls `ready` for up to kSpinMicroseconds; true as soon as it holds.
template <typename Ready>
bool spin_until(const Ready& ready) {
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::microseconds(kSpinMicroseconds);
  for (;;) {
    for (int k = 0; k < 64; ++k) {
      if (ready()) return true;
      cpu_relax();
    }
    if (std::chrono::steady_clock::now() >= deadline) return ready();
  }
}

/// One parallel loop: chunks are taken from `next` by whoever joined.
struct Job {
  RangeBody body = nullptr;
  const void* context = nullptr;
  int64_t n = 0, grain = 1;
  std::atomic<int64_t> next{0};
  std::atomic<bool> failed{false};
  std::mutex error_mutex;
  std::exception_ptr error;

  void work() {
    while (!failed.load(std::memory_order_relaxed)) {
      const int64_t begin = next.fetch_add(grain, std::memory_order_relaxed);
      if (begin >= n) return;
      try {
        body(context, begin, std::min(n, begin + grain));
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
        failed.store(true, std::memory_order_relaxed);
      }
    }
  }
};

/// True on a thread while it runs a chunk: loops inside run serially.
thread_local bool t_in_chunk = false;

struct ChunkScope {
  ChunkScope() { t_in_chunk = true; }
  ~ChunkScope() { t_in_chunk = false; }
};

class Pool {
 public:
  void run(Job& job, int threads) {
    std::lock_guard<std::mutex> turn(turn_);  // one loop at a time
    grow(threads - 1);
    {
      std::lock_guard<std::mutex> lock(m_);
      job_ = &job;
      seats_ = threads - 1;  // workers that may still join
      active_ = 0;
      generation_.fetch_add(1, std::memory_order_release);
    }
    wake_.notify_all();
    {
      ChunkScope scope;
      job.work();
    }
    // Every chunk is handed out: close the job to workers that have not joined yet, and wait
    // only for those that did (a worker the scheduler has not run yet does not hold us).
    {
      std::lock_guard<std::mutex> lock(m_);
      seats_ = 0;
    }
    spin_until([&] { return active_.load(std::memory_order_acquire) == 0; });
    std::unique_lock<std::mutex> lock(m_);
    done_.wait(lock, [&] { return active_.load(std::memory_order_acquire) == 0; });
    job_ = nullptr;
  }

 private:
  void grow(int workers) {
    while (int(workers_started_) < workers) {
      // The generation before this loop's: a worker that starts late still joins it.
      std::thread(&Pool::worker_main, this, generation_.load(std::memory_order_acquire)).detach();
      ++workers_started_;
    }
  }

  void worker_main(uint64_t seen) {
    for (;;) {
      if (!spin_until([&] { return generation_.load(std::memory_order_acquire) != seen; })) {
        std::unique_lock<std::mutex> lock(m_);
        wake_.wait(lock, [&] { return generation_.load(std::memory_order_acquire) != seen; });
      }
      Job* job = nullptr;
      {
        std::lock_guard<std::mutex> lock(m_);
        seen = generation_.load(std::memory_order_acquire);
        if (job_ && seats_ > 0) {
          --seats_;
          active_.fetch_add(1, std::memory_order_acq_rel);
          job = job_;
        }
      }
      if (!job) continue;
      {
        ChunkScope scope;
        job->work();
      }
      std::lock_guard<std::mutex> lock(m_);
      if (active_.fetch_sub(1, std::memory_order_acq_rel) == 1) done_.notify_one();
    }
  }

  std::mutex turn_;
  std::mutex m_;
  std::condition_variable wake_, done_;
  std::atomic<uint64_t> generation_{0};
  Job* job_ = nullptr;  // guarded by m_
  int seats_ = 0;       // guarded by m_
  std::atomic<int> active_{0};
  int workers_started_ = 0;  // guarded by turn_
};

// Never destroyed: detached workers may still be waiting on it while the process exits.
Pool* g_pool = nullptr;
std::once_flag g_pool_once;

Pool& pool() {
  std::call_once(g_pool_once, [] {
    g_pool = new Pool;
#if defined(__linux__)
    // A forked child (a torch DataLoader or multiprocessing worker) has none of the parent's
    // workers: it starts a fresh pool. The parent's stays reachable for leak checkers.
    pthread_atfork(nullptr, nullptr, [] {
      static std::vector<Pool*> left_behind;
      left_behind.push_back(g_pool);
      g_pool = new Pool;
    });
#endif
  });
  return *g_pool;
}

}  // namespace

int available_cpus() {
#if defined(__linux__)
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) return std::max(1, CPU_COUNT(&set));
#endif
  return std::max(1, int(std::thread::hardware_concurrency()));
}

int parallel_width() {
  return t_in_chunk ? 1 : cpu_threads();
}

void run_parallel(int64_t n, int64_t grain, RangeBody body, const void* context) {
  if (n <= 0) return;
  grain = std::max<int64_t>(1, grain);
  const int64_t chunks = (n + grain - 1) / grain;
  const int threads = int(std::min<int64_t>(cpu_threads(), chunks));
  if (threads <= 1 || t_in_chunk) {
    body(context, 0, n);
    return;
  }
  Job job;
  job.body = body;
  job.context = context;
  job.n = n;
  job.grain = grain;
  pool().run(job, threads);
  if (job.error) std::rethrow_exception(job.error);
}

}  // namespace backend
}  // namespace sonoslice
