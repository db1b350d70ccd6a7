// The CPU driver of PLUS-exact compounding (PlusExactImpl.h), for PLUS's three CPU paths
// (Optimization NONE, PARTIAL, FULL): PLUS's single-threaded order of updates (frames in order,
// then rows, then pixels; a pixel's eight corners from the last to the first), kept for any
// number of threads by owner-computes slabs along z. Each slab task
// walks every pixel and applies only the updates that land in its slab, so every voxel sees the
// same updates in the same order as PLUS with NumberOfThreads="1" (whose output the references
// are; PLUS's own multi-threaded output differs from it in 0.1-0.8 % of voxels).
#include "PlusExact.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

#include "../backend/ParallelFor.h"
#include "PlusExactImpl.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace compound_impl {
namespace {

using plus_exact::floor_;
using plus_exact::round_;

using plus_exact::Fixed;
using plus_exact::fixed_from_int;
using plus_exact::to_double;

// vtkTrilinearInterpolation: floor and fraction per axis, the far corner only where the fraction
// is not 0, the whole cell inside the volume, corners from 7 down to 0 (bit 2 x, bit 1 y, bit 0
// z: PLUS's numbering); only the corners in the slab [zlo, zhi). In double (NONE, PARTIAL)...
template <typename T>
void insert_linear(const AccumulatorView& g, const double* p, T in, Mode mode, int zlo, int zhi) {
  const int x0 = floor_(p[0]), y0 = floor_(p[1]), z0 = floor_(p[2]);
  const double fx = p[0] - x0, fy = p[1] - y0, fz = p[2] - z0;
  const int x1 = x0 + (fx != 0), y1 = y0 + (fy != 0), z1 = z0 + (fz != 0);
  if (x0 < 0 || y0 < 0 || z0 < 0 || x1 > g.nx - 1 || y1 > g.ny - 1 || z1 > g.nz - 1) return;
  const double rx = 1 - fx, ry = 1 - fy, rz = 1 - fz;
  const double ryrz = ry * rz, ryfz = ry * fz, fyrz = fy * rz, fyfz = fy * fz;
  const double w[8] = {rx * ryrz, rx * ryfz, rx * fyrz, rx * fyfz,
                       fx * ryrz, fx * ryfz, fx * fyrz, fx * fyfz};
  for (int j = 7; j >= 0; --j) {
    if (w[j] == 0) continue;
    const int cz = (j & 1) ? z1 : z0;
    if (cz < zlo || cz >= zhi) continue;
    const int cx = (j & 4) ? x1 : x0, cy = (j & 2) ? y1 : y0;
    plus_exact::linear_update<T>(g.cells[g.offset(cx, cy, cz)], in, w[j], mode);
  }
}

// ... and in fixed point (FULL): the fraction is the low 14 bits, weights are rounded products.
template <typename T>
void insert_linear(const AccumulatorView& g, const Fixed* p, T in, Mode mode, int zlo, int zhi) {
  int i0[3], i1[3];
  Fixed frac[3], rest[3];
  for (int a = 0; a < 3; ++a) {
    i0[a] = floor_(to_double(p[a]));
    frac[a] = p[a] - fixed_from_int(i0[a]);
    i1[a] = i0[a] + (frac[a] != Fixed{});
    rest[a] = fixed_from_int(1) - frac[a];
  }
  if (i0[0] < 0 || i0[1] < 0 || i0[2] < 0 || i1[0] > g.nx - 1 || i1[1] > g.ny - 1 ||
      i1[2] > g.nz - 1)
    return;
  const Fixed ryrz = rest[1] * rest[2], ryfz = rest[1] * frac[2], fyrz = frac[1] * rest[2],
              fyfz = frac[1] * frac[2];
  const Fixed w[8] = {rest[0] * ryrz, rest[0] * ryfz, rest[0] * fyrz, rest[0] * fyfz,
                      frac[0] * ryrz, frac[0] * ryfz, frac[0] * fyrz, frac[0] * fyfz};
  for (int j = 7; j >= 0; --j) {
    if (w[j].i == 0) continue;
    const int cz = (j & 1) ? i1[2] : i0[2];
    if (cz < zlo || cz >= zhi) continue;
    const int cx = (j & 4) ? i1[0] : i0[0], cy = (j & 2) ? i1[1] : i0[1];
    plus_exact::linear_update_fixed<T>(g.cells[g.offset(cx, cy, cz)], in, w[j], mode);
  }
}

template <typename T>
void insert_slab(const AccumulatorView& g, const PlusExactBatch& b, int zlo, int zhi) {
  const plus_exact::PixelFilter& pf = b.filter;
  const int64_t frame_pixels = int64_t(b.width) * b.height;
  for (int64_t f = 0; f < b.count; ++f) {
    const T* frame = static_cast<const T*>(b.pixels) + f * frame_pixels;
    const IndexMap& m = b.matrices[f];
    for (int y = pf.y0; y <= pf.y1; ++y) {
      const T* row = frame + int64_t(y) * b.width;
      for (int x = pf.x0; x <= pf.x1; ++x) {
        const T in = row[x];
        if (pf.reject && double(in) < pf.threshold) continue;
        if (!pf.in_fan(x, y)) continue;
        // PLUS's matrix × (x, y, 0, 1), term by term; its homogeneous w is exactly 1.
        const double dx = x, dy = y;
        const double pz = m.A[2][0] * dx + m.A[2][1] * dy + m.A[2][2] * 0.0 + m.a[2];
        if (pz < zlo - 2.0 || pz > zhi + 1.0) continue;  // cannot reach this slab
        const double px = m.A[0][0] * dx + m.A[0][1] * dy + m.A[0][2] * 0.0 + m.a[0];
        const double py = m.A[1][0] * dx + m.A[1][1] * dy + m.A[1][2] * 0.0 + m.a[1];
        if (!b.linear) {
          const int ix = round_(px), iy = round_(py), iz = round_(pz);
          if (ix < 0 || iy < 0 || iz < 0 || ix >= g.nx || iy >= g.ny || iz >= g.nz) continue;
          if (iz < zlo || iz >= zhi) continue;
          plus_exact::nearest_update<T>(g.cells[g.offset(ix, iy, iz)], in, b.mode);
          continue;
        }
        const double p[3] = {px, py, pz};
        insert_linear<T>(g, p, in, b.mode, zlo, zhi);
      }
    }
  }
}

// vtkOptimizedInsertSlice's pixel range of row y (Optimization PARTIAL and FULL), before the
// skipped middle segment: the fan's lines and radius with IGSIO's one-pixel margins, then the
// clip extent. `skip` gets the fan's inner segment [skip0, skip1] when there is one.
inline void clip_row(const plus_exact::PixelFilter& pf, int y, int& start, int& end, bool& skip,
                     int& skip0, int& skip1, int first_pixel) {
  skip = false;
  if (pf.fan && start <= end) {
    const double yy = y - pf.fan_origin[1], ox = pf.fan_origin[0];
    // -Floor(-v) is IGSIO's ceiling.
    if (start < -floor_(-(pf.tan_left * yy + ox + 1)))
      start = -floor_(-(pf.tan_left * yy + ox + 1));
    if (end > floor_(pf.tan_right * yy + ox - 1)) end = floor_(pf.tan_right * yy + ox - 1);
    const double depth2 = yy * yy;  // pixel spacing 1: PLUS's frames are in pixels
    double stop = pf.radius2_stop - depth2;
    if (stop < 0) {
      start = first_pixel;
      end = first_pixel - 1;
    } else {
      stop = std::sqrt(stop);
      if (std::isfinite(stop)) {  // no FanRadiusStop given: no bound
        if (start < -floor_(-(ox - stop + 1))) start = -floor_(-(ox - stop + 1));
        if (end > floor_(ox + stop - 1)) end = floor_(ox + stop - 1);
      }
      double inner = pf.radius2_start - depth2;
      if (inner > 0) {
        inner = std::sqrt(inner);
        skip0 = -floor_(-(ox - inner + 1));
        skip1 = floor_(ox + inner - 1);
        skip = true;
      }
    }
  }
  if (start < pf.x0) start = pf.x0;
  if (end > pf.x1) end = pf.x1;
  if (start > end || y < pf.y0 || y > pf.y1) {
    start = first_pixel;
    end = first_pixel - 1;
  }
  if (skip) {
    // A middle segment on one side only trims the range.
    if (skip0 < start) {
      if (start < skip1 + 1) {
        start = skip1 + 1;
        if (end < start) end = start - 1;
      }
      skip = false;
    } else if (skip1 > end) {
      if (end > skip0 - 1) {
        end = skip0 - 1;
        if (end < start) end = start - 1;
      }
      skip = false;
    }
  }
}

inline double as_f(double x, double) {
  return x;
}
inline plus_exact::Fixed as_f(double x, plus_exact::Fixed) {
  return plus_exact::fixed_from(x);
}

// vtkOptimizedInsertSlice<F, T> restricted to the slab [zlo, zhi): F = double for PARTIAL,
// Fixed for FULL.
template <typename F, typename T>
void insert_slab_optimized(const AccumulatorView& g, const PlusExactBatch& b, int zlo, int zhi) {
  using plus_exact::round_position;
  const plus_exact::PixelFilter& pf = b.filter;
  const int64_t frame_pixels = int64_t(b.width) * b.height;
  const int vmin[3] = {0, 0, 0}, vmax[3] = {g.nx - 1, g.ny - 1, g.nz - 1};
  const int pixels[2] = {0, b.width - 1};
  for (int64_t f = 0; f < b.count; ++f) {
    const T* frame = static_cast<const T*>(b.pixels) + f * frame_pixels;
    const IndexMap& m = b.matrices[f];
    F x_axis[3], y_axis[3], origin[3];
    for (int i = 0; i < 3; ++i) {
      x_axis[i] = as_f(m.A[i][0], F{});
      y_axis[i] = as_f(m.A[i][1], F{});
      origin[i] = as_f(m.a[i], F{});  // + 0 × the z axis: frames are 2D
    }
    for (int y = 0; y < b.height; ++y) {
      F row[3];
      for (int i = 0; i < 3; ++i) row[i] = origin[i] + y * y_axis[i];
      plus_exact::RowExtent<F> extent{row, x_axis, vmin, vmax, pixels, {1, 1, 1}};
      int start, end, skip0 = 0, skip1 = -1;
      bool skip;
      extent.find(start, end);
      clip_row(pf, y, start, end, skip, skip0, skip1, pixels[0]);
      const T* in_row = frame + int64_t(y) * b.width;
      for (int x = start; x <= end; ++x) {
        if (skip && x >= skip0 && x <= skip1) continue;
        const T in = in_row[x];
        if (pf.reject && double(in) < pf.threshold) continue;
        F p[3];
        for (int i = 0; i < 3; ++i) p[i] = row[i] + x * x_axis[i];
        if (!b.linear) {
          // vtkFreehand2OptimizedNNHelper: no bounds test in PLUS (the row extent keeps it
          // inside); kept here so that nothing is written outside.
          const int ix = round_position(p[0]), iy = round_position(p[1]), iz = round_position(p[2]);
          if (iz < zlo || iz >= zhi) continue;
          if (ix < 0 || iy < 0 || ix >= g.nx || iy >= g.ny) continue;
          plus_exact::nearest_update<T>(g.cells[g.offset(ix, iy, iz)], in, b.mode, true);
          continue;
        }
        insert_linear<T>(g, p, in, b.mode, zlo, zhi);
      }
    }
  }
}

}  // namespace

