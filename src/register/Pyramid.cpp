// Registration's pyramid and per-frame data: levels of block-averaged frames and volume (made
// when first asked for), each frame's centre, and MI's robust intensity ranges.
#include <algorithm>
#include <cmath>
#include <vector>

#include "../backend/ParallelFor.h"
#include "RegistrationState.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

using register_impl::Level;

const Level& FrameRegistration::State::make_level(int f, const float* frames, const uint8_t* mask) {
  for (Level& l : levels)
    if (l.f == f) return l;
  levels.emplace_back();
  Level& l = levels.back();
  const Level& first = levels.front();  // level 1 (made first, by the constructor)
  const bool int16 = volume.pixel_type() == PixelType::Int16;
  l.f = f;
  const int W = probe.image.width, H = probe.image.height;
  const int64_t nx = grid.dims[0], ny = grid.dims[1], nz = grid.dims[2];
  const double pixel = std::min(probe.image.spacing_mm[0], probe.image.spacing_mm[1]);
  const double spacing = std::min({grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2]});
  l.g = std::max(1, int(std::floor(f * pixel / spacing + 1e-9)));
  if (l.g == 1) {
    l.volume = int16 ? nullptr : volume.data_as<float>();
    l.volume16 = int16 ? volume.data_as<int16_t>() : nullptr;
    l.nx = int(nx);
    l.ny = int(ny);
    l.nz = int(nz);
  } else {
    const int g = l.g;
    l.nx = int(std::max<int64_t>(1, nx / g));
    l.ny = int(std::max<int64_t>(1, ny / g));
    l.nz = int(std::max<int64_t>(1, nz / g));
    l.volume_copy.assign(size_t(l.nx) * l.ny * l.nz, 0.f);
    backend::parallel_for(l.nz, [&](int64_t z) {
      for (int y = 0; y < l.ny; ++y)
        for (int x = 0; x < l.nx; ++x) {
          double s = 0;
          int n = 0;
          for (int dz = 0; dz < g && z * g + dz < nz; ++dz)
            for (int dy = 0; dy < g && int64_t(y) * g + dy < ny; ++dy)
              for (int dx = 0; dx < g && int64_t(x) * g + dx < nx; ++dx, ++n)
                s += voxel(((z * g + dz) * ny + (int64_t(y) * g + dy)) * nx + int64_t(x) * g + dx);
          l.volume_copy[(size_t(z) * l.ny + y) * l.nx + x] = float(s / std::max(n, 1));
        }
    });
    l.volume = l.volume_copy.data();
  }
  l.width = std::max(1, W / f);
  l.height = std::max(1, H / f);
  const size_t plane = size_t(l.width) * l.height;
  l.frames.assign(count * plane, 0.f);
  l.masks.assign(count * plane, 0);
  for (size_t k = 0; k < count; ++k)
    for (int v = 0; v < l.height; ++v)
      for (int u = 0; u < l.width; ++u) {
        double s = 0;
        bool all = true;
        for (int dv = 0; dv < f && all; ++dv)
          for (int du = 0; du < f && all; ++du) {
            const int uu = std::min(u * f + du, W - 1), vv = std::min(v * f + dv, H - 1);
            const size_t i = size_t(vv) * W + uu;
            if (f == 1) {
              const float value = frames[k * size_t(W) * H + i];
              all = mask[i] && std::isfinite(value);
              s += value;
            } else {
              all = first.masks[k * size_t(W) * H + i] != 0;
              s += first.frames[k * size_t(W) * H + i];
            }
          }
        const size_t j = k * plane + size_t(v) * l.width + u;
        l.masks[j] = all ? 1 : 0;
        l.frames[j] = all ? float(s / (f * f)) : 0.f;
      }
  l.spans.assign(count * size_t(l.height) * 2, 0);
  for (size_t k = 0; k < count; ++k)
    for (int v = 0; v < l.height; ++v) {
      const uint8_t* row = l.masks.data() + k * plane + size_t(v) * l.width;
      int first = 0, end = l.width;
      while (first < end && !row[first]) ++first;
      while (end > first && !row[end - 1]) --end;
      int32_t* span = l.spans.data() + (k * l.height + size_t(v)) * 2;
      span[0] = first;
      span[1] = end;
    }
  return l;
}

void FrameRegistration::prepare_level(int level) const {
  if (level < 1 || level > 64)
    throw InputError("pyramid: level " + std::to_string(level) + " is outside 1..64");
  state_->make_level(level);
}

