// The C++ side of the Python package: thin bindings over the library. Arrays cross the border
// without copies (NumPy's buffer protocol / DLPack through nanobind's ndarray); the GIL is
// released while C++ computes; C++ errors become ValueError / OSError / RuntimeError. The
// Pythonic API (argument handling, torch tensors, tqdm) is python/sonoslice/__init__.py.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>

#include "sonoslice/backend/Device.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/BeamGeometryFile.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/PlusConfig.h"
#include "sonoslice/io/PlusSequence.h"
#include "sonoslice/io/SurfaceConfig.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/slice/Slicer.h"
#include "sonoslice/surface/Colorize.h"
#include "sonoslice/surface/SurfaceSlicer.h"
#include "sonoslice/surface/Voxelize.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace sonoslice {
namespace {

constexpr int kCpu = nb::device::cpu::value;
constexpr int kCuda = nb::device::cuda::value;

// ---- dtypes ----------------------------------------------------------------------------------
PixelType pixel_type_of(nb::dlpack::dtype d, const char* what) {
  using C = nb::dlpack::dtype_code;
  if (d.lanes == 1) {
    if (d.code == uint8_t(C::UInt)) {
      if (d.bits == 8) return PixelType::UInt8;
      if (d.bits == 16) return PixelType::UInt16;
      if (d.bits == 32) return PixelType::UInt32;
    } else if (d.code == uint8_t(C::Int)) {
      if (d.bits == 8) return PixelType::Int8;
      if (d.bits == 16) return PixelType::Int16;
      if (d.bits == 32) return PixelType::Int32;
    } else if (d.code == uint8_t(C::Float)) {
      if (d.bits == 32) return PixelType::Float32;
      if (d.bits == 64) return PixelType::Float64;
    }
  }
  throw InputError(std::string(what) + ": unsupported dtype (supported: uint8, int8, uint16, int16, "
                   "uint32, int32, float32, float64)");
}

nb::dlpack::dtype dlpack_dtype(PixelType t) {
  return visit_pixel_type(t, [](auto zero) { return nb::dtype<decltype(zero)>(); });
}

template <typename... Args>
bool c_contiguous(const nb::ndarray<Args...>& a) {
  int64_t expected = 1;
  for (size_t i = a.ndim(); i-- > 0;) {
    if (a.shape(i) != 1 && a.stride(i) != expected) return false;
    expected *= int64_t(a.shape(i));
  }
  return true;
}

// A NumPy view of memory that `keep` keeps alive (a copy of a shared handle).
template <typename Keep>
nb::ndarray<nb::numpy> numpy_view(void* data, std::vector<size_t> shape, PixelType type, Keep keep) {
  auto* holder = new Keep(std::move(keep));
  nb::capsule owner(holder, [](void* p) noexcept { delete static_cast<Keep*>(p); });
  return nb::ndarray<nb::numpy>(data, shape.size(), shape.data(), owner, nullptr, dlpack_dtype(type));
}

// ---- volumes ---------------------------------------------------------------------------------
VolumeGrid make_grid(const std::array<double, 3>& spacing, const std::array<double, 3>& origin,
                     const std::array<double, 9>& direction) {
  VolumeGrid g;
  g.spacing_mm = {spacing[0], spacing[1], spacing[2]};
  g.origin_mm = {origin[0], origin[1], origin[2]};
  for (int i = 0; i < 9; ++i) g.direction.m[i / 3][i % 3] = direction[size_t(i)];
  return g;
}

// Zero-copy: the volume points into the caller's array, which it keeps alive.
Volume volume_from_array(nb::ndarray<> a, const std::array<double, 3>& spacing,
                         const std::array<double, 3>& origin, const std::array<double, 9>& direction) {
  if (a.ndim() != 3)
    throw InputError("volume array: expected 3 dimensions (nz, ny, nx), got " + std::to_string(a.ndim()));
  if (a.device_type() != kCpu)
    throw InputError("volume array: must be in host memory (for a GPU tensor, pass tensor.cpu())");
  if (!c_contiguous(a))
    throw InputError("volume array: not C-contiguous; pass numpy.ascontiguousarray(a) (a copy)");
  const PixelType type = pixel_type_of(a.dtype(), "volume array");
  VolumeGrid g = make_grid(spacing, origin, direction);
  g.dims = {int64_t(a.shape(2)), int64_t(a.shape(1)), int64_t(a.shape(0))};
  g.validate("volume array");
  auto* keep = new nb::ndarray<>(a);
  std::shared_ptr<void> owner(keep, [](void* p) {
    nb::gil_scoped_acquire gil;  // dropping a Python reference needs the GIL
    delete static_cast<nb::ndarray<>*>(p);
  });
  return Volume::wrap(a.data(), type, g, owner);
}

std::array<double, 9> direction_of(const Volume& v) { return v.grid().direction.row_major(); }

// ---- probes ----------------------------------------------------------------------------------
ProbeGeometry probe_grid(ProbeGeometry p, int width, int height, std::pair<double, double> spacing,
                         std::optional<std::pair<double, double>> origin, const char* what) {
  p.image.width = width;
  p.image.height = height;
  p.image.spacing_mm[0] = spacing.first;
  p.image.spacing_mm[1] = spacing.second;
  if (origin) {
    p.image.origin_mm[0] = origin->first;
    p.image.origin_mm[1] = origin->second;
  } else {
    p.image.set_default_origin();
  }
  p.validate(what);
  return p;
}

// ---- slicing ---------------------------------------------------------------------------------
std::vector<Pose> poses_from(const nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu>& a) {
  if (a.shape(1) != 4 || a.shape(2) != 4)
    throw InputError("poses: expected shape (N, 4, 4)");
  std::vector<Pose> poses(a.shape(0));
  for (size_t n = 0; n < poses.size(); ++n) poses[n] = Mat4::from_row_major(a.data() + 16 * n);
  return poses;
}

void slice_into(const Slicer& slicer,
                nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu> pose_array,
                nb::ndarray<> out, uintptr_t stream, nb::object progress, int64_t chunk) {
  const std::vector<Pose> poses = poses_from(pose_array);
  const int64_t n = int64_t(poses.size());
  if (out.ndim() != 3 || int64_t(out.shape(0)) != n || int64_t(out.shape(1)) != slicer.height() ||
      int64_t(out.shape(2)) != slicer.width())
    throw InputError("out: expected shape (" + std::to_string(n) + ", " + std::to_string(slicer.height()) +
                     ", " + std::to_string(slicer.width()) + ")");
  if (!c_contiguous(out)) throw InputError("out: must be C-contiguous");
  if (pixel_type_of(out.dtype(), "out") != slicer.settings().output_type)
    throw InputError("out: dtype must be " + pixel_type_name(slicer.settings().output_type));
  const bool on_gpu = out.device_type() == kCuda;
  if (!on_gpu && out.device_type() != kCpu) throw InputError("out: must be in host or CUDA memory");
  const Device device = slicer.device();
  if (on_gpu && (device.type != DeviceType::CUDA || device.index != out.device_id()))
    throw InputError("out: is on cuda:" + std::to_string(out.device_id()) + " but the slicer runs on " +
                     device.to_string());
  // Validate every pose before the first chunk, so nothing is written when one is bad.
  validate_poses(poses.data(), poses.size(), "poses", 0, /*warn_non_orthonormal=*/true);
  auto* base = static_cast<char*>(out.data());
  const size_t image_bytes = slicer.image_bytes();
  if (chunk <= 0) chunk = n;
  for (int64_t first = 0; first < n; first += chunk) {
    const int64_t count = std::min(chunk, n - first);
    {
      nb::gil_scoped_release release;
      if (on_gpu)
        slicer.slice_into_device(poses.data() + first, size_t(count), base + size_t(first) * image_bytes,
                                 reinterpret_cast<void*>(stream), size_t(first));
      else
        slicer.slice(poses.data() + first, size_t(count), base + size_t(first) * image_bytes, size_t(first));
    }
    if (!progress.is_none()) progress(first + count, n);
  }
}

// (N, H, W) label images from exact plane cuts, into a CPU array, chunk by chunk.
void surface_slice_into(const SurfaceSlicer& slicer,
                        nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu> pose_array,
                        nb::ndarray<> out, nb::object progress, int64_t chunk) {
  const std::vector<Pose> poses = poses_from(pose_array);
  const int64_t n = int64_t(poses.size());
  if (out.ndim() != 3 || int64_t(out.shape(0)) != n || int64_t(out.shape(1)) != slicer.height() ||
      int64_t(out.shape(2)) != slicer.width() || !c_contiguous(out) || out.device_type() != kCpu)
    throw InputError("out: expected a C-contiguous (" + std::to_string(n) + ", " +
                     std::to_string(slicer.height()) + ", " + std::to_string(slicer.width()) +
                     ") array in host memory");
  if (pixel_type_of(out.dtype(), "out") != slicer.output_type())
    throw InputError("out: dtype must be " + pixel_type_name(slicer.output_type()));
  validate_poses(poses.data(), poses.size(), "poses", 0, true);
  const size_t image_bytes = size_t(slicer.width()) * size_t(slicer.height()) * pixel_size(slicer.output_type());
  if (chunk <= 0) chunk = n;
  for (int64_t first = 0; first < n; first += chunk) {
    const int64_t count = std::min(chunk, n - first);
    {
      nb::gil_scoped_release release;
      slicer.slice(poses.data() + first, size_t(count), static_cast<char*>(out.data()) + size_t(first) * image_bytes,
                   size_t(first));
    }
    if (!progress.is_none()) progress(first + count, n);
  }
}

TriangleMesh mesh_from_arrays(nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> vertices,
                              nb::ndarray<const int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> triangles,
                              const std::string& name) {
  if (vertices.shape(1) != 3 || triangles.shape(1) != 3)
    throw InputError("mesh '" + name + "': vertices must be (V, 3) and triangles (T, 3)");
  TriangleMesh m;
  m.name = name;
  m.vertices.resize(vertices.shape(0));
  for (size_t i = 0; i < m.vertices.size(); ++i)
    m.vertices[i] = {vertices(i, 0), vertices(i, 1), vertices(i, 2)};
  m.triangles.resize(triangles.shape(0));
  for (size_t i = 0; i < m.triangles.size(); ++i)
    m.triangles[i] = {triangles(i, 0), triangles(i, 1), triangles(i, 2)};
  m.validate();
  return m;
}

}  // namespace
}  // namespace sonoslice

