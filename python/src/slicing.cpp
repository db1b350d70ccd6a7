// Probes, the volume slicer (CPU threads or CUDA, into NumPy/torch/DLPack arrays) and pose checks.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>

#include <memory>

#include "bindings.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;

constexpr int kCpu = nb::device::cpu::value;
constexpr int kCuda = nb::device::cuda::value;

/// The image grid of a probe made in Python: W × H pixels of spacing (sx, sy) mm, at `origin`
/// or the default origin.
ImageGrid image_grid(int width, int height, std::pair<double, double> spacing,
                     std::optional<std::pair<double, double>> origin) {
  ImageGrid g = ImageGrid::centred(width, height, spacing.first, spacing.second);
  if (origin) {
    g.origin_mm[0] = origin->first;
    g.origin_mm[1] = origin->second;
  }
  return g;
}

/// The bound Slicer: a CPU slicer reads the volume's memory at every call, so it keeps what the
/// volume views (null for a volume that owns its memory, or on CUDA, where the volume was
/// uploaded when the slicer was made) and checks it before each call.
struct PySlicer : Slicer {
  using Slicer::Slicer;
  std::shared_ptr<const ArraySource> source;
};

void slice_into(const PySlicer& slicer, Matrices pose_array, nb::ndarray<> out, uintptr_t stream,
                nb::object progress, int64_t chunk) {
  if (slicer.source) slicer.source->check("slice");
  const std::vector<Pose> poses = matrices_from(pose_array);
  const int64_t n = int64_t(poses.size());
  if (!has_shape(out, n, slicer.height(), slicer.width()))
    throw InputError("out: expected shape " + shape_text(n, slicer.height(), slicer.width()));
  if (!c_contiguous(out)) throw InputError("out: must be C-contiguous");
  check_out_dtype(out, slicer.settings().output_type);
  const bool on_gpu = out.device_type() == kCuda;
  if (!on_gpu && out.device_type() != kCpu) throw InputError("out: must be in host or CUDA memory");
  const Device device = slicer.device();
  if (on_gpu && (device.type != DeviceType::CUDA || device.index != out.device_id()))
    throw InputError("out: is on cuda:" + std::to_string(out.device_id()) +
                     " but the slicer runs on " + device.to_string());
  auto* base = static_cast<char*>(out.data());
  const size_t image_bytes = slicer.image_bytes();
  slice_in_chunks(poses, progress, chunk, [&](int64_t first, int64_t count) {
    if (on_gpu)
      slicer.slice_into_device(poses.data() + first, size_t(count),
                               base + size_t(first) * image_bytes, reinterpret_cast<void*>(stream),
                               size_t(first));
    else
      slicer.slice(poses.data() + first, size_t(count), base + size_t(first) * image_bytes,
                   size_t(first));
  });
}

}  // namespace

