// Live compounding: a queue in front of the Compounder, one worker thread inserting the frames in
// arrival order (the Compounder's own kernels use the CPU thread pool), counts and latencies.
#include "sonoslice/live/LiveCompounder.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "../compound/CompoundGrid.h"
#include "../core/Clock.h"
#include "../core/Text.h"
#include "../io/TextParse.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

struct Frame {
  std::vector<uint8_t> pixels;
  Mat4 to_reference;
  double timestamp = 0, arrival = 0;
};

// A lattice box of voxel indices (voxel n's centre at n · spacing), inclusive.
struct Box {
  std::array<int64_t, 3> lo{}, hi{};
  bool contains(const Box& b) const {
    for (int a = 0; a < 3; ++a)
      if (b.lo[a] < lo[a] || b.hi[a] > hi[a]) return false;
    return true;
  }
  void add(const Box& b) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], b.lo[a]);
      hi[a] = std::max(hi[a], b.hi[a]);
    }
  }
  // The margin a growing grid adds along axis a: a quarter of its size, at least 16 voxels (a
  // sweep re-inserts its frames a few times, not at every frame, and allocates quickly).
  int64_t margin(int a) const { return std::max<int64_t>(16, (hi[a] - lo[a] + 1) / 4); }
  VolumeGrid grid(const Vec3& spacing) const {
    VolumeGrid g;
    g.spacing_mm = spacing;
    for (int a = 0; a < 3; ++a) {
      g.origin_mm[a] = double(lo[a]) * spacing[a];
      g.dims[a] = hi[a] - lo[a] + 1;
    }
    return g;
  }
};

}  // namespace

Latencies Latencies::of(std::vector<float> ms) {
  Latencies l;
  if (ms.empty()) return l;
  std::sort(ms.begin(), ms.end());
  // Nearest rank: the smallest value with at least p % of the values at or below it.
  const auto rank = [&](double p) {
    return double(ms[std::max<size_t>(1, size_t(std::ceil(p / 100.0 * double(ms.size())))) - 1]);
  };
  l.p50 = rank(50);
  l.p95 = rank(95);
  l.p99 = rank(99);
  l.max = ms.back();
  return l;
}

static nlohmann::ordered_json latency_json(const Latencies& l) {
  return {{"p50", l.p50}, {"p95", l.p95}, {"p99", l.p99}, {"max", l.max}};
}

QueuePolicy parse_queue_policy(const std::string& text, const std::string& what) {
  const std::string t = text::lower(text);
  if (t == "all") return QueuePolicy::All;
  if (t == "newest") return QueuePolicy::Newest;
  throw InputError(what + " \"" + text + "\": expected all or newest");
}

struct LiveCompounder::Impl {
  std::shared_ptr<const PlusReconstructionConfig> config;
  ReconstructionOptions options;
  LiveOptions live;
  double start = now_seconds();

  mutable std::mutex mutex;  // queue, counts, kept frames
  std::condition_variable changed;
  std::deque<Frame> queue;
  bool busy = false, stop = false, suspended = false;
  LiveStats counts;
  std::vector<float> latencies_ms;
  // The first frame fixes these.
  std::optional<PixelType> type;
  int width = 0, height = 0;

  mutable std::mutex volume_mutex;  // the compounder and the grid
  std::optional<StreamPlan> plan;
  std::unique_ptr<Compounder> compounder;
  // The compounded frames, when kept: in blocks of frames stored one after the other, so they go
  // back in batches and keeping one more never copies the others.
  std::vector<std::vector<uint8_t>> kept_pixels;
  std::vector<Mat4> kept_to_reference;
  std::vector<double> kept_timestamps;
  bool growing = false;
  Box allocated;  // the growing grid, on the spacing's lattice
  // Frames the growing grid refused (the box around them and the frames so far would be absurd),
  // with the reason each was counted under; cleared when a frame goes in as usual.
  std::vector<Frame> held;
  std::vector<std::string> held_reasons;
  static constexpr size_t kMaxHeld = 64;
  std::thread worker;

