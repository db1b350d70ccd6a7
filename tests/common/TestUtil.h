#pragma once
// Helpers shared by the test programs: temporary directories, analytic volumes, poses, and an
// independent float64 evaluation of docs/conventions.md §5 to compare the kernels against.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/slice/Slicer.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {
namespace test {

/// A fresh directory under the system temp dir, removed at the end of the test.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::filesystem::path& path() const { return path_; }
  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

/// Restores the CPU backend's global settings (thread count, kernel instruction set) to the
/// suite's defaults when it goes out of scope, so a test that changes them cannot leak them into
/// the next test, even when an assertion returns early.
class ScopedCpuSettings {
 public:
  ScopedCpuSettings() = default;
  ~ScopedCpuSettings();
  ScopedCpuSettings(const ScopedCpuSettings&) = delete;
  ScopedCpuSettings& operator=(const ScopedCpuSettings&) = delete;
};

/// SONOSLICE_REQUIRE_CUDA=1 (set by scripts/gpu-check.sh on GPU machines): a CUDA test that would
/// skip for want of a GPU fails instead, so a broken GPU setup can never look green.
bool cuda_required();

/// Skips the current test (`why`: the reason), or fails it under SONOSLICE_REQUIRE_CUDA=1. Use in
/// place of GTEST_SKIP() wherever the reason is a missing GPU or a build without CUDA.
#define SONOSLICE_SKIP_WITHOUT_CUDA(why)                                              \
  do {                                                                                \
    if (::sonoslice::test::cuda_required()) {                                         \
      GTEST_FAIL() << "SONOSLICE_REQUIRE_CUDA=1, but the test would skip: " << (why); \
    }                                                                                 \
    GTEST_SKIP() << (why);                                                            \
  } while (0)

/// Whether cuda:0 can run here; `why` says why not ("built without CUDA", "cuda:0: not
/// available (...)").
bool gpu_available(std::string* why);

/// Expects `make` (making a slicer, simulator, ... on cuda:0) to throw Error saying cuda:0 is not
/// available or the build has no CUDA.
void expect_cuda_unavailable(const std::function<void()>& make);

/// A test fixture for GPU tests: skipped where gpu_available() is false (failed under
/// SONOSLICE_REQUIRE_CUDA=1).
class GpuTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string why;
    if (!gpu_available(&why)) SONOSLICE_SKIP_WITHOUT_CUDA(why);
  }
};

/// The library's warnings (warn()) while it lives, instead of stderr; one at a time.
class CapturedWarnings {
 public:
  CapturedWarnings();
  ~CapturedWarnings();
  CapturedWarnings(const CapturedWarnings&) = delete;
  CapturedWarnings& operator=(const CapturedWarnings&) = delete;
  const std::vector<std::string>& messages() const;
  void clear();
};

/// A file's whole content, byte for byte ("" when it cannot be read).
std::string read_file_bytes(const std::string& path);

/// The repository's data/ folder of real files (CMake passes its location; see data/README.md);
/// empty when it is not there.
std::string data_dir();
/// The real data ships with the repository, so a missing data/ is a broken checkout: fail, never
/// skip (a skipped real-data test would let a fresh clone look green without testing anything).
#define SONOSLICE_REQUIRE_DATA()                                                       \
  do {                                                                                 \
    if (::sonoslice::test::data_dir().empty())                                         \
      GTEST_FAIL() << "the repository's data/ folder is missing (see data/README.md)"; \
  } while (0)

/// A volume of type T whose voxel (i, j, k) holds f(world position of its centre).
template <typename T>
Volume make_volume(const VolumeGrid& grid, const std::function<double(const Vec3&)>& f) {
  Volume v = Volume::allocate(PixelTypeOf<T>::value, grid);
  T* p = v.data_as<T>();
  for (int64_t k = 0; k < grid.dims[2]; ++k)
    for (int64_t j = 0; j < grid.dims[1]; ++j)
      for (int64_t i = 0; i < grid.dims[0]; ++i)
        p[(k * grid.dims[1] + j) * grid.dims[0] + i] =
            static_cast<T>(f(grid.index_to_world({double(i), double(j), double(k)})));
  return v;
}

/// A rotation by `degrees` about the unit axis.
Mat3 rotation(Vec3 axis, double degrees);

/// A curvilinear probe (docs/conventions.md §3) with a width × height image of square pixels,
/// centred laterally.
ProbeGeometry curvilinear_probe(double radius_mm, double depth_mm, double sector_deg, int width,
                                int height, double spacing_mm, double face_y_mm = 0.0);

/// A linear probe with a width × height image of square pixels of `spacing_mm`, face at y = 0,
/// centred laterally.
ProbeGeometry linear_probe(int width, int height, double spacing_mm);

/// An oblique grid: rotated axes, anisotropic spacing, non-zero origin.
VolumeGrid oblique_grid(std::array<int64_t, 3> dims);

/// A pose with probe origin `origin` and orthonormal axes from a rotation.
Pose make_pose(const Mat3& r, const Vec3& origin);

/// Random poses whose probe origin lies within `radius` mm of `centre`.
std::vector<Pose> random_poses(size_t count, const Vec3& centre, double radius, uint32_t seed);

/// docs/conventions.md §5 evaluated in float64 for one world point: returns false (and `fill`)
/// outside the buffer; `margin` receives the distance (in voxels) of c to the nearest
/// inside/outside boundary (and, for nearest, to the nearest rounding tie x.5), so callers can
/// exclude pixels within 1e-3 voxel of it.
bool reference_sample(const Volume& volume, const Vec3& world, Interpolation interp, double fill,
                      double* value, double* margin);

struct Comparison {
  double max_abs_error = 0;     ///< over pixels farther than 1e-3 voxel from the boundary
  int64_t compared = 0;         ///< pixels compared
  int64_t excluded = 0;         ///< pixels within 1e-3 voxel of the inside/outside boundary
  int64_t mask_mismatches = 0;  ///< fill where a value was expected or vice versa
};

/// Compares float32 images sliced by sonoslice with the float64 reference, pixel by pixel.
Comparison compare_with_reference(const Volume& volume, const ProbeGeometry& probe,
                                  const std::vector<Pose>& poses, Interpolation interp, double fill,
                                  const std::vector<float>& images);

/// Device-parameterised tests (Open3D style): each TEST_P body runs once per backend —
/// "cpu-generic", "cpu-avx2" and "cuda" — and is reported as skipped where that backend is not
/// available here, never silently passed.
class BackendTest : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override;
  void TearDown() override;
  Device device() const;  ///< the Device to hand to Slicer
};
std::vector<std::string> all_backends();
#define SONOSLICE_INSTANTIATE_BACKENDS(Suite)                                      \
  INSTANTIATE_TEST_SUITE_P(Backends, Suite,                                        \
                           ::testing::ValuesIn(::sonoslice::test::all_backends()), \
                           [](const auto& info) {                                  \
                             std::string n = info.param;                           \
                             for (auto& c : n)                                     \
                               if (c == '-') c = '_';                              \
                             return n;                                             \
                           })

}  // namespace test
}  // namespace sonoslice
