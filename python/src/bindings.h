#pragma once
// Internal to the extension: what the binding files (one per area, python/src/<area>.cpp)
// share. Typed array aliases for the arrays whose type is known, conversions between arrays and
// the library's types, and each area's bind_<area>(module), called by module.cpp.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/compound/Reconstruction.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/volume/PixelType.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice::bindings {

namespace nb = nanobind;

void bind_volumes(nb::module_& m);         // Volume, VolumeGrid, the phantom
void bind_slicing(nb::module_& m);         // Probe, Slicer, pose checks
void bind_surfaces(nb::module_& m);        // Mesh, voxelize, SurfaceSlicer, colours
void bind_compounding(nb::module_& m);     // Compounder and its small classes
void bind_io(nb::module_& m);              // pose and stack files, PNG bytes
void bind_plus(nb::module_& m);            // PLUS sequences, transform repositories, configs
void bind_reconstruction(nb::module_& m);  // the reconstruction recipe (reconstruct_plus)
void bind_simulation(nb::module_& m);      // Simulator, its settings, tissue tables, presets
void bind_registration(nb::module_& m);    // register_frames, its settings and report
void bind_sampling(nb::module_& m);        // PoseSampler, SamplerSettings, sample_seeds
void bind_live(nb::module_& m);            // LiveCompounder, the live compound server

/// A Python value (dicts, lists, tuples, numbers, strings, None, NumPy arrays and scalars,
/// objects with keys() such as Tissue) as JSON text for the library's parsers (json.cpp), so a
/// dict of settings is checked by the same code as a JSON or YAML file. InputError naming `where`
/// and the key path ("sampler.reject.min_body") for a value JSON cannot hold (NaN, an object).
std::string json_text(nb::handle value, const std::string& where);

// ---- choices
/// Binds the enum E as `name`, one member per value, named as the library spells the value
/// (to_string; '-' becomes '_': "nelder-mead" → nelder_mead), and whose str() is that spelling
/// ("nelder-mead"), so that a member and the string users pass read alike.
template <typename E, size_t N>
nb::enum_<E> bind_enum(nb::module_& m, const char* name, const E (&values)[N], const char* doc) {
  nb::enum_<E> e(m, name, doc);
  for (E v : values) {
    std::string member = to_string(v);
    std::replace(member.begin(), member.end(), '-', '_');
    e.value(member.c_str(), v);
  }
  e.def("__str__", [](E v) { return std::string(to_string(v)); });
  return e;
}

// ---- volumes that view a caller's array (Volume(array), volumes.cpp)
/// What a Volume made from a caller's array views. The volume holds the array (and the DLPack
/// export or buffer nanobind took from it), so the memory lives as long as the volume; but an
/// array can change in place: torch's resize_ reallocates its storage, NumPy's
/// resize(refcheck=False) too, assigning .shape or .dtype reinterprets it. Reading the old
/// pointer then reads freed memory. So the layout seen at construction (data pointer, shape,
/// strides, dtype) is compared with the array's current one, exported again, before every use
/// from Python: check() raises RuntimeError naming the volume instead. (Copying every array
/// would be safe too, but doubles the memory of a large CT and breaks "the volume sees changes
/// made to the array".) Needs the GIL; dropped under the GIL (volume_from_array's deleter).
class ArraySource {
 public:
  ArraySource(nb::object array, nb::ndarray<nb::ro> view, bool read_only, std::string volume);
  /// Error (RuntimeError) "<volume>: cannot <use>: the <type> it views was resized, reshaped or
  /// reallocated since ..." when the array's layout is not the recorded one.
  void check(const std::string& use) const;
  /// True for read-only arrays (a read-only memmap): Volume.array is read-only too.
  bool read_only() const { return read_only_; }

 private:
  std::string layout_text(const nb::ndarray<nb::ro>& a) const;

  nb::object array_;          // the caller's object, exported again by check()
  nb::ndarray<nb::ro> view_;  // the export the volume reads (holds the DLPack capsule / buffer)
  bool read_only_;
  std::string volume_, type_name_;
};

/// The source of a Python Volume made from an array; null for volumes that own their memory
/// (files, results, copies).
std::shared_ptr<const ArraySource> volume_source(nb::handle volume);

/// Raises RuntimeError when `volume` views an array that changed since it was made (see
/// ArraySource); `use` says what was about to happen ("slice", "save", ...).
inline void check_volume_source(nb::handle volume, const std::string& use) {
  if (const auto source = volume_source(volume)) source->check(use);
}