FrameRegistration::FrameRegistration(const Volume& volume, const ProbeGeometry& probe,
                                     const float* frames, size_t frame_count,
                                     const uint8_t* user_mask)
    : state_(std::make_unique<State>()) {
  probe.validate("probe");
  State& s = *state_;
  s.probe = probe;
  s.volume = volume;
  s.grid = volume.grid();
  s.L = s.grid.world_to_index_linear();
  s.count = frame_count;
  if (frame_count == 0) throw InputError("frames: no frames");
  for (int k = 0; k < 3; ++k)
    if (s.grid.dims[k] < 2)
      throw InputError("volume: needs at least 2 voxels along each axis for trilinear gradients");
  // The kernels read float32 or int16 (a CT's own type: no copy of a few hundred MB to make, and
  // half the memory to read): those volumes are shared, others converted once to float32.
  const PixelType type = volume.pixel_type();
  if (type != PixelType::Float32 && type != PixelType::Int16)
    s.volume = volume.converted(PixelType::Float32);
  std::vector<uint8_t> mask = probe.mask();
  if (user_mask)
    for (size_t i = 0; i < mask.size(); ++i) mask[i] = mask[i] && user_mask[i];
  // Full resolution now (a copy of the frames, masked); coarser levels when run() asks.
  const Level& l = s.make_level(1, frames, mask.data());
  s.mask_centre.assign(frame_count, Vec3{0, 0, 0});
  for (size_t k = 0; k < frame_count; ++k) {
    double sx = 0, sy = 0, n = 0;
    for (int v = 0; v < l.height; ++v)
      for (int u = 0; u < l.width; ++u)
        if (l.masks[k * size_t(l.width) * l.height + size_t(v) * l.width + u]) {
          sx += probe.image.origin_mm[0] + u * probe.image.spacing_mm[0];
          sy += probe.image.origin_mm[1] + v * probe.image.spacing_mm[1];
          n += 1;
        }
    if (n == 0)
      throw InputError("frames: frame " + std::to_string(k) +
                       " has no pixel inside the probe's fan and the mask with a finite value");
    s.mask_centre[k] = {sx / n, sy / n, 0};
  }
  // NaN and infinite pixels are left out like pixels outside the mask; run() says how many.
  const size_t plane = size_t(probe.image.width) * probe.image.height;
  for (size_t k = 0; k < frame_count; ++k)
    for (size_t i = 0; i < plane; ++i)
      if (mask[i]) {
        ++s.masked_pixels;
        s.non_finite_pixels += !std::isfinite(frames[k * plane + i]);
      }
  // MI's ranges (robust: a few bright voxels or pixels do not squeeze the histogram).
  const auto percentiles = [](std::vector<float> values, double out[2]) {
    if (values.empty()) {
      out[0] = 0;
      out[1] = 1;
      return;
    }
    const size_t lo = values.size() / 100, hi = values.size() - 1 - values.size() / 100;
    std::nth_element(values.begin(), values.begin() + lo, values.end());
    out[0] = values[lo];
    std::nth_element(values.begin(), values.begin() + hi, values.end());
    out[1] = values[hi];
    if (!(out[1] > out[0])) out[1] = out[0] + 1;
  };
  {
    const int64_t voxels = s.grid.voxel_count();
    const int64_t stride = std::max<int64_t>(1, voxels / 1000000);
    std::vector<float> sample;
    for (int64_t i = 0; i < voxels; i += stride)
      if (std::isfinite(s.voxel(i))) sample.push_back(float(s.voxel(i)));
    percentiles(std::move(sample), s.volume_range);
  }
  s.frame_range.resize(frame_count);
  for (size_t k = 0; k < frame_count; ++k) {
    std::vector<float> values;
    const size_t plane = size_t(l.width) * l.height;
    for (size_t i = 0; i < plane; ++i)
      if (l.masks[k * plane + i]) values.push_back(l.frames[k * plane + i]);
    double r[2];
    percentiles(std::move(values), r);
    s.frame_range[k] = {r[0], r[1]};
  }
}

FrameRegistration::~FrameRegistration() = default;

Vec3 FrameRegistration::centre(size_t frame, const Pose& pose) const {
  return pose.transform_point(state_->mask_centre[frame]);
}

}  // namespace sonoslice
