// Registration: FrameRegistration::run on NumPy frames and poses → refined poses and the report.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <tuple>

#include "bindings.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;
using Frames = nb::ndarray<const float, nb::shape<-1, -1, -1>, nb::c_contig, nb::device::cpu>;
using MaskArray = nb::ndarray<const uint8_t, nb::shape<-1, -1>, nb::c_contig, nb::device::cpu>;

}  // namespace

void bind_registration(nb::module_& m) {
  m.def(
      "register_frames",
      [](nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe, Frames frames,
         Matrices pose_array, std::optional<MaskArray> mask, const std::string& metric,
         const std::string& optimizer, const std::string& mode, int starts, double search_rot_deg,
         double search_trans_mm, uint64_t seed, std::vector<int> pyramid) {
        auto source = volume_source(volume.h);
        if (source) source->check("register");
        RegistrationSettings s;
        s.metric = parse_registration_metric(metric);
        s.optimizer = parse_registration_optimizer(optimizer);
        s.mode = parse_registration_mode(mode);
        s.starts = starts;
        s.search_rot_deg = search_rot_deg;
        s.search_trans_mm = search_trans_mm;
        s.seed = seed;
        s.pyramid = std::move(pyramid);
        s.validate();
        if (int64_t(frames.shape(1)) != probe.image.height ||
            int64_t(frames.shape(2)) != probe.image.width)
          throw InputError("frames: expected (N, " + std::to_string(probe.image.height) + ", " +
                           std::to_string(probe.image.width) + ") for this probe, got (" +
                           std::to_string(frames.shape(0)) + ", " +
                           std::to_string(frames.shape(1)) + ", " +
                           std::to_string(frames.shape(2)) + ")");
        if (mask && (int64_t(mask->shape(0)) != probe.image.height ||
                     int64_t(mask->shape(1)) != probe.image.width))
          throw InputError("mask: expected the probe's (H, W)");
        const std::vector<Pose> initial = matrices_from(pose_array);
        std::vector<Pose> refined;
        RegistrationReport report;
        {
          nb::gil_scoped_release release;
          const FrameRegistration reg(*volume.p, probe, frames.data(), frames.shape(0),
                                      mask ? mask->data() : nullptr);
          refined = reg.run(initial, s, &report);
        }
        std::vector<std::tuple<size_t, double, int64_t, int64_t, double, double>> rows;
        for (const FrameReport& r : report.frames)
          rows.emplace_back(r.index, r.metric, r.evaluations, r.iterations, r.translation_change_mm,
                            r.rotation_change_deg);
        return std::make_tuple(matrices_to_numpy(std::move(refined)), rows, report.evaluations,
                               report.seconds);
      },
      "volume"_a, "probe"_a, "frames"_a, "poses"_a, "mask"_a.none(), "metric"_a, "optimizer"_a,
      "mode"_a, "starts"_a, "search_rot_deg"_a, "search_trans_mm"_a, "seed"_a, "pyramid"_a);
}

}  // namespace sonoslice::bindings
