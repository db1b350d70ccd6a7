// The viewer's geometry (the planes the page shows) and its embedded page. The HTTP server and the
// page itself are tested in a real browser (python/tests/test_view.py).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>

#ifdef SONOSLICE_HAVE_HTTPLIB
#include "WebAssets.h"
#endif
#include "sonoslice/view/ViewServer.h"

namespace sonoslice {
namespace {

Vec3 pixel_world(const ViewPlane& p, double i, double j, double position) {
  const Pose t = p.pose_at(position);
  Vec3 w;
  for (int r = 0; r < 3; ++r)
    w[size_t(r)] = t.m[r][0] * i * p.spacing + t.m[r][1] * j * p.spacing + t.m[r][3];
  return w;
}

TEST(ViewPlanes, AxisAlignedVolumeAsSlicerShowsIt) {
  VolumeGrid g;
  g.dims = {{10, 20, 30}};
  g.spacing_mm = {{1, 2, 3}};
  g.origin_mm = {{5, 6, 7}};
  const auto planes = view_planes(g);
  const ViewPlane& axial = planes[2];
  EXPECT_STREQ(axial.name(), "axial");
  EXPECT_EQ(axial.width, 10);   // x: 9 mm at 1 mm
  EXPECT_EQ(axial.height, 39);  // y: 38 mm at 1 mm
  EXPECT_DOUBLE_EQ(axial.step, 3);
  EXPECT_DOUBLE_EQ(axial.min, 7);
  EXPECT_DOUBLE_EQ(axial.max, 7 + 29 * 3);
  // Axial: right = +x (patient left), down = +y (posterior); pixel (0, 0) at the box's corner.
  const Vec3 c = pixel_world(axial, 0, 0, 10);
  EXPECT_DOUBLE_EQ(c[0], 5);
  EXPECT_DOUBLE_EQ(c[1], 6);
  EXPECT_DOUBLE_EQ(c[2], 10);
  EXPECT_DOUBLE_EQ(pixel_world(axial, 9, 38, 10)[0], 14);
  EXPECT_DOUBLE_EQ(pixel_world(axial, 9, 38, 10)[1], 44);
  // Coronal and sagittal: down = −z (inferior), row 0 at the top of the box.
  EXPECT_DOUBLE_EQ(pixel_world(planes[1], 0, 0, 0)[2], 7 + 29 * 3);
  EXPECT_EQ(planes[1].height, 88);
  EXPECT_DOUBLE_EQ(pixel_world(planes[1], 0, 87, 0)[2], 7 + 29 * 3 - 87);
  EXPECT_DOUBLE_EQ(planes[0].u[1], 1);  // sagittal: right = +y (posterior)
  for (const ViewPlane& p : planes) {
    const Pose t = p.pose_at(p.min);
    EXPECT_NO_THROW(validate_poses(&t, 1, "plane", 0, false)) << p.name();
    EXPECT_DOUBLE_EQ(t.m[p.axis][3], p.min);
  }
}

TEST(ViewPlanes, ObliqueVolumeIsCoveredInWorldAxes) {
  VolumeGrid g;
  g.dims = {{40, 30, 20}};
  g.spacing_mm = {{0.5, 0.5, 2}};
  const double a = 30 * 3.14159265358979 / 180;
  g.direction = Mat3::identity();
  g.direction.m[0][0] = std::cos(a), g.direction.m[0][1] = -std::sin(a);
  g.direction.m[1][0] = std::sin(a), g.direction.m[1][1] = std::cos(a);
  const auto planes = view_planes(g);
  // Every voxel centre of the box lies on the axial plane's pixel grid extent.
  const ViewPlane& axial = planes[2];
  for (int b = 0; b < 8; ++b) {
    const Vec3 w =
        g.index_to_world({double(b & 1 ? 39 : 0), double(b & 2 ? 29 : 0), double(b & 4 ? 19 : 0)});
    const double i = (w[0] - axial.origin[0]) / axial.spacing;
    const double j = (w[1] - axial.origin[1]) / axial.spacing;
    EXPECT_GE(i, -1e-9);
    EXPECT_LE(i, axial.width - 1 + 1e-9);
    EXPECT_GE(j, -1e-9);
    EXPECT_LE(j, axial.height - 1 + 1e-9);
    EXPECT_GE(w[2], axial.min - 1e-9);
    EXPECT_LE(w[2], axial.max + 1e-9);
  }
  EXPECT_DOUBLE_EQ(axial.spacing, 0.5);
  EXPECT_DOUBLE_EQ(planes[2].step, 2);  // z is index axis 2's
}

TEST(ViewPlanes, HugeBoxesAreCappedInPixels) {
  VolumeGrid g;
  g.dims = {{4000, 10, 10}};
  g.spacing_mm = {{0.1, 0.1, 0.1}};
  const auto planes = view_planes(g, 1024);
  EXPECT_EQ(planes[2].width, 1024);
  EXPECT_NEAR(planes[2].spacing, 399.9 / 1023, 1e-12);
}

#ifdef SONOSLICE_HAVE_HTTPLIB
TEST(ViewPage, IsCompiledIn) {
  const WebAsset* index = find_web_asset("index.html");
  ASSERT_NE(index, nullptr);
  EXPECT_NE(std::string(index->data, index->size).find("view.js"), std::string::npos);
  EXPECT_EQ(std::strlen(index->data), index->size);  // terminated, no NUL inside
  ASSERT_NE(find_web_asset("view.js"), nullptr);
  EXPECT_NE(std::string(find_web_asset("view.css")->mime).find("text/css"), std::string::npos);
  EXPECT_EQ(find_web_asset("../CMakeLists.txt"), nullptr);
}
#endif

}  // namespace
}  // namespace sonoslice
