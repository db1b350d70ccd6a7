// Compounding (docs/conventions.md §7): known answers for every splat and compounding mode, clip
// rectangles and fans, hole filling, an independent float64 oracle, thread-count bit identity,
// incremental vs batch, 3-D beam frames, the slicer round trip, memory limits and bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <map>
#include <random>

#include "../../src/compound/CompoundBackends.h"
#include "../../src/compound/Finish.h"
#include "../../src/compound/FinishImpl.h"
#include "../../src/compound/PlusExactImpl.h"
#include "../common/TestUtil.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

using test::BackendTest;

VolumeGrid unit_grid(int64_t nx, int64_t ny, int64_t nz, double spacing = 1.0) {
  VolumeGrid g;
  g.dims = {nx, ny, nz};
  g.spacing_mm = {spacing, spacing, spacing};
  return g;
}

// Pixel (i, j) at origin + i·ex + j·ey.
Mat4 frame_matrix(const Vec3& origin, const Vec3& ex, const Vec3& ey) {
  return Mat4::from_columns(ex, ey, cross(ex, ey), origin);
}

Mat4 translation(double x, double y, double z) {
  return frame_matrix({{x, y, z}}, {{1, 0, 0}}, {{0, 1, 0}});
}

CompoundSettings settings(Interpolation interp, CompoundingMode mode) {
  CompoundSettings s;
  s.interpolation = interp;
  s.mode = mode;
  return s;
}

std::vector<float> as_floats(const Volume& v) {
  const Volume f = v.pixel_type() == PixelType::Float32 ? v : v.converted(PixelType::Float32);
  const float* p = f.data_as<float>();
  return std::vector<float>(p, p + f.grid().voxel_count());
}

int64_t offset(const VolumeGrid& g, int64_t x, int64_t y, int64_t z) {
  return (z * g.dims[1] + y) * g.dims[0] + x;
}

// --- Known answers ----------------------------------------------------------------------------

TEST(Compound, NearestFrameOnVoxelCentresIsCopiedIntoItsSlice) {
  const VolumeGrid g = unit_grid(8, 6, 4);
  Compounder c(g, settings(Interpolation::Nearest, CompoundingMode::Mean));
  std::vector<uint8_t> frame(8 * 6);
  for (size_t i = 0; i < frame.size(); ++i) frame[i] = uint8_t(3 * i + 1);
  c.add_image(frame.data(), PixelType::UInt8, 8, 6, translation(0, 0, 2));
  const auto v = as_floats(c.volume(PixelType::Float32));
  const auto w = as_floats(c.weights());
  for (int z = 0; z < 4; ++z)
    for (int y = 0; y < 6; ++y)
      for (int x = 0; x < 8; ++x) {
        const int64_t i = offset(g, x, y, z);
        EXPECT_EQ(v[i], z == 2 ? frame[y * 8 + x] : 0.f) << x << "," << y << "," << z;
        EXPECT_EQ(w[i], z == 2 ? 1.f : 0.f);
      }
  EXPECT_EQ(c.frames_added(), 1);
}

class CompoundBackendTest : public BackendTest {};

TEST_P(CompoundBackendTest, MeanMaxLatestOfThreeFramesAtOnePose) {
  const VolumeGrid g = unit_grid(4, 4, 3);
  const std::vector<uint8_t> a(16, 10), b(16, 25), low(16, 4);
  struct Case {
    CompoundingMode mode;
    float expected;
  };
  for (const Case& k : {Case{CompoundingMode::Mean, (10.f + 25.f + 4.f) / 3.f},
                        Case{CompoundingMode::Max, 25.f}, Case{CompoundingMode::Latest, 4.f}}) {
    for (auto interp : {Interpolation::Nearest, Interpolation::Linear}) {
      Compounder c(g, settings(interp, k.mode), device());
      for (const auto* f : {&a, &b, &low})
        c.add_image(f->data(), PixelType::UInt8, 4, 4, translation(0, 0, 1));
      const auto v = as_floats(c.volume(PixelType::Float32));
      for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x) EXPECT_FLOAT_EQ(v[offset(g, x, y, 1)], k.expected);
      EXPECT_EQ(v[offset(g, 1, 1, 0)], 0.f);
    }
  }
}

TEST(Compound, LinearSplatSpreadsOneSampleWithTrilinearWeights) {
  const VolumeGrid g = unit_grid(6, 6, 6);
  Compounder c(g, settings(Interpolation::Linear, CompoundingMode::Mean));
  const float sample = 80.f;
  c.add_image(&sample, PixelType::Float32, 1, 1, translation(2.25, 3.5, 1.75));
  const auto w = as_floats(c.weights());
  const auto v = as_floats(c.volume(PixelType::Float32));
  const double fx = 0.25, fy = 0.5, fz = 0.75;
  double total = 0;
  for (int k = 0; k < 8; ++k) {
    const int dx = k & 1, dy = (k >> 1) & 1, dz = k >> 2;
    const double expected = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy) * (dz ? fz : 1 - fz);
    const int64_t i = offset(g, 2 + dx, 3 + dy, 1 + dz);
    EXPECT_NEAR(w[i], expected, 1e-6);
    EXPECT_FLOAT_EQ(v[i], sample);
    total += w[i];
  }
  EXPECT_NEAR(total, 1.0, 1e-6);
  double all = 0;
  for (float x : w) all += x;
  EXPECT_NEAR(all, 1.0, 1e-6);  // nothing anywhere else
}

TEST(Compound, LinearSplatOfARampOnASymmetricSampleLatticeIsExact) {
  // Samples every 0.25 voxel, symmetric around each voxel centre: the weighted mean of a linear
  // function is its value at the voxel centre.
  const VolumeGrid g = unit_grid(10, 10, 5);
  Compounder c(g, settings(Interpolation::Linear, CompoundingMode::Mean));
  const int W = 37, H = 37;  // 0 .. 9 voxels in steps of 0.25
  for (int s = 0; s <= 16; ++s) {
    const double z = s * 0.25;
    std::vector<float> frame(W * H);
    for (int j = 0; j < H; ++j)
      for (int i = 0; i < W; ++i) frame[j * W + i] = float(3 + 2 * (0.25 * i) - (0.25 * j) + 4 * z);
    c.add_image(frame.data(), PixelType::Float32, W, H,
                frame_matrix({{0, 0, z}}, {{0.25, 0, 0}}, {{0, 0.25, 0}}));
  }
  const auto v = as_floats(c.volume(PixelType::Float32));
  // Interior voxels (every neighbour sample present on both sides).
  for (int z = 1; z < 4; ++z)
    for (int y = 1; y < 9; ++y)
      for (int x = 1; x < 9; ++x) EXPECT_NEAR(v[offset(g, x, y, z)], 3 + 2 * x - y + 4 * z, 1e-4);
}

TEST(Compound, LatestKeepsTheMeanOfTheNewestFrameThatReachedEachVoxel) {
  const VolumeGrid g = unit_grid(4, 4, 1);
  Compounder c(g, settings(Interpolation::Nearest, CompoundingMode::Latest));
  // 8×8 pixels of 0.5 mm: four pixels per voxel.
  const std::vector<uint8_t> old(64, 100);
  c.add_image(old.data(), PixelType::UInt8, 8, 8,
              frame_matrix({{-0.25, -0.25, 0}}, {{0.5, 0, 0}}, {{0, 0.5, 0}}));
  // The newer frame covers only the left half (4 columns of pixels = voxels x 0..1).
  std::vector<uint8_t> fresh(4 * 8);
  for (int j = 0; j < 8; ++j)
    for (int i = 0; i < 4; ++i) fresh[j * 4 + i] = uint8_t(10 * i + j);
  c.add_image(fresh.data(), PixelType::UInt8, 4, 8,
              frame_matrix({{-0.25, -0.25, 0}}, {{0.5, 0, 0}}, {{0, 0.5, 0}}));
  const auto v = as_floats(c.volume(PixelType::Float32));
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) {
      double expected = 100;
      if (x < 2) {
        expected = 0;
        for (int j = 2 * y; j < 2 * y + 2; ++j)
          for (int i = 2 * x; i < 2 * x + 2; ++i) expected += fresh[j * 4 + i] / 4.0;
      }
      EXPECT_FLOAT_EQ(v[offset(g, x, y, 0)], float(expected)) << x << "," << y;
    }
}

TEST(Compound, RejectionThresholdSkipsDarkerSamplesOnly) {
  const VolumeGrid g = unit_grid(4, 1, 1);
  CompoundSettings s = settings(Interpolation::Nearest, CompoundingMode::Mean);
  s.rejection_threshold = 20;
  Compounder c(g, s);
  const uint8_t frame[4] = {5, 19, 20, 200};
  c.add_image(frame, PixelType::UInt8, 4, 1, translation(0, 0, 0));
  const auto w = as_floats(c.weights());
  EXPECT_EQ(w[0], 0.f);
  EXPECT_EQ(w[1], 0.f);
  EXPECT_EQ(w[2], 1.f);  // equal to the threshold: inserted (as in PLUS)
  EXPECT_EQ(w[3], 1.f);
}

