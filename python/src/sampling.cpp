// Pose samplers (docs/datasets.md §2): settings as JSON (the dataset SPEC's sampler entries),
// seeds in, poses out.
#include <nanobind/stl/string.h>

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
  nb::class_<PySampler>(m, "PoseSampler")
      .def(
          "__init__",
          [](PySampler* self, const std::string& config, const ProbeGeometry& probe,
             nb::object volume, nb::object labels, const TriangleMesh* mesh) {
            const SamplerSettings s = parse_sampler_json(config, "sampler");
            const Volume* v = volume.is_none() ? nullptr : nb::cast<const Volume*>(volume);
            const Volume* l = labels.is_none() ? nullptr : nb::cast<const Volume*>(labels);
            for (const nb::object& o : {volume, labels})
              if (!o.is_none()) check_volume_source(o, "sample");
            std::unique_ptr<PoseSampler> sampler;
            {
              nb::gil_scoped_release release;
              sampler = std::make_unique<PoseSampler>(s, probe, v, l, mesh);
            }
            new (self) PySampler{volume, labels, std::move(sampler)};
          },
          "config"_a, "probe"_a, "volume"_a.none(), "labels"_a.none(), "mesh"_a.none())
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
