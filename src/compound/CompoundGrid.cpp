// The output grid of a reconstruction: fitted around the frames (grid_around, as PLUS does) and
// sized against the memory there is, with a spacing that fits when it is not.
#include "CompoundGrid.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "BeamPoints.h"
#include "CompoundTypes.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"

namespace sonoslice {

namespace compound_impl {

std::string format_bytes(uint64_t bytes) {
  char text[64];
  if (bytes >= (uint64_t(1) << 30))
    std::snprintf(text, sizeof text, "%.1f GiB", double(bytes) / double(uint64_t(1) << 30));
  else
    std::snprintf(text, sizeof text, "%.0f MiB", double(bytes) / double(1 << 20));
  return text;
}

std::string format_dims(const std::array<int64_t, 3>& d) {
  return std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x" + std::to_string(d[2]);
}

uint64_t accumulator_bytes_per_voxel(const CompoundSettings& s) {
  return sizeof(Accumulator) + (s.mode == CompoundingMode::Latest ? sizeof(int32_t) : 0);
}

void check_matrix(const Mat4& m, const std::string& what, int axes) {
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      if (!std::isfinite(m.m[r][c]))
        throw InputError(what + ": the matrix has a non-finite element (row " + std::to_string(r) +
                         ", column " + std::to_string(c) + ")");
  if (m.m[3][0] != 0 || m.m[3][1] != 0 || m.m[3][2] != 0 || m.m[3][3] != 1)
    throw InputError(what + ": the matrix's last row must be 0 0 0 1");
  Vec3 c[3];
  double norms = 1;
  for (int k = 0; k < 3; ++k) {
    c[k] = Vec3{{m.m[0][k], m.m[1][k], m.m[2][k]}};
    if (k < axes) norms *= std::sqrt(c[k][0] * c[k][0] + c[k][1] * c[k][1] + c[k][2] * c[k][2]);
  }
  const Vec3 x{{c[0][1] * c[1][2] - c[0][2] * c[1][1], c[0][2] * c[1][0] - c[0][0] * c[1][2],
                c[0][0] * c[1][1] - c[0][1] * c[1][0]}};
  const double volume = axes == 2 ? std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
                                  : std::fabs(x[0] * c[2][0] + x[1] * c[2][1] + x[2] * c[2][2]);
  if (!(norms > 0) || !(volume > 1e-9 * norms))
    throw InputError(what + ": the matrix is singular (its " +
                     (axes == 2 ? "pixel x and y columns" : "x, y and z columns") +
                     " are zero or parallel): the frame would collapse");
}

}  // namespace compound_impl

using compound_impl::accumulator_bytes_per_voxel;
using compound_impl::beam_directions;
using compound_impl::beam_point;
using compound_impl::check_matrix;
using compound_impl::format_bytes;
using compound_impl::format_dims;

uint64_t compounding_memory_bytes(const VolumeGrid& grid, const CompoundSettings& settings,
                                  PixelType output_type) {
  const uint64_t voxels = uint64_t(grid.voxel_count());
  return voxels * (accumulator_bytes_per_voxel(settings) + pixel_size(output_type));
}

namespace {

// A spacing (two decimals, mm) at which the same physical box fits in `limit` bytes.
std::string suggest_spacing(const VolumeGrid& grid, const CompoundSettings& settings,
                            PixelType output_type, uint64_t limit) {
  const double s0 = std::max({grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2]});
  for (double s = std::ceil(s0 * 100 + 1) / 100; s < s0 * 1000; s = std::ceil(s * 105) / 100) {
    VolumeGrid g = grid;
    for (int a = 0; a < 3; ++a) {
      const double extent = double(grid.dims[a] - 1) * grid.spacing_mm[a];
      g.dims[a] = int64_t(std::round(extent / s)) + 1;
      g.spacing_mm[a] = s;
    }
    const uint64_t need = compounding_memory_bytes(g, settings, output_type);
    if (need <= limit) {
      char text[160];
      std::snprintf(text, sizeof text, "a spacing of %.2f mm fits (%s voxels, %s)", s,
                    format_dims(g.dims).c_str(), format_bytes(need).c_str());
      return text;
    }
  }
  return "no spacing fits";
}

}  // namespace

namespace compound_impl {

void check_fits_in_memory(const VolumeGrid& grid, const CompoundSettings& settings,
                          PixelType output_type, uint64_t max_memory_bytes) {
  const uint64_t need = compounding_memory_bytes(grid, settings, output_type);
  const uint64_t limit = max_memory_bytes ? max_memory_bytes : available_memory_bytes();
  if (need > limit)
    throw ResourceError("compounding: the output grid (" + format_dims(grid.dims) + " voxels at " +
                        std::to_string(grid.spacing_mm[0]).substr(0, 5) + " mm) needs " +
                        format_bytes(need) + ", more than the " + format_bytes(limit) +
                        (max_memory_bytes ? " allowed (the memory limit given)" : " available") +
                        "; " + suggest_spacing(grid, settings, output_type, limit));
}

}  // namespace compound_impl