TEST(Compound, OutputTypesRoundAndSaturate) {
  const VolumeGrid g = unit_grid(3, 1, 1);
  Compounder c(g, settings(Interpolation::Nearest, CompoundingMode::Mean), Device::cpu(), 0,
               PixelType::Float32);
  const float frame[3] = {-7.6f, 2.5f, 300.4f};
  c.add_image(frame, PixelType::Float32, 3, 1, translation(0, 0, 0));
  const Volume u8 = c.volume(PixelType::UInt8);
  EXPECT_EQ(u8.data_as<uint8_t>()[0], 0);
  EXPECT_EQ(u8.data_as<uint8_t>()[1], 3);
  EXPECT_EQ(u8.data_as<uint8_t>()[2], 255);
  const Volume i16 = c.volume(PixelType::Int16);
  EXPECT_EQ(i16.data_as<int16_t>()[0], -8);
  EXPECT_EQ(i16.data_as<int16_t>()[2], 300);
}

// --- Clip rectangles and fans -----------------------------------------------------------------

TEST(Compound, ClipRectangleKeepsOnlyItsPixels) {
  FrameClip clip;
  clip.x = 2;
  clip.y = 1;
  clip.width = 3;
  clip.height = 2;
  const auto m = clip.mask(8, 6);
  int count = 0;
  for (int y = 0; y < 6; ++y)
    for (int x = 0; x < 8; ++x) {
      const bool inside = x >= 2 && x < 5 && y >= 1 && y < 3;
      EXPECT_EQ(m[y * 8 + x], inside ? 1 : 0);
      count += m[y * 8 + x];
    }
  EXPECT_EQ(count, 6);

  const VolumeGrid g = unit_grid(8, 6, 1);
  Compounder c(g, settings(Interpolation::Nearest, CompoundingMode::Mean));
  const std::vector<uint8_t> frame(48, 9);
  c.add_image(frame.data(), PixelType::UInt8, 8, 6, translation(0, 0, 0), clip);
  const auto w = as_floats(c.weights());
  for (int i = 0; i < 48; ++i) EXPECT_EQ(w[i], m[i] ? 1.f : 0.f);

  // A rectangle reaching past the frame is cut at its edge.
  clip.x = 6;
  clip.width = 10;
  const auto r = clip.rectangle(8, 6);
  EXPECT_EQ(r[0], 6);
  EXPECT_EQ(r[2], 8);
}

TEST(Compound, FanClipFollowsPlusConventions) {
  FrameClip clip;
  clip.fan = true;
  clip.fan_angles_deg[0] = -30;
  clip.fan_angles_deg[1] = 30;
  clip.fan_origin_px[0] = 20;
  clip.fan_origin_px[1] = 2;
  clip.fan_radius_px[0] = 5;
  clip.fan_radius_px[1] = 15;
  const int W = 41, H = 20;
  const auto m = clip.mask(W, H);
  const auto at = [&](int x, int y) { return m[y * W + x]; };
  EXPECT_EQ(at(20, 12), 1);      // on the axis, radius 10
  EXPECT_EQ(at(20, 5), 0);       // radius 3 < start
  EXPECT_EQ(at(20, 7), 1);       // radius 5: inclusive
  EXPECT_EQ(at(20, 17), 1);      // radius 15: inclusive
  EXPECT_EQ(at(20, 18), 0);      // radius 16
  EXPECT_EQ(at(20 + 6, 12), 0);  // 31° off axis
  EXPECT_EQ(at(20 + 5, 12), 1);  // 26.6°
  EXPECT_EQ(at(20, 0), 0);       // above the origin
  // Symmetric about the axis.
  for (int y = 0; y < H; ++y)
    for (int d = 0; d <= 20; ++d) EXPECT_EQ(at(20 + d, y), at(20 - d, y));
}

// --- Hole filling -----------------------------------------------------------------------------

// Inserts single samples (value at voxel) with 1×1 frames, nearest.
Compounder with_known_voxels(const VolumeGrid& g, const std::map<std::array<int, 3>, float>& known,
                             const std::vector<HoleFillingKernel>& kernels) {
  CompoundSettings s = settings(Interpolation::Nearest, CompoundingMode::Mean);
  s.fill_holes = true;
  s.hole_filling = kernels;
  Compounder c(g, s);
  for (const auto& [p, value] : known)
    c.add_image(&value, PixelType::Float32, 1, 1, translation(p[0], p[1], p[2]));
  return c;
}

TEST(HoleFilling, GaussianFillsAHoleInAConstantRegionAndLeavesIsolatedHoles) {
  const VolumeGrid g = unit_grid(7, 7, 7);
  std::map<std::array<int, 3>, float> known;
  for (int z = 0; z < 5; ++z)
    for (int y = 0; y < 5; ++y)
      for (int x = 0; x < 5; ++x)
        if (!(x == 2 && y == 2 && z == 2)) known[{x, y, z}] = 7.f;
  known[{6, 6, 6}] = 90.f;  // a lone sample: its neighbours are holes with 1/27 known
  HoleFillingKernel k;
  k.type = HoleFillingKernel::Gaussian;
  k.size = 3;
  k.stdev = 1;
  k.minimum_known_ratio = 0.5;
  const Compounder c = with_known_voxels(g, known, {k});
  const auto v = as_floats(c.volume(PixelType::Float32));
  EXPECT_FLOAT_EQ(v[offset(g, 2, 2, 2)], 7.f);  // 26 of 27 known
  EXPECT_EQ(v[offset(g, 5, 5, 5)], 0.f);        // 1 of 27 known: not filled
  EXPECT_EQ(v[offset(g, 6, 6, 6)], 90.f);       // known voxels unchanged
  // Edge of the block: (5, 2, 2) has 9 of 27 known (1/3 < 0.5): not filled.
  EXPECT_EQ(v[offset(g, 5, 2, 2)], 0.f);
}

TEST(HoleFilling, GaussianWeightsFavourCloserVoxels) {
  const VolumeGrid g = unit_grid(3, 3, 3);
  std::map<std::array<int, 3>, float> known;
  for (int z = 0; z < 3; ++z)
    for (int y = 0; y < 3; ++y)
      for (int x = 0; x < 3; ++x)
        if (!(x == 1 && y == 1 && z == 1)) known[{x, y, z}] = x == 2 ? 100.f : 0.f;
  HoleFillingKernel k;
  k.type = HoleFillingKernel::Gaussian;
  k.stdev = 0.8;
  k.minimum_known_ratio = 0.5;
  const Compounder c = with_known_voxels(g, known, {k});
  // Known answer: sum over the x = 2 face of 100·w(d) / sum over all 26 of w(d).
  double num = 0, den = 0;
  for (int z = -1; z <= 1; ++z)
    for (int y = -1; y <= 1; ++y)
      for (int x = -1; x <= 1; ++x) {
        if (!x && !y && !z) continue;
        const double w = std::exp(-(x * x + y * y + z * z) / (2 * 0.8 * 0.8));
        den += w;
        if (x == 1) num += 100 * w;
      }
  const auto v = as_floats(c.volume(PixelType::Float32));
  EXPECT_NEAR(v[offset(g, 1, 1, 1)], num / den, 1e-4);
}

TEST(HoleFilling, InverseDistanceAndAccumulationWeights) {
  // A hole at (1, 1, 1) with known voxels at distance 1 (value 10) and sqrt(3) (value 40).
  const VolumeGrid g = unit_grid(3, 3, 3);
  std::map<std::array<int, 3>, float> known{{{2, 1, 1}, 10.f}, {{0, 0, 0}, 40.f}};
  HoleFillingKernel k;
  k.type = HoleFillingKernel::DistanceWeightInverse;
  k.minimum_known_ratio = 0;
  const Compounder dwi = with_known_voxels(g, known, {k});
  const double w1 = 1.0, w3 = 1.0 / std::sqrt(3.0);
  EXPECT_NEAR(as_floats(dwi.volume(PixelType::Float32))[offset(g, 1, 1, 1)],
              (10 * w1 + 40 * w3) / (w1 + w3), 1e-4);
  // Gaussian weights times each voxel's splat weight: a voxel reached twice counts double.
  CompoundSettings s = settings(Interpolation::Nearest, CompoundingMode::Mean);
  s.fill_holes = true;
  k.type = HoleFillingKernel::GaussianAccumulation;
  k.stdev = 1;
  s.hole_filling = {k};
  Compounder acc(g, s);
  const float ten = 10.f, forty = 40.f;
  acc.add_image(&ten, PixelType::Float32, 1, 1, translation(2, 1, 1));
  acc.add_image(&ten, PixelType::Float32, 1, 1, translation(2, 1, 1));
  acc.add_image(&forty, PixelType::Float32, 1, 1, translation(0, 0, 0));
  const double g1 = 2 * std::exp(-1 / 2.0), g3 = std::exp(-3 / 2.0);
  EXPECT_NEAR(as_floats(acc.volume(PixelType::Float32))[offset(g, 1, 1, 1)],
              (10 * g1 + 40 * g3) / (g1 + g3), 1e-4);
}