NB_MODULE(_sonoslice, m) {
  using namespace sonoslice;
  m.doc() = "sonoslice C++ core (use the sonoslice package, not this module)";

  // C++ errors → the Python exceptions users expect. Messages are the C++ ones.
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const InputError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const FileError& e) {
      PyErr_SetString(PyExc_OSError, e.what());
    } catch (const Error& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    }
  });

  // Warnings go through Python's warnings module, once the interpreter can take them.
  set_warning_handler([](const std::string& message) {
    nb::gil_scoped_acquire gil;
    // With warnings turned into errors there is no caller to raise into here: report it.
    if (PyErr_WarnEx(PyExc_UserWarning, message.c_str(), 1) < 0) PyErr_WriteUnraisable(nullptr);
  });

  // ---- devices and threads
  m.def("describe_devices", &describe_devices);
  m.def("built_with_cuda", &built_with_cuda);
  m.def("built_with_itk", &built_with_itk);
  m.def("require_device", [](const std::string& d) { require_device(Device::parse(d)); });
  m.def("cpu_threads", &cpu_threads);
  m.def("set_cpu_threads", &set_cpu_threads, "n"_a);
  m.def("cpu_kernel_isa", &cpu_kernel_isa);
  m.def("set_cpu_kernel_isa", &set_cpu_kernel_isa, "isa"_a);

  // ---- volumes
  nb::class_<Volume>(m, "Volume")
      .def_static("from_array", &volume_from_array, "array"_a, "spacing"_a, "origin"_a, "direction"_a)
      .def_static(
          "from_file",
          [](const std::string& path, std::optional<std::array<double, 3>> spacing,
             std::optional<std::array<double, 3>> origin, std::optional<std::array<double, 9>> direction,
             const std::string& series, const std::string& npy_config) {
            VolumeReadOptions o;
            o.series_uid = series;
            o.fanslicer_npy_config = npy_config;
            if (spacing) o.spacing_mm = Vec3{(*spacing)[0], (*spacing)[1], (*spacing)[2]};
            if (origin) o.origin_mm = Vec3{(*origin)[0], (*origin)[1], (*origin)[2]};
            if (direction) o.direction = make_grid({1, 1, 1}, {0, 0, 0}, *direction).direction;
            nb::gil_scoped_release release;
            return read_volume(path, o);
          },
          "path"_a, "spacing"_a = nb::none(), "origin"_a = nb::none(), "direction"_a = nb::none(),
          "series"_a = "", "npy_config"_a = "")
      .def("array",
           [](const Volume& v) {
             const auto& d = v.grid().dims;
             return numpy_view(const_cast<void*>(v.data()),
                               {size_t(d[2]), size_t(d[1]), size_t(d[0])}, v.pixel_type(), v);
           })
      .def_prop_ro("dtype", [](const Volume& v) { return pixel_type_name(v.pixel_type()); })
      .def_prop_ro("shape", [](const Volume& v) {
        const auto& d = v.grid().dims;
        return std::make_tuple(d[2], d[1], d[0]);
      })
      .def_prop_ro("spacing", [](const Volume& v) { return v.grid().spacing_mm; })
      .def_prop_ro("origin", [](const Volume& v) { return v.grid().origin_mm; })
      .def_prop_ro("direction", &direction_of)
      .def_prop_ro("nbytes", &Volume::byte_size)
      .def("value_range",
           [](const Volume& v) {
             nb::gil_scoped_release release;
             return v.value_range();
           })
      .def("converted",
           [](const Volume& v, const std::string& dtype) {
             const PixelType t = parse_pixel_type(dtype);
             nb::gil_scoped_release release;
             return v.converted(t);
           })
      .def("save",
           [](const Volume& v, const std::string& path) {
             nb::gil_scoped_release release;
             write_volume(path, v);
           })
      .def("world_to_index",
           [](const Volume& v, std::array<double, 3> p) {
             return v.grid().world_to_index({p[0], p[1], p[2]});
           })
      .def("index_to_world", [](const Volume& v, std::array<double, 3> c) {
        return v.grid().index_to_world({c[0], c[1], c[2]});
      });

  // ---- probes
  nb::class_<ProbeGeometry>(m, "Probe")
      .def_static(
          "curvilinear",
          [](double radius_mm, double depth_mm, double sector_deg, int width, int height,
             std::pair<double, double> spacing_mm, double face_y_mm,
             std::optional<std::pair<double, double>> origin_mm) {
            ProbeGeometry p;
            p.type = ProbeType::Curvilinear;
            p.radius_mm = radius_mm;
            p.depth_mm = depth_mm;
            p.sector_deg = sector_deg;
            p.face_y_mm = face_y_mm;
            return probe_grid(p, width, height, spacing_mm, origin_mm, "curvilinear probe");
          },
          "radius_mm"_a, "depth_mm"_a, "sector_deg"_a, "width"_a, "height"_a, "spacing_mm"_a,
          "face_y_mm"_a = 0.0, "origin_mm"_a = nb::none())
      .def_static(
          "linear",
          [](int width, int height, std::pair<double, double> spacing_mm, std::optional<double> width_mm,
             std::optional<double> depth_mm, double face_y_mm,
             std::optional<std::pair<double, double>> origin_mm) {
            ProbeGeometry p;
            p.type = ProbeType::Linear;
            p.has_width = width_mm.has_value();
            p.width_mm = width_mm.value_or(0.0);
            p.has_depth = depth_mm.has_value();
            p.depth_mm = depth_mm.value_or(0.0);
            p.face_y_mm = face_y_mm;
            return probe_grid(p, width, height, spacing_mm, origin_mm, "linear probe");
          },
          "width"_a, "height"_a, "spacing_mm"_a, "width_mm"_a = nb::none(), "depth_mm"_a = nb::none(),
          "face_y_mm"_a = 0.0, "origin_mm"_a = nb::none())
      .def_static("from_file", &read_probe, "path"_a, "downsampling"_a = 1)
      .def_static("from_json_text", &parse_probe_json, "text"_a, "source"_a = "<string>",
                  "downsampling"_a = 1)
      .def_static("workload", [](const std::string& name) {
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
      .def_prop_ro("type", [](const ProbeGeometry& p) {
        return std::string(p.type == ProbeType::Curvilinear ? "curvilinear" : "linear");
      })
      .def_prop_ro("width", [](const ProbeGeometry& p) { return p.image.width; })
      .def_prop_ro("height", [](const ProbeGeometry& p) { return p.image.height; })
      .def_prop_ro("spacing_mm",
                   [](const ProbeGeometry& p) { return std::make_pair(p.image.spacing_mm[0], p.image.spacing_mm[1]); })
      .def_prop_ro("origin_mm",
                   [](const ProbeGeometry& p) { return std::make_pair(p.image.origin_mm[0], p.image.origin_mm[1]); })
      .def_prop_ro("radius_mm", [](const ProbeGeometry& p) { return p.radius_mm; })
      .def_prop_ro("depth_mm", [](const ProbeGeometry& p) { return p.depth_mm; })
      .def_prop_ro("sector_deg", [](const ProbeGeometry& p) { return p.sector_deg; })
      .def_prop_ro("face_y_mm", [](const ProbeGeometry& p) { return p.face_y_mm; });

  // ---- slicing
  nb::class_<Slicer>(m, "Slicer")
      .def(
          "__init__",
          [](Slicer* self, const Volume& volume, const ProbeGeometry& probe, const std::string& device,
             const std::string& interp, double fill, const std::string& dtype) {
            SliceSettings s;
            s.interpolation = parse_interpolation(interp);
            s.fill_value = fill;
            if (dtype != "float32" && dtype != "int16" && dtype != "uint8" && dtype != "uint16")
              throw InputError("dtype '" + dtype + "': expected float32, int16, uint8 or uint16");
            s.output_type = parse_pixel_type(dtype);
            const Device d = Device::parse(device);
            nb::gil_scoped_release release;  // a CUDA slicer uploads the volume here
            new (self) Slicer(volume, probe, s, d);
          },
          "volume"_a, "probe"_a, "device"_a = "cpu", "interp"_a = "linear", "fill"_a = 0.0,
          "dtype"_a = "float32")
      .def("slice_into", &slice_into, "poses"_a, "out"_a, "stream"_a = 0, "progress"_a = nb::none(),
           "chunk"_a = 0)
      .def_prop_ro("width", &Slicer::width)
      .def_prop_ro("height", &Slicer::height)
      .def_prop_ro("device", [](const Slicer& s) { return s.device().to_string(); })
      .def_prop_ro("dtype", [](const Slicer& s) { return pixel_type_name(s.settings().output_type); })
      .def_prop_ro("interp", [](const Slicer& s) { return interpolation_name(s.settings().interpolation); })
      .def_prop_ro("fill", [](const Slicer& s) { return s.settings().fill_value; })
      .def_prop_ro("probe", &Slicer::probe)
      .def_prop_ro("volume", &Slicer::volume)
      .def("mask", [](const Slicer& s) {
        auto m = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(m->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8, m);
      });

  // ---- poses, files, phantom
  m.def(
      "read_poses",
      [](const std::string& path, const std::string& world) {
        auto poses = std::make_shared<std::vector<Pose>>(read_poses(path, parse_world_frame(world)));
        static_assert(sizeof(Pose) == 16 * sizeof(double), "Pose is 16 doubles");
        return numpy_view(poses->data(), {poses->size(), 4, 4}, PixelType::Float64, poses);
      },
      "path"_a, "world"_a = "LPS");
  m.def(
      "validate_poses",
      [](nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu> a, const std::string& source) {
        const auto poses = poses_from(a);
        validate_poses(poses.data(), poses.size(), source);
      },
      "poses"_a, "source"_a = "poses");
  m.def(
      "write_poses",
      [](const std::string& path, nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu> a) {
        const auto poses = poses_from(a);
        if (file_extension(path) == ".npy")
          write_poses_npy(path, poses);
        else
          write_poses_text(path, poses);
      },
      "path"_a, "poses"_a);
  m.def(
      "write_stack",
      [](const std::string& path, nb::ndarray<> images, std::pair<double, double> spacing,
         std::optional<std::pair<double, double>> window,
         std::optional<nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu>> poses,
         std::optional<nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>> mask) {
        if (images.ndim() != 3 || images.device_type() != kCpu || !c_contiguous(images))
          throw InputError("images: expected a C-contiguous (N, H, W) array in host memory");
        StackSpec spec;
        spec.type = pixel_type_of(images.dtype(), "images");
        spec.count = int64_t(images.shape(0));
        spec.height = int(images.shape(1));
        spec.width = int(images.shape(2));
        spec.spacing_mm[0] = spacing.first;
        spec.spacing_mm[1] = spacing.second;
        spec.window = window;
        if (poses) spec.poses = poses_from(*poses);
        else spec.poses.assign(size_t(spec.count), Pose::identity());
        if (mask) spec.mask = mask->data();
        const size_t image_bytes = size_t(spec.width) * size_t(spec.height) * pixel_size(spec.type);
        nb::gil_scoped_release release;
        auto writer = StackWriter::create(path, spec);
        const int64_t chunk = std::max<int64_t>(1, int64_t((size_t(64) << 20) / std::max<size_t>(image_bytes, 1)));
        for (int64_t first = 0; first < spec.count; first += chunk) {
          const int64_t n = std::min(chunk, spec.count - first);
          std::memcpy(writer->buffer(first, n), static_cast<const char*>(images.data()) + size_t(first) * image_bytes,
                      size_t(n) * image_bytes);
          writer->write(first, n);
        }
        writer->commit();
      },
      "path"_a, "images"_a, "spacing_mm"_a, "window"_a = nb::none(), "poses"_a = nb::none(),
      "mask"_a = nb::none());
  m.def(
      "make_phantom",
      [](const std::string& size) {
        const PhantomSize s = parse_phantom_size(size);
        nb::gil_scoped_release release;
        Phantom p = make_phantom(s);
        return std::make_pair(p.ct, p.labels);
      },
      "size"_a = "small");
  m.def(
      "phantom_random_poses",
      [](size_t count, uint64_t seed) {
        auto poses = std::make_shared<std::vector<Pose>>(phantom_random_poses(count, seed));
        return numpy_view(poses->data(), {poses->size(), 4, 4}, PixelType::Float64, poses);
      },
      "count"_a, "seed"_a = 2024);
  m.def(
      "phantom_surface_poses",
      [](size_t count, double face_y_mm) {
        auto poses = std::make_shared<std::vector<Pose>>(phantom_surface_poses(count, face_y_mm));
        return numpy_view(poses->data(), {poses->size(), 4, 4}, PixelType::Float64, poses);
      },
      "count"_a, "face_y_mm"_a = 0.0);
  // ---- surfaces
  m.def("built_with_vtk", &built_with_vtk);
  nb::class_<TriangleMesh>(m, "Mesh")
      .def_static("from_arrays", &mesh_from_arrays, "vertices"_a, "triangles"_a, "name"_a = "mesh")
      .def_static(
          "from_file",
          [](const std::string& path, const std::string& world) {
            const WorldFrame f = parse_world_frame(world);
            nb::gil_scoped_release release;
            return read_mesh(path, f);
          },
          "path"_a, "world"_a = "LPS")
      .def("save", [](const TriangleMesh& mesh, const std::string& path) { write_mesh(path, mesh); })
      .def_prop_ro("name", [](const TriangleMesh& mesh) { return mesh.name; })
      .def("vertices",
           [](const TriangleMesh& mesh) {
             auto keep = std::make_shared<std::vector<Vec3>>(mesh.vertices);
             return numpy_view(keep->data(), {keep->size(), 3}, PixelType::Float64, keep);
           })
      .def("triangles",
           [](const TriangleMesh& mesh) {
             auto keep = std::make_shared<std::vector<std::array<int32_t, 3>>>(mesh.triangles);
             return numpy_view(keep->data(), {keep->size(), 3}, PixelType::Int32, keep);
           })
      .def("bounds", &TriangleMesh::bounds)
      .def("closed", [](const TriangleMesh& mesh) { return mesh_topology(mesh).closed(); })
      .def("topology", [](const TriangleMesh& mesh) { return mesh_topology(mesh).describe(); });
  m.def(
      "voxel_grid_around",
      [](const std::vector<TriangleMesh>& meshes, double spacing, double margin) {
        const VolumeGrid g = voxel_grid_around(meshes, spacing, margin);
        return std::make_tuple(g.dims, g.spacing_mm, g.origin_mm);
      },
      "meshes"_a, "spacing"_a, "margin"_a);
  m.def(
      "voxelize",
      [](const std::vector<TriangleMesh>& meshes, double spacing, double margin, const Volume* reference,
         const std::vector<uint16_t>& labels) {
        nb::gil_scoped_release release;
        const VolumeGrid g = reference ? reference->grid() : voxel_grid_around(meshes, spacing, margin);
        return voxelize(meshes, g, labels);
      },
      "meshes"_a, "spacing"_a = 0.0, "margin"_a = 0.0, "reference"_a = nb::none(),
      "labels"_a = std::vector<uint16_t>{});
  nb::class_<SurfaceSlicer>(m, "SurfaceSlicer")
      .def(
          "__init__",
          [](SurfaceSlicer* self, const std::vector<TriangleMesh>& meshes, const ProbeGeometry& probe,
             const std::vector<uint16_t>& labels, const std::string& dtype) {
            if (dtype != "uint8" && dtype != "uint16")
              throw InputError("dtype '" + dtype + "': label images are uint8 or uint16");
            const PixelType t = parse_pixel_type(dtype);
            nb::gil_scoped_release release;
            new (self) SurfaceSlicer(meshes, probe, labels, t);
          },
          "meshes"_a, "probe"_a, "labels"_a = std::vector<uint16_t>{}, "dtype"_a = "uint8")
      .def("slice_into", &surface_slice_into, "poses"_a, "out"_a, "progress"_a = nb::none(), "chunk"_a = 0)
      .def_prop_ro("width", &SurfaceSlicer::width)
      .def_prop_ro("height", &SurfaceSlicer::height)
      .def_prop_ro("dtype", [](const SurfaceSlicer& s) { return pixel_type_name(s.output_type()); })
      .def("mask", [](const SurfaceSlicer& s) {
        auto mk = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(mk->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8, mk);
      });
  m.def(
      "cut_polygons",
      [](const TriangleMesh& mesh, nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu> pose) {
        const auto poses = poses_from(pose);
        if (poses.size() != 1) throw InputError("cut_polygons: one pose");
        std::vector<std::pair<std::vector<std::array<double, 2>>, bool>> out;
        for (const CutPolygon& p : cut_polygons(mesh, poses[0])) out.emplace_back(p.points, p.closed);
        return out;
      },
      "mesh"_a, "pose"_a);
  m.def(
      "colorize",
      [](nb::ndarray<> labels, nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> mask,
         const std::vector<std::array<uint8_t, 3>>& colors) {
        if (labels.ndim() != 3 || !c_contiguous(labels) || labels.device_type() != kCpu)
          throw InputError("labels: expected a C-contiguous (N, H, W) array in host memory");
        const PixelType t = pixel_type_of(labels.dtype(), "labels");
        if (mask.shape(0) != labels.shape(1) || mask.shape(1) != labels.shape(2))
          throw InputError("mask: must be (H, W) like the labels");
        auto rgb = std::make_shared<std::vector<uint8_t>>(labels.size() * 3);
        {
          nb::gil_scoped_release release;
          colorize(labels.data(), t, int64_t(labels.shape(0)), int(labels.shape(2)), int(labels.shape(1)),
                   mask.data(), colors, rgb->data());
        }
        return numpy_view(rgb->data(), {labels.shape(0), labels.shape(1), labels.shape(2), 3},
                          PixelType::UInt8, rgb);
      },
      "labels"_a, "mask"_a, "colors"_a);
  m.def("default_label_color", &default_label_color, "label"_a);
  m.def(
      "fanslicer_models",
      [](const std::string& config, const std::string& mesh_dir) {
        std::vector<std::tuple<std::string, std::string, uint16_t, std::array<uint8_t, 3>>> out;
        for (const SurfaceModel& s : read_fanslicer_models(config, mesh_dir))
          out.emplace_back(s.name, s.path, s.label, s.color);
        return out;
      },
      "config"_a, "mesh_dir"_a);

  m.def("phantom_label_names", [] {
    std::vector<std::string> names;
    for (int l = 0; l < kPhantomLabelCount; ++l) names.push_back(phantom_label_name(l));
    return names;
  });
}
