// Volumes (zero-copy from NumPy/torch, or read from files), voxel grids and the built-in phantom.
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <memory>

#include "bindings.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;

constexpr int kCpu = nb::device::cpu::value;

/// A 3×3 matrix as rows (Python: a tuple of three (x, y, z) tuples).
using Rows = std::array<std::array<double, 3>, 3>;

Rows rows_of(const Mat3& d) {
  Rows r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[size_t(i)][size_t(j)] = d.m[i][j];
  return r;
}

Mat3 mat3_of(const Rows& r) {
  Mat3 d;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) d.m[i][j] = r[size_t(i)][size_t(j)];
  return d;
}

template <typename T>
std::tuple<T, T, T> tuple3(const std::array<T, 3>& a) {
  return {a[0], a[1], a[2]};
}

using Row = std::tuple<double, double, double>;

std::tuple<Row, Row, Row> rows_tuple(const Mat3& d) {
  const Rows r = rows_of(d);
  return {tuple3(r[0]), tuple3(r[1]), tuple3(r[2])};
}

// Zero-copy: the volume points into the caller's array, which it keeps alive. The array is
// untyped and checked here rather than converted by nanobind: a converted copy would silently
// break "the volume sees changes made to the array".
Volume volume_from_array(nb::ndarray<> a, const Vec3& spacing, const Vec3& origin,
                         const Rows& direction) {
  if (a.ndim() != 3)
    throw InputError("volume array: expected 3 dimensions (nz, ny, nx), got " +
                     std::to_string(a.ndim()));
  if (a.device_type() != kCpu)
    throw InputError("volume array: must be in host memory (for a GPU tensor, pass tensor.cpu())");
  if (!c_contiguous(a))
    throw InputError("volume array: not C-contiguous; pass numpy.ascontiguousarray(a) (a copy)");
  const PixelType type = pixel_type_of(a.dtype(), "volume array");
  VolumeGrid g;
  g.dims = {int64_t(a.shape(2)), int64_t(a.shape(1)), int64_t(a.shape(0))};
  g.spacing_mm = spacing;
  g.origin_mm = origin;
  g.direction = mat3_of(direction);
  g.validate("volume array");
  auto* keep = new nb::ndarray<>(a);
  std::shared_ptr<void> owner(keep, [](void* p) {
    nb::gil_scoped_acquire gil;  // dropping a Python reference needs the GIL
    delete static_cast<nb::ndarray<>*>(p);
  });
  return Volume::wrap(a.data(), type, g, owner);
}

bool same_grid(const VolumeGrid& a, const VolumeGrid& b) {
  return a.dims == b.dims && a.spacing_mm == b.spacing_mm && a.origin_mm == b.origin_mm &&
         a.direction.row_major() == b.direction.row_major();
}

std::string grid_repr(const VolumeGrid& g) {
  std::string s = "VolumeGrid(dims=" + repr(g.dims) + ", spacing=" + repr(g.spacing_mm) +
                  ", origin=" + repr(g.origin_mm);
  if (g.direction.row_major() != Mat3::identity().row_major()) {
    const Rows r = rows_of(g.direction);
    s += ", direction=(" + repr(r[0]) + ", " + repr(r[1]) + ", " + repr(r[2]) + ")";
  }
  return s + ")";
}

}  // namespace

void bind_volumes(nb::module_& m) {
  const VolumeGrid defaults;
  nb::class_<VolumeGrid>(m, "VolumeGrid",
                         "A voxel grid: voxel (i, j, k) has its centre at origin + direction · "
                         "(spacing * (i, j, k)) (mm).")
      .def(
          "__init__",
          [](VolumeGrid* self, const std::array<int64_t, 3>& dims, const Vec3& spacing,
             const Vec3& origin, const Rows& direction) {
            VolumeGrid g;
            g.dims = dims;
            g.spacing_mm = spacing;
            g.origin_mm = origin;
            g.direction = mat3_of(direction);
            g.validate("VolumeGrid");
            new (self) VolumeGrid(g);
          },
          "dims"_a, "spacing"_a = defaults.spacing_mm, "origin"_a = defaults.origin_mm,
          "direction"_a = rows_of(defaults.direction),
          "dims: voxels along x, y, z (i, j, k); spacing (mm) and origin (mm, centre of voxel "
          "0) along x, y, z; direction: 3x3 as rows, the index axes as columns.")
      .def_prop_ro("dims", [](const VolumeGrid& g) { return tuple3(g.dims); })
      .def_prop_ro("spacing", [](const VolumeGrid& g) { return tuple3(g.spacing_mm); })
      .def_prop_ro("origin", [](const VolumeGrid& g) { return tuple3(g.origin_mm); })
      .def_prop_ro("direction", [](const VolumeGrid& g) { return rows_tuple(g.direction); })
      .def_prop_ro("voxel_count", &VolumeGrid::voxel_count)
      .def(
          "index_to_world", [](const VolumeGrid& g, const Vec3& c) { return g.index_to_world(c); },
          "index"_a)
      .def(
          "world_to_index", [](const VolumeGrid& g, const Vec3& p) { return g.world_to_index(p); },
          "point_mm"_a)
      .def("__eq__", &same_grid, nb::is_operator())
      .def("__repr__", &grid_repr);

  nb::class_<Volume>(m, "Volume")
      .def_static("from_array", &volume_from_array, "array"_a, "spacing"_a, "origin"_a,
                  "direction"_a)
      .def_static(
          "from_file",
          [](const std::string& path, std::optional<Vec3> spacing, std::optional<Vec3> origin,
             std::optional<Rows> direction, const std::string& series,
             const std::string& npy_config) {
            VolumeReadOptions o;
            o.series_uid = series;
            o.fanslicer_npy_config = npy_config;
            o.spacing_mm = spacing;
            o.origin_mm = origin;
            if (direction) o.direction = mat3_of(*direction);
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
      .def_prop_ro("spacing", [](const Volume& v) { return tuple3(v.grid().spacing_mm); })
      .def_prop_ro("origin", [](const Volume& v) { return tuple3(v.grid().origin_mm); })
      .def_prop_ro("direction", [](const Volume& v) { return rows_tuple(v.grid().direction); })
      .def_prop_ro("grid", [](const Volume& v) { return v.grid(); })
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
           [](const Volume& v, const Vec3& p) { return v.grid().world_to_index(p); })
      .def("index_to_world",
           [](const Volume& v, const Vec3& c) { return v.grid().index_to_world(c); });

  // ---- the built-in phantom
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
  m.def("phantom_label_names", [] {
    std::vector<std::string> names;
    for (int l = 0; l < kPhantomLabelCount; ++l) names.push_back(phantom_label_name(l));
    return names;
  });
}

}  // namespace sonoslice::bindings