  std::string reject(const std::string& why) {
    ++counts.rejected;
    ++counts.rejected_by_reason[why];
    return why;
  }
  Box frame_box(const Frame& f) const {
    const VolumeGrid g =
        Compounder::grid_around({f.to_reference}, width, height, plan->clip, plan->spacing_mm,
                                Compounder::GridFit::PlusLattice);
    Box b;
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::llround(g.origin_mm[a] / plan->spacing_mm[a]);
      b.hi[a] = b.lo[a] + g.dims[a] - 1;
    }
    return b;
  }
  void rebuild(const VolumeGrid& grid) {
    compounder = std::make_unique<Compounder>(grid, plan->settings, options.device,
                                              options.max_memory_bytes, plan->output_type);
    int64_t first = 0;
    for (const auto& block : kept_pixels) {
      const int64_t count = int64_t(block.size() / frame_bytes());
      compounder->add_images(block.data(), *type, width, height, count,
                             kept_to_reference.data() + first, plan->clip);
      first += count;
    }
  }
  size_t frame_bytes() const { return size_t(width) * size_t(height) * pixel_size(*type); }
  void keep(const Frame& f) {
    const size_t block_frames = std::max<size_t>(1, (size_t(32) << 20) / frame_bytes());
    if (kept_pixels.empty() || kept_pixels.back().size() == block_frames * frame_bytes()) {
      kept_pixels.emplace_back();
      kept_pixels.back().reserve(block_frames * frame_bytes());
    }
    kept_pixels.back().insert(kept_pixels.back().end(), f.pixels.begin(), f.pixels.end());
    kept_to_reference.push_back(f.to_reference);
    kept_timestamps.push_back(f.timestamp);
  }
  void insert_into_compounder(const Frame& f) {
    compounder->add_image(f.pixels.data(), *type, width, height, f.to_reference, plan->clip);
  }
  // What an insert changed besides its own frame: frames compounded before that now count as
  // rejected (strays), and refused ones that now count as compounded (with their old reasons).
  struct Regrid {
    int64_t displaced = 0;
    std::vector<std::string> revived_reasons;
  };
  Regrid insert(Frame& f);  // under volume_mutex
  Regrid refuse_growth(Frame& f, const std::string& reason);
  void clear_volume() {
    compounder.reset();
    kept_pixels.clear();
    kept_to_reference.clear();
    kept_timestamps.clear();
    held.clear();
    held_reasons.clear();
    plan.reset();
  }
  void run();
};

// A stray first pose (a tracker before it locks on) would otherwise make every later frame of
// the sweep "absurd" to the grid (or more than the memory). Refused frames are held; once at
// least three are held, more than twice the frames compounded, and a grid around them alone is
// possible, they are the sweep: the grid starts over from them, and the frames compounded before
// count as rejected strays. (A long sweep never gives way: at most kMaxHeld frames are held.)
LiveCompounder::Impl::Regrid LiveCompounder::Impl::refuse_growth(Frame& f,
                                                                 const std::string& reason) {
  held.push_back(std::move(f));
  held_reasons.push_back(reason);
  if (held.size() > kMaxHeld) {
    held.erase(held.begin());
    held_reasons.erase(held_reasons.begin());
  }
  if (held.size() < 3 || held.size() <= 2 * kept_to_reference.size()) throw InputError(reason);
  Box box = frame_box(held.front());
  for (const Frame& h : held) box.add(frame_box(h));
  for (int a = 0; a < 3; ++a) {
    const int64_t pad = box.margin(a);
    box.lo[a] -= pad;
    box.hi[a] += pad;
  }
  std::unique_ptr<Compounder> fresh;
  try {
    fresh = std::make_unique<Compounder>(box.grid(plan->spacing_mm), plan->settings, options.device,
                                         options.max_memory_bytes, plan->output_type);
  } catch (const Error&) {
    // The held frames disagree among themselves too: hold again from this one.
    held.erase(held.begin(), held.end() - 1);
    held_reasons.erase(held_reasons.begin(), held_reasons.end() - 1);
    throw InputError(reason);
  }
  Regrid r;
  r.displaced = int64_t(kept_to_reference.size());
  r.revived_reasons.assign(held_reasons.begin(), held_reasons.end() - 1);  // not this frame's
  compounder = std::move(fresh);
  allocated = box;
  kept_pixels.clear();
  kept_to_reference.clear();
  kept_timestamps.clear();
  for (const Frame& h : held) {
    insert_into_compounder(h);
    keep(h);
  }
  held.clear();
  held_reasons.clear();
  return r;
}

