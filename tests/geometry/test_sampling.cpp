// docs/conventions.md §5 as every capability reads a volume (src/geometry/Sampling.h): the inside
// test of both edge rules, trilinear values and gradients on a linear ramp (exact), the corners
// and weights, and nearest's rounding and clamp.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "../../src/geometry/Sampling.h"

namespace sonoslice {
namespace {

using geometry::EdgeRule;
using geometry::VolumeView;

/// A 4 × 3 × 5 volume holding the ramp v = 1 + 2x + 3y + 5z at voxel (x, y, z).
struct Ramp {
  VolumeView view = VolumeView::of(4, 3, 5);
  std::vector<double> v;
  Ramp() {
    for (int z = 0; z < 5; ++z)
      for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 4; ++x) v.push_back(1 + 2 * x + 3 * y + 5 * z);
  }
  static double at(double x, double y, double z) { return 1 + 2 * x + 3 * y + 5 * z; }
};

TEST(Sampling, ClampedInsideTestIsItksIsInsideBuffer) {
  const VolumeView g = VolumeView::of(4, 3, 5);
  EXPECT_TRUE(geometry::inside(g, -0.5, 0.0, 0.0));
  EXPECT_FALSE(geometry::inside(g, -0.5001, 0.0, 0.0));
  EXPECT_TRUE(geometry::inside(g, 3.4999, 1.0, 1.0));
  EXPECT_FALSE(geometry::inside(g, 3.5, 1.0, 1.0));
  EXPECT_FALSE(geometry::inside(g, 1.0, 2.5, 1.0));
  EXPECT_TRUE(geometry::inside(g, 1.0, 1.0, 4.4));
  EXPECT_FALSE(geometry::inside(g, std::nan(""), 1.0, 1.0));
  EXPECT_FALSE(geometry::inside(g, 1.0f, std::numeric_limits<float>::quiet_NaN(), 1.0f));
}

TEST(Sampling, InteriorInsideTestKeepsWholeCells) {
  const VolumeView g = VolumeView::of(4, 3, 5);
  EXPECT_TRUE(geometry::inside<EdgeRule::Interior>(g, 0.0, 0.0, 0.0));
  EXPECT_TRUE(geometry::inside<EdgeRule::Interior>(g, 3.0, 2.0, 4.0));
  EXPECT_FALSE(geometry::inside<EdgeRule::Interior>(g, -0.25, 1.0, 1.0));  // in the clamped rim
  EXPECT_FALSE(geometry::inside<EdgeRule::Interior>(g, 3.25, 1.0, 1.0));
  EXPECT_FALSE(geometry::inside<EdgeRule::Interior>(g, std::nan(""), 1.0, 1.0));
  // One voxel along an axis: no cell, nothing inside.
  EXPECT_FALSE(geometry::inside<EdgeRule::Interior>(VolumeView::of(4, 1, 5), 1.0, 0.0, 1.0));
  EXPECT_TRUE(geometry::inside(VolumeView::of(4, 1, 5), 1.0, 0.0, 1.0));
}

// Trilinear reproduces a linear function exactly inside the voxel centres, for both rules; in the
// clamped rim the value is held at the face.
TEST(Sampling, LinearIsExactOnARampAndClampedInTheRim) {
  const Ramp r;
  for (double x : {0.0, 0.3, 1.5, 2.75, 3.0})
    for (double y : {0.0, 0.6, 2.0})
      for (double z : {0.0, 1.25, 4.0}) {
        const double want = Ramp::at(x, y, z);
        EXPECT_NEAR(geometry::sample_linear(r.v.data(), r.view, x, y, z), want, 1e-12);
        const auto cell = geometry::linear_cell<EdgeRule::Interior>(r.view, x, y, z);
        EXPECT_NEAR(geometry::linear_value<double>(r.v.data(), cell), want, 1e-12);
      }
  EXPECT_NEAR(geometry::sample_linear(r.v.data(), r.view, -0.4, 1.0, 1.0), Ramp::at(0, 1, 1),
              1e-12);
  EXPECT_NEAR(geometry::sample_linear(r.v.data(), r.view, 3.4, 1.0, 1.0), Ramp::at(3, 1, 1), 1e-12);
  // A callable voxel source (host code reading any pixel type) gives the same value.
  const auto read = [&](int64_t i) { return r.v[size_t(i)]; };
  EXPECT_EQ(geometry::sample_linear(read, r.view, 1.3, 0.7, 2.2),
            geometry::sample_linear(r.v.data(), r.view, 1.3, 0.7, 2.2));
}

// The gradient along each index axis is the ramp's slope inside; the interior rule keeps it at
// the last voxel centre (the last whole cell), the clamped rule gives 0 across a clamped face.
TEST(Sampling, GradientIsTheSlopeAndZeroAcrossAClampedFace) {
  const Ramp r;
  const std::array<double, 3> points[] = {{1.2, 0.5, 2.7}, {3.0, 2.0, 4.0}};
  for (const auto& c : points) {
    double g[3];
    const auto cell = geometry::linear_cell<EdgeRule::Interior>(r.view, c[0], c[1], c[2]);
    EXPECT_NEAR(geometry::linear_value_gradient<double>(r.v.data(), cell, g),
                Ramp::at(c[0], c[1], c[2]), 1e-12);
    EXPECT_NEAR(g[0], 2, 1e-12);
    EXPECT_NEAR(g[1], 3, 1e-12);
    EXPECT_NEAR(g[2], 5, 1e-12);
  }
  double g[3];
  const auto rim = geometry::linear_cell(r.view, 3.25, 0.5, 2.5);
  EXPECT_NEAR(geometry::linear_value_gradient<double>(r.v.data(), rim, g), Ramp::at(3, 0.5, 2.5),
              1e-12);
  EXPECT_EQ(g[0], 0.0);
  EXPECT_NEAR(g[1], 3, 1e-12);
  EXPECT_NEAR(g[2], 5, 1e-12);
}

// The corners and weights are the transpose of the value: Σ w·v is the value, Σ w is 1, and
// clamped corners coincide.
TEST(Sampling, CornersAndWeightsReproduceTheValue) {
  const Ramp r;
  const std::array<double, 3> points[] = {{1.2, 0.5, 2.7}, {-0.3, 2.2, 4.1}};
  for (const auto& c : points) {
    const auto cell = geometry::linear_cell(r.view, c[0], c[1], c[2]);
    int64_t offset[8];
    double weight[8];
    geometry::linear_corners(cell, offset, weight);
    double value = 0, total = 0;
    for (int q = 0; q < 8; ++q) {
      ASSERT_GE(offset[q], 0);
      ASSERT_LT(offset[q], int64_t(r.v.size()));
      value += weight[q] * r.v[size_t(offset[q])];
      total += weight[q];
    }
    EXPECT_NEAR(total, 1.0, 1e-12);
    EXPECT_NEAR(value, geometry::linear_value<double>(r.v.data(), cell), 1e-12);
  }
  const auto clamped = geometry::linear_cell(r.view, -0.3, 2.2, 1.0);
  int64_t offset[8];
  double weight[8];
  geometry::linear_corners(clamped, offset, weight);
  EXPECT_EQ(offset[0], offset[1]);  // x clamped onto voxel 0
}

TEST(Sampling, NearestRoundsHalfUpAndStaysInTheVolume) {
  const VolumeView g = VolumeView::of(4, 3, 5);
  EXPECT_EQ(geometry::nearest_offset(g, -0.5, 0.0, 0.0), 0);
  EXPECT_EQ(geometry::nearest_offset(g, 0.49, 0.0, 0.0), 0);
  EXPECT_EQ(geometry::nearest_offset(g, 0.5, 0.0, 0.0), 1);
  EXPECT_EQ(geometry::nearest_offset(g, 1.0, 1.5, 2.0), 1 + 2 * 4 + 2 * 12);
  // Just below the upper face: the last voxel.
  const float below = std::nextafter(3.5f, 0.0f);
  ASSERT_TRUE(geometry::inside(g, below, 0.f, 0.f));
  EXPECT_EQ(geometry::nearest_offset(g, below, 0.f, 0.f), 3);
}

}  // namespace
}  // namespace sonoslice