// ---- arrays in: nanobind checks these types and converts other dtypes and strides (a copy).
/// (N, 4, 4) float64 matrices: poses (probe → world), image/probe → reference; row-major.
using Matrices = nb::ndarray<const double, nb::shape<-1, 4, 4>, nb::c_contig, nb::device::cpu>;
/// One 4×4 float64 matrix, row-major.
using Matrix4 = nb::ndarray<const double, nb::shape<4, 4>, nb::c_contig, nb::device::cpu>;
/// An (H, W) uint8 mask (non-zero: inside).
using Mask = nb::ndarray<const uint8_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
/// Pixels of any supported type (pixel_type_of) in host memory, C-order.
using HostPixels = nb::ndarray<nb::ro, nb::c_contig, nb::device::cpu>;

// ---- arrays out
using MatrixOut = nb::ndarray<nb::numpy, double, nb::shape<4, 4>>;

/// The reconstruction recipe's parameter → Python's keyword ("mode" → "compounding", ...).
std::string keyword_of(const std::string& parameter);
/// reconstruct_plus's (and LiveCompounder's) keywords → the recipe's options (strings parsed by
/// the library's parsers; messages name the keywords).
ReconstructionOptions reconstruction_options(
    std::optional<Vec3> spacing, const std::optional<std::string>& interpolation,
    const std::optional<std::string>& compounding, std::optional<bool> fill_holes,
    std::optional<std::vector<HoleFillingKernel>> hole_filling,
    std::optional<double> rejection_threshold, std::optional<FrameClip> clip,
    std::optional<int> skip, std::optional<std::string> transform,
    const std::optional<Matrix4>& image_to_probe, const std::optional<std::string>& dtype,
    const std::string& device, uint64_t max_memory, bool plus_exact,
    const std::optional<std::string>& plus_optimization,
    const std::optional<std::string>& plus_grid, std::optional<Vec3> origin = std::nullopt,
    std::optional<std::array<int64_t, 3>> extent = std::nullopt);
using MatricesOut = nb::ndarray<nb::numpy, double, nb::shape<-1, 4, 4>>;

/// A seed given as any Python int: 0..2^64 − 1, else an InputError (ValueError) naming `what`
/// instead of nanobind's generic "incompatible function arguments" (-1) or a silent wrap.
inline uint64_t seed_value(const nb::int_& value, const std::string& what) {
  const unsigned long long v = PyLong_AsUnsignedLongLong(value.ptr());
  if (v == static_cast<unsigned long long>(-1) && PyErr_Occurred()) {
    PyErr_Clear();
    throw InputError(what + " " + nb::str(value).c_str() +
                     ": expected a whole number from 0 to 18446744073709551615");
  }
  return uint64_t(v);
}

/// Keywords a settings class does not take (a typo, a setting of another class): an InputError
/// (ValueError) naming them and the ones it takes, instead of nanobind's generic "incompatible
/// function arguments" that lists every signature.
template <typename Names>
void refuse_unknown_keywords(const nb::kwargs& given, const std::string& what, const Names& known) {
  if (given.size() == 0) return;
  std::string unknown, expected;
  for (auto item : given)
    unknown += (unknown.empty() ? "'" : ", '") + std::string(nb::str(item.first).c_str()) + "'";
  for (const auto& name : known) expected += (expected.empty() ? "" : ", ") + std::string(name);
  throw InputError(what + ": unknown keyword" + (given.size() > 1 ? "s " : " ") + unknown +
                   " (expected " + expected + ")");
}

/// NumPy's name of a DLPack dtype ("uint8", "float32", "complex64", "bool", ...).
inline std::string dtype_name(nb::dlpack::dtype d) {
  using C = nb::dlpack::dtype_code;
  std::string name;
  switch (C(d.code)) {
    case C::Bool:
      return "bool";
    case C::Int:
      name = "int";
      break;
    case C::UInt:
      name = "uint";
      break;
    case C::Float:
      name = "float";
      break;
    case C::Bfloat:
      name = "bfloat";
      break;
    case C::Complex:
      name = "complex";
      break;
    default:  // a code of a newer DLPack
      name = "dlpack code " + std::to_string(int(d.code)) + " of ";
  }
  name += std::to_string(d.bits);
  if (d.lanes != 1) name += "x" + std::to_string(d.lanes);
  return name;
}

/// The library's pixel type of an array's dtype; InputError "<what> has dtype X, ..." otherwise.
inline PixelType pixel_type_of(nb::dlpack::dtype d, const std::string& what) {
  const std::string name = dtype_name(d);
  try {
    return parse_pixel_type(name);
  } catch (const InputError& e) {
    throw InputError(what + " has dtype " + name + ", an unsupported dtype (" + e.what() + ")");
  }
}