TEST(HoleFilling, NearestNeighborUsesTheSmallestCubeWithKnownVoxels) {
  const VolumeGrid g = unit_grid(9, 9, 9);
  std::map<std::array<int, 3>, float> known;
  // A shell at distance 2 around (4, 4, 4), two voxels at distance 1.
  for (int z = 2; z <= 6; ++z)
    for (int y = 2; y <= 6; ++y)
      for (int x = 2; x <= 6; ++x)
        if (std::max({std::abs(x - 4), std::abs(y - 4), std::abs(z - 4)}) == 2)
          known[{x, y, z}] = 50.f;
  known[{5, 4, 4}] = 10.f;
  known[{3, 4, 4}] = 20.f;
  HoleFillingKernel k;
  k.type = HoleFillingKernel::NearestNeighbor;
  k.size = 5;
  k.minimum_known_ratio = 0.0;
  const Compounder c = with_known_voxels(g, known, {k});
  const auto v = as_floats(c.volume(PixelType::Float32));
  EXPECT_FLOAT_EQ(v[offset(g, 4, 4, 4)], 15.f);  // radius 1: the two inner voxels
  // (4, 5, 4) sees both inner voxels and the shell at radius 1: the mean of the 9 + 2 known.
  double sum = 10 + 20;
  int n = 2;
  for (int z = 3; z <= 5; ++z)
    for (int x = 3; x <= 5; ++x) {
      sum += 50;
      ++n;
    }
  EXPECT_NEAR(v[offset(g, 4, 5, 4)], sum / n, 1e-4);
}

// PLUS's stick value (vtkIGSIOFillHolesInVolume::applySticks): the forward end weighs
// (back + 1) / (forward + back + 1), the backward end the rest; not the linear interpolation
// back / (forward + back) it approximates.
TEST(HoleFilling, StickWeighsItsEndsAsPlusDoes) {
  const VolumeGrid g = unit_grid(9, 3, 3);
  std::map<std::array<int, 3>, float> known{{{0, 1, 1}, 10.f}, {{4, 1, 1}, 50.f}};
  HoleFillingKernel k;
  k.type = HoleFillingKernel::Stick;
  k.stick_length_limit = 9;
  k.sticks_to_use = 1;
  const Compounder c = with_known_voxels(g, known, {k});
  const auto v = as_floats(c.volume(PixelType::Float32));
  EXPECT_FLOAT_EQ(v[offset(g, 1, 1, 1)], 26.f);  // forward 3, back 1: 0.6·10 + 0.4·50
  EXPECT_FLOAT_EQ(v[offset(g, 2, 1, 1)], 34.f);  // 2 and 2: 0.4·10 + 0.6·50
  EXPECT_FLOAT_EQ(v[offset(g, 3, 1, 1)], 42.f);  // 1 and 3: 0.2·10 + 0.8·50
  // Integer output: each stick's value, then their mean, truncated toward zero (PLUS's casts).
  std::map<std::array<int, 3>, float> odd{{{0, 1, 1}, 10.f}, {{3, 1, 1}, 21.f}};
  const Compounder t = with_known_voxels(g, odd, {k});
  const Volume u8 = t.volume(PixelType::UInt8);
  // (1, 1, 1): forward 2, back 1: 0.5·10 + 0.5·21 = 15.5 → 15; (2, 1, 1): 0.25·10 + 0.75·21.
  EXPECT_EQ(static_cast<const uint8_t*>(u8.data())[offset(g, 1, 1, 1)], 15);
  EXPECT_EQ(static_cast<const uint8_t*>(u8.data())[offset(g, 2, 1, 1)], 18);  // 18.25
  EXPECT_EQ(v[offset(g, 5, 1, 1)], 0.f);                                      // only one known end
  // A stick longer than the limit is not used.
  k.stick_length_limit = 4;
  const Compounder shorter = with_known_voxels(g, known, {k});
  EXPECT_EQ(as_floats(shorter.volume(PixelType::Float32))[offset(g, 2, 1, 1)], 0.f);
}

// PLUS's ratio test counts the known voxels found against the whole size³ cube, also for the
// nearest-neighbour element (whose search stops at the first radius with any): 2 known voxels
// pass 0.01 of 125 but not 0.02 (they would pass 0.02 of the radius-1 cube, 2/27).
TEST(HoleFilling, NearestNeighborRatioIsOverTheWholeCube) {
  const VolumeGrid g = unit_grid(9, 9, 9);
  std::map<std::array<int, 3>, float> known{{{5, 4, 4}, 10.f}, {{3, 4, 4}, 21.f}};
  HoleFillingKernel k;
  k.type = HoleFillingKernel::NearestNeighbor;
  k.size = 5;
  k.minimum_known_ratio = 0.01;
  EXPECT_FLOAT_EQ(
      as_floats(with_known_voxels(g, known, {k}).volume(PixelType::Float32))[offset(g, 4, 4, 4)],
      15.5f);
  // Integer output: truncated, 15 (not rounded to 16).
  EXPECT_EQ(
      static_cast<const uint8_t*>(
          with_known_voxels(g, known, {k}).volume(PixelType::UInt8).data())[offset(g, 4, 4, 4)],
      15);
  k.minimum_known_ratio = 0.02;
  EXPECT_EQ(
      as_floats(with_known_voxels(g, known, {k}).volume(PixelType::Float32))[offset(g, 4, 4, 4)],
      0.f);
}

// Which voxels are holes is PLUS's test: the accumulation buffer (256 per unit of splat weight,
// rounded) is 0. A voxel that a linear splat reaches with a weight below 1/512 is a hole and is
// filled (or emptied); without hole filling it keeps its value.
TEST(HoleFilling, HolesAreWherePlusAccumulationBufferIsZero) {
  const VolumeGrid g = unit_grid(5, 5, 5);
  CompoundSettings s = settings(Interpolation::Linear, CompoundingMode::Mean);
  s.fill_holes = true;
  HoleFillingKernel k;
  k.type = HoleFillingKernel::NearestNeighbor;
  k.size = 3;
  k.minimum_known_ratio = 0.5;  // cannot fill here: the hole stays a hole
  s.hole_filling = {k};
  // One sample at (2.999, 2, 2): voxel (2, 2, 2) gets 0.001 of it (0.256 of 256: rounds to 0),
  // voxel (3, 2, 2) the rest.
  const float sample = 80.f;
  for (bool fill : {true, false}) {
    s.fill_holes = fill;
    Compounder c(g, s);
    c.add_image(&sample, PixelType::Float32, 1, 1, translation(2.999, 2, 2));
    const auto v = as_floats(c.volume(PixelType::Float32));
    // A hole that no element fills: 0, as in PLUS; its own sample without hole filling.
    EXPECT_FLOAT_EQ(v[offset(g, 2, 2, 2)], fill ? 0.f : 80.f) << "fill " << fill;
    EXPECT_FLOAT_EQ(v[offset(g, 3, 2, 2)], 80.f);
  }
}

TEST(HoleFilling, ElementsApplyInOrder) {
  const VolumeGrid g = unit_grid(9, 3, 3);
  std::map<std::array<int, 3>, float> known{{{0, 1, 1}, 10.f}, {{4, 1, 1}, 50.f}};
  HoleFillingKernel gauss;  // cannot fill (too few known voxels)
  gauss.minimum_known_ratio = 0.5;
  HoleFillingKernel stick;
  stick.type = HoleFillingKernel::Stick;
  const Compounder c = with_known_voxels(g, known, {gauss, stick});
  EXPECT_FLOAT_EQ(as_floats(c.volume(PixelType::Float32))[offset(g, 2, 1, 1)], 34.f);
  HoleFillingKernel loose = gauss;  // can fill: wins over the stick
  loose.minimum_known_ratio = 0.0;
  const Compounder d = with_known_voxels(g, known, {loose, stick});
  EXPECT_FLOAT_EQ(as_floats(d.volume(PixelType::Float32))[offset(g, 1, 1, 1)], 10.f);
}