void bind_slicing(nb::module_& m) {
  nb::class_<ProbeGeometry>(m, "Probe")
      .def_static(
          "curvilinear",
          [](double radius_mm, double depth_mm, double sector_deg, int width, int height,
             std::pair<double, double> spacing_mm, double face_y_mm,
             std::optional<std::pair<double, double>> origin_mm) {
            const ProbeGeometry p = ProbeGeometry::curvilinear(
                radius_mm, depth_mm, sector_deg, image_grid(width, height, spacing_mm, origin_mm),
                face_y_mm);
            p.validate("curvilinear probe");
            return p;
          },
          "radius_mm"_a, "depth_mm"_a, "sector_deg"_a, "width"_a, "height"_a, "spacing_mm"_a,
          nb::kw_only(), "face_y_mm"_a = 0.0, "origin_mm"_a = nb::none())
      .def_static(
          "linear",
          [](int width, int height, std::pair<double, double> spacing_mm,
             std::optional<double> width_mm, std::optional<double> depth_mm, double face_y_mm,
             std::optional<std::pair<double, double>> origin_mm) {
            const ProbeGeometry p = ProbeGeometry::linear(
                image_grid(width, height, spacing_mm, origin_mm), width_mm, depth_mm, face_y_mm);
            p.validate("linear probe");
            return p;
          },
          "width"_a, "height"_a, "spacing_mm"_a, nb::kw_only(), "width_mm"_a = nb::none(),
          "depth_mm"_a = nb::none(), "face_y_mm"_a = 0.0, "origin_mm"_a = nb::none())
      .def_static("from_file", &read_probe, "path"_a, "downsampling"_a = 1)
      .def_static("from_json_text", &parse_probe_json, "text"_a, "source"_a = "<string>",
                  "downsampling"_a = 1)
      .def_static("workload",
                  [](const std::string& name) {
                    if (name == "W1") return workload_w1_fan_probe();
                    if (name == "W2") return workload_w2_linear_probe();
                    throw InputError("workload '" + name + "': expected W1 or W2");
                  })
      .def("to_json", &probe_to_json)
      .def("describe", &ProbeGeometry::describe)
      .def("mask",
           [](const ProbeGeometry& p) {
             auto m = std::make_shared<std::vector<uint8_t>>(p.mask());
             return numpy_view(m->data(), {size_t(p.image.height), size_t(p.image.width)},
                               PixelType::UInt8, m);
           })
      .def("inside", &ProbeGeometry::inside, "x"_a, "y"_a)
      .def_prop_ro("type", [](const ProbeGeometry& p) { return to_string(p.type); })
      .def_prop_ro("width", [](const ProbeGeometry& p) { return p.image.width; })
      .def_prop_ro("height", [](const ProbeGeometry& p) { return p.image.height; })
      .def_prop_ro("spacing_mm",
                   [](const ProbeGeometry& p) {
                     return std::make_pair(p.image.spacing_mm[0], p.image.spacing_mm[1]);
                   })
      .def_prop_ro("origin_mm",
                   [](const ProbeGeometry& p) {
                     return std::make_pair(p.image.origin_mm[0], p.image.origin_mm[1]);
                   })
      .def_prop_ro("radius_mm", [](const ProbeGeometry& p) { return p.radius_mm; })
      .def_prop_ro("depth_mm", [](const ProbeGeometry& p) { return p.depth_mm; })
      .def_prop_ro("sector_deg", [](const ProbeGeometry& p) { return p.sector_deg; })
      .def_prop_ro("face_y_mm", [](const ProbeGeometry& p) { return p.face_y_mm; });

  const SliceSettings defaults;
  nb::class_<PySlicer>(m, "Slicer")
      .def(
          "__init__",
          [](PySlicer* self, nb::pointer_and_handle<Volume> volume, const ProbeGeometry& probe,
             const std::string& device, const std::string& interpolation, double fill,
             const std::string& dtype) {
            SliceSettings s;
            s.interpolation = parse_interpolation(interpolation);
            s.fill_value = fill;
            s.output_type = parse_pixel_type(dtype);  // the Slicer says which types it makes
            const Device d = Device::parse(device);
            auto source = volume_source(volume.h);
            if (source) source->check("make a Slicer");
            {
              nb::gil_scoped_release release;  // a CUDA slicer uploads the volume here
              new (self) PySlicer(*volume.p, probe, s, d);
            }
            if (d.type == DeviceType::CPU) self->source = std::move(source);
          },
          "volume"_a, "probe"_a, "device"_a = "cpu",
          "interpolation"_a = to_string(defaults.interpolation), "fill"_a = defaults.fill_value,
          "dtype"_a = to_string(defaults.output_type))
      .def("slice_into", &slice_into, "poses"_a, "out"_a, "stream"_a = 0, "progress"_a = nb::none(),
           "chunk"_a = 0)
      .def_prop_ro("width", [](const PySlicer& s) { return s.width(); })
      .def_prop_ro("height", [](const PySlicer& s) { return s.height(); })
      .def_prop_ro("device", [](const PySlicer& s) { return s.device().to_string(); })
      .def_prop_ro("dtype", [](const PySlicer& s) { return to_string(s.settings().output_type); })
      .def_prop_ro("interpolation",
                   [](const PySlicer& s) { return to_string(s.settings().interpolation); })
      .def_prop_ro("fill", [](const PySlicer& s) { return s.settings().fill_value; })
      .def_prop_ro("probe", [](const PySlicer& s) { return s.probe(); })
      .def("mask", [](const PySlicer& s) {
        auto m = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(m->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8, m);
      });

  m.def(
      "validate_poses",
      [](Matrices a, const std::string& source) {
        const std::vector<Pose> poses = matrices_from(a);
        validate_poses(poses.data(), poses.size(), source);
      },
      "poses"_a, "source"_a = "poses");
}

}  // namespace sonoslice::bindings
