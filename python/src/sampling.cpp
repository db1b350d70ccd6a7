// Pose samplers (docs/datasets.md §2): their settings (SamplerSettings, read from keywords or a
// dict by the library's parser of the dataset SPEC's sampler entries), seeds in, poses out.
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>

#include <tuple>

#include "bindings.h"
#include "sonoslice/sampling/PoseSampler.h"
#include "sonoslice/sampling/SamplerConfig.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;
using Seeds = nb::ndarray<const uint64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

/// A sampler and the inputs it reads (kept alive with it: the sampler reads their voxels).
struct PySampler {
  nb::object volume, labels;
  std::unique_ptr<PoseSampler> sampler;
};

/// `draw` (sample or candidates) of the seeds, without the GIL, as NumPy (N, 4, 4).
MatricesOut poses_of(const PySampler& s, const Seeds& seeds,
                     std::vector<Pose> (PoseSampler::*draw)(const uint64_t*, size_t) const) {
  std::vector<Pose> poses;
  {
    nb::gil_scoped_release release;
    poses = ((*s.sampler).*draw)(seeds.data(), seeds.shape(0));
  }
  return matrices_to_numpy(std::move(poses));
}

/// Settings from a dict of a SPEC's sampler keys: the parser of SPEC files checks every key and
/// value (errors name `where` and the key).
SamplerSettings settings_of(nb::handle keys, const std::string& where) {
  if (!nb::isinstance<nb::dict>(keys))
    throw nb::type_error(("SamplerSettings: expected a dict of sampler settings, got " +
                          std::string(nb::type_name(keys.type()).c_str()))
                             .c_str());
  return parse_sampler_json(json_text(keys, where), where);
}

std::tuple<double, double> pair_of(const Interval& i) {
  return {i.lo, i.hi};
}

std::string interval_repr(const Interval& i) {
  return "(" + repr(i.lo) + ", " + repr(i.hi) + ")";
}

std::string settings_repr(const SamplerSettings& s) {
  std::string r = "SamplerSettings(type=" + repr(std::string(to_string(s.type)));
  switch (s.type) {
    case SamplerType::Skin:
    case SamplerType::Mesh:
      r += ", rotation_deg=" + interval_repr(s.rotation_deg) +
           ", tilt_deg=" + interval_repr(s.tilt_deg) +
           ", heel_toe_deg=" + interval_repr(s.heel_toe_deg) +
           ", depth_mm=" + interval_repr(s.depth_mm);
      break;
    case SamplerType::Region:
      r += s.label >= 0 ? ", label=" + repr(s.label)
                        : ", intensity=" + interval_repr(s.intensity.value_or(Interval{}));
      r += ", cone_deg=" + repr(s.cone_deg);
      break;
    case SamplerType::Sweep:
      r += ", motion=" + repr(std::string(to_string(s.motion))) + ", step=" + repr(s.step) +
           ", frames=" + repr(s.frames);
      if (s.base) r += ", from=" + settings_repr(*s.base);
      break;
  }
  return r + ")";
}

}  // namespace

