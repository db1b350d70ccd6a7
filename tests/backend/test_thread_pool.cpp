// The CPU backend's thread pool (src/backend/ThreadPool.h) behind parallel_for: every item once,
// errors reach the caller, nested and concurrent loops, fork(), and idle workers that sleep.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

#include "../../src/backend/ParallelFor.h"
#include "sonoslice/backend/Device.h"

namespace sonoslice {
namespace {

struct Threads {
  explicit Threads(int n) { set_cpu_threads(n); }
  ~Threads() { reset_cpu_threads(); }
};

TEST(ThreadPool, EveryItemRunsOnceForAnyThreadCount) {
  for (int threads : {1, 2, 3, 8}) {
    Threads t(threads);
    for (int64_t n : {0, 1, 7, 1000, 100003}) {
      std::vector<std::atomic<int>> seen(static_cast<size_t>(n));
      backend::parallel_for(n, [&](int64_t i) { seen[size_t(i)].fetch_add(1); });
      for (int64_t i = 0; i < n; ++i) ASSERT_EQ(seen[size_t(i)].load(), 1) << i << " of " << n;
    }
  }
}

TEST(ThreadPool, UsesSeveralThreads) {
  // Each item waits (up to 5 s, for a busy machine) until a second thread has joined the loop.
  Threads t(4);
  std::mutex m;
  std::vector<std::thread::id> ids;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  backend::parallel_for(64, [&](int64_t) {
    for (;;) {
      {
        std::lock_guard<std::mutex> lock(m);
        if (std::find(ids.begin(), ids.end(), std::this_thread::get_id()) == ids.end())
          ids.push_back(std::this_thread::get_id());
        if (ids.size() >= 2 || std::chrono::steady_clock::now() > deadline) return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  });
  EXPECT_GE(ids.size(), 2u);
  EXPECT_LE(ids.size(), 4u);
}

TEST(ThreadPool, AnExceptionReachesTheCallerAndThePoolStaysUsable) {
  Threads t(4);
  std::atomic<int> ran{0};
  // Items of 100 µs: the 10,000 would take over a second on two cores; after the failure the
  // threads stop taking new ones.
  EXPECT_THROW(backend::parallel_for(10000,
                                     [&](int64_t i) {
                                       ran.fetch_add(1);
                                       if (i == 17) throw std::runtime_error("item 17");
                                       std::this_thread::sleep_for(std::chrono::microseconds(100));
                                     }),
               std::runtime_error);
  EXPECT_LT(ran.load(), 5000);
  std::atomic<int64_t> sum{0};
  backend::parallel_for(1000, [&](int64_t i) { sum.fetch_add(i); });
  EXPECT_EQ(sum.load(), 999 * 1000 / 2);
}

TEST(ThreadPool, NestedLoopsRunOnTheCallingThread) {
  Threads t(4);
  std::atomic<int> inner{0}, foreign{0};
  backend::parallel_for(16, [&](int64_t) {
    const auto outer = std::this_thread::get_id();
    backend::parallel_for(16, [&](int64_t) {
      inner.fetch_add(1);
      if (std::this_thread::get_id() != outer) foreign.fetch_add(1);
    });
  });
  EXPECT_EQ(inner.load(), 256);
  EXPECT_EQ(foreign.load(), 0);
}

TEST(ThreadPool, LoopsFromSeveralThreadsAtOnceAllComplete) {
  Threads t(2);
  std::vector<std::thread> callers;
  std::atomic<int64_t> total{0};
  for (int c = 0; c < 4; ++c)
    callers.emplace_back([&] {
      for (int rep = 0; rep < 50; ++rep)
        backend::parallel_for(200, [&](int64_t) { total.fetch_add(1); });
    });
  for (auto& c : callers) c.join();
  EXPECT_EQ(total.load(), 4 * 50 * 200);
}

TEST(ThreadPool, AForkedChildGetsAPoolOfItsOwn) {
  // A torch DataLoader worker forks after the parent has used the pool.
  Threads t(2);
  std::atomic<int64_t> sum{0};
  backend::parallel_for(100, [&](int64_t i) { sum.fetch_add(i); });
  ASSERT_EQ(sum.load(), 4950);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    std::atomic<int64_t> s{0};
    backend::parallel_for(100, [&](int64_t i) { s.fetch_add(i); });
    _exit(s.load() == 4950 ? 0 : 1);
  }
  int status = 0;
  // A hang (a child waiting for workers that did not survive fork) fails by the ctest timeout.
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

double process_cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

TEST(ThreadPool, IdleWorkersSleep) {
  // The point of the pool: between loops its workers give their cores back, so a job
  // sharing the machine with others does not burn their time. OpenMP's default spin-wait kept
  // each idle worker at 100% of a core for milliseconds after every loop.
  Threads t(4);
  backend::parallel_for(64, [](int64_t) {});
  const double before = process_cpu_seconds();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const double used = process_cpu_seconds() - before;
  EXPECT_LT(used, 0.05) << "idle workers used " << used << " s of CPU in 0.3 s";
}

}  // namespace
}  // namespace sonoslice