// The CPU driver visits only the holes its whole-grid bit searches say an element may fill
// (src/compound/FillCandidates.cpp); every other voxel must come out as the per-voxel rules of
// FinishImpl.h give it, walking from each hole. Random sparse grids across 64-voxel word
// boundaries, with known voxels on every face, many element kinds and lengths.
TEST(HoleFilling, CpuShortcutsGiveThePerVoxelRulesBits) {
  using namespace compound_impl;
  std::mt19937 rng(7);
  const std::array<std::array<int, 3>, 4> sizes{
      {{70, 9, 11}, {130, 6, 5}, {5, 40, 7}, {64, 3, 33}}};
  HoleFillingKernel stick9, stick3, stick_long, stick2, gauss5, nearest5, inverse3, accum3;
  stick9.type = stick3.type = stick_long.type = stick2.type = HoleFillingKernel::Stick;
  stick3.stick_length_limit = 3;
  stick3.sticks_to_use = 2;
  stick_long.stick_length_limit = 200;  // longer than any grid axis
  stick_long.sticks_to_use = 3;
  stick2.stick_length_limit = 2;  // too short for any stick
  gauss5.size = 5;
  gauss5.minimum_known_ratio = 0.05;
  nearest5.type = HoleFillingKernel::NearestNeighbor;
  nearest5.size = 5;
  nearest5.minimum_known_ratio = 0.01;
  inverse3.type = HoleFillingKernel::DistanceWeightInverse;
  accum3.type = HoleFillingKernel::GaussianAccumulation;
  accum3.minimum_known_ratio = 0;
  const std::vector<std::vector<HoleFillingKernel>> lists{
      {stick9},   {stick3}, {stick_long},           {stick2},        {gauss5}, {nearest5},
      {inverse3}, {accum3}, {nearest5, stick_long}, {gauss5, stick9}};
  int filled = 0;
  for (const auto& n : sizes)
    for (double density : {0.01, 0.08}) {
      std::vector<Accumulator> cells(size_t(n[0]) * n[1] * n[2]);
      std::uniform_real_distribution<double> u(0, 1);
      for (auto& c : cells) {
        const double r = u(rng);
        // Known (weights 1/512 and up), or reached by a weight too small to count, or empty.
        c.weight = r < density ? float(0x1p-9 + 3 * u(rng)) : r < 2 * density ? 0x1p-10f : 0.f;
        c.value = float(200 * u(rng)) * c.weight;
      }
      AccumulatorView g;
      g.nx = n[0];
      g.ny = n[1];
      g.nz = n[2];
      g.cells = cells.data();
      for (const auto& kernels : lists) {
        std::vector<float> out(cells.size());
        finish_volume(g, Mode::Mean, kernels, PixelType::Float32, out.data());
        const FillSetup setup = setup_fill_elements(kernels);
        FinishInput in;
        in.g = g;
        in.elements = setup.elements.data();
        in.element_count = int(setup.elements.size());
        for (int z = 0; z < g.nz; ++z)
          for (int y = 0; y < g.ny; ++y)
            for (int x = 0; x < g.nx; ++x) {
              const float want = finished_voxel<float>(in, x, y, z);
              const float got = out[size_t(g.offset(x, y, z))];
              ASSERT_EQ(std::memcmp(&want, &got, sizeof(float)), 0)
                  << "grid " << n[0] << "x" << n[1] << "x" << n[2] << " density " << density
                  << " element " << int(kernels[0].type) << " at " << x << "," << y << "," << z
                  << ": " << got << " instead of " << want;
              filled += want != 0.f && !is_known(in, g.offset(x, y, z));
            }
      }
    }
  EXPECT_GT(filled, 10000);  // the elements did fill holes
}

// --- An independent float64 oracle -------------------------------------------------------------

struct OracleFrame {
  std::vector<float> samples;  // rows × width
  int rows = 0, width = 0;
  // Position (world mm) of sample u of row r.
  std::function<Vec3(int r, int u)> position;
};

// Splats in double precision. Nearest: voxels a sample could reach with float32 coordinates
// (within 1e-3 voxel of a rounding decision) are marked uncertain. Linear weights are continuous,
// so float32 and float64 differ only by rounding.
struct Oracle {
  std::vector<double> sum, weight;
  std::vector<uint8_t> uncertain;
};

Oracle oracle(const VolumeGrid& g, const std::vector<OracleFrame>& frames, bool linear) {
  Oracle o;
  const size_t n = size_t(g.voxel_count());
  o.sum.assign(n, 0);
  o.weight.assign(n, 0);
  o.uncertain.assign(n, 0);
  for (const auto& f : frames)
    for (int r = 0; r < f.rows; ++r)
      for (int u = 0; u < f.width; ++u) {
        const Vec3 c = g.world_to_index(f.position(r, u));
        const double s = f.samples[size_t(r) * f.width + u];
        if (!linear) {
          int64_t i[3], other[3];  // other: the index across a boundary closer than 1e-3
          bool inside = true;
          for (int a = 0; a < 3; ++a) {
            const double t = c[a] + 0.5;
            i[a] = int64_t(std::floor(t));
            const double frac = t - double(i[a]);
            other[a] = frac < 1e-3 ? i[a] - 1 : (frac > 1 - 1e-3 ? i[a] + 1 : i[a]);
            inside = inside && i[a] >= 0 && i[a] < g.dims[a];
          }
          // float32 coordinates may round the other way: every candidate voxel is uncertain.
          const bool tie = other[0] != i[0] || other[1] != i[1] || other[2] != i[2];
          if (tie)
            for (int k = 0; k < 8; ++k) {
              const int64_t x = (k & 1) ? other[0] : i[0], y = (k & 2) ? other[1] : i[1],
                            z = (k & 4) ? other[2] : i[2];
              if (x >= 0 && y >= 0 && z >= 0 && x < g.dims[0] && y < g.dims[1] && z < g.dims[2])
                o.uncertain[size_t(offset(g, x, y, z))] = 1;
            }
          if (!inside) continue;
          o.sum[size_t(offset(g, i[0], i[1], i[2]))] += s;
          o.weight[size_t(offset(g, i[0], i[1], i[2]))] += 1;
          continue;
        }
        int64_t i[3];
        double fr[3];
        for (int a = 0; a < 3; ++a) {
          i[a] = int64_t(std::floor(c[a]));
          fr[a] = c[a] - double(i[a]);
        }
        for (int k = 0; k < 8; ++k) {
          const int64_t x = i[0] + (k & 1), y = i[1] + ((k >> 1) & 1), z = i[2] + (k >> 2);
          if (x < 0 || y < 0 || z < 0 || x >= g.dims[0] || y >= g.dims[1] || z >= g.dims[2])
            continue;
          const double w = ((k & 1) ? fr[0] : 1 - fr[0]) * ((k & 2) ? fr[1] : 1 - fr[1]) *
                           ((k & 4) ? fr[2] : 1 - fr[2]);
          const size_t v = size_t(offset(g, x, y, z));
          o.sum[v] += w * s;
          o.weight[v] += w;
        }
      }
  return o;
}

// A slow sweep of oblique frames through an oblique grid, random pixel values.
struct Sweep {
  VolumeGrid grid;
  int width = 48, height = 40;
  std::vector<Mat4> poses;
  std::vector<uint8_t> pixels;
};

Sweep make_sweep(int frames, uint32_t seed) {
  Sweep s;
  s.grid = test::oblique_grid({40, 36, 30});
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> value(0, 255);
  s.pixels.resize(size_t(frames) * s.width * s.height);
  for (auto& p : s.pixels) p = uint8_t(value(rng));
  const Vec3 centre = s.grid.index_to_world({{20, 18, 15}});
  for (int f = 0; f < frames; ++f) {
    const Mat3 r = test::rotation({{0.3, 1, 0.2}}, 10 + 1.5 * f);
    const Vec3 ex = r * Vec3{{0.45, 0, 0}}, ey = r * Vec3{{0, 0.5, 0}}, ez = r * Vec3{{0, 0, 1}};
    const Vec3 origin = centre - 24 * ex - 20 * ey + (0.3 * (f - frames / 2.0)) * ez;
    s.poses.push_back(frame_matrix(origin, ex, ey));
  }
  return s;
}

std::vector<OracleFrame> oracle_frames(const Sweep& s) {
  std::vector<OracleFrame> out;
  for (size_t f = 0; f < s.poses.size(); ++f) {
    OracleFrame o;
    o.rows = s.height;
    o.width = s.width;
    const uint8_t* p = s.pixels.data() + f * s.width * s.height;
    o.samples.assign(p, p + s.width * s.height);
    const Mat4 m = s.poses[f];
    o.position = [m](int r, int u) { return m.transform_point({{double(u), double(r), 0.0}}); };
    out.push_back(std::move(o));
  }
  return out;
}

TEST_P(CompoundBackendTest, MatchesTheFloat64Oracle) {
  const Sweep s = make_sweep(24, 7);
  for (bool linear : {false, true}) {
    const Oracle o = oracle(s.grid, oracle_frames(s), linear);
    Compounder c(
        s.grid,
        settings(linear ? Interpolation::Linear : Interpolation::Nearest, CompoundingMode::Mean),
        device());
    c.add_images(s.pixels.data(), PixelType::UInt8, s.width, s.height, int64_t(s.poses.size()),
                 s.poses.data());
    const auto v = as_floats(c.volume(PixelType::Float32));
    const auto w = as_floats(c.weights());
    int64_t reached_total = 0, reached = 0;
    double max_value_error = 0, max_weight_error = 0;
    for (size_t i = 0; i < v.size(); ++i) {
      reached_total += o.weight[i] > 1e-3;
      if (o.uncertain[i]) continue;
      max_weight_error = std::max(max_weight_error, std::fabs(w[i] - o.weight[i]));
      if (o.weight[i] > 1e-3) {
        ++reached;
        max_value_error = std::max(max_value_error, std::fabs(v[i] - o.sum[i] / o.weight[i]));
      }
    }
    SCOPED_TRACE(linear ? "linear" : "nearest");
    EXPECT_GT(reached, 1500);
    EXPECT_GT(reached, reached_total * 3 / 4);  // few voxels left out as uncertain
    EXPECT_LT(max_weight_error, linear ? 1e-3 : 1e-9);
    EXPECT_LT(max_value_error, linear ? 2e-2 : 1e-3);
  }
}