void bind_sampling(nb::module_& m) {
  m.def(
      "sample_seeds",
      [](uint64_t base, uint64_t stream, uint64_t first, size_t count) {
        auto* keep = new std::vector<uint64_t>(sample_seeds(base, stream, first, count));
        nb::capsule owner(keep,
                          [](void* p) noexcept { delete static_cast<std::vector<uint64_t>*>(p); });
        const size_t shape[1] = {count};
        return nb::ndarray<nb::numpy, uint64_t, nb::ndim<1>>(keep->data(), 1, shape, owner);
      },
      "base"_a, "stream"_a, "first"_a, "count"_a);

  nb::class_<RejectionRules>(m, "RejectionRules",
                             "A sampler's rejection rules (the SPEC's \"reject\" keys).")
      .def_ro("min_inside", &RejectionRules::min_inside)
      .def_ro("min_body", &RejectionRules::min_body)
      .def_ro("label", &RejectionRules::label)
      .def_ro("min_label", &RejectionRules::min_label)
      .def_ro("no_gas", &RejectionRules::no_gas)
      .def_ro("gas_hu", &RejectionRules::gas_hu)
      .def_ro("gas_depth_mm", &RejectionRules::gas_depth_mm);

  nb::class_<SamplerSettings>(
      m, "SamplerSettings",
      "A pose sampler's settings (docs/datasets.md §2), made from the keys of a dataset SPEC's "
      "sampler entry: SamplerSettings(type=\"skin\", tilt_deg=(-10, 10), reject={\"min_body\": "
      "0.5}) or SamplerSettings.from_dict(entry). Unknown keys, keys of another sampler type "
      "and bad values raise ValueError naming them.")
      .def("__init__",
           [](SamplerSettings* self, nb::kwargs keys) {
             new (self) SamplerSettings(settings_of(keys, "sampler"));
           })
      .def_static("from_dict", &settings_of, "settings"_a, "where"_a = "sampler",
                  "The settings of a dict of SPEC sampler keys (errors name `where`).")
      .def_prop_ro("type", [](const SamplerSettings& s) { return to_string(s.type); })
      .def_ro("threshold_hu", &SamplerSettings::threshold_hu)
      .def_prop_ro("rotation_deg", [](const SamplerSettings& s) { return pair_of(s.rotation_deg); })
      .def_prop_ro("tilt_deg", [](const SamplerSettings& s) { return pair_of(s.tilt_deg); })
      .def_prop_ro("heel_toe_deg", [](const SamplerSettings& s) { return pair_of(s.heel_toe_deg); })
      .def_prop_ro("depth_mm", [](const SamplerSettings& s) { return pair_of(s.depth_mm); })
      .def_ro("label", &SamplerSettings::label)
      .def_prop_ro("intensity",
                   [](const SamplerSettings& s) -> std::optional<std::tuple<double, double>> {
                     if (!s.intensity) return std::nullopt;
                     return pair_of(*s.intensity);
                   })
      .def_ro("cone_deg", &SamplerSettings::cone_deg)
      .def_ro("direction", &SamplerSettings::direction)
      .def_prop_ro("anchor",
                   [](const SamplerSettings& s) { return s.anchor_at_centre ? "centre" : "face"; })
      .def_prop_ro("motion", [](const SamplerSettings& s) { return to_string(s.motion); })
      .def_ro("step", &SamplerSettings::step)
      .def_ro("frames", &SamplerSettings::frames)
      .def_ro("jitter_mm", &SamplerSettings::jitter_mm)
      .def_ro("jitter_deg", &SamplerSettings::jitter_deg)
      .def_prop_ro(
          "start", [](const SamplerSettings& s) { return matrix_or_none(s.start); },
          nb::rv_policy::move, "a sweep's fixed start pose (4, 4), or None")
      .def_prop_ro(
          "base",
          [](const SamplerSettings& s) -> std::optional<SamplerSettings> {
            if (!s.base) return std::nullopt;
            return *s.base;
          },
          "a sweep's base sampler (the SPEC's \"from\")")
      .def_ro("reject", &SamplerSettings::reject)
      .def_ro("max_tries", &SamplerSettings::max_tries)
      .def("__repr__", &settings_repr);

  nb::class_<PySampler>(m, "PoseSampler",
                        "Poses as a pure function of a seed (use sonoslice.PoseSampler).")
      .def(
          "__init__",
          [](PySampler* self, const SamplerSettings& settings, const ProbeGeometry& probe,
             nb::object volume, nb::object labels, const TriangleMesh* mesh) {
            const Volume* v = volume.is_none() ? nullptr : nb::cast<const Volume*>(volume);
            const Volume* l = labels.is_none() ? nullptr : nb::cast<const Volume*>(labels);
            for (const nb::object& o : {volume, labels})
              if (!o.is_none()) check_volume_source(o, "sample");
            std::unique_ptr<PoseSampler> sampler;
            {
              nb::gil_scoped_release release;
              sampler = std::make_unique<PoseSampler>(settings, probe, v, l, mesh);
            }
            new (self) PySampler{volume, labels, std::move(sampler)};
          },
          "settings"_a, "probe"_a, nb::kw_only(), "volume"_a.none() = nb::none(),
          "labels"_a.none() = nb::none(), "mesh"_a.none() = nb::none())
      .def_prop_ro("poses_per_seed", [](const PySampler& s) { return s.sampler->poses_per_seed(); })
      .def(
          "sample",
          [](const PySampler& s, Seeds seeds) { return poses_of(s, seeds, &PoseSampler::sample); },
          "seeds"_a)
      .def(
          "candidates",
          [](const PySampler& s, Seeds seeds) {
            return poses_of(s, seeds, &PoseSampler::candidates);
          },
          "seeds"_a)
      .def("accepts",
           [](const PySampler& s, Matrices pose) {
             const std::vector<Pose> p = matrices_from(pose);
             if (p.size() != 1) throw InputError("accepts: expected one (1, 4, 4) pose");
             return s.sampler->accepts(p[0]);
           })
      .def("surface", [](const PySampler& s) {
        const auto& pts = s.sampler->surface_points();
        const auto& nrm = s.sampler->surface_normals();
        auto out = std::make_shared<std::vector<double>>();
        for (size_t k = 0; k < pts.size(); ++k)
          for (const Vec3* v : {&pts[k], &nrm[k]})
            for (double x : *v) out->push_back(x);
        return numpy_view(out->data(), {pts.size(), 2, 3}, PixelType::Float64, out);
      });
}

}  // namespace sonoslice::bindings