LiveCompounder::Impl::Regrid LiveCompounder::Impl::insert(Frame& f) {
  if (!plan) {
    plan = plan_stream(*type, width, height, config.get(), options);
    growing = !plan->grid;
  }
  if (!growing && !compounder)  // tried again at the next frame if memory was short
    compounder = std::make_unique<Compounder>(*plan->grid, plan->settings, options.device,
                                              options.max_memory_bytes, plan->output_type);
  if (growing) {
    const Box b = frame_box(f);
    if (!compounder || !allocated.contains(b)) {
      // Grow by Box::margin where the frame leaves the box.
      Box grown = compounder ? allocated : b;
      grown.add(b);
      for (int a = 0; a < 3; ++a) {
        const int64_t pad = grown.margin(a);
        if (!compounder || b.lo[a] < allocated.lo[a]) grown.lo[a] -= pad;
        if (!compounder || b.hi[a] > allocated.hi[a]) grown.hi[a] += pad;
      }
      try {
        rebuild(grown.grid(plan->spacing_mm));
      } catch (const Error& e) {  // absurd, or more than the memory
        if (!compounder) throw;   // the first frame alone: its own problem
        return refuse_growth(f, e.what());
      }
      allocated = grown;  // once the larger grid exists (a failed one leaves the old)
    }
  }
  insert_into_compounder(f);
  if (live.keep_frames || growing) keep(f);
  held.clear();
  held_reasons.clear();
  return {};
}

void LiveCompounder::Impl::run() {
  std::unique_lock<std::mutex> lock(mutex);
  for (;;) {
    changed.wait(lock, [&] { return stop || !queue.empty(); });
    if (queue.empty()) return;  // stop, and nothing left
    Frame f = std::move(queue.front());
    queue.pop_front();
    busy = true;
    changed.notify_all();  // room in the queue
    lock.unlock();
    std::string error;
    const double arrival = f.arrival;
    Regrid regrid;
    try {
      std::lock_guard<std::mutex> v(volume_mutex);
      regrid = insert(f);
    } catch (const std::exception& e) {
      error = e.what();
    }
    const double done = now_seconds();
    lock.lock();
    busy = false;
    if (error.empty()) {
      ++counts.compounded;
      latencies_ms.push_back(float((done - arrival) * 1e3));
      for (const std::string& why : regrid.revived_reasons) {
        ++counts.compounded;
        --counts.rejected;
        if (--counts.rejected_by_reason[why] == 0) counts.rejected_by_reason.erase(why);
      }
      for (int64_t k = 0; k < regrid.displaced; ++k) {
        --counts.compounded;
        reject("a stray pose: far from the frames that followed it, which went on without it");
      }
    } else {
      reject(error);
    }
    changed.notify_all();
  }
}

LiveCompounder::LiveCompounder(std::shared_ptr<const PlusReconstructionConfig> config,
                               ReconstructionOptions options, LiveOptions live)
    : impl_(std::make_unique<Impl>()) {
  Impl& im = *impl_;
  if (live.queue_size < 1 || live.queue_size > 100000)
    throw InputError(spelled(options.names, "queue_size") + " " + std::to_string(live.queue_size) +
                     ": expected 1 to 100000 frames");
  if (options.plus_exact)
    throw InputError(spelled(options.names, "plus_exact") + ": not for live frames");
  im.config = std::move(config);
  im.options = std::move(options);
  im.live = live;
  // Every setting is checked now, before a frame arrives (the frames' type only changes the
  // default output type).
  reset(im.options);
  im.worker = std::thread([&im] { im.run(); });
}