SONOSLICE_INSTANTIATE_BACKENDS(CompoundBackendTest);

// --- Determinism ------------------------------------------------------------------------------

TEST(Compound, BitIdenticalFor1_2And16Threads) {
  const test::ScopedCpuSettings restore;
  const Sweep s = make_sweep(30, 11);
  for (auto mode : {CompoundingMode::Mean, CompoundingMode::Max, CompoundingMode::Latest}) {
    for (auto interp : {Interpolation::Nearest, Interpolation::Linear}) {
      std::vector<std::vector<uint8_t>> results;
      for (int threads : {1, 2, 16}) {
        set_cpu_threads(threads);
        Compounder c(s.grid, settings(interp, mode));
        c.add_images(s.pixels.data(), PixelType::UInt8, s.width, s.height, int64_t(s.poses.size()),
                     s.poses.data());
        const Volume v = c.volume(PixelType::Float32), w = c.weights();
        std::vector<uint8_t> bytes(v.byte_size() + w.byte_size());
        std::memcpy(bytes.data(), v.data(), v.byte_size());
        std::memcpy(bytes.data() + v.byte_size(), w.data(), w.byte_size());
        results.push_back(std::move(bytes));
      }
      EXPECT_TRUE(results[0] == results[1]) << "1 vs 2 threads";
      EXPECT_TRUE(results[0] == results[2]) << "1 vs 16 threads";
    }
  }
}

TEST(Compound, GenericAndAvx2KernelsGiveTheSameBits) {
  const test::ScopedCpuSettings restore;
  try {
    set_cpu_kernel_isa("avx2");
  } catch (const InputError&) {
    GTEST_SKIP() << "no AVX2 kernels on this machine";
  }
  const Sweep s = make_sweep(20, 13);
  for (auto mode : {CompoundingMode::Mean, CompoundingMode::Max, CompoundingMode::Latest}) {
    for (auto interp : {Interpolation::Nearest, Interpolation::Linear}) {
      std::vector<float> results[2];
      for (const char* isa : {"avx2", "generic"}) {
        set_cpu_kernel_isa(isa);
        Compounder c(s.grid, settings(interp, mode));
        c.add_images(s.pixels.data(), PixelType::UInt8, s.width, s.height, int64_t(s.poses.size()),
                     s.poses.data());
        results[isa[0] == 'g'] = as_floats(c.volume(PixelType::Float32));
        const auto w = as_floats(c.weights());
        results[isa[0] == 'g'].insert(results[isa[0] == 'g'].end(), w.begin(), w.end());
      }
      EXPECT_EQ(std::memcmp(results[0].data(), results[1].data(), results[0].size() * 4), 0);
    }
  }
}

// The finishing pass without hole filling (written with selects so that it vectorises) gives, on
// each instruction set and for every output type, what the per-voxel rule gives: accumulators
// that round to ties, saturate both ways, reach ±inf or NaN, and carry weight 0.
TEST(Compound, VectorisedFinishingGivesThePerVoxelRule) {
  using namespace compound_impl;
  const test::ScopedCpuSettings restore;
  std::mt19937 rng(11);
  const float specials[] = {0.f,   0.5f,    -0.5f,    1.5f,      -1.5f,    2.4999998f, 127.5f,
                            128.f, 255.49f, 255.5f,   -128.5f,   32767.5f, -32768.6f,  65535.5f,
                            3e9f,  -3e9f,   INFINITY, -INFINITY, NAN,      1e-30f,     -1e-30f};
  const int n = 4000;
  std::vector<Accumulator> cells(n);
  std::uniform_real_distribution<float> wide(-70000.f, 70000.f), weight(0.f, 4.f);
  for (int i = 0; i < n; ++i) {
    const int kind = i % 4;
    cells[i].value = kind == 0 ? specials[i / 4 % (sizeof(specials) / sizeof(float))] : wide(rng);
    cells[i].weight = kind == 3 ? 0.f : (kind == 0 ? 1.f : weight(rng));
  }
  FinishInput in;
  in.g.nx = 100;
  in.g.ny = 8;
  in.g.nz = 5;
  in.g.cells = cells.data();
  std::vector<std::string> isas{"generic"};
  try {
    set_cpu_kernel_isa("avx2");
    isas.push_back("avx2");
  } catch (const InputError&) {
  }
  for (Mode mode : {Mode::Mean, Mode::Max}) {
    in.mode = mode;
    for (PixelType type :
         {PixelType::UInt8, PixelType::Int8, PixelType::UInt16, PixelType::Int16, PixelType::UInt32,
          PixelType::Int32, PixelType::Float32, PixelType::Float64}) {
      visit_pixel_type(type, [&](auto zero) {
        using T = decltype(zero);
        std::vector<T> expected(n);
        for (int i = 0; i < n; ++i)
          expected[i] = finished_voxel<T>(in, i % 100, i / 100 % 8, i / 800);
        for (const std::string& isa : isas) {
          std::vector<T> got(n);
          finish_values_cpu(isa == "avx2" ? CpuIsa::Avx2 : CpuIsa::Generic, in, type, 0, n,
                            got.data());
          EXPECT_EQ(std::memcmp(got.data(), expected.data(), n * sizeof(T)), 0)
              << isa << " " << to_string(type) << " mode " << int(mode);
        }
      });
    }
  }
}

// Nearest splats of integer frames sum each run of samples in one voxel exactly, in integers
// (SIMD chunks of running sums on AVX2); float frames add sample by sample. For values whose
// sums stay below 2^24 both are exact, so integer frames and the same values as float32 must
// give the same bits, with and without a rejection threshold, on both kernels.
TEST(Compound, NearestIntegerRunSumsEqualTheFloatPath) {
  const test::ScopedCpuSettings restore;
  const Sweep s = make_sweep(12, 17);
  const size_t n = s.pixels.size();
  std::vector<uint16_t> u16(n);
  std::vector<int16_t> i16(n);
  for (size_t i = 0; i < n; ++i) {
    u16[i] = uint16_t(s.pixels[i] * 257);              // up to 65535
    i16[i] = int16_t(int(s.pixels[i]) * 100 - 12000);  // negative and positive
  }
  const auto as_float = [](const auto& v) { return std::vector<float>(v.begin(), v.end()); };
  struct Case {
    PixelType type;
    const void* data;
    std::vector<float> floats;
    double threshold;
  };
  const Case cases[] = {
      {PixelType::UInt8, s.pixels.data(), as_float(s.pixels), -1e30},
      {PixelType::UInt8, s.pixels.data(), as_float(s.pixels), 100.5},
      {PixelType::UInt16, u16.data(), as_float(u16), -1e30},
      {PixelType::UInt16, u16.data(), as_float(u16), 30000},
      {PixelType::Int16, i16.data(), as_float(i16), -1e30},
      {PixelType::Int16, i16.data(), as_float(i16), -10},
  };
  std::vector<std::string> isas = {"generic"};
  try {
    set_cpu_kernel_isa("avx2");
    isas.push_back("avx2");
  } catch (const InputError&) {
  }
  for (const std::string& isa : isas) {
    set_cpu_kernel_isa(isa);
    for (auto mode : {CompoundingMode::Mean, CompoundingMode::Latest}) {
      for (const Case& c : cases) {
        SCOPED_TRACE(isa + " " + to_string(c.type) + " threshold " + std::to_string(c.threshold) +
                     (mode == CompoundingMode::Mean ? " mean" : " latest"));
        CompoundSettings st = settings(Interpolation::Nearest, mode);
        st.rejection_threshold = c.threshold;
        Compounder ints(s.grid, st), floats(s.grid, st);
        ints.add_images(c.data, c.type, s.width, s.height, int64_t(s.poses.size()), s.poses.data());
        floats.add_images(c.floats.data(), PixelType::Float32, s.width, s.height,
                          int64_t(s.poses.size()), s.poses.data());
        const auto a = as_floats(ints.volume(PixelType::Float32));
        const auto b = as_floats(floats.volume(PixelType::Float32));
        const auto wa = as_floats(ints.weights()), wb = as_floats(floats.weights());
        EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * 4), 0);
        EXPECT_EQ(std::memcmp(wa.data(), wb.data(), wa.size() * 4), 0);
        EXPECT_GT(std::count_if(wa.begin(), wa.end(), [](float w) { return w > 0; }), 1000);
      }
    }
  }
}

