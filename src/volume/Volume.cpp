#include "sonoslice/volume/Volume.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <sstream>
#include <vector>

#include "../backend/Convert.h"
#include "../backend/ParallelFor.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"

namespace sonoslice {

// value_range() works in chunks of this many voxels: enough per task to amortise the thread
// start, small enough to spread a CT over every core.
constexpr int64_t kRangeChunkVoxels = int64_t(1) << 20;

Volume Volume::allocate(PixelType type, const VolumeGrid& grid) {
  grid.validate("volume");
  const size_t bytes = size_t(grid.voxel_count()) * pixel_size(type);
  // calloc: large blocks come from the OS already zeroed, so this costs no extra pass.
  void* p = std::calloc(size_t(grid.voxel_count()), pixel_size(type));
  if (!p) {
    std::ostringstream s;
    s << "cannot allocate a " << grid.dims[0] << "x" << grid.dims[1] << "x" << grid.dims[2] << " "
      << to_string(type) << " volume (" << double(bytes) / double(kMiB) << " MiB)";
    throw ResourceError(s.str());
  }
  return wrap(p, type, grid, std::shared_ptr<void>(p, std::free));
}

Volume Volume::wrap(void* data, PixelType type, const VolumeGrid& grid,
                    std::shared_ptr<void> owner) {
  // Every volume, however made (a file, a Python array, a compounder), has a grid the kernels
  // and the writers can take: ITK aborts writing a NIfTI of spacing 1e300.
  grid.validate("volume");
  Volume v;
  v.type_ = type;
  v.grid_ = grid;
  v.data_ = data;
  v.owner_ = std::move(owner);
  return v;
}

std::pair<double, double> Volume::value_range() const {
  const int64_t n = grid_.voxel_count();
  const int64_t chunk = kRangeChunkVoxels;
  const int64_t chunks = (n + chunk - 1) / chunk;
  std::vector<double> lo(size_t(chunks), std::numeric_limits<double>::infinity());
  std::vector<double> hi(size_t(chunks), -std::numeric_limits<double>::infinity());
  visit_pixel_type(type_, [&](auto zero) {
    using T = decltype(zero);
    const T* p = data_as<T>();
    backend::parallel_for_chunks(n, chunk, [&](int64_t c, int64_t begin, int64_t end) {
      T mn = std::numeric_limits<T>::max(), mx = std::numeric_limits<T>::lowest();
      bool any = false;
      for (int64_t i = begin; i < end; ++i) {
        const T v = p[i];
        if (v != v) continue;  // NaN
        any = true;
        mn = v < mn ? v : mn;
        mx = v > mx ? v : mx;
      }
      if (any) {
        lo[size_t(c)] = double(mn);
        hi[size_t(c)] = double(mx);
      }
    });
  });
  double mn = std::numeric_limits<double>::infinity(), mx = -mn;
  for (int64_t c = 0; c < chunks; ++c) {
    mn = std::min(mn, lo[size_t(c)]);
    mx = std::max(mx, hi[size_t(c)]);
  }
  if (mn > mx) mn = mx = std::numeric_limits<double>::quiet_NaN();  // all NaN
  return {mn, mx};
}

int64_t count_non_finite(const void* data, PixelType type, int64_t n) {
  if (type != PixelType::Float32 && type != PixelType::Float64) return 0;  // integers are finite
  const int64_t chunks = (n + kRangeChunkVoxels - 1) / kRangeChunkVoxels;
  std::vector<int64_t> counts(size_t(chunks), 0);
  visit_pixel_type(type, [&](auto zero) {
    using T = decltype(zero);
    const T* p = static_cast<const T*>(data);
    backend::parallel_for_chunks(n, kRangeChunkVoxels, [&](int64_t c, int64_t begin, int64_t end) {
      int64_t bad = 0;
      for (int64_t i = begin; i < end; ++i) bad += !std::isfinite(double(p[i]));
      counts[size_t(c)] = bad;
    });
  });
  int64_t total = 0;
  for (int64_t c : counts) total += c;
  return total;
}

void check_label_volume(const Volume& labels, const std::string& what) {
  const PixelType type = labels.pixel_type();
  if (type != PixelType::UInt8 && type != PixelType::UInt16)
    throw InputError(what + ": a label volume is uint8 or uint16, this one is " + to_string(type));
}

void check_label_values(const Volume& labels, const std::string& what) {
  const PixelType type = labels.pixel_type();
  const bool integer = type != PixelType::Float32 && type != PixelType::Float64;
  const auto [lo, hi] = labels.value_range();
  if (!integer || lo < 0 || hi > 65535) {
    std::ostringstream range;
    range << "[" << lo << ", " << hi << "]";
    throw InputError(what + ": a label volume holds whole numbers 0..65535; this one is " +
                     to_string(type) + " with values in " + range.str());
  }
}

int64_t Volume::non_finite_count() const {
  return count_non_finite(data_, type_, grid_.voxel_count());
}

Volume Volume::converted(PixelType type) const {
  Volume out = allocate(type, grid_);
  const int64_t n = grid_.voxel_count();
  visit_pixel_type(type_, [&](auto in_zero) {
    using TIn = decltype(in_zero);
    visit_pixel_type(type, [&](auto out_zero) {
      using TOut = decltype(out_zero);
      const TIn* src = data_as<TIn>();
      TOut* dst = out.data_as<TOut>();
      backend::parallel_for_chunks(n, int64_t(1) << 20, [&](int64_t, int64_t begin, int64_t end) {
        for (int64_t i = begin; i < end; ++i) dst[i] = backend::saturate_cast<TOut>(double(src[i]));
      });
    });
  });
  return out;
}

}  // namespace sonoslice
