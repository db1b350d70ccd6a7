// Slicing against closed-form answers and a float64 evaluation of docs/conventions.md §5, on every
// backend.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

using test::BackendTest;

// A smooth but non-trivial field: trilinear will not reproduce it exactly, the reference will.
double wiggly(const Vec3& p) {
  return 100 * std::sin(p[0] * 0.21) * std::cos(p[1] * 0.17) + 40 * std::sin(p[2] * 0.31) + 7;
}

ProbeGeometry fan_probe(int w = 96, int h = 80, double spacing = 0.35) {
  return test::curvilinear_probe(12, 25, 70, w, h, spacing, 1.5);
}

ProbeGeometry linear_probe(int w = 64, int h = 48, double spacing = 0.3) {
  return test::linear_probe(w, h, spacing);
}

// A one-pixel probe: the pose's origin is the sample point.
ProbeGeometry point_probe() {
  ProbeGeometry p;
  p.type = ProbeType::Linear;
  p.image.width = p.image.height = 1;
  return p;
}

Vec3 grid_centre(const VolumeGrid& g) {
  return g.index_to_world({(g.dims[0] - 1) / 2.0, (g.dims[1] - 1) / 2.0, (g.dims[2] - 1) / 2.0});
}

class SliceTest : public BackendTest {};

// Trilinear interpolation reproduces a linear function exactly away from the clamped border.
TEST_P(SliceTest, LinearRampIsExactThroughObliqueVolume) {
  const VolumeGrid grid = test::oblique_grid({40, 36, 30});
  auto ramp = [](const Vec3& p) { return 3.0 + 0.5 * p[0] - 1.25 * p[1] + 2.0 * p[2]; };
  const Volume volume = test::make_volume<float>(grid, ramp);
  const ProbeGeometry probe = linear_probe();
  const auto poses = test::random_poses(12, grid_centre(grid), 5.0, 11);
  Slicer slicer(volume, probe, {}, device());
  const auto images = slicer.slice<float>(poses);
  const auto range = volume.value_range();
  const Mat3 w2i = grid.world_to_index_linear();
  int64_t checked = 0;
  double worst = 0;
  size_t idx = 0;
  for (const Pose& pose : poses)
    for (int v = 0; v < probe.image.height; ++v)
      for (int u = 0; u < probe.image.width; ++u, ++idx) {
        const Vec3 p =
            pose.transform_point({probe.image.origin_mm[0] + u * probe.image.spacing_mm[0],
                                  probe.image.origin_mm[1] + v * probe.image.spacing_mm[1], 0});
        const Vec3 c = w2i * (p - grid.origin_mm);
        bool interior = true;
        for (int a = 0; a < 3; ++a) interior &= c[a] >= 0 && c[a] <= double(grid.dims[a] - 1);
        if (!interior) continue;
        worst = std::max(worst, std::fabs(images[idx] - ramp(p)));
        ++checked;
      }
  EXPECT_GT(checked, 20000);
  EXPECT_LE(worst, 1e-4 * (range.second - range.first)) << "checked " << checked << " pixels";
}

// Float64 reference (docs/conventions.md §5) on an oblique grid, both probe shapes, both
// interpolations.
TEST_P(SliceTest, MatchesFloat64ReferenceOnObliqueGrid) {
  const VolumeGrid grid = test::oblique_grid({48, 40, 32});
  const Volume volume = test::make_volume<float>(grid, wiggly);
  const auto range = volume.value_range();
  // Poses reach well outside the volume so the inside/outside rule is exercised too.
  const auto poses = test::random_poses(16, grid_centre(grid), 25.0, 3);
  for (const ProbeGeometry& probe : {fan_probe(), linear_probe()}) {
    for (Interpolation interp : {Interpolation::Linear, Interpolation::Nearest}) {
      SliceSettings s;
      s.interpolation = interp;
      s.fill_value = -77;
      const auto images = Slicer(volume, probe, s, device()).slice<float>(poses);
      const auto cmp =
          test::compare_with_reference(volume, probe, poses, interp, s.fill_value, images);
      SCOPED_TRACE(probe.describe() + " " + to_string(interp));
      EXPECT_EQ(cmp.mask_mismatches, 0);
      EXPECT_GT(cmp.compared, 10000);
      EXPECT_LT(cmp.excluded, cmp.compared / 100);
      EXPECT_LE(cmp.max_abs_error, 1e-4 * (range.second - range.first));
    }
  }
}

