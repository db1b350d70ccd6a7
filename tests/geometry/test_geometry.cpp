// Probe shapes (docs/conventions.md §3), poses (docs/conventions.md §2) and volume grids
// (docs/conventions.md §1).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/geometry/VolumeGrid.h"
#include "sonoslice/phantom/Workloads.h"

namespace sonoslice {
namespace {

ProbeGeometry w1_fan() {
  return workload_w1_fan_probe();
}

// The mask, recomputed here from the docs/conventions.md §3 wording with polar coordinates about
// the apex.
TEST(ProbeMask, CurvilinearMatchesSpecFormula) {
  for (const double sector : {36.0, 70.0, 110.0}) {
    ProbeGeometry p = w1_fan();
    p.sector_deg = sector;
    const auto mask = p.mask();
    ASSERT_EQ(mask.size(), size_t(334 * 272));
    int inside = 0;
    for (int v = 0; v < 272; ++v)
      for (int u = 0; u < 334; ++u) {
        const double x = p.image.origin_mm[0] + u * 0.247, y = v * 0.247;
        const double apex_y = p.face_y_mm - p.radius_mm;
        const double r = std::hypot(x, y - apex_y);
        const double phi = std::atan2(x, y - apex_y);
        const bool expected = r >= p.radius_mm && r <= p.radius_mm + p.depth_mm &&
                              std::fabs(phi) <= sector / 2 * kPi / 180;
        ASSERT_EQ(mask[size_t(v) * 334 + u], expected ? 1 : 0) << "u=" << u << " v=" << v;
        inside += expected;
      }
    // The sector's area, in pixels, is known in closed form (the 36° fan fits in the image).
    const double R = p.radius_mm, D = p.depth_mm;
    const double area = 0.5 * sector * kPi / 180 * ((R + D) * (R + D) - R * R) / (0.247 * 0.247);
    if (sector <= 36) {
      EXPECT_NEAR(inside, area, 0.02 * area);
    }
    EXPECT_GT(inside, 1000);
  }
}

TEST(ProbeMask, CentreLineAndCorners) {
  const ProbeGeometry p = w1_fan();
  // On the centre line x = 0 the fan spans face_y .. face_y + depth.
  EXPECT_FALSE(p.inside(0, p.face_y_mm - 0.01));
  EXPECT_TRUE(p.inside(0, p.face_y_mm + 0.01));
  EXPECT_TRUE(p.inside(0, p.face_y_mm + p.depth_mm - 0.01));
  EXPECT_FALSE(p.inside(0, p.face_y_mm + p.depth_mm + 0.01));
  // Top corners of the image are outside a 36° fan.
  EXPECT_FALSE(p.inside(-41, 0.5));
  EXPECT_FALSE(p.inside(41, 0.5));
  // Along the sector edge: just inside and just outside the half-angle.
  const double apex = p.face_y_mm - p.radius_mm, r = p.radius_mm + 20;
  for (double side : {-1.0, 1.0}) {
    const double in = (18 - 0.1) * kPi / 180, out = (18 + 0.1) * kPi / 180;
    EXPECT_TRUE(p.inside(side * r * std::sin(in), apex + r * std::cos(in)));
    EXPECT_FALSE(p.inside(side * r * std::sin(out), apex + r * std::cos(out)));
  }
}

TEST(ProbeMask, LinearLimits) {
  ProbeGeometry p;
  p.type = ProbeType::Linear;
  p.image.width = 10;
  p.image.height = 10;
  p.image.set_default_origin();
  EXPECT_EQ(p.mask(), std::vector<uint8_t>(100, 1));  // no limits: everything inside
  p.has_width = true;
  p.width_mm = 4.0;  // |x| <= 2: columns at x = -4.5 .. 4.5 → x in {-1.5,...,1.5} → 4 columns
  p.has_depth = true;
  p.depth_mm = 5.0;
  p.face_y_mm = 2.0;  // 0 <= y - 2 <= 5 → rows 2..7
  const auto m = p.mask();
  int count = 0;
  for (int v = 0; v < 10; ++v)
    for (int u = 0; u < 10; ++u) {
      const bool expected = std::fabs(-4.5 + u) <= 2.0 && v >= 2 && v <= 7;
      EXPECT_EQ(m[size_t(v) * 10 + u], expected ? 1 : 0);
      count += m[size_t(v) * 10 + u];
    }
  EXPECT_EQ(count, 4 * 6);
}

TEST(ProbeValidate, RejectsBadSizes) {
  ProbeGeometry p = w1_fan();
  p.validate("ok");
  auto expect_error = [](ProbeGeometry bad, const std::string& needle) {
    try {
      bad.validate("probe 'x.json'");
      ADD_FAILURE() << "expected an error mentioning " << needle;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("probe 'x.json'"), std::string::npos);
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  ProbeGeometry b = p;
  b.image.width = -3;
  expect_error(b, "width and height");
  b = p;
  b.image.spacing_mm[1] = 0;
  expect_error(b, "spacing");
  b = p;
  b.radius_mm = -1;
  expect_error(b, "radius_mm");
  b = p;
  b.sector_deg = std::numeric_limits<double>::quiet_NaN();
  expect_error(b, "sector_deg");
  b = p;
  b.image.width = 1 << 20;
  b.image.height = 1 << 20;
  expect_error(b, "absurdly large");
}

TEST(Poses, ValidationNamesTheIndex) {
  std::vector<Pose> poses(4, Pose::identity());
  validate_poses(poses, "file.npy");
  auto expect_error = [&](const std::string& needle) {
    try {
      validate_poses(poses, "poses 'file.npy'");
      ADD_FAILURE() << "expected error " << needle;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("poses 'file.npy': pose 2"), std::string::npos)
          << e.what();
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  poses[2].m[0][3] = std::numeric_limits<double>::infinity();
  expect_error("non-finite");
  poses[2] = Pose::identity();
  poses[2].m[3][0] = 0.5;
  expect_error("last row");
  poses[2] = Pose::identity();
  poses[2].m[0][0] = poses[2].m[1][0] = poses[2].m[2][0] = 0.1;  // |x̂| = 0.17
  expect_error("lateral axis");
  poses[2] = Pose::identity();
  poses[2].m[1][1] = 3;
  expect_error("axial axis");
  poses[2] = Pose::identity();
  poses[2].m[0][1] = 0.9;  // ŷ = (0.9, 1, 0): |x̂·ŷ| = 0.9 > 0.5·1·1.35
  poses[2].m[1][1] = 1.0;
  expect_error("parallel");
}

TEST(Poses, OneWarningPerFileForNonOrthonormal) {
  const test::CapturedWarnings warnings;
  std::vector<Pose> poses(10, Pose::identity());
  for (auto& p : poses) p.m[0][0] = 1.01;  // 1% stretch: accepted, used as given, warned once
  validate_poses(poses, "poses 'a.txt'");
  ASSERT_EQ(warnings.messages().size(), 1u);
  EXPECT_NE(warnings.messages()[0].find("poses 'a.txt'"), std::string::npos);
  std::vector<Pose> good(3, Pose::identity());
  good[1] = test::make_pose(test::rotation({1, 1, 0}, 33), {1, 2, 3});
  const size_t before = warnings.messages().size();
  validate_poses(good, "b");
  EXPECT_EQ(warnings.messages().size(), before);
}

TEST(Poses, RasNegatesWorldXAndY) {
  Pose p = test::make_pose(test::rotation({0, 0, 1}, 30), {10, 20, 30});
  const Pose lps = pose_to_lps(p, WorldFrame::RAS);
  const Vec3 probe_point{1.5, 4.0, 0};
  const Vec3 ras = p.transform_point(probe_point), l = lps.transform_point(probe_point);
  EXPECT_DOUBLE_EQ(l[0], -ras[0]);
  EXPECT_DOUBLE_EQ(l[1], -ras[1]);
  EXPECT_DOUBLE_EQ(l[2], ras[2]);
  EXPECT_EQ(parse_world_frame("ras"), WorldFrame::RAS);
  EXPECT_THROW(parse_world_frame("RAI"), InputError);
}

TEST(VolumeGrid, WorldToIndexInvertsIndexToWorld) {
  const VolumeGrid g = test::oblique_grid({10, 11, 12});
  for (const Vec3 c : {Vec3{0, 0, 0}, Vec3{3.25, -0.5, 9.75}, Vec3{9, 10, 11}}) {
    const Vec3 back = g.world_to_index(g.index_to_world(c));
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(back[a], c[a], 1e-12);
  }
  // The affine form gives the same answer.
  const Vec3 p{3, -4, 50};
  const Vec3 c1 = g.world_to_index(p),
             c2 = g.world_to_index_linear() * p + g.world_to_index_offset();
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(c1[a], c2[a], 1e-12);
  // docs/conventions.md §1: voxel centre = origin + D·diag(spacing)·c (no half-voxel shift).
  const Vec3 w = g.index_to_world({1, 0, 0});
  const Vec3 axis = g.direction.column(0);
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(w[a], g.origin_mm[a] + 0.9 * axis[a], 1e-12);
}

TEST(VolumeGrid, ValidateRejectsBadGeometry) {
  VolumeGrid g;
  g.dims = {4, 4, 4};
  g.validate("v");
  VolumeGrid b = g;
  b.dims[1] = 0;
  EXPECT_THROW(b.validate("v"), InputError);
  b = g;
  b.spacing_mm[2] = -1;
  EXPECT_THROW(b.validate("v"), InputError);
  b = g;
  b.direction.m[2][2] = 0;  // singular
  EXPECT_THROW(b.validate("v"), InputError);
  b = g;
  b.origin_mm[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(b.validate("v"), InputError);
}

}  // namespace
}  // namespace sonoslice