LiveCompounder::~LiveCompounder() {
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    impl_->stop = true;
    impl_->queue.clear();
  }
  impl_->changed.notify_all();
  if (impl_->worker.joinable()) impl_->worker.join();
}

std::string LiveCompounder::push(const void* pixels, PixelType type, int width, int height,
                                 const Mat4& m, double timestamp_s, std::optional<double> arrival) {
  Impl& im = *impl_;
  Frame f;
  f.arrival = arrival ? *arrival : now_seconds();
  f.timestamp = timestamp_s;
  f.to_reference = m;
  std::unique_lock<std::mutex> lock(im.mutex);
  ++im.counts.received;
  if (type != PixelType::UInt8 && type != PixelType::Int8 && type != PixelType::UInt16 &&
      type != PixelType::Int16 && type != PixelType::Float32)
    return im.reject("a " + to_string(type) + " frame (uint8, int8, uint16, int16 or float32)");
  if (width < 1 || height < 1) return im.reject("an empty frame");
  try {
    compound_impl::check_matrix(m, "a frame", 2);  // the check the Compounder's callers use
  } catch (const InputError& e) {
    return im.reject(e.what());
  }
  // Beyond any scanner: a broken transform, said as such rather than as the grid it would need.
  for (int r = 0; r < 3; ++r)
    if (std::fabs(m.m[r][3]) > kMaxGeometryMm) {
      char at[64];
      std::snprintf(at, sizeof at, "%g mm along %c", m.m[r][3], "xyz"[r]);
      return im.reject(std::string("a frame at ") + at +
                       " (beyond any scanner's extent, at most 1e9 mm): a broken transform");
    }
  if (im.type && (*im.type != type || im.width != width || im.height != height))
    return im.reject("a frame of " + std::to_string(width) + "x" + std::to_string(height) + " " +
                     to_string(type) + " after frames of " + std::to_string(im.width) + "x" +
                     std::to_string(im.height) + " " + to_string(*im.type));
  im.type = type;
  im.width = width;
  im.height = height;
  const size_t bytes = size_t(width) * size_t(height) * pixel_size(type);
  im.counts.bytes += bytes;
  if (im.suspended) {
    ++im.counts.suspended;
    return "";
  }
  if (im.live.queue == QueuePolicy::All) {
    im.changed.wait(lock, [&] { return int(im.queue.size()) < im.live.queue_size; });
  } else if (!im.queue.empty()) {
    im.counts.dropped += int64_t(im.queue.size());
    im.queue.clear();
  }
  lock.unlock();
  // The copy happens outside the lock, so the worker is never held up by it.
  f.pixels.assign(static_cast<const uint8_t*>(pixels), static_cast<const uint8_t*>(pixels) + bytes);
  lock.lock();
  im.queue.push_back(std::move(f));
  im.changed.notify_all();
  return "";
}

bool LiveCompounder::full() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->live.queue == QueuePolicy::All &&
         int(impl_->queue.size()) >= impl_->live.queue_size;
}

void LiveCompounder::drain() {
  std::unique_lock<std::mutex> lock(impl_->mutex);
  impl_->changed.wait(lock, [&] { return impl_->queue.empty() && !impl_->busy; });
}

void LiveCompounder::suspend() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->suspended = true;
}
void LiveCompounder::resume() {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->suspended = false;
}
bool LiveCompounder::is_suspended() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->suspended;
}

void LiveCompounder::reset() {
  drain();
  std::lock_guard<std::mutex> v(impl_->volume_mutex);
  impl_->clear_volume();
}

void LiveCompounder::reset(const ReconstructionOptions& options) {
  const StreamPlan check = plan_stream(PixelType::UInt8, 1, 1, impl_->config.get(), options);
  if (check.grid) {  // a given grid must fit in memory now, not at the first frame
    check.grid->validate(spelled(options.names, "extent"));
    compound_impl::check_fits_in_memory(*check.grid, check.settings, check.output_type,
                                        options.max_memory_bytes);
  }
  drain();
  std::lock_guard<std::mutex> v(impl_->volume_mutex);
  impl_->options = options;
  impl_->clear_volume();
}

const ReconstructionOptions& LiveCompounder::options() const {
  return impl_->options;
}

