// Registration: FrameRegistration::run on NumPy frames and poses → refined poses and the report.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <tuple>

#include "bindings.h"
#include "sonoslice/register/Differentiable.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;
using Frames = nb::ndarray<const float, nb::shape<-1, -1, -1>, nb::c_contig, nb::device::cpu>;
using MaskArray = nb::ndarray<const uint8_t, nb::shape<-1, -1>, nb::c_contig, nb::device::cpu>;
using Images = nb::ndarray<const double, nb::shape<-1, -1, -1>, nb::c_contig, nb::device::cpu>;

}  // namespace

void bind_registration(nb::module_& m) {
  m.def(
      "slice_linear_f64",
      [](nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe, Matrices pose_array,
         double fill) {
        auto source = volume_source(volume.h);
        if (source) source->check("slice");
        const std::vector<Pose> poses = matrices_from(pose_array);
        auto out = std::make_shared<std::vector<double>>(poses.size() * size_t(probe.image.width) *
                                                         size_t(probe.image.height));
        {
          nb::gil_scoped_release release;
          slice_linear_f64(*volume.p, probe, poses.data(), poses.size(), fill, out->data());
        }
        return numpy_view(out->data(),
                          {poses.size(), size_t(probe.image.height), size_t(probe.image.width)},
                          PixelType::Float64, out);
      },
      "volume"_a, "probe"_a, "poses"_a, "fill"_a);
  m.def(
      "slice_linear_backward",
      [](nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe, Matrices pose_array,
         Images grad_images, bool volume_gradient) {
        auto source = volume_source(volume.h);
        if (source) source->check("slice");
        const std::vector<Pose> poses = matrices_from(pose_array);
        if (grad_images.shape(0) != poses.size() ||
            int64_t(grad_images.shape(1)) != probe.image.height ||
            int64_t(grad_images.shape(2)) != probe.image.width)
          throw InputError("grad_images: expected (N, H, W) of the forward's images");
        auto grad_poses = std::make_shared<std::vector<double>>(poses.size() * 16);
        auto grad_volume = std::make_shared<std::vector<double>>(
            volume_gradient ? size_t(volume.p->grid().voxel_count()) : 0);
        {
          nb::gil_scoped_release release;
          slice_linear_backward(*volume.p, probe, poses.data(), poses.size(), grad_images.data(),
                                grad_poses->data(),
                                volume_gradient ? grad_volume->data() : nullptr);
        }
        const auto& d = volume.p->grid().dims;
        return std::make_pair(
            numpy_view(grad_poses->data(), {poses.size(), 4, 4}, PixelType::Float64, grad_poses),
            numpy_view(grad_volume->data(),
                       volume_gradient
                           ? std::vector<size_t>{size_t(d[2]), size_t(d[1]), size_t(d[0])}
                           : std::vector<size_t>{0},
                       PixelType::Float64, grad_volume));
      },
      "volume"_a, "probe"_a, "poses"_a, "grad_images"_a, "volume_gradient"_a);
  m.def(
      "register_frames",
      [](nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe, Frames frames,
         Matrices pose_array, std::optional<MaskArray> mask, const std::string& metric,
         const std::string& optimizer, const std::string& mode, int starts, double search_rot_deg,
         double search_trans_mm, uint64_t seed, std::vector<int> pyramid, double smoothness) {
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
        s.smoothness = smoothness;
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
      "mode"_a, "starts"_a, "search_rot_deg"_a, "search_trans_mm"_a, "seed"_a, "pyramid"_a,
      "smoothness"_a);
}

}  // namespace sonoslice::bindings
