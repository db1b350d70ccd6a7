#include "TestUtil.h"

#include "sonoslice/core/Error.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <random>

namespace sonoslice {
namespace test {

namespace fs = std::filesystem;

TempDir::TempDir() {
  static std::atomic<int> counter{0};
  path_ = fs::temp_directory_path() /
          ("sonoslice-test-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
  fs::remove_all(path_);
  fs::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

ScopedCpuSettings::~ScopedCpuSettings() {
  reset_cpu_threads();
  set_cpu_kernel_isa("auto");
}

bool cuda_required() {
  const char* v = std::getenv("SONOSLICE_REQUIRE_CUDA");
  return v && std::string(v) != "" && std::string(v) != "0";
}

namespace {
std::vector<std::string> g_captured_warnings;
void capture_warning(const std::string& message) {
  g_captured_warnings.push_back(message);
}
}  // namespace

CapturedWarnings::CapturedWarnings() {
  g_captured_warnings.clear();
  set_warning_handler(&capture_warning);
}
CapturedWarnings::~CapturedWarnings() {
  set_warning_handler(nullptr);
}
const std::vector<std::string>& CapturedWarnings::messages() const {
  return g_captured_warnings;
}
void CapturedWarnings::clear() {
  g_captured_warnings.clear();
}

bool gpu_available(std::string* why) {
  if (!built_with_cuda()) {
    *why = "cuda: not available (built without CUDA)";
    return false;
  }
  try {
    require_device(Device{DeviceType::CUDA, 0});
    return true;
  } catch (const std::exception& e) {
    *why = e.what();
    return false;
  }
}

void expect_cuda_unavailable(const std::function<void()>& make) {
  try {
    make();
    ADD_FAILURE() << "expected an error";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_TRUE(m.find("cuda:0: not available") != std::string::npos ||
                m.find("built without CUDA") != std::string::npos)
        << m;
  }
}

std::string read_file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

std::string data_dir() {
#ifdef SONOSLICE_DATA_DIR
  const fs::path p(SONOSLICE_DATA_DIR);
  std::error_code ec;
  if (fs::is_directory(p / "fanslicer", ec)) return fs::canonical(p).string();
#endif
  return "";
}

Mat3 rotation(Vec3 axis, double degrees) {
  axis = normalized(axis);
  const double a = degrees * kPi / 180.0, c = std::cos(a), s = std::sin(a);
  const double x = axis[0], y = axis[1], z = axis[2];
  Mat3 r;
  r.m[0][0] = c + x * x * (1 - c);
  r.m[0][1] = x * y * (1 - c) - z * s;
  r.m[0][2] = x * z * (1 - c) + y * s;
  r.m[1][0] = y * x * (1 - c) + z * s;
  r.m[1][1] = c + y * y * (1 - c);
  r.m[1][2] = y * z * (1 - c) - x * s;
  r.m[2][0] = z * x * (1 - c) - y * s;
  r.m[2][1] = z * y * (1 - c) + x * s;
  r.m[2][2] = c + z * z * (1 - c);
  return r;
}

ProbeGeometry linear_probe(int width, int height, double spacing_mm) {
  ProbeGeometry p;
  p.type = ProbeType::Linear;
  p.image.width = width;
  p.image.height = height;
  p.image.spacing_mm[0] = p.image.spacing_mm[1] = spacing_mm;
  p.image.set_default_origin();
  return p;
}

ProbeGeometry curvilinear_probe(double radius_mm, double depth_mm, double sector_deg, int width,
                                int height, double spacing_mm, double face_y_mm) {
  return ProbeGeometry::curvilinear(radius_mm, depth_mm, sector_deg,
                                    ImageGrid::centred(width, height, spacing_mm, spacing_mm),
                                    face_y_mm);
}

VolumeGrid oblique_grid(std::array<int64_t, 3> dims) {
  VolumeGrid g;
  g.dims = dims;
  g.spacing_mm = {0.9, 1.3, 1.7};
  g.origin_mm = {-12.5, 7.25, 30.0};
  g.direction = rotation({1, 2, 3}, 27.0);
  return g;
}

Pose make_pose(const Mat3& r, const Vec3& origin) {
  return Mat4::from_rotation_translation(r, origin);
}

std::vector<Pose> random_poses(size_t count, const Vec3& centre, double radius, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Pose> poses;
  for (size_t n = 0; n < count; ++n) {
    const Vec3 axis{u(rng), u(rng), u(rng) + 1e-3};
    const Vec3 offset{u(rng) * radius, u(rng) * radius, u(rng) * radius};
    poses.push_back(make_pose(rotation(axis, 180.0 * u(rng)), centre + offset));
  }
  return poses;
}

namespace {
double voxel(const Volume& v, int64_t i, int64_t j, int64_t k) {
  const auto& d = v.grid().dims;
  const int64_t idx = (k * d[1] + j) * d[0] + i;
  return visit_pixel_type(v.pixel_type(),
                          [&](auto zero) { return double(v.data_as<decltype(zero)>()[idx]); });
}
}  // namespace

bool reference_sample(const Volume& volume, const Vec3& world, Interpolation interp, double fill,
                      double* value, double* margin) {
  const VolumeGrid& g = volume.grid();
  // c = diag(spacing)^-1 · D^-1 · (p - origin), solved in double.
  const Vec3 c = Mat3::diagonal({1 / g.spacing_mm[0], 1 / g.spacing_mm[1], 1 / g.spacing_mm[2]}) *
                 (g.direction.inverse() * (world - g.origin_mm));
  *margin = 1e300;
  bool inside = true;
  for (int a = 0; a < 3; ++a) {
    const double lo = -0.5, hi = double(g.dims[a]) - 0.5;
    *margin = std::min({*margin, std::fabs(c[a] - lo), std::fabs(c[a] - hi)});
    if (!(c[a] >= lo && c[a] < hi)) inside = false;
  }
  if (!inside) {
    *value = fill;
    return false;
  }
  auto clamp = [&](int64_t i, int a) {
    return std::max<int64_t>(0, std::min<int64_t>(i, g.dims[a] - 1));
  };
  if (interp == Interpolation::Nearest) {
    // Rounding ties: a float32 evaluation may round the other way within ~1e-5 voxel of x.5.
    for (int a = 0; a < 3; ++a)
      *margin = std::min(*margin, std::fabs(c[a] - std::floor(c[a]) - 0.5));
    *value =
        voxel(volume, clamp(int64_t(std::floor(c[0] + 0.5)), 0),
              clamp(int64_t(std::floor(c[1] + 0.5)), 1), clamp(int64_t(std::floor(c[2] + 0.5)), 2));
    return true;
  }
  int64_t i0[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    i0[a] = int64_t(std::floor(c[a]));
    f[a] = c[a] - double(i0[a]);
  }
  double sum = 0;
  for (int corner = 0; corner < 8; ++corner) {
    double w = 1;
    int64_t idx[3];
    for (int a = 0; a < 3; ++a) {
      const int bit = (corner >> a) & 1;
      w *= bit ? f[a] : 1 - f[a];
      idx[a] = clamp(i0[a] + bit, a);
    }
    sum += w * voxel(volume, idx[0], idx[1], idx[2]);
  }
  *value = sum;
  return true;
}

Comparison compare_with_reference(const Volume& volume, const ProbeGeometry& probe,
                                  const std::vector<Pose>& poses, Interpolation interp, double fill,
                                  const std::vector<float>& images) {
  Comparison out;
  const ImageGrid& im = probe.image;
  size_t idx = 0;
  for (const Pose& pose : poses) {
    for (int v = 0; v < im.height; ++v) {
      for (int u = 0; u < im.width; ++u, ++idx) {
        const double x = im.origin_mm[0] + u * im.spacing_mm[0];
        const double y = im.origin_mm[1] + v * im.spacing_mm[1];
        const double got = images[idx];
        if (!probe.inside(x, y)) {
          if (got != float(fill)) ++out.mask_mismatches;
          continue;
        }
        double expected, margin;
        reference_sample(volume, pose.transform_point({x, y, 0}), interp, fill, &expected, &margin);
        if (margin < 1e-3) {
          ++out.excluded;
          continue;
        }
        ++out.compared;
        out.max_abs_error = std::max(out.max_abs_error, std::fabs(got - expected));
      }
    }
  }
  return out;
}

std::vector<std::string> all_backends() {
  return {"cpu-generic", "cpu-avx2", "cuda"};
}

void BackendTest::SetUp() {
  const std::string& b = GetParam();
  if (b == "cuda") {
    if (!built_with_cuda()) SONOSLICE_SKIP_WITHOUT_CUDA("cuda: not available (built without CUDA)");
    try {
      require_device(Device{DeviceType::CUDA, 0});
    } catch (const std::exception& e) {
      SONOSLICE_SKIP_WITHOUT_CUDA(e.what());
    }
  } else if (b == "cpu-avx2") {
    try {
      set_cpu_kernel_isa("avx2");
    } catch (const std::exception&) {
      GTEST_SKIP() << "cpu-avx2: this CPU or build has no AVX2+FMA kernels";
    }
  } else {
    set_cpu_kernel_isa("generic");
  }
}

void BackendTest::TearDown() {
  set_cpu_kernel_isa("auto");
}

Device BackendTest::device() const {
  return GetParam() == "cuda" ? Device{DeviceType::CUDA, 0} : Device::cpu();
}

}  // namespace test
}  // namespace sonoslice
