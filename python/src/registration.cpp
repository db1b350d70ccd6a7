// Registration: its settings and choices (RegistrationSettings, the metric, optimiser and mode
// enums), FrameRegistration::run on NumPy frames and poses → refined poses and a typed report;
// and the differentiable slice's forward and backward (sonoslice.torch).
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <tuple>

#include "bindings.h"
#include "sonoslice/register/Differentiable.h"
#include "sonoslice/register/PlusRegistration.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;
using Frames = nb::ndarray<const float, nb::shape<-1, -1, -1>, nb::c_contig, nb::device::cpu>;

void check_frames(const Frames& frames, const ProbeGeometry& probe) {
  if (int64_t(frames.shape(1)) != probe.image.height ||
      int64_t(frames.shape(2)) != probe.image.width)
    throw InputError("frames: expected (N, " + std::to_string(probe.image.height) + ", " +
                     std::to_string(probe.image.width) + ") for this probe, got (" +
                     std::to_string(frames.shape(0)) + ", " + std::to_string(frames.shape(1)) +
                     ", " + std::to_string(frames.shape(2)) + ")");
}
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
  bind_enum(m, "RegistrationMetric", kRegistrationMetrics,
            "What registration compares (docs/registration.md §2): ssd, ncc, lncc, mi, lc2.");
  bind_enum(m, "RegistrationOptimizer", kRegistrationOptimizers,
            "gn, lm (analytic derivatives: ssd, ncc), bobyqa, nelder_mead (derivative-free; "
            "builds with NLopt).");
  bind_enum(m, "RegistrationMode", kRegistrationModes,
            "per_frame, rigid_sweep (one correction for all frames), smooth_sweep (per frame, "
            "tied along the sweep).");
  m.def("default_optimizer", &default_optimizer, "metric"_a,
        "The optimiser a metric gets when none is asked for: lm for ssd and ncc, bobyqa for the "
        "others.");
  m.def("default_pyramid", &default_pyramid, "metric"_a,
        "The pyramid a metric gets when none is asked for: [8, 4, 2, 1], or [2, 1] for lc2.");
  m.def("default_max_starts", &default_max_starts, "metric"_a,
        "The most automatic starts a frame gets when starts is None: 48 for ssd and ncc, 12 for "
        "the others (a sweep's shared correction: 16).");

  const RegistrationSettings settings;
  nb::class_<RegistrationSettings>(
      m, "RegistrationSettings",
      "What a registration does (docs/registration.md); the defaults are the library's. Checked "
      "when made (ValueError naming the setting).")
      .def(
          "__init__",
          [](RegistrationSettings* self, RegistrationMetric metric,
             std::optional<RegistrationOptimizer> optimizer, RegistrationMode mode,
             std::optional<int> starts, double search_rot_deg, double search_trans_mm,
             nb::int_ seed, std::optional<double> smoothness,
             std::optional<std::vector<int>> pyramid, int max_iterations, double tolerance_mm,
             double tolerance_deg) {
            RegistrationSettings s;
            s.metric = metric;
            s.optimizer = optimizer;
            s.mode = mode;
            s.starts = starts;
            s.search_rot_deg = search_rot_deg;
            s.search_trans_mm = search_trans_mm;
            s.seed = seed_value(seed, "seed");
            s.smoothness = smoothness;
            s.pyramid = std::move(pyramid);
            s.max_iterations = max_iterations;
            s.tolerance_mm = tolerance_mm;
            s.tolerance_deg = tolerance_deg;
            s.validate();
            new (self) RegistrationSettings(std::move(s));
          },
          nb::kw_only(), "metric"_a = settings.metric, "optimizer"_a.none() = nb::none(),
          "mode"_a = settings.mode, "starts"_a.none() = nb::none(),
          "search_rot_deg"_a = settings.search_rot_deg,
          "search_trans_mm"_a = settings.search_trans_mm, "seed"_a = nb::int_(settings.seed),
          "smoothness"_a.none() = nb::none(), "pyramid"_a.none() = nb::none(),
          "max_iterations"_a = settings.max_iterations, "tolerance_mm"_a = settings.tolerance_mm,
          "tolerance_deg"_a = settings.tolerance_deg,
          "optimizer: default lm for ssd and ncc, bobyqa for the others (default_optimizer). "
          "starts: None (default) runs starts until three reach the same pose, at most "
          "default_max_starts(metric). pyramid: None (default) is the metric's (default_pyramid).")
      .def_ro("metric", &RegistrationSettings::metric)
      .def_ro("optimizer", &RegistrationSettings::optimizer,
              "None: not chosen yet (resolved() chooses)")
      .def_ro("mode", &RegistrationSettings::mode)
      .def_ro("starts", &RegistrationSettings::starts, "None: automatic")
      .def_ro("search_rot_deg", &RegistrationSettings::search_rot_deg)
      .def_ro("search_trans_mm", &RegistrationSettings::search_trans_mm)
      .def_ro("seed", &RegistrationSettings::seed)
      .def_ro("smoothness", &RegistrationSettings::smoothness,
              "smooth-sweep's prior weight; None: not chosen yet (resolved() chooses for "
              "smooth-sweep)")
      .def_ro("pyramid", &RegistrationSettings::pyramid,
              "None: not chosen yet (resolved() chooses)")
      .def_ro("max_iterations", &RegistrationSettings::max_iterations)
      .def_ro("tolerance_mm", &RegistrationSettings::tolerance_mm)
      .def_ro("tolerance_deg", &RegistrationSettings::tolerance_deg)
      .def("resolved", &RegistrationSettings::resolved,
           "These settings with the defaults chosen (the optimiser and the pyramid).")
      .def("__repr__", [](const RegistrationSettings& s) {
        std::string levels = "None";
        if (s.pyramid) {
          levels = "[";
          for (int f : *s.pyramid) levels += (levels.size() > 1 ? ", " : "") + std::to_string(f);
          levels += "]";
        }
        return std::string("RegistrationSettings(metric=") +
               repr(std::string(to_string(s.metric))) + ", optimizer=" +
               (s.optimizer ? repr(std::string(to_string(*s.optimizer))) : "None") +
               ", mode=" + repr(std::string(to_string(s.mode))) +
               ", starts=" + (s.starts ? repr(*s.starts) : std::string("None")) +
               ", search_rot_deg=" + repr(s.search_rot_deg) +
               ", search_trans_mm=" + repr(s.search_trans_mm) + ", seed=" + repr(s.seed) +
               ", smoothness=" + (s.smoothness ? repr(*s.smoothness) : std::string("None")) +
               ", pyramid=" + levels + ")";
      });

  nb::class_<FrameReport>(m, "FrameReport", "One frame's outcome (docs/registration.md §4).")
      .def_ro("index", &FrameReport::index)
      .def_ro("metric", &FrameReport::metric, "the final cost at full resolution")
      .def_ro("evaluations", &FrameReport::evaluations)
      .def_ro("iterations", &FrameReport::iterations)
      .def_ro("translation_change_mm", &FrameReport::translation_change_mm)
      .def_ro("rotation_change_deg", &FrameReport::rotation_change_deg)
      .def_ro("starts", &FrameReport::starts, "optimisations run")
      .def_ro("agreeing_starts", &FrameReport::agreeing_starts,
              "of them, those that ended at the best pose")
      .def_prop_ro("confidence", &FrameReport::confidence,
                   "(agreeing_starts - 1) / (starts - 1): the share of the other starts that "
                   "confirmed the best pose; 0 with one start")
      .def_ro("uncertainty_mm", &FrameReport::uncertainty_mm,
              "standard deviation of the centre, mm (ssd, ncc; NaN otherwise)")
      .def_ro("uncertainty_deg", &FrameReport::uncertainty_deg,
              "standard deviation of the rotation, degrees (ssd, ncc; NaN otherwise)")
      .def_ro("converged", &FrameReport::converged,
              "the best pose was reached from at least three starts");
  nb::class_<RegistrationReport>(m, "RegistrationReport", "What a registration used and did.")
      .def_ro("settings", &RegistrationReport::settings, "the settings as resolved")
      .def_ro("frames", &RegistrationReport::frames)
      .def_ro("evaluations", &RegistrationReport::evaluations)
      .def_ro("seconds", &RegistrationReport::seconds)
      .def_prop_ro(
          "correction",
          [](const RegistrationReport& r) -> nb::object {
            if (!r.correction) return nb::none();
            return nb::cast(matrices_to_numpy({*r.correction}));
          },
          "the sweep modes' and calibration's shared correction, (1, 4, 4); None per frame")
      .def_ro("sweep_metric", &RegistrationReport::sweep_metric,
              "the sweep's own cost at the shared correction, full resolution; None per frame")
      .def_ro("halves_mm", &RegistrationReport::halves_mm,
              "how far apart the sweep's halves, each refined alone, end (mm); None per frame")
      .def_ro("sides_mm", &RegistrationReport::sides_mm,
              "how far apart the left and right halves of the sweep's frames, each refined alone, "
              "end (mm); None per frame");

  m.def(
      "registration_costs",
      [](nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe, Frames frames,
         Matrices pose_array, RegistrationMetric metric, int level) {
        auto source = volume_source(volume.h);
        if (source) source->check("registration_cost");
        check_frames(frames, probe);
        const std::vector<Pose> poses = matrices_from(pose_array);
        if (poses.size() != frames.shape(0))
          throw InputError("poses: expected one per frame (" + std::to_string(frames.shape(0)) +
                           "), got " + std::to_string(poses.size()));
        validate_poses(poses, "poses");  // as register and Slicer.slice check them
        std::vector<double> costs(poses.size());
        {
          nb::gil_scoped_release release;
          const FrameRegistration reg(*volume.p, probe, frames.data(), frames.shape(0));
          reg.prepare_level(level);
          for (size_t i = 0; i < poses.size(); ++i) costs[i] = reg.cost(i, poses[i], level, metric);
        }
        return costs;
      },
      "volume"_a, "probe"_a, "frames"_a, "poses"_a, "metric"_a, "level"_a,
      "FrameRegistration::cost of frame i at pose i, at pyramid level `level`.");

  m.def(
      "register_frames",
      [](nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe, Frames frames,
         Matrices pose_array, std::optional<MaskArray> mask, const RegistrationSettings& settings) {
        auto source = volume_source(volume.h);
        if (source) source->check("register");
        check_frames(frames, probe);
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
          refined = reg.run(initial, settings, &report);
        }
        return std::make_pair(matrices_to_numpy(std::move(refined)), std::move(report));
      },
      "volume"_a, "probe"_a, "frames"_a, "poses"_a, nb::kw_only(), "mask"_a.none() = nb::none(),
      "settings"_a = RegistrationSettings(),
      "(refined (N, 4, 4) poses, RegistrationReport): FrameRegistration::run.");

  m.def(
      "register_plus_sequence",
      [](nb::pointer_and_handle<Volume> volume, const PlusSequence& sequence,
         const PlusReconstructionConfig* config, const RegistrationSettings& settings,
         bool corrected) {
        auto source = volume_source(volume.h);
        if (source) source->check("register_sequence");
        PlusRegistration r;
        std::optional<PlusSequence> corrected_sequence;
        {
          nb::gil_scoped_release release;
          const PlusReconstructionConfig chosen = config ? *config : PlusReconstructionConfig();
          r = register_plus_sequence(*volume.p, sequence, chosen, settings);
          if (corrected) corrected_sequence = corrected_plus_sequence(sequence, chosen, r);
        }
        return std::make_tuple(std::move(r.frames), matrices_to_numpy(r.image_to_reference),
                               matrix_or_none(r.image_to_probe), std::move(r.skipped),
                               std::move(r.report), std::move(corrected_sequence));
      },
      "volume"_a, "sequence"_a, "config"_a.none(), nb::kw_only(),
      "settings"_a = RegistrationSettings(), "corrected"_a = false,
      "(frames used, (M, 4, 4) refined ImageToReference, corrected ImageToProbe or None, why "
      "frames were skipped, RegistrationReport, the corrected sequence or None): "
      "register_plus_sequence, and with corrected, corrected_plus_sequence.");
}

}  // namespace sonoslice::bindings
