// The CPU driver of PLUS-exact compounding (PlusExactImpl.h): PLUS's single-threaded order of
// updates (frames in order, then rows, then pixels; a pixel's eight corners from the last to
// the first), kept for any number of threads by owner-computes slabs along z. Each slab task
// walks every pixel and applies only the updates that land in its slab, so every voxel sees the
// same updates in the same order as PLUS with NumberOfThreads="1" (whose output the references
// are; PLUS's own multi-threaded output differs from it in 0.1-0.8 % of voxels).
#include "PlusExact.h"

#include <algorithm>
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

template <typename T>
void insert_slab(const AccumulatorView& g, const PlusExactBatch& b, int zlo, int zhi) {
  const plus_exact::PixelFilter& pf = b.filter;
  const int64_t frame_pixels = int64_t(b.width) * b.height;
  for (int64_t f = 0; f < b.count; ++f) {
    const T* frame = static_cast<const T*>(b.pixels) + f * frame_pixels;
    const double(&m)[3][4] = b.matrices[f].m;
    for (int y = pf.y0; y <= pf.y1; ++y) {
      const T* row = frame + int64_t(y) * b.width;
      for (int x = pf.x0; x <= pf.x1; ++x) {
        const T in = row[x];
        if (pf.reject && double(in) < pf.threshold) continue;
        if (!pf.in_fan(x, y)) continue;
        // PLUS's matrix × (x, y, 0, 1), term by term; its homogeneous w is exactly 1.
        const double dx = x, dy = y;
        const double pz = m[2][0] * dx + m[2][1] * dy + m[2][2] * 0.0 + m[2][3];
        if (pz < zlo - 2.0 || pz > zhi + 1.0) continue;  // cannot reach this slab
        const double px = m[0][0] * dx + m[0][1] * dy + m[0][2] * 0.0 + m[0][3];
        const double py = m[1][0] * dx + m[1][1] * dy + m[1][2] * 0.0 + m[1][3];
        if (!b.linear) {
          const int ix = round_(px), iy = round_(py), iz = round_(pz);
          if (ix < 0 || iy < 0 || iz < 0 || ix >= g.nx || iy >= g.ny || iz >= g.nz) continue;
          if (iz < zlo || iz >= zhi) continue;
          plus_exact::nearest_update<T>(g.cells[g.offset(ix, iy, iz)], in, b.mode);
          continue;
        }
        // vtkTrilinearInterpolation: floor and fraction per axis, the far corner only where
        // the fraction is not 0, the whole cell inside the volume.
        const int x0 = floor_(px), y0 = floor_(py), z0 = floor_(pz);
        const double fx = px - x0, fy = py - y0, fz = pz - z0;
        const int x1 = x0 + (fx != 0), y1 = y0 + (fy != 0), z1 = z0 + (fz != 0);
        if (x0 < 0 || y0 < 0 || z0 < 0 || x1 > g.nx - 1 || y1 > g.ny - 1 || z1 > g.nz - 1) continue;
        const double rx = 1 - fx, ry = 1 - fy, rz = 1 - fz;
        const double ryrz = ry * rz, ryfz = ry * fz, fyrz = fy * rz, fyfz = fy * fz;
        // Corner j: bit 2 x, bit 1 y, bit 0 z (PLUS's numbering), visited from 7 down to 0.
        const double w[8] = {rx * ryrz, rx * ryfz, rx * fyrz, rx * fyfz,
                             fx * ryrz, fx * ryfz, fx * fyrz, fx * fyfz};
        for (int j = 7; j >= 0; --j) {
          if (w[j] == 0) continue;
          const int cz = (j & 1) ? z1 : z0;
          if (cz < zlo || cz >= zhi) continue;
          const int cx = (j & 4) ? x1 : x0, cy = (j & 2) ? y1 : y0;
          plus_exact::linear_update<T>(g.cells[g.offset(cx, cy, cz)], in, w[j], b.mode);
        }
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
      insert_slab<T>(g, b, zlo, zhi);
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