// docs/conventions.md §5: inside iff -0.5 <= c < n - 0.5 (ITK's IsInsideBuffer).
TEST_P(SliceTest, HalfVoxelBoundaryRule) {
  VolumeGrid grid;
  grid.dims = {4, 3, 3};
  const Volume volume = test::make_volume<float>(grid, [](const Vec3& p) { return 10 + p[0]; });
  SliceSettings s;
  s.fill_value = -1;
  Slicer slicer(volume, point_probe(), s, device());
  const double xs[] = {-0.5001, -0.5, -0.4999, 0.0, 3.0, 3.4999, 3.5, 3.5001};
  const float expected[] = {-1, 10, 10, 10, 13, 13, -1, -1};  // clamped neighbours beyond 0 and 3
  for (size_t i = 0; i < 8; ++i) {
    const Pose pose = test::make_pose(Mat3::identity(), {xs[i], 1.0, 1.0});
    float out = 0;
    slicer.slice(&pose, 1, &out);
    EXPECT_FLOAT_EQ(out, expected[i]) << "x = " << xs[i];
  }
}

// docs/conventions.md §5 nearest: index floor(c + 0.5).
TEST_P(SliceTest, NearestRounding) {
  VolumeGrid grid;
  grid.dims = {5, 2, 2};
  grid.spacing_mm = {2.0, 1.0, 1.0};
  const Volume volume =
      test::make_volume<int16_t>(grid, [](const Vec3& p) { return p[0] / 2 * 10; });
  SliceSettings s;
  s.interpolation = Interpolation::Nearest;
  Slicer slicer(volume, point_probe(), s, device());
  const double cs[] = {-0.5, 0.49, 0.5, 1.49, 1.5, 2.51, 4.49};
  const float expected[] = {0, 0, 10, 10, 20, 30, 40};
  for (size_t i = 0; i < 7; ++i) {
    const Pose pose = test::make_pose(Mat3::identity(), {cs[i] * 2.0, 0.2, 0.7});
    float out = -1;
    slicer.slice(&pose, 1, &out);
    EXPECT_EQ(out, expected[i]) << "c = " << cs[i];
  }
}

// Outside the fan: fill (mask 0); inside the fan but outside the volume: fill (mask 1).
TEST_P(SliceTest, FillOutsideFanAndOutsideVolume) {
  VolumeGrid grid;
  grid.dims = {20, 20, 20};
  const Volume volume = test::make_volume<float>(grid, [](const Vec3&) { return 5.0; });
  const ProbeGeometry probe = fan_probe(60, 50, 0.8);
  SliceSettings s;
  s.fill_value = -3;
  Slicer slicer(volume, probe, s, device());
  EXPECT_EQ(slicer.mask(), probe.mask());
  // Probe at the volume's top face looking in +y: the fan starts inside and leaves the volume.
  const Pose pose = test::make_pose(Mat3::identity(), {9.5, 0.0, 9.5});
  const auto img = slicer.slice<float>({pose});
  int inside_volume = 0, outside_volume = 0;
  for (int v = 0; v < probe.image.height; ++v)
    for (int u = 0; u < probe.image.width; ++u) {
      const float got = img[size_t(v) * probe.image.width + u];
      const double x = probe.image.origin_mm[0] + u * probe.image.spacing_mm[0];
      const double y = probe.image.origin_mm[1] + v * probe.image.spacing_mm[1];
      const Vec3 c{9.5 + x, y, 9.5};
      const bool in_volume = c[0] >= -0.5 && c[0] < 19.5 && c[1] >= -0.5 && c[1] < 19.5;
      if (!probe.inside(x, y)) {
        EXPECT_EQ(got, -3.0f);
      } else if (in_volume) {
        EXPECT_EQ(got, 5.0f);
        ++inside_volume;
      } else {
        EXPECT_EQ(got, -3.0f);
        ++outside_volume;
      }
    }
  EXPECT_GT(inside_volume, 100);
  EXPECT_GT(outside_volume, 100);
}

// Integer outputs round half up and saturate; NaN becomes 0 in integers and stays NaN in float.
TEST_P(SliceTest, OutputTypesRoundAndSaturate) {
  VolumeGrid grid;
  grid.dims = {6, 1, 1};
  const double values[] = {40000.0, -40000.0, 2.5,
                           -2.5,    254.6,    std::numeric_limits<double>::quiet_NaN()};
  Volume volume = Volume::allocate(PixelType::Float32, grid);
  for (int i = 0; i < 6; ++i) volume.data_as<float>()[i] = float(values[i]);
  std::vector<Pose> poses;
  for (int i = 0; i < 6; ++i) poses.push_back(test::make_pose(Mat3::identity(), {double(i), 0, 0}));
  SliceSettings s;
  s.interpolation = Interpolation::Nearest;
  s.output_type = PixelType::Int16;
  const auto i16 = Slicer(volume, point_probe(), s, device()).slice<int16_t>(poses);
  EXPECT_EQ(i16, (std::vector<int16_t>{32767, -32768, 3, -2, 255, 0}));
  s.output_type = PixelType::UInt8;
  const auto u8 = Slicer(volume, point_probe(), s, device()).slice<uint8_t>(poses);
  EXPECT_EQ(u8, (std::vector<uint8_t>{255, 0, 3, 0, 255, 0}));
  s.output_type = PixelType::Float32;
  const auto f32 = Slicer(volume, point_probe(), s, device()).slice<float>(poses);
  EXPECT_TRUE(std::isnan(f32[5]));
  EXPECT_EQ(f32[2], 2.5f);
}

