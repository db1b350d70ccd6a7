#include "sonoslice/phantom/Workloads.h"

#include <algorithm>
#include <cmath>

namespace sonoslice {

ProbeGeometry workload_w1_fan_probe() {
  // fan-slicer's models_intensity_LUS_config.json: 668×544 px of 0.1235 mm, downsampled by 2.
  FanSlicerProbe fs;
  fs.transducer = ProbeType::Curvilinear;
  const double fan[6] = {0.05, 0.1235, 36, 526, 380, 17};
  std::copy(fan, fan + 6, fs.fan_geometry);
  fs.image_dimensions[0] = 668;
  fs.image_dimensions[1] = 544;
  fs.pixel_size_mm[0] = fs.pixel_size_mm[1] = 0.1235;
  return probe_from_fanslicer(fs, 2);
}

ProbeGeometry workload_w2_linear_probe() {
  // fan-slicer's linear_config.json: 400×500 px of 0.1235 mm, the whole image inside.
  FanSlicerProbe fs;
  fs.transducer = ProbeType::Linear;
  fs.image_dimensions[0] = 400;
  fs.image_dimensions[1] = 500;
  fs.pixel_size_mm[0] = fs.pixel_size_mm[1] = 0.1235;
  return probe_from_fanslicer(fs, 1);
}

namespace {

// A small rotation about world axis `a` (0 x, 1 y, 2 z) applied to v.
Vec3 rotate(const Vec3& v, int a, double radians) {
  const double c = std::cos(radians), s = std::sin(radians);
  const int i = (a + 1) % 3, j = (a + 2) % 3;
  Vec3 r = v;
  r[i] = c * v[i] - s * v[j];
  r[j] = s * v[i] + c * v[j];
  return r;
}
}  // namespace

BeamSweepWorkload workload_jauer_beam_sweep(int frames) {
  BeamSweepWorkload w;
  BeamGeometry& g = w.geometry;
  g.n_samples = 185;
  g.dr_mm = 0.3;
  g.r0_mm = 0.3;
  g.n_azimuth = 84;
  g.dazimuth_deg = 0.45;
  g.azimuth0_deg = -0.45 * 83 / 2;
  g.n_elevation = 22;
  g.delevation_deg = 0.88;
  g.elevation0_deg = -0.88 * 21 / 2;
  g.apex_offset_mm = 0;
  w.grid.dims = {300, 1000, 600};
  w.grid.spacing_mm = {0.5, 0.5, 0.5};
  // Probe x (azimuth) along world x, depth (probe y) along world z, elevation (probe z) along
  // world y, the sweep direction: 400 mm over the frames, rocking by a few degrees.
  for (int f = 0; f < frames; ++f) {
    const double t = frames > 1 ? double(f) / (frames - 1) : 0.0;
    const double rock = 0.06 * std::sin(6.283 * 3 * t), roll = 0.04 * std::sin(6.283 * 2 * t);
    const Vec3 ex = rotate(rotate({{1, 0, 0}}, 0, rock), 1, roll);
    const Vec3 ey = rotate(rotate({{0, 0, 1}}, 0, rock), 1, roll);
    const Vec3 ez = rotate(rotate({{0, -1, 0}}, 0, rock), 1, roll);
    w.probe_to_reference.push_back(
        Mat4::from_columns(ex, ey, ez, {{75 + 10 * std::sin(6.283 * t), 50 + 400 * t, 40}}));
  }
  return w;
}

ImageSweepWorkload workload_2d_sweep(int frames, double spacing_mm) {
  ImageSweepWorkload w;
  w.width = 820;
  w.height = 616;
  const double px = 0.085;
  // 0.1 mm between frames along the elevation direction, tilting by ±5°.
  for (int f = 0; f < frames; ++f) {
    const double t = frames > 1 ? double(f) / (frames - 1) : 0.0;
    const double tilt = 0.087 * std::sin(6.283 * t);
    const Vec3 ex = rotate({{px, 0, 0}}, 0, tilt), ey = rotate({{0, px, 0}}, 0, tilt);
    const Vec3 ez = rotate({{0, 0, 1}}, 0, tilt);
    w.image_to_reference.push_back(Mat4::from_columns(ex, ey, ez, {{-35, -10, 0.1 * f}}));
  }
  w.grid =
      Compounder::grid_around(w.image_to_reference, w.width, w.height, FrameClip{}, spacing_mm);
  return w;
}

std::vector<uint8_t> workload_frames(int64_t count, int64_t samples_per_frame, uint32_t seed) {
  std::vector<uint8_t> out(size_t(count * samples_per_frame));
  uint32_t state = seed * 2654435761u + 12345u;
  for (size_t i = 0; i < out.size(); ++i) {
    state = state * 1664525u + 1013904223u;
    // Speckle: a skewed distribution (most samples dark), occasional bright reflectors.
    const uint32_t r = state >> 24;
    out[i] = uint8_t((r * r) >> 9 | ((state & 0xfff000u) == 0 ? 255 : 0));
  }
  return out;
}

}  // namespace sonoslice