TEST(Compound, IncrementalFramesGiveTheBatchResult) {
  const Sweep s = make_sweep(20, 5);
  for (auto interp : {Interpolation::Nearest, Interpolation::Linear}) {
    CompoundSettings st = settings(interp, CompoundingMode::Mean);
    st.fill_holes = true;
    Compounder batch(s.grid, st), live(s.grid, st);
    batch.add_images(s.pixels.data(), PixelType::UInt8, s.width, s.height, int64_t(s.poses.size()),
                     s.poses.data());
    const size_t frame = size_t(s.width) * s.height;
    for (size_t f = 0; f < s.poses.size(); ++f) {
      live.add_image(s.pixels.data() + f * frame, PixelType::UInt8, s.width, s.height, s.poses[f]);
      if (f == 9) {  // the volume can be read at any point
        EXPECT_EQ(live.frames_added(), 10);
        (void)live.volume();
      }
    }
    const Volume a = batch.volume(PixelType::Float32), b = live.volume(PixelType::Float32);
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.byte_size()), 0);
  }
}

// --- 3-D beam-space frames
// ------------------------------------------------------------------------

TEST_P(CompoundBackendTest, BeamFramesLandWhereSpec7PutsTheirSamples) {
  BeamGeometry bg;
  bg.n_elevation = 5;
  bg.n_azimuth = 9;
  bg.n_samples = 40;
  bg.r0_mm = 3;
  bg.dr_mm = 0.4;
  bg.azimuth0_deg = -20;
  bg.dazimuth_deg = 5;
  bg.elevation0_deg = -8;
  bg.delevation_deg = 4;
  bg.apex_offset_mm = 2;
  const Mat4 pose = frame_matrix({{1, 2, 3}}, test::rotation({{1, 0.2, 0.1}}, 25) * Vec3{{1, 0, 0}},
                                 test::rotation({{1, 0.2, 0.1}}, 25) * Vec3{{0, 1, 0}});
  const VolumeGrid grid = Compounder::grid_around_beams({pose}, bg, 0.7);
  std::vector<float> samples(size_t(bg.n_elevation) * bg.n_azimuth * bg.n_samples);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> value(0, 100);
  for (auto& x : samples) x = value(rng);
  OracleFrame of;
  of.rows = bg.n_elevation * bg.n_azimuth;
  of.width = bg.n_samples;
  of.samples = samples;
  of.position = [&](int r, int s) {
    const double a = (bg.azimuth0_deg + (r % bg.n_azimuth) * bg.dazimuth_deg) * M_PI / 180;
    const double e = (bg.elevation0_deg + (r / bg.n_azimuth) * bg.delevation_deg) * M_PI / 180;
    const double d = bg.r0_mm + s * bg.dr_mm;
    const Vec3 p{{d * std::sin(a), -bg.apex_offset_mm + d * std::cos(a) * std::cos(e),
                  d * std::cos(a) * std::sin(e)}};
    return pose.transform_point(p);
  };
  // The grid encloses every sample.
  for (int r = 0; r < of.rows; ++r)
    for (int s : {0, bg.n_samples - 1}) {
      const Vec3 c = grid.world_to_index(of.position(r, s));
      for (int a = 0; a < 3; ++a) {
        EXPECT_GE(c[a], -1e-6);
        EXPECT_LE(c[a], grid.dims[a] - 1 + 0.5 + 1e-6);
      }
    }
  const Oracle o = oracle(grid, {of}, false);
  Compounder c(grid, settings(Interpolation::Nearest, CompoundingMode::Mean), device());
  c.add_beams(samples.data(), PixelType::Float32, bg, pose);
  const auto v = as_floats(c.volume(PixelType::Float32));
  const auto w = as_floats(c.weights());
  int64_t reached = 0;
  for (size_t i = 0; i < v.size(); ++i) {
    if (o.uncertain[i]) continue;
    EXPECT_EQ(w[i], o.weight[i]);
    if (o.weight[i] > 0) {
      ++reached;
      EXPECT_NEAR(v[i], o.sum[i] / o.weight[i], 1e-3);
    }
  }
  EXPECT_GT(reached, 500);
}

// --- Round trip through the slicer -------------------------------------------------------------

TEST(Compound, RoundTripThroughTheSlicerRecoversTheVolume) {
  // A smooth volume, sliced by a linear probe along a dense sweep and compounded back.
  VolumeGrid grid = unit_grid(60, 50, 40, 0.8);
  grid.origin_mm = {{-24, -5, -16}};
  const auto f = [](const Vec3& p) {
    return 100 + 40 * std::sin(p[0] / 7.0) * std::cos(p[1] / 9.0) + 0.8 * p[2];
  };
  const Volume volume = test::make_volume<float>(grid, f);
  ProbeGeometry probe;
  probe.type = ProbeType::Linear;
  probe.image.width = 120;
  probe.image.height = 90;
  probe.image.spacing_mm[0] = probe.image.spacing_mm[1] = 0.3;
  probe.image.set_default_origin();
  std::vector<Pose> poses;
  for (int k = 0; k < 100; ++k) {
    const Mat3 tilt = test::rotation({{1, 0, 0}}, 5.0 * std::sin(k * 0.05));
    poses.push_back(test::make_pose(tilt, {{0.0, 2.0, -13.0 + 0.26 * k}}));
  }
  Slicer slicer(volume, probe);
  const std::vector<float> images = slicer.slice<float>(poses);
  std::vector<Mat4> image_to_reference;
  for (const Pose& p : poses)
    image_to_reference.push_back(
        p * frame_matrix({{probe.image.origin_mm[0], probe.image.origin_mm[1], 0}}, {{0.3, 0, 0}},
                         {{0, 0.3, 0}}));
  Compounder c(grid, settings(Interpolation::Linear, CompoundingMode::Mean), Device::cpu(), 0,
               PixelType::Float32);
  c.add_images(images.data(), PixelType::Float32, probe.image.width, probe.image.height,
               int64_t(poses.size()), image_to_reference.data());
  const auto v = as_floats(c.volume(PixelType::Float32));
  const auto w = as_floats(c.weights());
  const float* original = volume.data_as<float>();
  double max_error = 0, sum_error = 0;
  int64_t covered = 0;
  // Interior voxels: samples on every side (at the edge of the covered region the splat's mean
  // leans towards the side the samples came from).
  const auto interior = [&](int64_t x, int64_t y, int64_t z) {
    for (int64_t dz = -1; dz <= 1; ++dz)
      for (int64_t dy = -1; dy <= 1; ++dy)
        for (int64_t dx = -1; dx <= 1; ++dx) {
          const int64_t px = x + dx, py = y + dy, pz = z + dz;
          if (px < 0 || py < 0 || pz < 0 || px >= grid.dims[0] || py >= grid.dims[1] ||
              pz >= grid.dims[2] || w[size_t(offset(grid, px, py, pz))] < 1)
            return false;
        }
    return true;
  };
  for (size_t i = 0; i < v.size(); ++i) {
    if (!interior(int64_t(i) % 60, int64_t(i) / 60 % 50, int64_t(i) / 3000)) continue;
    ++covered;
    const double e = std::fabs(v[i] - original[i]);
    max_error = std::max(max_error, e);
    sum_error += e;
  }
  // Range of f is about 80; the splat blurs by under a voxel.
  EXPECT_GT(covered, 20000);
  EXPECT_LT(sum_error / double(covered), 0.25);
  EXPECT_LT(max_error, 2.0);
}

// --- Grids, memory and bad input ---------------------------------------------------------------

TEST(Compound, GridAroundFollowsPlusRule) {
  // Pixels of 0.1 mm; the clip rectangle's corner pixel centres set the box.
  const Mat4 a = frame_matrix({{5, 6, 7}}, {{0.1, 0, 0}}, {{0, 0.1, 0}});
  const Mat4 b = frame_matrix({{5, 6, 9.6}}, {{0.1, 0, 0}}, {{0, 0.1, 0}});
  const VolumeGrid g = Compounder::grid_around({a, b}, 101, 51, FrameClip{}, 0.5);
  EXPECT_NEAR(g.origin_mm[0], 5, 1e-12);
  EXPECT_NEAR(g.origin_mm[1], 6, 1e-12);
  EXPECT_NEAR(g.origin_mm[2], 7, 1e-12);
  EXPECT_EQ(g.dims[0], 21);  // round(10 / 0.5) + 1
  EXPECT_EQ(g.dims[1], 11);
  EXPECT_EQ(g.dims[2], 6);  // round(2.6 / 0.5) + 1 = round(5.2) + 1
  FrameClip clip;
  clip.x = 10;
  clip.y = 20;
  clip.width = 51;   // pixels 10 .. 60
  clip.height = 11;  // rows 20 .. 30
  const VolumeGrid c = Compounder::grid_around({a}, 101, 51, clip, 0.5);
  EXPECT_NEAR(c.origin_mm[0], 6, 1e-12);
  EXPECT_NEAR(c.origin_mm[1], 8, 1e-12);
  EXPECT_EQ(c.dims[0], 11);
  EXPECT_EQ(c.dims[1], 3);
}