// Every voxel type gives the same images as float32 holding the same values.
TEST_P(SliceTest, EveryVoxelTypeMatchesFloat) {
  const VolumeGrid grid = test::oblique_grid({30, 28, 26});
  // Integers in [0, 120]: exact in every voxel type, int8 included.
  auto field = [](const Vec3& p) {
    return std::min(
        120.0, std::max(0.0, std::floor(60 + 50 * std::sin(p[0] * 0.3 + p[1] * 0.2) + 0.2 * p[2])));
  };
  const Volume reference = test::make_volume<float>(grid, field);
  const auto poses = test::random_poses(6, grid_centre(grid), 12.0, 5);
  for (Interpolation interp : {Interpolation::Linear, Interpolation::Nearest}) {
    SliceSettings s;
    s.interpolation = interp;
    const auto expected = Slicer(reference, fan_probe(), s, device()).slice<float>(poses);
    for (PixelType t : {PixelType::UInt8, PixelType::Int8, PixelType::UInt16, PixelType::Int16,
                        PixelType::UInt32, PixelType::Int32, PixelType::Float64}) {
      const Volume v = reference.converted(t);
      const auto got = Slicer(v, fan_probe(), s, device()).slice<float>(poses);
      double worst = 0;
      for (size_t i = 0; i < got.size(); ++i)
        worst = std::max(worst, double(std::fabs(got[i] - expected[i])));
      EXPECT_LE(worst, 1e-4) << to_string(t) << " " << to_string(interp);
    }
  }
}

// A bad pose is named by its index and nothing is written.
TEST_P(SliceTest, BadPoseRejectedWithIndexAndNoOutput) {
  VolumeGrid grid;
  grid.dims = {8, 8, 8};
  const Volume volume = test::make_volume<float>(grid, [](const Vec3&) { return 1.0; });
  Slicer slicer(volume, linear_probe(8, 8), {}, device());
  std::vector<Pose> poses(5, test::make_pose(Mat3::identity(), {3, 3, 3}));
  poses[3].m[1][2] = std::numeric_limits<double>::quiet_NaN();
  std::vector<float> out(5 * 64, 42.0f);
  try {
    slicer.slice(poses.data(), poses.size(), out.data(), 100);
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("pose 103"), std::string::npos) << e.what();
  }
  for (float v : out) ASSERT_EQ(v, 42.0f);
}

// Threads partition rows, so results are bit-identical for any thread count.
TEST_P(SliceTest, IdenticalForAnyThreadCount) {
  const VolumeGrid grid = test::oblique_grid({40, 40, 40});
  const Volume volume = test::make_volume<int16_t>(grid, wiggly);
  const auto poses = test::random_poses(20, grid_centre(grid), 10.0, 9);
  const test::ScopedCpuSettings restore;
  set_cpu_threads(1);
  const auto one = Slicer(volume, fan_probe(), {}, device()).slice<float>(poses);
  set_cpu_threads(3);
  const auto three = Slicer(volume, fan_probe(), {}, device()).slice<float>(poses);
  ASSERT_EQ(one.size(), three.size());
  EXPECT_EQ(0, std::memcmp(one.data(), three.data(), one.size() * sizeof(float)));
}

// The phantom at benchmark-like poses: the accuracy figure the README quotes.
TEST_P(SliceTest, PhantomAccuracyAgainstFloat64Reference) {
  const Phantom phantom = make_phantom(PhantomSize::Small);
  const auto poses = phantom_random_poses(40, 7);
  const ProbeGeometry probe = fan_probe(167, 136, 0.494);  // W1's fan at half resolution
  const auto range = phantom.ct.value_range();
  for (Interpolation interp : {Interpolation::Linear, Interpolation::Nearest}) {
    SliceSettings s;
    s.interpolation = interp;
    const auto images = Slicer(phantom.ct, probe, s, device()).slice<float>(poses);
    const auto cmp = test::compare_with_reference(phantom.ct, probe, poses, interp, 0.0, images);
    const double relative = cmp.max_abs_error / (range.second - range.first);
    std::printf(
        "[ accuracy ] %s %s: max |error| = %.3g HU = %.3g of the value range over %lld "
        "pixels (%lld within 1e-3 voxel of a boundary excluded)\n",
        GetParam().c_str(), to_string(interp), cmp.max_abs_error, relative,
        static_cast<long long>(cmp.compared), static_cast<long long>(cmp.excluded));
    EXPECT_EQ(cmp.mask_mismatches, 0);
    EXPECT_GT(cmp.compared, 100000);  // most of the 40 fans' pixels (about 122k)
    EXPECT_LE(relative, 1e-4);
  }
}

