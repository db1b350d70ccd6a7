// Live compounding (include/sonoslice/live): the LiveCompounder for frames from the caller's own
// acquisition code, and the `sonoslice live compound` server run on a thread of this process.
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <atomic>
#include <future>
#include <memory>
#include <thread>

#include "bindings.h"
#include "sonoslice/live/LiveServers.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;

// A LiveCompounder that keeps its configuration alive.
struct PyLiveCompounder {
  std::unique_ptr<LiveCompounder> live;
};

// The `live compound` server on its own thread: start() binds and returns, stop() asks it to
// end, wait() joins and gives the result.
struct PyLiveServer {
  nb::object compounder_owner;
  LiveCompounder* compounder = nullptr;
  LiveCompoundRun run;
  std::atomic<bool> stop{false};
  std::thread thread;
  std::promise<int> bound;
  int port = 0;
  LiveCompoundResult result;
  std::exception_ptr error;

  ~PyLiveServer() {
    stop.store(true);
    if (thread.joinable()) {
      nb::gil_scoped_release release;
      thread.join();
    }
  }
};

}  // namespace

void bind_live(nb::module_& m) {
  nb::class_<PyLiveCompounder>(m, "LiveCompounder")
      .def(
          "__init__",
          [](PyLiveCompounder* self, nb::object config, std::optional<Vec3> spacing,
             std::optional<Vec3> origin, std::optional<std::array<int64_t, 3>> extent,
             std::optional<std::string> interpolation, std::optional<std::string> compounding,
             std::optional<bool> fill_holes,
             std::optional<std::vector<HoleFillingKernel>> hole_filling,
             std::optional<double> rejection_threshold, std::optional<FrameClip> clip,
             std::optional<std::string> dtype, std::string device, uint64_t max_memory,
             std::string queue, int queue_size, bool keep_frames) {
            std::shared_ptr<const PlusReconstructionConfig> c;
            if (!config.is_none())
              c = std::make_shared<PlusReconstructionConfig>(
                  nb::cast<const PlusReconstructionConfig&>(config));
            ReconstructionOptions o = reconstruction_options(
                spacing, interpolation, compounding, fill_holes, std::move(hole_filling),
                rejection_threshold, std::move(clip), std::nullopt, std::nullopt, std::nullopt,
                dtype, device, max_memory, false, std::nullopt, std::nullopt, origin, extent);
            LiveOptions live;
            live.queue = parse_queue_policy(queue, "queue");
            live.queue_size = queue_size;
            live.keep_frames = keep_frames;
            new (self) PyLiveCompounder{std::make_unique<LiveCompounder>(c, o, live)};
          },
          "config"_a.none(), nb::kw_only(), "spacing"_a.none() = nb::none(),
          "origin"_a.none() = nb::none(), "extent"_a.none() = nb::none(),
          "interpolation"_a.none() = nb::none(), "compounding"_a.none() = nb::none(),
          "fill_holes"_a.none() = nb::none(), "hole_filling"_a.none() = nb::none(),
          "rejection_threshold"_a.none() = nb::none(), "clip"_a.none() = nb::none(),
          "dtype"_a.none() = nb::none(), "device"_a = "cpu", "max_memory"_a = 0, "queue"_a = "all",
          "queue_size"_a = 16, "keep_frames"_a = false)
      .def(
          "push",
          [](PyLiveCompounder& self, HostPixels frame, Matrix4 image_to_reference,
             double timestamp) {
            if (frame.ndim() != 2)
              throw InputError("push: a frame is (H, W); got " + std::to_string(frame.ndim()) +
                               " dimensions");
            const PixelType type = pixel_type_of(frame.dtype(), "push: frame");
            if (frame.shape(0) > (1u << 20) || frame.shape(1) > (1u << 20))
              throw InputError("push: a frame of " + std::to_string(frame.shape(1)) + "x" +
                               std::to_string(frame.shape(0)) + " pixels is absurd");
            const Mat4 m = Mat4::from_row_major(image_to_reference.data());
            nb::gil_scoped_release release;  // QueuePolicy::All waits while the queue is full
            return self.live->push(frame.data(), type, int(frame.shape(1)), int(frame.shape(0)), m,
                                   timestamp);
          },
          "frame"_a, "image_to_reference"_a, "timestamp"_a = 0.0,
          "Queues one (H, W) frame; returns '' or why it was refused.")
      .def_prop_ro("full", [](const PyLiveCompounder& s) { return s.live->full(); })
      .def("drain",
           [](PyLiveCompounder& s) {
             nb::gil_scoped_release release;
             s.live->drain();
           })
      .def("suspend", [](PyLiveCompounder& s) { s.live->suspend(); })
      .def("resume", [](PyLiveCompounder& s) { s.live->resume(); })
      .def_prop_ro("suspended", [](const PyLiveCompounder& s) { return s.live->is_suspended(); })
      .def("reset",
           [](PyLiveCompounder& s) {
             nb::gil_scoped_release release;
             s.live->reset();
           })
      .def("snapshot",
           [](PyLiveCompounder& s) {
             nb::gil_scoped_release release;
             return s.live->snapshot();
           })
      .def("finish",
           [](PyLiveCompounder& s) {
             nb::gil_scoped_release release;
             return s.live->finish();
           })
      .def("stats_json", [](const PyLiveCompounder& s) { return s.live->stats().json(); })
      .def("recorded", [](const PyLiveCompounder& s) { return s.live->recorded(); });

  nb::class_<PyLiveServer>(m, "LiveCompoundServer")
      .def(
          "__init__",
          [](PyLiveServer* self, nb::object compounder, bool listen, std::string host, int port,
             std::string image_device, int64_t max_frames, double max_seconds) {
            new (self) PyLiveServer();
            self->compounder_owner = compounder;
            self->compounder = nb::cast<PyLiveCompounder&>(compounder).live.get();
            self->run.endpoint.listen = listen;
            self->run.endpoint.host = std::move(host);
            self->run.endpoint.port = port;
            self->run.image_device = std::move(image_device);
            if (max_frames < 0) throw InputError("max_frames must be >= 0");
            if (!(max_seconds >= 0)) throw InputError("max_seconds must be >= 0");
            self->run.limits.max_frames = max_frames;
            self->run.limits.max_seconds = max_seconds;
            self->run.limits.stop = &self->stop;
            self->run.on_ready = [self](const IgtlEndpoint& e) { self->bound.set_value(e.port()); };
            std::future<int> port_of = self->bound.get_future();
            self->thread = std::thread([self] {
              try {
                self->result = run_live_compound(*self->compounder, self->run);
              } catch (...) {
                self->error = std::current_exception();
                try {
                  self->bound.set_exception(std::current_exception());
                } catch (const std::future_error&) {  // bound already: the error waits for wait()
                }
              }
            });
            nb::gil_scoped_release release;
            try {
              self->port = port_of.get();  // rethrows a bind error
            } catch (...) {
              self->thread.join();  // it has ended: an object that failed to start holds nothing
              self->~PyLiveServer();
              throw;
            }
          },
          "compounder"_a, nb::kw_only(), "listen"_a, "host"_a, "port"_a, "image_device"_a = "",
          "max_frames"_a = 0, "max_seconds"_a = 0.0)
      .def_prop_ro("port", [](const PyLiveServer& s) { return s.port; })
      .def("stop", [](PyLiveServer& s) { s.stop.store(true); })
      .def(
          "wait",
          [](PyLiveServer& s) {
            {
              nb::gil_scoped_release release;
              if (s.thread.joinable()) s.thread.join();
            }
            if (s.error) std::rethrow_exception(s.error);
            return nb::make_tuple(s.result.volume, s.result.json());
          },
          "Joins the server: (volume, statistics JSON with network counts and stopped_by).");
}

}  // namespace sonoslice::bindings
