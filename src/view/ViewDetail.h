#pragma once
// What the viewer's parts share inside src/view: the box of a grid, the clock, and the live feed's
// state (the server reads it under its mutex).
#include <algorithm>
#include <array>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "../core/Clock.h"
#include "sonoslice/view/ViewServer.h"

namespace sonoslice {
namespace view_detail {

/// World positions of the 8 corner voxel centres, index bits (i, j, k) = (1, 2, 4).
std::array<Vec3, 8> box_corners(const VolumeGrid& grid);

}  // namespace view_detail

struct LiveFeed::Impl {
  std::mutex mutex;
  std::condition_variable wake;
  // newest frame
  std::vector<uint8_t> pixels;
  PixelType type = PixelType::UInt8;
  int width = 0, height = 0;
  Mat4 to_world;
  int64_t seq = 0;
  std::function<std::string()> stats;
  // The volume: snapshots taken on the refresher thread, so that neither the run's thread nor a
  // request waits for one.
  std::function<Volume()> snapshot;
  double min_interval = kMinSnapshotInterval;
  // Snapshots start three times their length apart, plus what they last beyond kShortSnapshot:
  // short ones (a small grid, whose hold the frames barely notice) take up to a third of the
  // time, long ones (a large grid, hole filling) approach a quarter.
  static constexpr double kSnapshotSpacing = 3, kShortSnapshot = 0.05;
  std::thread refresher;
  bool stopping = false;
  // Snapshots are taken only while a page polls: no page, no cost (a snapshot holds the
  // compounder for its length).
  bool wanted = true;
  int64_t frames_at_snapshot = 0;
  std::shared_ptr<const Volume> volume;
  int64_t volume_version = 0, scene_version = 0;
  bool running = true;

  void refresh_loop() {
    std::unique_lock<std::mutex> lock(mutex);
    double last = -1e9, took = 0;
    while (!stopping) {
      // A snapshot holds the compounder (and on two cores both cores) for its length: snapshots
      // start far enough apart (kSnapshotSpacing) that the frames keep up whatever the volume's
      // size. Their length is averaged over the last few: one snapshot slowed by a busy core (the
      // browser, the sender) would otherwise hold the next one back as long.
      const double gap =
          std::max(min_interval, kSnapshotSpacing * took + std::max(0.0, took - kShortSnapshot));
      const double wait = gap - (now_seconds() - last);
      if (seq == frames_at_snapshot || !wanted || wait > 0) {
        // Woken by a new frame, by a page taking the last snapshot, or when the interval ends.
        wake.wait_for(lock, std::chrono::duration<double>(std::max(wait, 0.005)));
        continue;
      }
      const int64_t at = seq;
      last = now_seconds();
      lock.unlock();
      std::shared_ptr<Volume> v;
      try {
        v = std::make_shared<Volume>(snapshot());
      } catch (const std::exception&) {
        // nothing compounded yet (every frame so far rejected): no volume to show
      }
      const double length = now_seconds() - last;
      took = took == 0 ? length : 0.7 * took + 0.3 * length;
      lock.lock();
      frames_at_snapshot = at;
      if (v && v->grid().voxel_count() > 0 && running) {
        set_volume(std::move(v));
        wanted = false;
      }
    }
  }
  void stop_refresher() {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stopping = true;
    }
    wake.notify_all();
    if (refresher.joinable()) refresher.join();
  }
  void set_volume(std::shared_ptr<const Volume> v) {  // under mutex
    const bool same_grid = volume && v && volume->grid().dims == v->grid().dims &&
                           volume->grid().origin_mm == v->grid().origin_mm;
    if (!same_grid) ++scene_version;
    volume = std::move(v);
    ++volume_version;
  }
};

}  // namespace sonoslice