TEST(Compound, GridAroundFitsAsEachPlusVersion) {
  // Corners from (5.05, 6.2, 7.3) to (15.05, 11.2, 9.9) mm, spacing 0.5.
  const Mat4 a = frame_matrix({{5.05, 6.2, 7.3}}, {{0.1, 0, 0}}, {{0, 0.1, 0}});
  const Mat4 b = frame_matrix({{5.05, 6.2, 9.9}}, {{0.1, 0, 0}}, {{0, 0.1, 0}});
  using Fit = Compounder::GridFit;
  const Vec3 s{{0.5, 0.5, 0.5}};
  const VolumeGrid round = Compounder::grid_around({a, b}, 101, 51, FrameClip{}, s, Fit::Round);
  const VolumeGrid legacy =
      Compounder::grid_around({a, b}, 101, 51, FrameClip{}, s, Fit::PlusLegacy);
  const VolumeGrid lattice =
      Compounder::grid_around({a, b}, 101, 51, FrameClip{}, s, Fit::PlusLattice);
  // z: min 7.3, max 9.9, 2.6 / 0.5 = 5.2.
  EXPECT_NEAR(round.origin_mm[2], 7.3, 1e-12);
  EXPECT_EQ(round.dims[2], 6);  // round(5.2) + 1
  EXPECT_NEAR(legacy.origin_mm[2], 7.3, 1e-12);
  EXPECT_EQ(legacy.dims[2], 6);                   // int(5.2) + 1
  EXPECT_NEAR(lattice.origin_mm[2], 7.0, 1e-12);  // floor(7.3 / 0.5) · 0.5
  EXPECT_EQ(lattice.dims[2], 7);                  // ceil((9.9 - 7) / 0.5) + 1 = ceil(5.8) + 1
  // x: min 5.05, max 15.05: 20 steps exactly for round and legacy; the lattice starts at 5.0.
  EXPECT_EQ(legacy.dims[0], 21);
  EXPECT_NEAR(lattice.origin_mm[0], 5.0, 1e-12);
  EXPECT_EQ(lattice.dims[0], 22);  // ceil(10.05 / 0.5) + 1
  // y: min 6.2, max 6.2 + 50 · 0.1: (max - min) / 0.5 is 10 less an ulp in double, so PLUS 2.x's
  // int() gives 9 steps where round() gives 10 (NWire's 104 rows against 105); lattice from 6.0.
  EXPECT_EQ(round.dims[1], 11);
  EXPECT_EQ(legacy.dims[1], 10);
  EXPECT_NEAR(lattice.origin_mm[1], 6.0, 1e-12);
  EXPECT_EQ(lattice.dims[1], 12);  // ceil(5.2 / 0.5) + 1
  // A box of 2.8 steps: round gives 4 voxels, legacy 3.
  const Mat4 c = frame_matrix({{5.05, 6.2, 8.7}}, {{0.1, 0, 0}}, {{0, 0.1, 0}});
  EXPECT_EQ(Compounder::grid_around({a, c}, 101, 51, FrameClip{}, s, Fit::Round).dims[2], 4);
  EXPECT_EQ(Compounder::grid_around({a, c}, 101, 51, FrameClip{}, s, Fit::PlusLegacy).dims[2], 3);
}

TEST(Compound, TooBigAGridStopsWithASizeAndASpacingThatFits) {
  VolumeGrid g = unit_grid(2000, 2000, 1000, 0.1);
  try {
    Compounder c(g, CompoundSettings{}, Device::cpu(), uint64_t(1) << 30);
    FAIL() << "no error";
  } catch (const ResourceError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("2000x2000x1000"), std::string::npos) << m;
    EXPECT_NE(m.find("GiB"), std::string::npos) << m;
    EXPECT_NE(m.find("a spacing of"), std::string::npos) << m;
    EXPECT_EQ(m.find('\n'), std::string::npos);
    // The suggested spacing does fit.
    const double s = std::stod(m.substr(m.find("a spacing of") + 13));
    VolumeGrid h = g;
    for (int a = 0; a < 3; ++a) {
      h.dims[a] = int64_t(std::round((g.dims[a] - 1) * 0.1 / s)) + 1;
      h.spacing_mm[a] = s;
    }
    EXPECT_LE(compounding_memory_bytes(h, CompoundSettings{}, PixelType::UInt8), uint64_t(1) << 30);
  }
}

TEST(Compound, BadInputIsRejectedWithAClearMessage) {
  const VolumeGrid g = unit_grid(4, 4, 4);
  Compounder c(g, CompoundSettings{});
  const uint8_t px[4] = {1, 2, 3, 4};
  Mat4 nan = translation(0, 0, 0);
  nan.m[1][2] = std::nan("");
  EXPECT_THROW(c.add_image(px, PixelType::UInt8, 2, 2, nan), InputError);
  Mat4 projective = translation(0, 0, 0);
  projective.m[3][0] = 1;
  EXPECT_THROW(c.add_image(px, PixelType::UInt8, 2, 2, projective), InputError);
  EXPECT_THROW(c.add_image(px, PixelType::UInt8, 0, 2, translation(0, 0, 0)), InputError);
  BeamGeometry bg;  // zero sizes
  EXPECT_THROW(c.add_beams(px, PixelType::UInt8, bg, translation(0, 0, 0)), InputError);
  FrameClip fan;
  fan.fan = true;
  fan.fan_angles_deg[0] = -95;
  EXPECT_THROW(c.add_image(px, PixelType::UInt8, 2, 2, translation(0, 0, 0), fan), InputError);
  CompoundSettings bad;
  bad.hole_filling[0].size = 4;
  EXPECT_THROW(Compounder(g, bad), InputError);
  EXPECT_THROW(parse_compounding_mode("median"), InputError);
  EXPECT_THROW(parse_interpolation("cubic"), InputError);
  EXPECT_EQ(c.frames_added(), 0);  // nothing went in
  // Frames entirely outside the grid are accepted and change nothing.
  c.add_image(px, PixelType::UInt8, 2, 2, translation(100, 100, 100));
  const auto w = as_floats(c.weights());
  for (float x : w) EXPECT_EQ(x, 0.f);
}

TEST(Compound, OtherSampleTypesAreConvertedNotRejected) {
  const VolumeGrid g = unit_grid(2, 1, 1);
  Compounder c(g, settings(Interpolation::Nearest, CompoundingMode::Mean));
  const double px[2] = {1.5, -2.25};
  c.add_image(px, PixelType::Float64, 2, 1, translation(0, 0, 0));
  const auto v = as_floats(c.volume(PixelType::Float32));
  EXPECT_FLOAT_EQ(v[0], 1.5f);
  EXPECT_FLOAT_EQ(v[1], -2.25f);
}

// --plus-exact (docs/compounding.md §4b): PLUS's integer updates, worked out by hand from
// vtkNearestNeighborInterpolation and vtkTrilinearInterpolation.
std::vector<uint8_t> plus_exact_voxel(Interpolation interp, CompoundingMode mode,
                                      const std::vector<uint8_t>& samples, const Vec3& at,
                                      std::vector<float>* buffer = nullptr,
                                      PlusOptimization path = PlusOptimization::None) {
  CompoundSettings s = settings(interp, mode);
  s.plus_exact = true;
  s.plus_optimization = path;
  Compounder c(unit_grid(4, 4, 4), s);
  std::vector<uint8_t> after;
  for (uint8_t v : samples) {
    c.add_image(&v, PixelType::UInt8, 1, 1, translation(at[0], at[1], at[2]));
    after.push_back(c.volume(PixelType::UInt8).data_as<uint8_t>()[offset(c.grid(), 1, 1, 1)]);
    if (buffer) buffer->push_back(c.weights().data_as<float>()[offset(c.grid(), 1, 1, 1)] * 256);
  }
  return after;
}

TEST(PlusExact, NearestMeanTruncatesEachUpdate) {
  // (100·256 + 0)/256 = 100; (51·256 + 100·256)/512 = 75.5 → 75; (0 + 75·512)/768 = 50.
  std::vector<float> buffer;
  EXPECT_EQ(plus_exact_voxel(Interpolation::Nearest, CompoundingMode::Mean, {100, 51, 0},
                             {{1.2, 0.9, 1.0}}, &buffer),
            (std::vector<uint8_t>{100, 75, 50}));
  EXPECT_EQ(buffer, (std::vector<float>{256, 512, 768}));
  // The default (float) mode keeps the mean: (100 + 51 + 0) / 3 = 50.33 → 50, after two 75.5 → 76.
  Compounder c(unit_grid(4, 4, 4), settings(Interpolation::Nearest, CompoundingMode::Mean));
  for (uint8_t v : {uint8_t(100), uint8_t(51)})
    c.add_image(&v, PixelType::UInt8, 1, 1, translation(1.2, 0.9, 1.0));
  EXPECT_EQ(c.volume(PixelType::UInt8).data_as<uint8_t>()[offset(c.grid(), 1, 1, 1)], 76);
}