inline nb::dlpack::dtype dlpack_dtype(PixelType t) {
  return visit_pixel_type(t, [](auto zero) { return nb::dtype<decltype(zero)>(); });
}

/// Whether an array (of any nanobind ndarray type) is C-contiguous.
template <typename... Args>
bool c_contiguous(const nb::ndarray<Args...>& a) {
  int64_t expected = 1;
  for (size_t i = a.ndim(); i-- > 0;) {
    if (a.shape(i) != 1 && a.stride(i) != expected) return false;
    expected *= int64_t(a.shape(i));
  }
  return true;
}

/// An array's shape as Python prints it: "(3, 4)", "(2,)".
template <typename... Args>
std::string shape_text(const nb::ndarray<Args...>& a) {
  std::string s = "(";
  for (size_t i = 0; i < a.ndim(); ++i) s += (i ? ", " : "") + std::to_string(a.shape(i));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

/// A NumPy view of memory that `keep` keeps alive (a copy of a shared handle).
template <typename Keep>
nb::ndarray<nb::numpy> numpy_view(void* data, std::vector<size_t> shape, PixelType type,
                                  Keep keep) {
  auto* holder = new Keep(std::move(keep));
  nb::capsule owner(holder, [](void* p) noexcept { delete static_cast<Keep*>(p); });
  return nb::ndarray<nb::numpy>(data, shape.size(), shape.data(), owner, nullptr,
                                dlpack_dtype(type));
}

inline std::vector<Mat4> matrices_from(const Matrices& a) {
  std::vector<Mat4> out(a.shape(0));
  for (size_t n = 0; n < out.size(); ++n) out[n] = Mat4::from_row_major(a.data() + 16 * n);
  return out;
}

/// NumPy (N, 4, 4) float64 owning the matrices.
inline MatricesOut matrices_to_numpy(std::vector<Mat4> matrices) {
  static_assert(sizeof(Mat4) == 16 * sizeof(double), "Mat4 is 16 doubles");
  auto* keep = new std::vector<Mat4>(std::move(matrices));
  nb::capsule owner(keep, [](void* p) noexcept { delete static_cast<std::vector<Mat4>*>(p); });
  const size_t shape[3] = {keep->size(), 4, 4};
  return MatricesOut(keep->data(), 3, shape, owner);
}

inline std::optional<MatrixOut> matrix_or_none(const std::optional<Mat4>& m) {
  if (!m) return std::nullopt;
  auto* keep = new Mat4(*m);
  nb::capsule owner(keep, [](void* p) noexcept { delete static_cast<Mat4*>(p); });
  const size_t shape[2] = {4, 4};
  return MatrixOut(keep->m, 2, shape, owner);
}

// ---- slicing into (N, H, W) image arrays (Slicer, SurfaceSlicer)
/// Whether `out` is (n, height, width).
inline bool has_shape(const nb::ndarray<>& out, int64_t n, int64_t height, int64_t width) {
  return out.ndim() == 3 && int64_t(out.shape(0)) == n && int64_t(out.shape(1)) == height &&
         int64_t(out.shape(2)) == width;
}

inline std::string shape_text(int64_t n, int64_t height, int64_t width) {
  return "(" + std::to_string(n) + ", " + std::to_string(height) + ", " + std::to_string(width) +
         ")";
}

inline void check_out_dtype(const nb::ndarray<>& out, PixelType type) {
  if (pixel_type_of(out.dtype(), "out") != type)
    throw InputError("out: dtype must be " + to_string(type));
}

/// Validates every pose before the first chunk (so nothing is written when one is bad), then
/// calls slice_chunk(first, count) without the GIL for `chunk` poses at a time (all of them when
/// chunk <= 0), reporting progress(done, total) after each chunk.
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

/// Python's repr of a value (numbers as Python prints them: 0.4, not 0.400000).
template <typename T>
std::string repr(const T& value) {
  return nb::repr(nb::cast(value)).c_str();
}

/// A fixed-size array as a Python tuple's repr: "(0.0, 1.5)".
template <typename T, size_t N>
std::string repr(const std::array<T, N>& values) {
  std::string s = "(";
  for (size_t i = 0; i < N; ++i) s += (i ? ", " : "") + repr(values[i]);
  return s + (N == 1 ? ",)" : ")");
}

}  // namespace sonoslice::bindings
