// The reconstruction recipe (include/sonoslice/compound/Reconstruction.h) for Python's
// reconstruct_plus and plus_image_to_reference: the same C++ function `sonoslice compound` calls,
// so the CLI and Python cannot drift. Parameters are named as Python's keywords in messages.
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <memory>

#include "bindings.h"
#include "sonoslice/compound/Reconstruction.h"
#include "sonoslice/plus/FrameSelection.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"

namespace sonoslice::bindings {

using namespace nb::literals;

std::string keyword_of(const std::string& parameter) {
  if (parameter == "mode") return "compounding";
  if (parameter == "output_type") return "dtype";
  if (parameter == "max_memory_bytes") return "max_memory";
  if (parameter == "origin_mm") return "origin";
  return parameter;
}

ReconstructionOptions reconstruction_options(
    std::optional<Vec3> spacing, const std::optional<std::string>& interpolation,
    const std::optional<std::string>& compounding, std::optional<bool> fill_holes,
    std::optional<std::vector<HoleFillingKernel>> hole_filling,
    std::optional<double> rejection_threshold, std::optional<FrameClip> clip,
    std::optional<int> skip, std::optional<std::string> transform,
    const std::optional<Matrix4>& image_to_probe, const std::optional<std::string>& dtype,
    const std::string& device, uint64_t max_memory, bool plus_exact,
    const std::optional<std::string>& plus_optimization,
    const std::optional<std::string>& plus_grid, std::optional<Vec3> origin,
    std::optional<std::array<int64_t, 3>> extent) {
  ReconstructionOptions o;
  o.names = keyword_of;
  o.spacing_mm = spacing;
  if (interpolation) o.interpolation = parse_interpolation(*interpolation);
  if (compounding) o.mode = parse_compounding_mode(*compounding);
  o.fill_holes = fill_holes;
  o.hole_filling = std::move(hole_filling);
  o.rejection_threshold = rejection_threshold;
  o.clip = std::move(clip);
  o.skip = skip;
  o.transform = std::move(transform);
  if (image_to_probe) o.image_to_probe = Mat4::from_row_major(image_to_probe->data());
  if (dtype) o.output_type = parse_pixel_type(*dtype);
  o.device = Device::parse(device);
  o.max_memory_bytes = max_memory;
  o.plus_exact = plus_exact;
  o.plus_optimization = plus_optimization;
  o.plus_grid = plus_grid;
  o.origin_mm = origin;
  o.extent = extent;
  return o;
}

namespace {

// A Reconstruction that keeps the Python objects whose memory it views alive.
struct PyReconstruction {
  nb::object sequence_owner, config_owner;
  std::unique_ptr<Reconstruction> recon;
};

nb::dict report_dict(const ReconstructionReport& r) {
  nb::dict d;
  d["input"] = r.input;
  d["frames_in_input"] = r.frames_in_input;
  d["frames_considered"] = r.frames_considered;
  d["frames_used"] = r.frames_used;
  d["skipped_bad_image"] = r.skipped_bad_image;
  d["skipped_bad_transform"] = r.skipped_bad_transform;
  d["skipped_unusable_transform"] = r.skipped_unusable_transform;
  d["skipped_frames"] = r.skipped_frames;
  d["skipped_reason"] = r.skipped_reason();
  d["skip"] = r.skip;
  d["transform"] = r.transform;
  d["grid_from_config"] = r.grid_from_config;
  d["grid_given"] = r.grid_given;
  d["splat_seconds"] = r.splat_seconds;
  d["finish_seconds"] = r.finish_seconds;
  return d;
}

}  // namespace

void bind_reconstruction(nb::module_& m) {
  nb::class_<PyReconstruction>(
      m, "Reconstruction",
      "The reconstruction recipe for a PLUS sequence (use sonoslice.reconstruct_plus).")
      .def(
          "__init__",
          [](PyReconstruction* self, nb::object sequence, nb::object config,
             std::optional<Vec3> spacing, std::optional<std::string> interpolation,
             std::optional<std::string> compounding, std::optional<bool> fill_holes,
             std::optional<std::vector<HoleFillingKernel>> hole_filling,
             std::optional<double> rejection_threshold, std::optional<FrameClip> clip,
             std::optional<int> skip, std::optional<std::string> transform,
             std::optional<Matrix4> image_to_probe, std::optional<std::string> dtype,
             std::string device, uint64_t max_memory, bool plus_exact,
             std::optional<std::string> plus_optimization, std::optional<std::string> plus_grid,
             std::optional<Vec3> origin, std::optional<std::array<int64_t, 3>> extent) {
            const PlusSequence& s = nb::cast<const PlusSequence&>(sequence);
            const PlusReconstructionConfig* c =
                config.is_none() ? nullptr : &nb::cast<const PlusReconstructionConfig&>(config);
            const ReconstructionOptions o = reconstruction_options(
                spacing, interpolation, compounding, fill_holes, std::move(hole_filling),
                rejection_threshold, std::move(clip), skip, std::move(transform), image_to_probe,
                dtype, device, max_memory, plus_exact, plus_optimization, plus_grid, origin,
                extent);
            std::unique_ptr<Reconstruction> r;
            {
              nb::gil_scoped_release release;  // fitting the grid and allocating take a while
              r = std::make_unique<Reconstruction>(FrameSource::plus(s), c, o);
            }
            new (self) PyReconstruction{sequence, config, std::move(r)};
          },
          "sequence"_a, "config"_a.none(), nb::kw_only(), "spacing"_a.none() = nb::none(),
          "interpolation"_a.none() = nb::none(), "compounding"_a.none() = nb::none(),
          "fill_holes"_a.none() = nb::none(), "hole_filling"_a.none() = nb::none(),
          "rejection_threshold"_a.none() = nb::none(), "clip"_a.none() = nb::none(),
          "skip"_a.none() = nb::none(), "transform"_a.none() = nb::none(),
          "image_to_probe"_a.none() = nb::none(), "dtype"_a.none() = nb::none(), "device"_a = "cpu",
          "max_memory"_a = 0, "plus_exact"_a = false, "plus_optimization"_a = nb::none(),
          "plus_grid"_a = nb::none(), "origin"_a.none() = nb::none(),
          "extent"_a.none() = nb::none())
      .def_prop_ro("grid", [](const PyReconstruction& r) { return r.recon->grid(); })
      .def_prop_ro("settings", [](const PyReconstruction& r) { return r.recon->settings(); })
      .def_prop_ro("clip", [](const PyReconstruction& r) { return r.recon->clip(); })
      .def_prop_ro("dtype",
                   [](const PyReconstruction& r) { return to_string(r.recon->output_type()); })
      .def_prop_ro("report",
                   [](const PyReconstruction& r) { return report_dict(r.recon->report()); })
      .def_prop_ro("frame_indices",
                   [](const PyReconstruction& r) { return r.recon->frame_indices(); })
      .def_prop_ro("frames_to_reference",
                   [](const PyReconstruction& r) {
                     return matrices_to_numpy(r.recon->frames_to_reference());
                   })
      .def(
          "run",
          [](PyReconstruction& r, bool with_weights) {
            nb::gil_scoped_release release;
            ReconstructionResult out = r.recon->run(with_weights);
            return std::make_tuple(std::move(out.volume), std::move(out.weights));
          },
          "with_weights"_a = false,
          "(volume, weights) once; weights is an empty Volume unless asked for.");

  m.def(
      "select_plus_frames",
      [](const PlusSequence& s, const PlusReconstructionConfig* c, std::optional<int> skip,
         std::optional<std::string> transform, std::optional<Matrix4> image_to_probe) {
        ReconstructionOptions o;
        o.names = keyword_of;
        o.skip = skip;
        o.transform = std::move(transform);
        if (image_to_probe) o.image_to_probe = Mat4::from_row_major(image_to_probe->data());
        FrameSelection sel;
        {
          nb::gil_scoped_release release;
          sel = select_frames(FrameSource::plus(s), c, o);
        }
        return std::make_tuple(std::move(sel.indices),
                               matrices_to_numpy(std::move(sel.to_reference)),
                               report_dict(sel.report));
      },
      "sequence"_a, "config"_a.none(), "skip"_a.none() = nb::none(),
      "transform"_a.none() = nb::none(), "image_to_probe"_a.none() = nb::none(),
      "(frame indices, (M, 4, 4) image->reference matrices, report) as the recipe picks them.");
}

}  // namespace sonoslice::bindings