TEST(PlusExact, NearestMaxAndLatestCountEveryPixelInTheBuffer) {
  std::vector<float> buffer;
  EXPECT_EQ(plus_exact_voxel(Interpolation::Nearest, CompoundingMode::Max, {30, 90, 60},
                             {{1, 1, 1}}, &buffer),
            (std::vector<uint8_t>{30, 90, 90}));
  EXPECT_EQ(buffer, (std::vector<float>{256, 512, 768}));
  EXPECT_EQ(
      plus_exact_voxel(Interpolation::Nearest, CompoundingMode::Latest, {30, 90, 60}, {{1, 1, 1}}),
      (std::vector<uint8_t>{30, 90, 60}));
}

TEST(PlusExact, LinearMeanRoundsTheVoxelAndTheBufferAfterEveryUpdate) {
  // A sample at (1.5, 1, 1): corner (1,1,1) weight f = 0.5. First: out = Round(0.5·200/0.5) =
  // 200, buffer Round(0.5·256) = 128. Second (value 101): r = 0.5, a = 1, out =
  // Round((0.5·101 + 0.5·200)/1) = Round(150.5) = 151, buffer 256. Third (value 0): r = 1,
  // a = 1.5, out = Round(151/1.5) = Round(100.67) = 101.
  std::vector<float> buffer;
  EXPECT_EQ(plus_exact_voxel(Interpolation::Linear, CompoundingMode::Mean, {200, 101, 0},
                             {{1.5, 1, 1}}, &buffer),
            (std::vector<uint8_t>{200, 151, 101}));
  EXPECT_EQ(buffer, (std::vector<float>{128, 256, 384}));
}

TEST(PlusExact, LinearMaxTakesASampleOnlyAtWeightOneEighthAndSetsTheBuffer) {
  // At (0.1, 1, 1) the corner (1,1,1) has weight 0.1 < 1/8: the voxel stays empty.
  EXPECT_EQ(plus_exact_voxel(Interpolation::Linear, CompoundingMode::Max, {200}, {{0.1, 1, 1}}),
            (std::vector<uint8_t>{0}));
  // At (1.25, 1, 1) the weight is 0.75: the value is taken and the buffer set to
  // Round(0.75·256) = 192 each time, not accumulated.
  std::vector<float> buffer;
  EXPECT_EQ(plus_exact_voxel(Interpolation::Linear, CompoundingMode::Max, {50, 40}, {{1.25, 1, 1}},
                             &buffer),
            (std::vector<uint8_t>{50, 50}));
  EXPECT_EQ(buffer, (std::vector<float>{192, 192}));
}

// IGSIO's fixed.h: value × 2^14 in an int; fixed(double) rounds half to even.
TEST(PlusExact, FixedPointIsIgsioFixed) {
  using compound_impl::plus_exact::Fixed;
  using compound_impl::plus_exact::fixed_from;
  using compound_impl::plus_exact::fixed_from_int;
  EXPECT_EQ(fixed_from(0.125).i, 2048);
  EXPECT_EQ(fixed_from(-1.0).i, -16384);
  EXPECT_EQ(fixed_from(0.5 / 16384).i, 0);  // ties to even
  EXPECT_EQ(fixed_from(1.5 / 16384).i, 2);
  EXPECT_EQ(fixed_from(-37.3).i, int(std::lround(-37.3 * 16384)));
  EXPECT_EQ(fixed_from_int(-3).i, -3 * 16384);
  // fast_multiply rounds: 0.3 × 0.7 = 0.21 → (4915 · 11469 + 8192) >> 14 = 3441.
  EXPECT_EQ((fixed_from(0.3) * fixed_from(0.7)).i, (4915 * 11469 + 8192) >> 14);
  EXPECT_EQ((7 * fixed_from(0.25)).i, 7 * 4096);
  EXPECT_EQ((fixed_from(1.0) / fixed_from(3.0)).i, 5461);
}

// vtkUltraFindExtent's row extent is exactly the pixels whose rounded position is inside the
// volume (for rows that cross it once), in double and in fixed point.
template <typename F>
void check_row_extents() {
  using compound_impl::plus_exact::fixed_from;
  using compound_impl::plus_exact::round_position;
  using compound_impl::plus_exact::RowExtent;
  const auto as_f = [](double v) {
    if constexpr (std::is_same<F, double>::value)
      return v;
    else
      return fixed_from(v);
  };
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> pos(-20, 45), step(-0.6, 0.6);
  const int vmin[3] = {0, 0, 0}, vmax[3] = {19, 24, 29}, pixels[2] = {0, 199};
  int rows_inside = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    F point[3], axis[3];
    for (int a = 0; a < 3; ++a) {
      point[a] = as_f(pos(rng));
      axis[a] = as_f(step(rng));
    }
    RowExtent<F> e{point, axis, vmin, vmax, pixels, {1, 1, 1}};
    int start, end;
    e.find(start, end);
    int first = -1, last = -2;
    for (int x = pixels[0]; x <= pixels[1]; ++x) {
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        const int i = round_position(point[a] + RowExtent<F>::step_of(x, axis[a]));
        inside = inside && i >= vmin[a] && i <= vmax[a];
      }
      if (!inside) continue;
      if (first < 0) first = x;
      last = x;
    }
    if (first < 0) {
      // A row that misses the volume can come back as one pixel (IGSIO's search stops on the
      // row's first pixel); PLUS writes it unchecked, PlusExact.cpp skips it.
      EXPECT_LE(end - start, 0) << "trial " << trial;
    } else {
      ++rows_inside;
      EXPECT_EQ(start, first) << "trial " << trial;
      EXPECT_EQ(end, last) << "trial " << trial;
    }
  }
  EXPECT_GT(rows_inside, 400);
}
TEST(PlusExact, RowExtentIsThePixelsInsideTheVolume) {
  check_row_extents<double>();
  check_row_extents<compound_impl::plus_exact::Fixed>();
}

TEST(PlusExact, OptimizedPathsSetTheBufferForMaxAndFollowFixedPoint) {
  // PARTIAL and FULL nearest MAXIMUM set the buffer to 256 where NONE adds 256.
  for (PlusOptimization path : {PlusOptimization::Partial, PlusOptimization::Full}) {
    std::vector<float> buffer;
    EXPECT_EQ(plus_exact_voxel(Interpolation::Nearest, CompoundingMode::Max, {30, 90, 60},
                               {{1, 1, 1}}, &buffer, path),
              (std::vector<uint8_t>{30, 90, 90}));
    EXPECT_EQ(buffer, (std::vector<float>{256, 256, 256}));
  }
  // Linear MEAN at (1.3, 1, 1), corner (1,1,1). PARTIAL is NONE's double arithmetic:
  // f = 0.7, out = Round(0.7·200/0.7) = 200, buffer Round(0.7·256) = Round(179.2) = 179; then
  // r = 179/256, a = 0.7 + r, out = Round((0.7·101 + r·200)/a) = Round(150.47) = 150.
  std::vector<float> partial;
  EXPECT_EQ(plus_exact_voxel(Interpolation::Linear, CompoundingMode::Mean, {200, 101},
                             {{1.3, 1, 1}}, &partial, PlusOptimization::Partial),
            (std::vector<uint8_t>{200, 150}));
  EXPECT_EQ(partial, (std::vector<float>{179, 358}));
  // FULL: the position 1.3 is 21299/16384, the weight 1 - 4915/16384 = 11469/16384 (0.70001),
  // whose buffer is Round(11469/64) = Round(179.2) = 179 too; the second mean is
  // fixed((11469·101 + 11456·200) / (11469 + 11456)) = 150.47 → 150.
  std::vector<float> full;
  EXPECT_EQ(plus_exact_voxel(Interpolation::Linear, CompoundingMode::Mean, {200, 101},
                             {{1.3, 1, 1}}, &full, PlusOptimization::Full),
            (std::vector<uint8_t>{200, 150}));
  EXPECT_EQ(full, (std::vector<float>{179, 358}));
}

TEST(PlusExact, RefusesWhatPlusCannotDo) {
  CompoundSettings s;
  s.plus_exact = true;
  Compounder c(unit_grid(4, 4, 4), s);
  const double d = 1.0;
  EXPECT_THROW(c.add_image(&d, PixelType::Float64, 1, 1, translation(1, 1, 1)), InputError);
  BeamGeometry g;
  g.n_elevation = g.n_azimuth = g.n_samples = 1;
  const uint8_t b = 1;
  EXPECT_THROW(c.add_beams(&b, PixelType::UInt8, g, translation(1, 1, 1)), InputError);
  const uint8_t v = 5;
  c.add_image(&v, PixelType::UInt8, 1, 1, translation(1, 1, 1));
  EXPECT_THROW((void)c.volume(PixelType::Float32), InputError);  // PLUS's volume is uint8 here
}

}  // namespace
}  // namespace sonoslice