namespace {

// The box around the points given to add(): the grid PLUS fits around the frames.
struct Bounds {
  Vec3 lo{{1e300, 1e300, 1e300}}, hi{{-1e300, -1e300, -1e300}};
  size_t lo_frame[3] = {0, 0, 0}, hi_frame[3] = {0, 0, 0};  // the frames that set lo and hi
  bool empty = true;
  void add(const Vec3& p, size_t frame) {
    empty = false;
    for (int a = 0; a < 3; ++a) {
      if (p[a] < lo[a]) lo[a] = p[a], lo_frame[a] = frame;
      if (p[a] > hi[a]) hi[a] = p[a], hi_frame[a] = frame;
    }
  }
  // A box no scan spans (10 km) comes from a broken transform; a sane box at a spacing that
  // would need more than 2^31 voxels along an axis, from the spacing.
  void check_span(const Vec3& spacing_mm, const char* what) const {
    static const char* const axis[3] = {"x", "y", "z"};
    for (int a = 0; a < 3; ++a) {
      const double span = hi[a] - lo[a];
      char text[320];
      if (!(span < 1e7)) {
        std::snprintf(text, sizeof text,
                      "%s: the frames span %.3g mm along %s (frame %zu at %.3g mm, frame %zu at "
                      "%.3g mm): a frame's transform is broken",
                      what, span, axis[a], lo_frame[a], lo[a], hi_frame[a], hi[a]);
        throw InputError(text);
      }
      if (!(span / spacing_mm[a] < 2147483647.0)) {
        std::snprintf(text, sizeof text,
                      "%g mm: the frames span %.1f mm along %s, more than 2^31 voxels at this "
                      "spacing",
                      spacing_mm[a], span, axis[a]);
        throw ParameterError("spacing_mm", text);
      }
    }
  }
  // The grid fitted to the box per axis (Compounder::GridFit).
  VolumeGrid grid(const Vec3& spacing_mm, const char* what,
                  Compounder::GridFit fit = Compounder::GridFit::Round) const {
    for (double s : spacing_mm)
      if (!(s > 0 && std::isfinite(s)))
        throw InputError(std::string(what) + ": output spacing must be a positive number of mm");
    if (empty)
      throw InputError(std::string(what) + ": no valid frame to compute the output extent from");
    check_span(spacing_mm, what);
    VolumeGrid g;
    for (int a = 0; a < 3; ++a) {
      const double s = spacing_mm[a];
      g.spacing_mm[a] = s;
      switch (fit) {
        case Compounder::GridFit::Round:
          g.origin_mm[a] = lo[a];
          g.dims[a] = int64_t(std::round((hi[a] - lo[a]) / s)) + 1;
          break;
        case Compounder::GridFit::PlusLegacy:  // vtkVolumeReconstructor, PLUS 2.x: int() truncates
          g.origin_mm[a] = lo[a];
          g.dims[a] = int64_t((hi[a] - lo[a]) / s) + 1;
          break;
        case Compounder::GridFit::PlusLattice:  // vtkIGSIOVolumeReconstructor: a lattice origin
          g.origin_mm[a] = std::floor(lo[a] / s) * s;
          g.dims[a] = int64_t(std::ceil((hi[a] - g.origin_mm[a]) / s)) + 1;
          break;
      }
    }
    return g;
  }
};

}  // namespace

VolumeGrid Compounder::grid_around(const std::vector<Mat4>& image_to_reference, int width,
                                   int height, const FrameClip& clip, const Vec3& spacing_mm,
                                   GridFit fit) {
  clip.require_pixels(width, height, "compounding: the clip rectangle");
  const auto r = clip.rectangle(width, height);
  // Corner pixel centres: first and last pixel of the clip rectangle.
  const double xs[2] = {double(r[0]), double(r[2] - 1)}, ys[2] = {double(r[1]), double(r[3] - 1)};
  Bounds box;
  for (size_t k = 0; k < image_to_reference.size(); ++k) {
    const Mat4& m = image_to_reference[k];
    check_matrix(m, "compounding: image-to-reference", 2);
    for (double x : xs)
      for (double y : ys) box.add(m.transform_point(Vec3{{x, y, 0.0}}), k);
  }
  return box.grid(spacing_mm, "compounding", fit);
}

VolumeGrid Compounder::grid_around_beams(const std::vector<Mat4>& probe_to_reference,
                                         const BeamGeometry& geometry, const Vec3& spacing_mm) {
  geometry.validate("compounding: beam geometry");
  // Every beam's first and last sample, in the probe frame once, then per pose.
  const double r1 = geometry.r0_mm + (geometry.n_samples - 1) * geometry.dr_mm;
  std::vector<Vec3> ends;
  for (const Vec3& d : beam_directions(geometry))
    for (double r : {geometry.r0_mm, r1}) ends.push_back(beam_point(geometry, d, r));
  Bounds box;
  for (size_t k = 0; k < probe_to_reference.size(); ++k) {
    check_matrix(probe_to_reference[k], "compounding: probe-to-reference");
    for (const Vec3& p : ends) box.add(probe_to_reference[k].transform_point(p), k);
  }
  return box.grid(spacing_mm, "compounding");
}

}  // namespace sonoslice