SONOSLICE_INSTANTIATE_BACKENDS(SliceTest);

// The AVX2 kernels and the generic kernels agree (FMA changes the last bits only).
TEST(SliceKernels, Avx2MatchesGeneric) {
  const test::ScopedCpuSettings restore;
  try {
    set_cpu_kernel_isa("avx2");
  } catch (const std::exception&) {
    GTEST_SKIP() << "cpu-avx2: this CPU or build has no AVX2+FMA kernels";
  }
  const Phantom phantom = make_phantom(PhantomSize::Small);
  const auto poses = phantom_random_poses(30, 3);
  for (PixelType t : {PixelType::Int16, PixelType::Float32, PixelType::UInt8, PixelType::UInt16}) {
    const Volume v = t == PixelType::Int16 ? phantom.ct : phantom.ct.converted(t);
    for (Interpolation interp : {Interpolation::Linear, Interpolation::Nearest}) {
      SliceSettings s;
      s.interpolation = interp;
      set_cpu_kernel_isa("avx2");
      const auto a = Slicer(v, fan_probe(120, 100, 0.7), s).slice<float>(poses);
      set_cpu_kernel_isa("generic");
      const auto g = Slicer(v, fan_probe(120, 100, 0.7), s).slice<float>(poses);
      double worst = 0;
      size_t differ = 0;
      for (size_t i = 0; i < a.size(); ++i) {
        const double d = std::fabs(double(a[i]) - double(g[i]));
        worst = std::max(worst, d);
        differ += d > 0;
      }
      SCOPED_TRACE(to_string(t) + " " + to_string(interp));
      // Same coordinates, same decisions; only the fused lerps round differently.
      const auto range = v.value_range();
      if (interp == Interpolation::Nearest)
        EXPECT_EQ(differ, 0u);
      else
        EXPECT_LE(worst, 1e-5 * (range.second - range.first));
    }
  }
  // Integer outputs: the vector rounding/saturation matches the scalar one (exactly for nearest;
  // within one unit for linear, where the fused lerps may land across a .5).
  const Volume labels = phantom.labels;
  for (const Volume* v : {&phantom.ct, &labels})
    for (PixelType out : {PixelType::UInt8, PixelType::Int16, PixelType::UInt16})
      for (Interpolation interp : {Interpolation::Linear, Interpolation::Nearest}) {
        SliceSettings s;
        s.interpolation = interp;
        s.output_type = out;
        s.fill_value = 7;
        std::vector<unsigned char> a(30 * 120 * 100 * pixel_size(out)), g(a.size());
        set_cpu_kernel_isa("avx2");
        Slicer(*v, fan_probe(120, 100, 0.7), s).slice(poses.data(), poses.size(), a.data());
        set_cpu_kernel_isa("generic");
        Slicer(*v, fan_probe(120, 100, 0.7), s).slice(poses.data(), poses.size(), g.data());
        int worst = 0;
        visit_pixel_type(out, [&](auto zero) {
          using T = decltype(zero);
          const T* x = reinterpret_cast<const T*>(a.data());
          const T* y = reinterpret_cast<const T*>(g.data());
          for (size_t i = 0; i < a.size() / sizeof(T); ++i)
            worst = std::max(worst, std::abs(int(x[i]) - int(y[i])));
        });
        SCOPED_TRACE(to_string(v->pixel_type()) + " -> " + to_string(out) + " " +
                     to_string(interp));
        EXPECT_LE(worst, interp == Interpolation::Nearest ? 0 : 1);
      }
}

TEST(SliceKernels, RejectsBadSettings) {
  VolumeGrid grid;
  grid.dims = {4, 4, 4};
  const Volume volume = test::make_volume<float>(grid, [](const Vec3&) { return 0.0; });
  SliceSettings s;
  s.output_type = PixelType::Float64;
  EXPECT_THROW(Slicer(volume, linear_probe(), s), InputError);
  s.output_type = PixelType::Int16;
  s.fill_value = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(Slicer(volume, linear_probe(), s), InputError);
  ProbeGeometry bad = linear_probe();
  bad.image.width = 0;
  EXPECT_THROW(Slicer(volume, bad), InputError);
  EXPECT_THROW(Slicer(Volume(), linear_probe()), InputError);
}

}  // namespace
}  // namespace sonoslice
