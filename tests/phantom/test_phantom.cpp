// The built-in phantom: deterministic, anatomically plausible HU per tissue, probes on the skin.
#include <gtest/gtest.h>

#include <cstring>
#include <map>

#include "../common/TestUtil.h"
#include "sonoslice/phantom/Phantom.h"

namespace sonoslice {
namespace {

TEST(Phantom, DeterministicForAnyThreadCount) {
  const test::ScopedCpuSettings restore;
  set_cpu_threads(1);
  const Phantom a = make_phantom(PhantomSize::Small);
  reset_cpu_threads();
  const Phantom b = make_phantom(PhantomSize::Small);
  ASSERT_EQ(a.ct.byte_size(), b.ct.byte_size());
  EXPECT_EQ(0, std::memcmp(a.ct.data(), b.ct.data(), a.ct.byte_size()));
  EXPECT_EQ(0, std::memcmp(a.labels.data(), b.labels.data(), a.labels.byte_size()));
  EXPECT_EQ(a.ct.pixel_type(), PixelType::Int16);
  EXPECT_EQ(a.labels.pixel_type(), PixelType::UInt8);
  EXPECT_EQ(phantom_grid(PhantomSize::Full).dims, (std::array<int64_t, 3>{512, 512, 400}));
}

TEST(Phantom, TissuesHavePlausibleHounsfieldUnits) {
  const Phantom p = make_phantom(PhantomSize::Small);
  std::map<int, std::pair<double, int64_t>> sums;  // label → (sum of HU, voxels)
  const int64_t n = p.ct.grid().voxel_count();
  for (int64_t i = 0; i < n; ++i) {
    auto& s = sums[p.labels.data_as<uint8_t>()[i]];
    s.first += p.ct.data_as<int16_t>()[i];
    s.second += 1;
  }
  for (int label = 0; label < kPhantomLabelCount; ++label)
    EXPECT_GT(sums[label].second, 50) << phantom_label_name(label) << " is missing";
  auto mean = [&](int label) { return sums[label].first / double(sums[label].second); };
  EXPECT_NEAR(mean(kAir), -1000, 5);
  EXPECT_NEAR(mean(kFat), -95, 10);
  EXPECT_NEAR(mean(kLiver), 60, 5);
  EXPECT_NEAR(mean(kLung), -850, 10);
  EXPECT_GT(mean(kBone), 250);
  EXPECT_GT(mean(kHepaticVessel), 140);
  EXPECT_GT(mean(kGreatVessel), 140);
  // The body fills a good part of the field of view, air surrounds it.
  EXPECT_GT(sums[kAir].second, n / 5);
  EXPECT_LT(sums[kAir].second, n * 3 / 4);
}

TEST(Phantom, SurfacePosesTouchTheSkinLookingInward) {
  const Phantom p = make_phantom(PhantomSize::Full);
  const VolumeGrid& g = p.labels.grid();
  auto label_at = [&](const Vec3& w) {
    const Vec3 c = g.world_to_index(w);
    const int64_t i = std::llround(c[0]), j = std::llround(c[1]), k = std::llround(c[2]);
    return int(p.labels.data_as<uint8_t>()[(k * g.dims[1] + j) * g.dims[0] + i]);
  };
  const double face_y = 2.1;
  for (const Pose& pose : phantom_surface_poses(8, face_y)) {
    EXPECT_EQ(label_at(pose.transform_point({0, face_y - 5, 0})), kAir);   // 5 mm outside
    EXPECT_NE(label_at(pose.transform_point({0, face_y + 5, 0})), kAir);   // 5 mm inside
    EXPECT_NE(label_at(pose.transform_point({0, face_y + 40, 0})), kAir);  // deeper still inside
  }
  for (const Pose& pose : phantom_random_poses(50, 1))
    EXPECT_NE(label_at(pose.transform_point({0, 0, 0})), kAir);  // benchmark poses inside the body
}

}  // namespace
}  // namespace sonoslice
