// Volumes (zero-copy from NumPy/torch, or read from files), voxel grids and the built-in phantom.
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cstring>
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

/// A Python Volume made from a caller's array: the volume plus what it views (null for a copy).
struct ArrayVolume : Volume {
  std::shared_ptr<const ArraySource> source;
};

std::string volume_text(const VolumeGrid& g, PixelType type) {
  return "Volume(" + std::to_string(g.dims[0]) + "x" + std::to_string(g.dims[1]) + "x" +
         std::to_string(g.dims[2]) + " " + to_string(type) + ")";
}

// Zero-copy: the volume points into the caller's array, which it keeps alive. The array is
// untyped and checked here rather than converted by nanobind: a converted copy would silently
// break "the volume sees changes made to the array". Read-only arrays (a read-only memmap) are
// fine: slicing only reads. A bare DLPack capsule is copied: once consumed, it cannot be
// exported again, so a resize of the tensor behind it could not be noticed.
ArrayVolume volume_from_array(nb::handle array, const Vec3& spacing, const Vec3& origin,
                              const Rows& direction) {
  const bool capsule = PyCapsule_CheckExact(array.ptr());
  nb::ndarray<nb::ro> a;
  bool read_only = false;
  if (nb::ndarray<> writable; nb::try_cast(array, writable, false)) {
    a = nb::ndarray<nb::ro>(writable);
  } else if (nb::try_cast(array, a, false)) {
    read_only = true;
  } else if (nb::hasattr(array, "dtype") && nb::hasattr(array.attr("dtype"), "name")) {
    // A NumPy array whose values have no buffer to share (object, str).
    throw InputError("volume array: dtype '" +
                     nb::cast<std::string>(nb::str(array.attr("dtype").attr("name"))) +
                     "' is not supported (supported: uint8, int8, uint16, int16, uint32, int32, "
                     "float32, float64)");
  } else {
    throw InputError(
        "volume array: expected a NumPy array or a torch tensor (any object with __dlpack__ or "
        "the buffer protocol), got " +
        std::string(nb::type_name(array.type()).c_str()));
  }
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
  ArrayVolume v;
  if (capsule) {
    static_cast<Volume&>(v) = Volume::allocate(type, g);
    std::memcpy(v.data(), a.data(), v.byte_size());
    return v;
  }
  // Dropping Python references needs the GIL; a Volume copy may die on a worker thread.
  std::shared_ptr<ArraySource> source(
      new ArraySource(nb::borrow(array), a, read_only, volume_text(g, type)), [](ArraySource* p) {
        nb::gil_scoped_acquire gil;
        delete p;
      });
  static_cast<Volume&>(v) = Volume::wrap(const_cast<void*>(a.data()), type, g, source);
  v.source = std::move(source);
  return v;
}

/// Volume.array: a NumPy view (read-only when the volume views a read-only array).
nb::object volume_array(nb::pointer_and_handle<Volume> self) {
  const auto source = volume_source(self.h);
  if (source) source->check("give its array");
  const Volume& v = *self.p;
  const auto& d = v.grid().dims;
  if (!source || !source->read_only())
    return nb::cast(numpy_view(const_cast<void*>(v.data()),
                               {size_t(d[2]), size_t(d[1]), size_t(d[0])}, v.pixel_type(), v));
  auto* keep = new Volume(v);
  nb::capsule owner(keep, [](void* p) noexcept { delete static_cast<Volume*>(p); });
  const size_t shape[3] = {size_t(d[2]), size_t(d[1]), size_t(d[0])};
  return nb::cast(nb::ndarray<nb::numpy, nb::ro>(v.data(), 3, shape, owner, nullptr,
                                                 dlpack_dtype(v.pixel_type())));
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

ArraySource::ArraySource(nb::object array, nb::ndarray<nb::ro> view, bool read_only,
                         std::string volume)
    : array_(std::move(array)),
      view_(std::move(view)),
      read_only_(read_only),
      volume_(std::move(volume)),
      type_name_(nb::str(array_.type().attr("__module__")).c_str() + std::string(".") +
                 nb::str(array_.type().attr("__qualname__")).c_str()) {}

std::string ArraySource::layout_text(const nb::ndarray<nb::ro>& a) const {
  return shape_text(a) + " " + dtype_name(a.dtype());
}

void ArraySource::check(const std::string& use) const {
  nb::ndarray<nb::ro> now;
  const bool exported = nb::try_cast(array_, now, false);
  bool same = exported && now.data() == view_.data() && now.ndim() == view_.ndim() &&
              now.dtype() == view_.dtype() && now.device_type() == view_.device_type();
  for (size_t i = 0; same && i < view_.ndim(); ++i)
    same = now.shape(i) == view_.shape(i) && now.stride(i) == view_.stride(i);
  if (same) return;
  std::string change;
  if (!exported)
    change = "it can no longer be exported";
  else if (layout_text(now) != layout_text(view_))
    change = layout_text(view_) + " then, " + layout_text(now) + " now";
  else
    change = "its memory moved or its strides changed";
  throw Error(volume_ + ": cannot " + use + ": the " + type_name_ +
              " it views was resized, reshaped or reallocated since the Volume was made: " +
              change + "; the old memory may be freed. Make a new sonoslice.Volume from it.");
}

std::shared_ptr<const ArraySource> volume_source(nb::handle volume) {
  ArrayVolume* v = nullptr;
  if (nb::try_cast(volume, v, false) && v) return v->source;
  return nullptr;
}

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
      .def("array", &volume_array)
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
           [](nb::pointer_and_handle<Volume> self) {
             check_volume_source(self.h, "compute its value range");
             nb::gil_scoped_release release;
             return self.p->value_range();
           })
      .def("converted",
           [](nb::pointer_and_handle<Volume> self, const std::string& dtype) {
             const PixelType t = parse_pixel_type(dtype);
             check_volume_source(self.h, "convert");
             nb::gil_scoped_release release;
             return self.p->converted(t);
           })
      .def("save",
           [](nb::pointer_and_handle<Volume> self, const std::string& path) {
             check_volume_source(self.h, "save");
             nb::gil_scoped_release release;
             write_volume(path, *self.p);
           })
      .def("world_to_index",
           [](const Volume& v, const Vec3& p) { return v.grid().world_to_index(p); })
      .def("index_to_world",
           [](const Volume& v, const Vec3& c) { return v.grid().index_to_world(c); });

  nb::class_<ArrayVolume, Volume>(m, "ArrayVolume",
                                  "A Volume viewing a caller's array (checked before each use).")
      .def_static("from_array", &volume_from_array, "array"_a.none(), "spacing"_a, "origin"_a,
                  "direction"_a);

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
