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
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/SurfaceConfig.h"
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
  throw InputError(std::string(what) +
                   ": unsupported dtype (supported: uint8, int8, uint16, int16, "
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
nb::ndarray<nb::numpy> numpy_view(void* data, std::vector<size_t> shape, PixelType type,
                                  Keep keep) {
  auto* holder = new Keep(std::move(keep));
  nb::capsule owner(holder, [](void* p) noexcept { delete static_cast<Keep*>(p); });
  return nb::ndarray<nb::numpy>(data, shape.size(), shape.data(), owner, nullptr,
                                dlpack_dtype(type));
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
                         const std::array<double, 3>& origin,
                         const std::array<double, 9>& direction) {
  if (a.ndim() != 3)
    throw InputError("volume array: expected 3 dimensions (nz, ny, nx), got " +
                     std::to_string(a.ndim()));
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

std::array<double, 9> direction_of(const Volume& v) {
  return v.grid().direction.row_major();
}

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

// ---- matrices --------------------------------------------------------------------------------
using Matrices = nb::ndarray<const double, nb::ndim<3>, nb::c_contig, nb::device::cpu>;
using Matrix4 = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

std::vector<Mat4> matrices_from(const Matrices& a, const std::string& what) {
  if (a.shape(1) != 4 || a.shape(2) != 4)
    throw InputError(what + ": expected shape (N, 4, 4), got (" + std::to_string(a.shape(0)) +
                     ", " + std::to_string(a.shape(1)) + ", " + std::to_string(a.shape(2)) + ")");
  std::vector<Mat4> out(a.shape(0));
  for (size_t n = 0; n < out.size(); ++n) out[n] = Mat4::from_row_major(a.data() + 16 * n);
  return out;
}

std::vector<Pose> poses_from(const Matrices& a) {
  return matrices_from(a, "poses");
}

Mat4 matrix_from(const Matrix4& a, const std::string& what) {
  if (a.shape(0) != 4 || a.shape(1) != 4)
    throw InputError(what + ": expected a 4x4 matrix, got (" + std::to_string(a.shape(0)) + ", " +
                     std::to_string(a.shape(1)) + ")");
  return Mat4::from_row_major(a.data());
}

using MatrixOut = nb::ndarray<nb::numpy, double, nb::shape<4, 4>>;
using MatricesOut = nb::ndarray<nb::numpy, double, nb::shape<-1, 4, 4>>;

// NumPy (N, 4, 4) float64 owning the matrices.
MatricesOut matrices_to_numpy(std::vector<Mat4> matrices) {
  static_assert(sizeof(Mat4) == 16 * sizeof(double), "Mat4 is 16 doubles");
  auto* keep = new std::vector<Mat4>(std::move(matrices));
  nb::capsule owner(keep, [](void* p) noexcept { delete static_cast<std::vector<Mat4>*>(p); });
  const size_t shape[3] = {keep->size(), 4, 4};
  return MatricesOut(keep->data(), 3, shape, owner);
}

std::optional<MatrixOut> matrix_or_none(const std::optional<Mat4>& m) {
  if (!m) return std::nullopt;
  auto* keep = new Mat4(*m);
  nb::capsule owner(keep, [](void* p) noexcept { delete static_cast<Mat4*>(p); });
  const size_t shape[2] = {4, 4};
  return MatrixOut(keep->m, 2, shape, owner);
}

// ---- slicing ---------------------------------------------------------------------------------
// Whether `out` is (n, height, width), and that shape as text.
bool has_shape(const nb::ndarray<>& out, int64_t n, int64_t height, int64_t width) {
  return out.ndim() == 3 && int64_t(out.shape(0)) == n && int64_t(out.shape(1)) == height &&
         int64_t(out.shape(2)) == width;
}

std::string shape_text(int64_t n, int64_t height, int64_t width) {
  return "(" + std::to_string(n) + ", " + std::to_string(height) + ", " + std::to_string(width) +
         ")";
}

void check_out_dtype(const nb::ndarray<>& out, PixelType type) {
  if (pixel_type_of(out.dtype(), "out") != type)
    throw InputError("out: dtype must be " + to_string(type));
}

// Validates every pose before the first chunk (so nothing is written when one is bad), then
// calls slice_chunk(first, count) without the GIL for `chunk` poses at a time (all of them when
// chunk <= 0), reporting progress(done, total) after each chunk.
template <typename SliceChunk>
void slice_in_chunks(const std::vector<Pose>& poses, const nb::object& progress, int64_t chunk,
                     SliceChunk slice_chunk) {
  validate_poses(poses.data(), poses.size(), "poses", 0, /*warn_non_orthonormal=*/true);
  const int64_t n = int64_t(poses.size());
  if (chunk <= 0) chunk = n;
  for (int64_t first = 0; first < n; first += chunk) {
    const int64_t count = std::min(chunk, n - first);
    {
      nb::gil_scoped_release release;
      slice_chunk(first, count);
    }
    if (!progress.is_none()) progress(first + count, n);
  }
}

void slice_into(const Slicer& slicer, Matrices pose_array, nb::ndarray<> out, uintptr_t stream,
                nb::object progress, int64_t chunk) {
  const std::vector<Pose> poses = poses_from(pose_array);
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

// (N, H, W) label images from exact plane cuts, into a CPU array, chunk by chunk.
void surface_slice_into(const SurfaceSlicer& slicer, Matrices pose_array, nb::ndarray<> out,
                        nb::object progress, int64_t chunk) {
  const std::vector<Pose> poses = poses_from(pose_array);
  const int64_t n = int64_t(poses.size());
  if (!has_shape(out, n, slicer.height(), slicer.width()) || !c_contiguous(out) ||
      out.device_type() != kCpu)
    throw InputError("out: expected a C-contiguous " +
                     shape_text(n, slicer.height(), slicer.width()) + " array in host memory");
  check_out_dtype(out, slicer.output_type());
  auto* base = static_cast<char*>(out.data());
  const size_t image_bytes =
      size_t(slicer.width()) * size_t(slicer.height()) * pixel_size(slicer.output_type());
  slice_in_chunks(poses, progress, chunk, [&](int64_t first, int64_t count) {
    slicer.slice(poses.data() + first, size_t(count), base + size_t(first) * image_bytes,
                 size_t(first));
  });
}

TriangleMesh mesh_from_arrays(
    nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> vertices,
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

// ---- compounding -----------------------------------------------------------------------------
// (dims along x, y, z; spacing x, y, z (mm); origin (mm); direction, row-major)
using GridTuple = std::tuple<std::array<int64_t, 3>, std::array<double, 3>, std::array<double, 3>,
                             std::array<double, 9>>;
// (type, size, stdev, minimum known ratio, stick length limit, sticks to use); None: the default
using HoleTuple = std::tuple<std::string, std::optional<int>, std::optional<double>,
                             std::optional<double>, std::optional<int>, std::optional<int>>;
// (r0_mm, dr_mm, azimuth0_deg, dazimuth_deg, elevation0_deg, delevation_deg, apex_offset_mm)
using BeamTuple = std::array<double, 7>;

GridTuple grid_tuple(const VolumeGrid& g) {
  return GridTuple{g.dims, g.spacing_mm, g.origin_mm, g.direction.row_major()};
}


std::vector<HoleTuple> hole_tuples(const std::vector<HoleFillingKernel>& kernels) {
  std::vector<HoleTuple> out;
  for (const HoleFillingKernel& k : kernels)
    out.emplace_back(to_string(k.type), k.size, k.stdev, k.minimum_known_ratio,
                     k.stick_length_limit, k.sticks_to_use);
  return out;
}

// The compounding settings settings_of(self) gives, as read-only properties of `cls`:
// interpolation, compounding, fill_holes, hole_filling and rejection_threshold (None for -inf).
template <typename T, typename SettingsOf>
void def_settings_properties(nb::class_<T>& cls, SettingsOf settings_of) {
  cls.def_prop_ro(
         "interpolation",
         [settings_of](const T& self) { return to_string(settings_of(self).interpolation); })
      .def_prop_ro("compounding",
                   [settings_of](const T& self) { return to_string(settings_of(self).mode); })
      .def_prop_ro("fill_holes",
                   [settings_of](const T& self) { return settings_of(self).fill_holes; })
      .def_prop_ro(
          "hole_filling",
          [settings_of](const T& self) { return hole_tuples(settings_of(self).hole_filling); })
      .def_prop_ro("rejection_threshold", [settings_of](const T& self) -> std::optional<double> {
        const double t = settings_of(self).rejection_threshold;
        if (std::isinf(t) && t < 0) return std::nullopt;
        return t;
      });
}

CompoundSettings make_settings(const std::string& interpolation, const std::string& compounding,
                               bool fill_holes, const std::vector<HoleTuple>& hole_filling,
                               std::optional<double> rejection_threshold) {
  CompoundSettings s;
  s.interpolation = parse_interpolation(interpolation);
  s.mode = parse_compounding_mode(compounding);
  s.fill_holes = fill_holes;
  if (rejection_threshold) {
    if (std::isnan(*rejection_threshold))
      throw InputError("rejection_threshold: NaN (give None for no threshold)");
    s.rejection_threshold = *rejection_threshold;
  }
  if (!hole_filling.empty()) {
    s.hole_filling.clear();
    for (const HoleTuple& t : hole_filling) {
      HoleFillingKernel k;
      k.type = parse_hole_filling_type(std::get<0>(t));
      if (std::get<1>(t)) k.size = *std::get<1>(t);
      if (std::get<2>(t)) k.stdev = *std::get<2>(t);
      if (std::get<3>(t)) k.minimum_known_ratio = *std::get<3>(t);
      if (std::get<4>(t)) k.stick_length_limit = *std::get<4>(t);
      if (std::get<5>(t)) k.sticks_to_use = *std::get<5>(t);
      s.hole_filling.push_back(k);
    }
  }
  return s;
}

BeamGeometry beam_geometry(const BeamTuple& t, int64_t n_elevation, int64_t n_azimuth,
                           int64_t n_samples) {
  const int64_t limit = std::numeric_limits<int>::max();
  if (n_elevation > limit || n_azimuth > limit || n_samples > limit)
    throw InputError("beam-space frames: " + std::to_string(n_elevation) + "x" +
                     std::to_string(n_azimuth) + "x" + std::to_string(n_samples) +
                     " samples is absurd");
  BeamGeometry g;
  g.n_elevation = int(n_elevation);
  g.n_azimuth = int(n_azimuth);
  g.n_samples = int(n_samples);
  g.r0_mm = t[0];
  g.dr_mm = t[1];
  g.azimuth0_deg = t[2];
  g.dazimuth_deg = t[3];
  g.elevation0_deg = t[4];
  g.delevation_deg = t[5];
  g.apex_offset_mm = t[6];
  return g;
}

BeamTuple beam_tuple(const BeamGeometry& g) {
  return {g.r0_mm,          g.dr_mm,          g.azimuth0_deg,  g.dazimuth_deg,
          g.elevation0_deg, g.delevation_deg, g.apex_offset_mm};
}

std::optional<std::array<double, 6>> fan_tuple(const FrameClip& c) {
  if (!c.fan) return std::nullopt;
  return std::array<double, 6>{c.fan_angles_deg[0], c.fan_angles_deg[1], c.fan_origin_px[0],
                               c.fan_origin_px[1],  c.fan_radius_px[0],  c.fan_radius_px[1]};
}

// Frames (2D: (H, W) or (N, H, W); beams: (E, A, S) or (N, E, A, S)) in host memory, C-order.
int64_t check_frames(const nb::ndarray<nb::ro>& a, size_t frame_ndim, const std::string& what,
                     const char* layout, PixelType* type) {
  if (a.device_type() != kCpu)
    throw InputError(what + ": must be in host memory (for a GPU tensor, pass tensor.cpu())");
  if (a.ndim() != frame_ndim && a.ndim() != frame_ndim + 1)
    throw InputError(what + ": has " + std::to_string(a.ndim()) + " dimensions; expected " +
                     layout);
  if (!c_contiguous(a))
    throw InputError(what + ": not C-contiguous; pass numpy.ascontiguousarray(frames) (a copy)");
  *type = pixel_type_of(a.dtype(), what.c_str());
  return a.ndim() == frame_ndim ? 1 : int64_t(a.shape(0));
}

// A Compounder with a lock: Python threads may share one, and its methods run without the GIL.
// The GIL is always released before the lock is taken (a warning raised while the lock is held
// takes the GIL).
struct PyCompounder {
  Compounder compounder;
  PixelType dtype;
  std::mutex mutex;
  PyCompounder(const VolumeGrid& grid, CompoundSettings settings, Device device,
               uint64_t max_memory, PixelType type)
      : compounder(grid, std::move(settings), device, max_memory, type), dtype(type) {}
};

// The valid frames of a PLUS sequence and their `from`→`to` transforms (docs/conventions.md §7), as the CLI
// picks them: every `skip`-th frame whose image status is OK and whose chain is valid.
std::tuple<std::vector<int64_t>, MatricesOut, int, int> plus_frames(const PlusSequence& s,
                                                                    const TransformRepository& base,
                                                                    const std::string& from,
                                                                    const std::string& to, int skip,
                                                                    const std::string& hint) {
  PlusFrameSelection sel;
  {
    nb::gil_scoped_release release;
    sel = select_plus_frames(s, base, from, to, skip, hint);
  }
  std::vector<int64_t> frames(sel.frames.begin(), sel.frames.end());
  return {frames, matrices_to_numpy(std::move(sel.to_reference)), sel.bad_image, sel.bad_transform};
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
      .def_static("from_array", &volume_from_array, "array"_a, "spacing"_a, "origin"_a,
                  "direction"_a)
      .def_static(
          "from_file",
          [](const std::string& path, std::optional<std::array<double, 3>> spacing,
             std::optional<std::array<double, 3>> origin,
             std::optional<std::array<double, 9>> direction, const std::string& series,
             const std::string& npy_config) {
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
      .def_prop_ro("dtype", [](const Volume& v) { return to_string(v.pixel_type()); })
      .def_prop_ro("shape",
                   [](const Volume& v) {
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
          [](int width, int height, std::pair<double, double> spacing_mm,
             std::optional<double> width_mm, std::optional<double> depth_mm, double face_y_mm,
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
          "width"_a, "height"_a, "spacing_mm"_a, "width_mm"_a = nb::none(),
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
      .def_prop_ro(
          "type",
          [](const ProbeGeometry& p) {
            return std::string(p.type == ProbeType::Curvilinear ? "curvilinear" : "linear");
          })
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

  // ---- slicing
  nb::class_<Slicer>(m, "Slicer")
      .def(
          "__init__",
          [](Slicer* self, const Volume& volume, const ProbeGeometry& probe,
             const std::string& device, const std::string& interp, double fill,
             const std::string& dtype) {
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
      .def_prop_ro("dtype",
                   [](const Slicer& s) { return to_string(s.settings().output_type); })
      .def_prop_ro("interp",
                   [](const Slicer& s) { return to_string(s.settings().interpolation); })
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
        return matrices_to_numpy(read_poses(path, parse_world_frame(world)));
      },
      "path"_a, "world"_a = "LPS");
  m.def(
      "validate_poses",
      [](Matrices a, const std::string& source) {
        const auto poses = poses_from(a);
        validate_poses(poses.data(), poses.size(), source);
      },
      "poses"_a, "source"_a = "poses");
  m.def(
      "write_poses",
      [](const std::string& path, Matrices a) {
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
         std::optional<std::pair<double, double>> window, std::optional<Matrices> poses,
         std::optional<nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>>
             mask) {
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
        if (poses)
          spec.poses = poses_from(*poses);
        else
          spec.poses.assign(size_t(spec.count), Pose::identity());
        if (mask) spec.mask = mask->data();
        const size_t image_bytes = size_t(spec.width) * size_t(spec.height) * pixel_size(spec.type);
        nb::gil_scoped_release release;
        auto writer = StackWriter::create(path, spec);
        const int64_t chunk = chunk_images(image_bytes, spec.count);
        for (int64_t first = 0; first < spec.count; first += chunk) {
          const int64_t n = std::min(chunk, spec.count - first);
          std::memcpy(writer->buffer(first, n),
                      static_cast<const char*>(images.data()) + size_t(first) * image_bytes,
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
        return matrices_to_numpy(phantom_random_poses(count, seed));
      },
      "count"_a, "seed"_a = 2024);
  m.def(
      "phantom_surface_poses",
      [](size_t count, double face_y_mm) {
        return matrices_to_numpy(phantom_surface_poses(count, face_y_mm));
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
      .def("save",
           [](const TriangleMesh& mesh, const std::string& path) { write_mesh(path, mesh); })
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
      [](const std::vector<TriangleMesh>& meshes, double spacing, double margin,
         const Volume* reference, const std::vector<uint16_t>& labels) {
        nb::gil_scoped_release release;
        const VolumeGrid g =
            reference ? reference->grid() : voxel_grid_around(meshes, spacing, margin);
        return voxelize(meshes, g, labels);
      },
      "meshes"_a, "spacing"_a = 0.0, "margin"_a = 0.0, "reference"_a = nb::none(),
      "labels"_a = std::vector<uint16_t>{});
  nb::class_<SurfaceSlicer>(m, "SurfaceSlicer")
      .def(
          "__init__",
          [](SurfaceSlicer* self, const std::vector<TriangleMesh>& meshes,
             const ProbeGeometry& probe, const std::vector<uint16_t>& labels,
             const std::string& dtype) {
            if (dtype != "uint8" && dtype != "uint16")
              throw InputError("dtype '" + dtype + "': label images are uint8 or uint16");
            const PixelType t = parse_pixel_type(dtype);
            nb::gil_scoped_release release;
            new (self) SurfaceSlicer(meshes, probe, labels, t);
          },
          "meshes"_a, "probe"_a, "labels"_a = std::vector<uint16_t>{}, "dtype"_a = "uint8")
      .def("slice_into", &surface_slice_into, "poses"_a, "out"_a, "progress"_a = nb::none(),
           "chunk"_a = 0)
      .def_prop_ro("width", &SurfaceSlicer::width)
      .def_prop_ro("height", &SurfaceSlicer::height)
      .def_prop_ro("dtype", [](const SurfaceSlicer& s) { return to_string(s.output_type()); })
      .def("mask", [](const SurfaceSlicer& s) {
        auto mk = std::make_shared<std::vector<uint8_t>>(s.mask());
        return numpy_view(mk->data(), {size_t(s.height()), size_t(s.width())}, PixelType::UInt8,
                          mk);
      });
  m.def(
      "cut_polygons",
      [](const TriangleMesh& mesh, Matrices pose) {
        const auto poses = poses_from(pose);
        if (poses.size() != 1) throw InputError("cut_polygons: one pose");
        std::vector<std::pair<std::vector<std::array<double, 2>>, bool>> out;
        for (const CutPolygon& p : cut_polygons(mesh, poses[0]))
          out.emplace_back(p.points, p.closed);
        return out;
      },
      "mesh"_a, "pose"_a);
  m.def(
      "colorize",
      [](nb::ndarray<> labels,
         nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu> mask,
         const std::vector<std::array<uint8_t, 3>>& colors) {
        if (labels.ndim() != 3 || !c_contiguous(labels) || labels.device_type() != kCpu)
          throw InputError("labels: expected a C-contiguous (N, H, W) array in host memory");
        const PixelType t = pixel_type_of(labels.dtype(), "labels");
        if (mask.shape(0) != labels.shape(1) || mask.shape(1) != labels.shape(2))
          throw InputError("mask: must be (H, W) like the labels");
        auto rgb = std::make_shared<std::vector<uint8_t>>(labels.size() * 3);
        {
          nb::gil_scoped_release release;
          colorize(labels.data(), t, int64_t(labels.shape(0)), int(labels.shape(2)),
                   int(labels.shape(1)), mask.data(), colors, rgb->data());
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

  // ---- compounding (freehand reconstruction, docs/conventions.md §7)
  nb::class_<FrameClip>(m, "FrameClip", "Which pixels of a 2D frame go in (MF-oriented pixels).")
      .def(
          "__init__",
          [](FrameClip* self, std::optional<std::array<int, 4>> rect,
             std::optional<std::array<double, 6>> fan,
             std::optional<nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>>
                 mask) {
            FrameClip c;
            if (rect) {
              c.x = (*rect)[0];
              c.y = (*rect)[1];
              c.width = (*rect)[2];
              c.height = (*rect)[3];
              if (c.x < 0 || c.y < 0)
                throw InputError("clip: rect (x, y) = (" + std::to_string(c.x) + ", " +
                                 std::to_string(c.y) + ") must not be negative");
            }
            if (fan) {
              c.fan = true;
              const auto& f = *fan;
              c.fan_angles_deg[0] = f[0];
              c.fan_angles_deg[1] = f[1];
              c.fan_origin_px[0] = f[2];
              c.fan_origin_px[1] = f[3];
              c.fan_radius_px[0] = f[4];
              c.fan_radius_px[1] = f[5];
            }
            if (mask) {
              if (rect || fan) throw InputError("clip: give a mask or a rect/fan, not both");
              c.custom_mask.resize(mask->size());
              for (size_t i = 0; i < c.custom_mask.size(); ++i)
                c.custom_mask[i] = mask->data()[i] != 0;
              if (c.custom_mask.empty()) throw InputError("clip: the mask is empty");
            }
            c.validate("clip");
            new (self) FrameClip(std::move(c));
          },
          "rect"_a = nb::none(), "fan"_a = nb::none(), "mask"_a = nb::none(),
          "rect: (x, y, width, height) pixels (width/height -1: to the frame's edge); fan: "
          "(angle0_deg, "
          "angle1_deg, origin_x_px, origin_y_px, radius_start_px, radius_stop_px); mask: (H, W), "
          "non-zero "
          "pixels go in.")
      .def(
          "mask",
          [](const FrameClip& c, int width, int height) {
            auto keep = std::make_shared<std::vector<uint8_t>>(c.mask(width, height));
            return numpy_view(keep->data(), {size_t(height), size_t(width)}, PixelType::UInt8,
                              keep);
          },
          "width"_a, "height"_a,
          "The (H, W) uint8 mask (1: inserted) for frames of width x height pixels.")
      .def("rectangle", &FrameClip::rectangle, "width"_a, "height"_a,
           "Pixels [x0, x1) x [y0, y1) of the clip rectangle within the frame: (x0, y0, x1, y1).")
      .def_prop_ro("rect",
                   [](const FrameClip& c) {
                     return std::array<int, 4>{c.x, c.y, c.width, c.height};
                   })
      .def_prop_ro("fan", &fan_tuple)
      .def_prop_ro("mask_pixels", [](const FrameClip& c) { return c.custom_mask.size(); });

  nb::class_<PyCompounder> compounder(
      m, "Compounder", "Tracked frames compounded into one voxel grid (use sonoslice.Compounder).");
  compounder
      .def(
          "__init__",
          [](PyCompounder* self, std::array<int64_t, 3> dims, std::array<double, 3> spacing,
             std::array<double, 3> origin, std::array<double, 9> direction,
             const std::string& interpolation, const std::string& compounding, bool fill_holes,
             const std::vector<HoleTuple>& hole_filling, std::optional<double> rejection_threshold,
             const std::string& device, uint64_t max_memory, const std::string& dtype) {
            VolumeGrid g = make_grid(spacing, origin, direction);
            g.dims = dims;
            CompoundSettings s = make_settings(interpolation, compounding, fill_holes, hole_filling,
                                               rejection_threshold);
            const PixelType t = parse_pixel_type(dtype);
            const Device d = Device::parse(device);
            nb::gil_scoped_release release;  // allocating and clearing a large grid takes a while
            new (self) PyCompounder(g, std::move(s), d, max_memory, t);
          },
          "dims"_a, "spacing"_a, "origin"_a, "direction"_a, "interpolation"_a = "linear",
          "compounding"_a = "mean", "fill_holes"_a = false,
          "hole_filling"_a = std::vector<HoleTuple>{}, "rejection_threshold"_a = nb::none(),
          "device"_a = "cpu", "max_memory"_a = 0, "dtype"_a = "float32",
          "dims: voxels along x, y, z; spacing (mm) and origin (mm, centre of voxel 0) along x, y, "
          "z; "
          "direction: 3x3 row-major, index axes as columns. max_memory: bytes (0: what the machine "
          "has).")
      .def(
          "add_images",
          [](PyCompounder& self, nb::ndarray<nb::ro> frames, Matrices image_to_reference,
             const FrameClip& clip) {
            PixelType type;
            const int64_t n = check_frames(frames, 2, "add: frames", "(H, W) or (N, H, W)", &type);
            const size_t nd = frames.ndim();
            const int64_t height = int64_t(frames.shape(nd - 2)),
                          width = int64_t(frames.shape(nd - 1));
            if (width > (int64_t(1) << 28) || height > (int64_t(1) << 28))
              throw InputError("add: frames of " + std::to_string(width) + "x" +
                               std::to_string(height) + " pixels are too large");
            const std::vector<Mat4> m =
                matrices_from(image_to_reference, "add: image_to_reference");
            if (int64_t(m.size()) != n)
              throw InputError("add: " + std::to_string(n) + " frames but " +
                               std::to_string(m.size()) + " image_to_reference matrices");
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            self.compounder.add_images(frames.data(), type, int(width), int(height), n, m.data(),
                                       clip);
          },
          "frames"_a, "image_to_reference"_a, "clip"_a,
          "frames: (H, W) or (N, H, W), C-order, MF-oriented; image_to_reference: (N, 4, 4), pixel "
          "(i, j) "
          "at (i, j, 0) to reference mm.")
      .def(
          "add_beams",
          [](PyCompounder& self, nb::ndarray<nb::ro> frames, Matrices probe_to_reference,
             const BeamTuple& g) {
            PixelType type;
            const int64_t n =
                check_frames(frames, 3, "add_beams: frames",
                             "(n_elevation, n_azimuth, n_samples) or (N, n_elevation, n_azimuth, "
                             "n_samples)",
                             &type);
            const size_t nd = frames.ndim();
            const BeamGeometry geometry =
                beam_geometry(g, int64_t(frames.shape(nd - 3)), int64_t(frames.shape(nd - 2)),
                              int64_t(frames.shape(nd - 1)));
            geometry.validate("add_beams: geometry");
            const std::vector<Mat4> m =
                matrices_from(probe_to_reference, "add_beams: probe_to_reference");
            if (int64_t(m.size()) != n)
              throw InputError("add_beams: " + std::to_string(n) + " frames but " +
                               std::to_string(m.size()) + " probe_to_reference matrices");
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            self.compounder.add_beams(frames.data(), type, geometry, n, m.data());
          },
          "frames"_a, "probe_to_reference"_a, "geometry"_a,
          "frames: (E, A, S) or (N, E, A, S), samples along each beam fastest; geometry: (r0_mm, "
          "dr_mm, "
          "azimuth0_deg, dazimuth_deg, elevation0_deg, delevation_deg, apex_offset_mm).")
      .def(
          "volume",
          [](PyCompounder& self, std::optional<std::string> dtype) {
            const PixelType t = dtype ? parse_pixel_type(*dtype) : self.dtype;
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            return self.compounder.volume(t);
          },
          "dtype"_a = nb::none(),
          "The reconstruction so far (empty voxels 0; integers round and saturate).")
      .def(
          "weights",
          [](PyCompounder& self) {
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            return self.compounder.weights();
          },
          "The summed splat weight per voxel (float32; 0 where no sample arrived).")
      .def_prop_ro("frames_added",
                   [](PyCompounder& self) {
                     nb::gil_scoped_release release;
                     std::lock_guard<std::mutex> lock(self.mutex);
                     return self.compounder.frames_added();
                   })
      .def_prop_ro("grid", [](PyCompounder& self) { return grid_tuple(self.compounder.grid()); })
      .def_prop_ro("dtype", [](PyCompounder& self) { return to_string(self.dtype); });
  def_settings_properties(compounder, [](const PyCompounder& self) -> const CompoundSettings& {
    return self.compounder.settings();
  });

  m.def(
      "compound_grid_around",
      [](Matrices image_to_reference, int width, int height, const FrameClip& clip,
         std::array<double, 3> spacing) {
        const std::vector<Mat4> mats =
            matrices_from(image_to_reference, "grid_around: image_to_reference");
        if (!clip.custom_mask.empty() && clip.custom_mask.size() != size_t(width) * size_t(height))
          throw InputError("grid_around: the clip mask has " +
                           std::to_string(clip.custom_mask.size()) + " pixels but frames have " +
                           std::to_string(height) + "x" + std::to_string(width));
        return grid_tuple(Compounder::grid_around(mats, width, height, clip,
                                                  Vec3{spacing[0], spacing[1], spacing[2]}));
      },
      "image_to_reference"_a, "width"_a, "height"_a, "clip"_a, "spacing"_a,
      "PLUS's output grid around clipped frames: (dims xyz, spacing, origin, direction).");
  m.def(
      "compound_grid_around_beams",
      [](Matrices probe_to_reference, const BeamTuple& g, std::array<int64_t, 3> beam_shape,
         std::array<double, 3> spacing) {
        const std::vector<Mat4> mats =
            matrices_from(probe_to_reference, "grid_around_beams: probe_to_reference");
        const BeamGeometry geometry = beam_geometry(g, beam_shape[0], beam_shape[1], beam_shape[2]);
        return grid_tuple(Compounder::grid_around_beams(mats, geometry,
                                                        Vec3{spacing[0], spacing[1], spacing[2]}));
      },
      "probe_to_reference"_a, "geometry"_a, "beam_shape"_a, "spacing"_a,
      "The grid around every beam's first and last sample: (dims xyz, spacing, origin, "
      "direction).");
  m.def(
      "compounding_memory_bytes",
      [](std::array<int64_t, 3> dims, const std::string& compounding, const std::string& dtype) {
        VolumeGrid g;
        g.dims = dims;
        CompoundSettings s;
        s.mode = parse_compounding_mode(compounding);
        return compounding_memory_bytes(g, s, parse_pixel_type(dtype));
      },
      "dims"_a, "compounding"_a = "mean", "dtype"_a = "float32");
  m.def(
      "read_beam_geometry",
      [](const std::string& path) { return beam_tuple(read_beam_geometry(path)); }, "path"_a,
      "(r0_mm, dr_mm, azimuth0_deg, dazimuth_deg, elevation0_deg, delevation_deg, apex_offset_mm)");
  m.def(
      "write_beam_geometry",
      [](const std::string& path, const BeamTuple& g) {
        write_beam_geometry(path, beam_geometry(g, 0, 0, 0));
      },
      "path"_a, "geometry"_a);

  // ---- PLUS toolkit files
  nb::class_<PlusSequence>(m, "PlusSequence",
                           "A PLUS tracked-frame sequence, frames in MF orientation.")
      .def_ro("path", &PlusSequence::path)
      .def_ro("width", &PlusSequence::width)
      .def_ro("height", &PlusSequence::height)
      .def_ro("frame_count", &PlusSequence::frame_count)
      .def_ro("orientation", &PlusSequence::orientation)
      .def_prop_ro("dtype", [](const PlusSequence& s) { return to_string(s.pixel_type); })
      .def_ro("frame_fields", &PlusSequence::frame_fields,
              "Per frame, every Seq_FrameNNNN_<Field> (a copy).")
      .def(
          "frames",
          [](nb::handle_t<PlusSequence> self) {
            PlusSequence& s = nb::cast<PlusSequence&>(self);
            const size_t shape[3] = {size_t(s.frame_count), size_t(s.height), size_t(s.width)};
            // A view of the sequence's pixels; the array keeps the sequence object alive.
            return nb::ndarray<nb::numpy>(s.pixels.data(), 3, shape, self, nullptr,
                                          dlpack_dtype(s.pixel_type));
          },
          "(N, H, W) view of the frames (no copy).")
      .def("image_ok", &PlusSequence::image_ok, "frame"_a)
      .def("transform_names", &PlusSequence::transform_names, "frame"_a)
      .def(
          "transform",
          [](const PlusSequence& s, int frame, const std::string& name) {
            return matrix_or_none(s.transform(frame, name));
          },
          "frame"_a, "name"_a,
          "Frame's <name>Transform (4x4) or None (missing or its status not OK).")
      .def("timestamps", [](const PlusSequence& s) {
        std::vector<double> t(size_t(s.frame_count));
        for (int k = 0; k < s.frame_count; ++k) t[size_t(k)] = s.timestamp(k);
        return t;
      });
  m.def(
      "read_plus_sequence",
      [](const std::string& path) {
        nb::gil_scoped_release release;
        return read_plus_sequence(path);
      },
      "path"_a);
  m.def(
      "write_plus_sequence",
      [](const std::string& path, nb::ndarray<nb::ro> frames,
         const std::vector<std::map<std::string, std::string>>& fields,
         const std::string& orientation, bool compress) {
        const std::string what = "write_plus_sequence: frames";
        if (frames.device_type() != kCpu || frames.ndim() != 3 || !c_contiguous(frames))
          throw InputError(what + ": expected a C-contiguous (N, H, W) array in host memory");
        PlusSequence s;
        s.path = path;
        s.pixel_type = pixel_type_of(frames.dtype(), what.c_str());
        s.frame_count = int(frames.shape(0));
        s.height = int(frames.shape(1));
        s.width = int(frames.shape(2));
        if (int64_t(s.frame_count) != int64_t(frames.shape(0)) ||
            int64_t(s.height) != int64_t(frames.shape(1)) ||
            int64_t(s.width) != int64_t(frames.shape(2)))
          throw InputError(what + ": too many frames or pixels");
        s.orientation = orientation;
        s.frame_fields = fields;
        const auto* p = static_cast<const uint8_t*>(frames.data());
        s.pixels.assign(p, p + frames.nbytes());
        nb::gil_scoped_release release;
        write_plus_sequence(path, s, compress);
      },
      "path"_a, "frames"_a, "fields"_a, "orientation"_a = "MF", "compress"_a = true);

  nb::class_<TransformRepository>(m, "TransformRepository",
                                  "Named transforms; chains of them on request.")
      .def(nb::init<>())
      .def("copy", [](const TransformRepository& r) { return r; })
      .def(
          "set",
          [](TransformRepository& r, const std::string& from, const std::string& to, Matrix4 matrix,
             bool valid) {
            r.set(from, to, matrix_from(matrix, "transform " + from + "To" + to), valid);
          },
          "from_frame"_a, "to_frame"_a, "matrix"_a, "valid"_a = true)
      .def("set_frame", &TransformRepository::set_frame, "sequence"_a, "frame"_a)
      .def(
          "get",
          [](const TransformRepository& r, const std::string& from, const std::string& to) {
            return matrix_or_none(r.get(from, to));
          },
          "from_frame"_a, "to_frame"_a)
      .def_static("split_name", &TransformRepository::split_name, "name"_a);

  nb::class_<PlusReconstructionConfig> plus_config(
      m, "PlusConfig", "A PLUS configuration's reconstruction settings.");
  plus_config.def_ro("path", &PlusReconstructionConfig::path)
      .def_prop_ro("coordinate_definitions",
                   [](const PlusReconstructionConfig& c) { return c.coordinate_definitions; })
      .def_ro("image_frame", &PlusReconstructionConfig::image_frame)
      .def_ro("reference_frame", &PlusReconstructionConfig::reference_frame)
      .def_ro("spacing", &PlusReconstructionConfig::output_spacing_mm)
      .def_ro("origin", &PlusReconstructionConfig::output_origin_mm)
      .def_ro("extent", &PlusReconstructionConfig::output_extent)
      .def_ro("clip", &PlusReconstructionConfig::clip)
      .def_ro("skip_interval", &PlusReconstructionConfig::skip_interval)
      .def_ro("ignored_attributes", &PlusReconstructionConfig::ignored_attributes)
      .def_ro("unknown_attributes", &PlusReconstructionConfig::unknown_attributes);
  def_settings_properties(
      plus_config,
      [](const PlusReconstructionConfig& c) -> const CompoundSettings& { return c.settings; });
  m.def(
      "read_plus_config",
      [](const std::string& path) {
        nb::gil_scoped_release release;
        return read_plus_config(path);
      },
      "path"_a);
  m.def(
      "plus_frames", &plus_frames, "sequence"_a, "repository"_a, "from_frame"_a, "to_frame"_a,
      "skip"_a = 1, "hint"_a = "",
      "(frame indices, (M, 4, 4) from->to matrices, frames with a bad image status, frames with an "
      "invalid transform) for every skip-th frame.");
}
