// ITK's ResampleImageFilter as an independent oracle: linear-probe planes through an obliquely
// oriented volume must match it pixel for pixel (docs/conventions.md §5 says they are the same
// rule).
#include <gtest/gtest.h>

#include <cmath>

#include <itkIdentityTransform.h>
#include <itkImage.h>
#include <itkLinearInterpolateImageFunction.h>
#include <itkNearestNeighborInterpolateImageFunction.h>
#include <itkResampleImageFilter.h>

#include "../common/TestUtil.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

using Image = itk::Image<float, 3>;

Image::Pointer to_itk(const Volume& v) {
  const VolumeGrid& g = v.grid();
  auto img = Image::New();
  Image::SizeType size;
  Image::SpacingType spacing;
  Image::PointType origin;
  Image::DirectionType direction;
  for (int a = 0; a < 3; ++a) {
    size[a] = itk::SizeValueType(g.dims[a]);
    spacing[a] = g.spacing_mm[a];
    origin[a] = g.origin_mm[a];
    for (int b = 0; b < 3; ++b) direction[a][b] = g.direction.m[a][b];
  }
  img->SetRegions(Image::RegionType(size));
  img->SetSpacing(spacing);
  img->SetOrigin(origin);
  img->SetDirection(direction);
  img->Allocate();
  std::copy(v.data_as<float>(), v.data_as<float>() + g.voxel_count(), img->GetBufferPointer());
  return img;
}

// The image plane of `pose` as an ITK output grid: W×H×1, spacing (sx, sy, 1), origin at pixel
// (0, 0), direction = the pose's axes.
std::vector<float> resample_with_itk(Image::Pointer input, const ProbeGeometry& probe,
                                     const Pose& pose, bool linear, double fill) {
  using Filter = itk::ResampleImageFilter<Image, Image, double>;
  auto filter = Filter::New();
  filter->SetInput(input);
  filter->SetTransform(itk::IdentityTransform<double, 3>::New());
  if (linear)
    filter->SetInterpolator(itk::LinearInterpolateImageFunction<Image, double>::New());
  else
    filter->SetInterpolator(itk::NearestNeighborInterpolateImageFunction<Image, double>::New());
  filter->SetDefaultPixelValue(float(fill));
  Image::SizeType size;
  size[0] = itk::SizeValueType(probe.image.width);
  size[1] = itk::SizeValueType(probe.image.height);
  size[2] = 1;
  Image::SpacingType spacing;
  spacing[0] = probe.image.spacing_mm[0];
  spacing[1] = probe.image.spacing_mm[1];
  spacing[2] = 1;
  const Vec3 p0 = pose.transform_point({probe.image.origin_mm[0], probe.image.origin_mm[1], 0});
  Image::PointType origin;
  Image::DirectionType direction;
  for (int a = 0; a < 3; ++a) {
    origin[a] = p0[a];
    for (int b = 0; b < 3; ++b) direction[a][b] = pose.m[a][b];
  }
  filter->SetSize(size);
  filter->SetOutputSpacing(spacing);
  filter->SetOutputOrigin(origin);
  filter->SetOutputDirection(direction);
  filter->Update();
  const float* out = filter->GetOutput()->GetBufferPointer();
  return std::vector<float>(out, out + probe.image.pixel_count());
}

TEST(ItkOracle, LinearProbePlanesThroughObliqueVolume) {
  const VolumeGrid grid = test::oblique_grid({60, 50, 40});
  const Volume volume = test::make_volume<float>(grid, [](const Vec3& p) {
    return 300 * std::sin(p[0] * 0.15) * std::cos(p[1] * 0.11) + 80 * std::cos(p[2] * 0.23);
  });
  const auto range = volume.value_range();
  const Image::Pointer itk_volume = to_itk(volume);
  ProbeGeometry probe;
  probe.type = ProbeType::Linear;
  probe.image.width = 90;
  probe.image.height = 70;
  probe.image.spacing_mm[0] = probe.image.spacing_mm[1] = 0.45;
  probe.image.set_default_origin();
  const Vec3 centre = grid.index_to_world({29.5, 24.5, 19.5});
  const auto poses = test::random_poses(25, centre, 30.0, 17);  // many planes leave the volume

  for (bool linear : {true, false}) {
    SliceSettings s;
    s.interpolation = linear ? Interpolation::Linear : Interpolation::Nearest;
    s.fill_value = -999;
    const auto ours = Slicer(volume, probe, s).slice<float>(poses);
    double worst = 0;
    int64_t compared = 0, excluded = 0, outside = 0;
    for (size_t n = 0; n < poses.size(); ++n) {
      const auto theirs = resample_with_itk(itk_volume, probe, poses[n], linear, s.fill_value);
      for (int v = 0; v < probe.image.height; ++v)
        for (int u = 0; u < probe.image.width; ++u) {
          const size_t i = size_t(v) * probe.image.width + u;
          double ref, margin;
          const Vec3 p = poses[n].transform_point(
              {probe.image.origin_mm[0] + u * probe.image.spacing_mm[0],
               probe.image.origin_mm[1] + v * probe.image.spacing_mm[1], 0});
          test::reference_sample(volume, p, s.interpolation, s.fill_value, &ref, &margin);
          if (margin < 1e-3) {
            ++excluded;
            continue;
          }
          outside += theirs[i] == float(s.fill_value);
          worst = std::max(worst,
                           double(std::fabs(ours[n * probe.image.pixel_count() + i] - theirs[i])));
          ++compared;
        }
    }
    std::printf(
        "[ accuracy ] vs ITK ResampleImageFilter (%s): max |difference| = %.3g (%.3g of the "
        "range) over %lld pixels, %lld outside the volume, %lld near-boundary excluded\n",
        linear ? "linear" : "nearest", worst, worst / (range.second - range.first),
        static_cast<long long>(compared), static_cast<long long>(outside),
        static_cast<long long>(excluded));
    EXPECT_GT(outside, 1000);
    EXPECT_GT(compared - outside, 50000);
    EXPECT_LE(worst, 1e-4 * (range.second - range.first));
  }
}

}  // namespace
}  // namespace sonoslice