bool plus_exact_frame_type(PixelType type) {
  return type == PixelType::UInt8 || type == PixelType::Int16 || type == PixelType::UInt16 ||
         type == PixelType::Float32;
}

void plus_exact_insert(const AccumulatorView& g, const PlusExactBatch& b) {
  if (b.count <= 0) return;
  // Slabs of at least two voxels; more slabs than threads even out uneven ones, but each slab
  // walks every pixel, so not many more.
  const int slabs = std::max(1, std::min(cpu_threads() * 2, g.nz / 2));
  const auto run = [&](auto zero) {
    using T = decltype(zero);
    backend::parallel_for(slabs, [&](int64_t s) {
      const int zlo = int(int64_t(g.nz) * s / slabs), zhi = int(int64_t(g.nz) * (s + 1) / slabs);
      switch (b.optimization) {
        case PlusOptimization::None:
          return insert_slab<T>(g, b, zlo, zhi);
        case PlusOptimization::Partial:
          return insert_slab_optimized<double, T>(g, b, zlo, zhi);
        case PlusOptimization::Full:
          return insert_slab_optimized<Fixed, T>(g, b, zlo, zhi);
      }
    });
  };
  switch (b.type) {
    case PixelType::UInt8:
      return run(uint8_t{});
    case PixelType::Int16:
      return run(int16_t{});
    case PixelType::UInt16:
      return run(uint16_t{});
    case PixelType::Float32:
      return run(float{});
    default:
      throw InputError(std::string("PLUS-exact compounding: ") + to_string(b.type) +
                       " frames are not supported (uint8, int16, uint16 or float32)");
  }
}

}  // namespace compound_impl
}  // namespace sonoslice