Volume LiveCompounder::snapshot() const {
  std::lock_guard<std::mutex> v(impl_->volume_mutex);
  if (!impl_->compounder) return Volume();
  return impl_->compounder->volume(impl_->plan->output_type);
}

Volume LiveCompounder::finish() {
  drain();
  Impl& im = *impl_;
  std::lock_guard<std::mutex> v(im.volume_mutex);
  if (!im.compounder) return Volume();
  if (im.growing) {
    // The grid `sonoslice compound` fits around the same frames, so the recording compounded
    // offline with the same settings gives these bytes.
    const VolumeGrid fitted = Compounder::grid_around(im.kept_to_reference, im.width, im.height,
                                                      im.plan->clip, im.plan->spacing_mm);
    const VolumeGrid& now = im.compounder->grid();
    if (fitted.dims != now.dims || fitted.origin_mm != now.origin_mm) im.rebuild(fitted);
  }
  return im.compounder->volume(im.plan->output_type);
}

LiveStats LiveCompounder::stats() const {
  const Impl& im = *impl_;
  LiveStats s;
  std::vector<float> latencies;
  {
    std::lock_guard<std::mutex> lock(im.mutex);
    s = im.counts;
    s.waiting = int64_t(im.queue.size()) + (im.busy ? 1 : 0);
    latencies = im.latencies_ms;
  }
  s.seconds = now_seconds() - im.start;
  s.latency_ms = Latencies::of(std::move(latencies));
  std::lock_guard<std::mutex> v(im.volume_mutex);
  if (im.compounder) s.grid = im.compounder->grid();
  return s;
}

PlusSequence LiveCompounder::recorded() const {
  const Impl& im = *impl_;
  std::lock_guard<std::mutex> v(im.volume_mutex);
  if (!im.live.keep_frames)
    throw Error("LiveCompounder::recorded: made without keep_frames (LiveOptions)");
  PlusSequence s;
  s.path = "recorded";
  s.width = im.width;
  s.height = im.height;
  s.pixel_type = im.type ? *im.type : PixelType::UInt8;
  s.frame_count = int(im.kept_to_reference.size());
  const std::string transform =
      (im.config ? im.config->image_frame + "To" + im.config->reference_frame
                 : std::string("ImageToReference")) +
      "Transform";
  for (const auto& block : im.kept_pixels)
    s.pixels.insert(s.pixels.end(), block.begin(), block.end());
  for (size_t k = 0; k < im.kept_to_reference.size(); ++k) {
    char t[40];
    std::snprintf(t, sizeof(t), "%.6f", im.kept_timestamps[k]);
    s.frame_fields.push_back({{transform, text::format_matrix16(im.kept_to_reference[k])},
                              {transform + "Status", "OK"},
                              {"Timestamp", t},
                              {"ImageStatus", "OK"}});
  }
  return s;
}

std::string LiveStats::json() const {
  nlohmann::ordered_json j;
  j["frames_received"] = received;
  j["frames_compounded"] = compounded;
  j["frames_dropped"] = dropped;
  j["frames_suspended"] = suspended;
  j["frames_rejected"] = rejected;
  j["rejected_by_reason"] = rejected_by_reason;
  j["frames_waiting"] = waiting;
  j["bytes"] = bytes;
  j["latency_ms"] = latency_json(latency_ms);
  j["seconds"] = seconds;
  if (grid) {
    j["grid"] = {
        {"origin_mm", grid->origin_mm}, {"spacing_mm", grid->spacing_mm}, {"extent", grid->dims}};
  }
  return j.dump(2);
}

std::string LiveStats::summary() const {
  char b[400];
  std::snprintf(b, sizeof(b),
                "%lld frames received, %lld compounded, %lld dropped, %lld rejected; latency "
                "p50 %.2f ms, p95 %.2f ms, p99 %.2f ms, max %.2f ms",
                (long long)received, (long long)compounded, (long long)dropped, (long long)rejected,
                latency_ms.p50, latency_ms.p95, latency_ms.p99, latency_ms.max);
  return b;
}

}  // namespace sonoslice
