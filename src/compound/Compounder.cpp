// The dispatch layer of compounding: checks inputs once, turns frames into rows in voxel-index
// space (CompoundTypes.h), picks the CPU slabs, and finishes the volume (Finish.cpp).
#include "sonoslice/compound/Compounder.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>
#include <utility>

#include "../backend/ParallelFor.h"
#include "../core/Text.h"
#include "CompoundBackends.h"
#include "Finish.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

using compound_impl::Accumulator;
using compound_impl::AccumulatorView;
using compound_impl::FrameBatch;
using compound_impl::kMaxSpans;
using compound_impl::Mode;
using compound_impl::RowLine;
using compound_impl::RowSpans;

namespace compound_impl {
void compound_cpu(const AccumulatorView& grid, const FrameBatch& batch, Mode mode, bool linear,
                  int axis, int lo, int hi, int slabs) {
#ifdef SONOSLICE_HAVE_AVX2_KERNELS
  if (cpu_kernel_isa() == "avx2")
    return compound_cpu_avx2(grid, batch, mode, linear, axis, lo, hi, slabs);
#endif
  compound_cpu_generic(grid, batch, mode, linear, axis, lo, hi, slabs);
}
}  // namespace compound_impl

namespace {

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

Mode to_kernel_mode(CompoundingMode m) {
  switch (m) {
    case CompoundingMode::Mean:
      return Mode::Mean;
    case CompoundingMode::Max:
      return Mode::Max;
    case CompoundingMode::Latest:
      return Mode::Latest;
  }
  return Mode::Mean;
}

uint64_t accumulator_bytes_per_voxel(const CompoundSettings& s) {
  return sizeof(Accumulator) + (s.mode == CompoundingMode::Latest ? sizeof(int32_t) : 0);
}

// Frames of these types go to the kernels as they are; others are converted to float first.
bool kernel_sample_type(PixelType t) {
  return t == PixelType::UInt8 || t == PixelType::UInt16 || t == PixelType::Int16 ||
         t == PixelType::Float32;
}

void check_matrix(const Mat4& m, const std::string& what) {
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      if (!std::isfinite(m.m[r][c]))
        throw InputError(what + ": the matrix has a non-finite element (row " + std::to_string(r) +
                         ", column " + std::to_string(c) + ")");
  if (m.m[3][0] != 0 || m.m[3][1] != 0 || m.m[3][2] != 0 || m.m[3][3] != 1)
    throw InputError(what + ": the matrix's last row must be 0 0 0 1");
}

// The affine (3×4) from frame coordinates to continuous voxel index: world_to_index ·
// frame_to_world.
struct Affine {
  double a[3][4];
  Vec3 apply(double x, double y, double z) const {
    return Vec3{{a[0][0] * x + a[0][1] * y + a[0][2] * z + a[0][3],
                 a[1][0] * x + a[1][1] * y + a[1][2] * z + a[1][3],
                 a[2][0] * x + a[2][1] * y + a[2][2] * z + a[2][3]}};
  }
  Vec3 direction(double x, double y, double z) const {
    return Vec3{{a[0][0] * x + a[0][1] * y + a[0][2] * z, a[1][0] * x + a[1][1] * y + a[1][2] * z,
                 a[2][0] * x + a[2][1] * y + a[2][2] * z}};
  }
};

Affine frame_to_index(const VolumeGrid& grid, const Mat4& frame_to_world) {
  const Mat3 w = grid.world_to_index_linear();
  const Vec3 o = grid.world_to_index_offset();
  Affine r;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 4; ++j) {
      double s = 0;
      for (int k = 0; k < 3; ++k) s += w.m[i][k] * frame_to_world.m[k][j];
      r.a[i][j] = s;
    }
    r.a[i][3] += o[i];
  }
  return r;
}

// `offset`: 0.5 for nearest splats (CompoundImpl.h), 0 for linear.
RowLine make_line(const Vec3& c0, const Vec3& dc, double offset) {
  RowLine l;
  for (int a = 0; a < 3; ++a) {
    l.c0[a] = float(c0[a] + offset);
    l.dc[a] = float(dc[a]);
  }
  return l;
}

// The unit directions of the beams (docs/conventions.md §7), elevation slowest:
// (sin α, cos α·cos β, cos α·sin β).
std::vector<Vec3> beam_directions(const BeamGeometry& g) {
  const double deg = kPi / 180.0;
  std::vector<Vec3> directions;
  directions.reserve(size_t(g.n_elevation) * g.n_azimuth);
  for (int e = 0; e < g.n_elevation; ++e)
    for (int a = 0; a < g.n_azimuth; ++a) {
      const double alpha = (g.azimuth0_deg + a * g.dazimuth_deg) * deg;
      const double beta = (g.elevation0_deg + e * g.delevation_deg) * deg;
      directions.push_back(
          {std::sin(alpha), std::cos(alpha) * std::cos(beta), std::cos(alpha) * std::sin(beta)});
    }
  return directions;
}

// The probe-frame point at depth r along the beam of direction d: apex + r·d, with
// apex = (0, -apex_offset, 0).
Vec3 beam_point(const BeamGeometry& g, const Vec3& d, double r) {
  return {r * d[0], r * d[1] - g.apex_offset_mm, r * d[2]};
}

// Frames go to the kernels in batches. CPU: about a million samples, one parallel pass over the
// output each, small enough to stay in cache while every slab task reads it. CUDA: 32 M samples
// per upload and launch, so that launches and copies are few.
constexpr int64_t kCpuBatchSamples = int64_t(1) << 20;
constexpr int64_t kCudaBatchSamples = int64_t(1) << 25;

// Turns a frame's mask rows into runs.
std::vector<RowSpans> spans_from_mask(const std::vector<uint8_t>& mask, int width, int height) {
  std::vector<RowSpans> spans(static_cast<size_t>(height));
  for (int v = 0; v < height; ++v) {
    RowSpans& s = spans[size_t(v)];
    for (int k = 0; k < kMaxSpans; ++k) s.begin[k] = s.end[k] = 0;
    int k = 0;
    const uint8_t* row = mask.data() + size_t(v) * width;
    for (int u = 0; u < width;) {
      if (!row[u]) {
        ++u;
        continue;
      }
      int e = u;
      while (e < width && row[e]) ++e;
      if (k == kMaxSpans)
        throw InputError("frame clip: row " + std::to_string(v) + " of the fan has more than " +
                         std::to_string(kMaxSpans) + " runs of pixels");
      s.begin[k] = u;
      s.end[k] = e;
      ++k;
      u = e;
    }
  }
  return spans;
}

}  // namespace

const char* to_string(CompoundingMode mode) {
  switch (mode) {
    case CompoundingMode::Mean:
      return "mean";
    case CompoundingMode::Max:
      return "max";
    case CompoundingMode::Latest:
      return "latest";
  }
  return "?";
}

const char* to_string(HoleFillingKernel::Type type) {
  switch (type) {
    case HoleFillingKernel::NearestNeighbor:
      return "nearest_neighbor";
    case HoleFillingKernel::Gaussian:
      return "gaussian";
    case HoleFillingKernel::GaussianAccumulation:
      return "gaussian_accumulation";
    case HoleFillingKernel::DistanceWeightInverse:
      return "distance_weight_inverse";
    case HoleFillingKernel::Stick:
      return "stick";
  }
  return "?";
}

CompoundingMode parse_compounding_mode(const std::string& name) {
  const std::string n = text::lower(name);
  if (n == "mean") return CompoundingMode::Mean;
  if (n == "max" || n == "maximum") return CompoundingMode::Max;
  if (n == "latest") return CompoundingMode::Latest;
  throw InputError("compounding mode '" + name + "': expected mean, max or latest");
}

HoleFillingKernel::Type parse_hole_filling_type(const std::string& name) {
  const std::string n = text::lower(name);
  if (n == "nearest_neighbor" || n == "nearest") return HoleFillingKernel::NearestNeighbor;
  if (n == "gaussian") return HoleFillingKernel::Gaussian;
  if (n == "gaussian_accumulation") return HoleFillingKernel::GaussianAccumulation;
  if (n == "distance_weight_inverse") return HoleFillingKernel::DistanceWeightInverse;
  if (n == "stick") return HoleFillingKernel::Stick;
  throw InputError("hole filling type '" + name +
                   "': expected NEAREST_NEIGHBOR, GAUSSIAN, GAUSSIAN_ACCUMULATION, "
                   "DISTANCE_WEIGHT_INVERSE or STICK");
}

int HoleFillingKernel::reach() const {
  if (type == Stick) return std::max(1, stick_length_limit - 2);
  return std::max(1, (size - 1) / 2);
}

void HoleFillingKernel::validate(const std::string& what) const {
  if (type == Stick) {
    if (stick_length_limit < 3 || stick_length_limit > 255)
      throw InputError(what + ": stick_length_limit " + std::to_string(stick_length_limit) +
                       " must be between 3 and 255 voxels");
    if (sticks_to_use < 1 || sticks_to_use > 13)
      throw InputError(what + ": sticks_to_use " + std::to_string(sticks_to_use) +
                       " must be between 1 and 13");
    return;
  }
  if (size < 3 || size > 31 || size % 2 == 0)
    throw InputError(what + ": size " + std::to_string(size) + " must be odd, 3 to 31 voxels");
  if ((type == Gaussian || type == GaussianAccumulation) && !(stdev > 0 && std::isfinite(stdev)))
    throw InputError(what + ": stdev (the Gaussian's, in voxels) must be positive");
  if (!(minimum_known_ratio >= 0 && minimum_known_ratio < 1))
    throw InputError(what + ": minimum_known_ratio must be in [0, 1)");
}

std::array<int, 4> FrameClip::rectangle(int frame_width, int frame_height) const {
  if (!custom_mask.empty() && custom_mask.size() == size_t(frame_width) * size_t(frame_height)) {
    // The box around the mask's pixels.
    std::array<int, 4> box{frame_width, frame_height, 0, 0};
    for (int v = 0; v < frame_height; ++v)
      for (int u = 0; u < frame_width; ++u)
        if (custom_mask[size_t(v) * frame_width + u]) {
          box = {std::min(box[0], u), std::min(box[1], v), std::max(box[2], u + 1),
                 std::max(box[3], v + 1)};
        }
    if (box[0] >= box[2]) box = {0, 0, 0, 0};
    return box;
  }
  const int x0 = std::max(0, x), y0 = std::max(0, y);
  const int x1 = width < 0 ? frame_width : std::min(frame_width, x + width);
  const int y1 = height < 0 ? frame_height : std::min(frame_height, y + height);
  return {x0, y0, std::max(x0, x1), std::max(y0, y1)};
}

void FrameClip::validate(const std::string& what) const {
  if (x < 0 || y < 0)
    throw InputError(what + ": clip rectangle x, y = " + std::to_string(x) + ", " +
                     std::to_string(y) + " must not be negative");
  if (width < -1 || height < -1)
    throw InputError(what + ": clip rectangle width x height = " + std::to_string(width) + "x" +
                     std::to_string(height) + " is negative (-1: to the frame's edge)");
  if (!fan) return;
  for (double a : fan_angles_deg)
    if (!(a > -90 && a < 90))
      throw InputError(what +
                       ": fan angles (fan_angles_deg) must be strictly between -90 and 90 degrees");
  if (!(fan_angles_deg[0] <= fan_angles_deg[1]))
    throw InputError(what + ": fan angles (fan_angles_deg) must be given smallest first");
  if (!std::isfinite(fan_origin_px[0]) || !std::isfinite(fan_origin_px[1]))
    throw InputError(what + ": fan origin (fan_origin_px) must be finite");
  if (!(fan_radius_px[0] >= 0 && fan_radius_px[1] >= fan_radius_px[0]))
    throw InputError(what + ": fan radii (fan_radius_px) must satisfy 0 <= start <= stop");
}

std::vector<uint8_t> FrameClip::mask(int frame_width, int frame_height) const {
  validate("frame clip");
  if (!custom_mask.empty()) {
    if (custom_mask.size() != size_t(frame_width) * size_t(frame_height))
      throw InputError("frame clip: the mask has " + std::to_string(custom_mask.size()) +
                       " pixels, frames have " + std::to_string(frame_width) + "x" +
                       std::to_string(frame_height));
    return custom_mask;
  }
  std::vector<uint8_t> m(size_t(frame_width) * frame_height, 0);
  const auto r = rectangle(frame_width, frame_height);
  // PLUS's fan test (unoptimised path): below the origin, tan(a0) <= dx/dy <= tan(a1), and
  // start <= distance <= stop, all inclusive.
  const double deg = kPi / 180.0;
  const double tan0 = std::tan(fan_angles_deg[0] * deg), tan1 = std::tan(fan_angles_deg[1] * deg);
  for (int v = r[1]; v < r[3]; ++v)
    for (int u = r[0]; u < r[2]; ++u) {
      if (fan) {
        const double dx = u - fan_origin_px[0], dy = v - fan_origin_px[1];
        if (dy < 0) continue;
        if (dy == 0 ? dx != 0 : (dx / dy < tan0 || dx / dy > tan1)) continue;
        const double d2 = dx * dx + dy * dy;
        if (d2 < fan_radius_px[0] * fan_radius_px[0] || d2 > fan_radius_px[1] * fan_radius_px[1])
          continue;
      }
      m[size_t(v) * frame_width + u] = 1;
    }
  return m;
}

void BeamGeometry::validate(const std::string& what) const {
  if (n_elevation <= 0 || n_azimuth <= 0 || n_samples <= 0)
    throw InputError(what + ": beam-space frame size " + std::to_string(n_elevation) + "x" +
                     std::to_string(n_azimuth) + "x" + std::to_string(n_samples) +
                     " must be positive");
  if (int64_t(n_elevation) * n_azimuth > (int64_t(1) << 28) || n_samples > (1 << 24))
    throw InputError(what + ": beam-space frame size is absurd");
  const std::pair<const char*, double> values[] = {{"r0_mm", r0_mm},
                                                   {"dr_mm", dr_mm},
                                                   {"azimuth0_deg", azimuth0_deg},
                                                   {"dazimuth_deg", dazimuth_deg},
                                                   {"elevation0_deg", elevation0_deg},
                                                   {"delevation_deg", delevation_deg},
                                                   {"apex_offset_mm", apex_offset_mm}};
  for (const auto& [name, v] : values)
    if (!std::isfinite(v)) throw InputError(what + ": beam geometry " + name + " is not finite");
  if (!(dr_mm > 0)) throw InputError(what + ": sample spacing dr_mm must be positive");
  if (r0_mm < 0) throw InputError(what + ": first sample depth r0_mm must not be negative");
  const double a_end = azimuth0_deg + (n_azimuth - 1) * dazimuth_deg;
  const double e_end = elevation0_deg + (n_elevation - 1) * delevation_deg;
  if (std::fabs(azimuth0_deg) >= 90 || std::fabs(a_end) >= 90)
    throw InputError(what + ": beam angles must stay within ±90 degrees (azimuth0_deg " +
                     std::to_string(azimuth0_deg) + " to " + std::to_string(a_end) + " over " +
                     std::to_string(n_azimuth) + " beams of dazimuth_deg)");
  if (std::fabs(elevation0_deg) >= 90 || std::fabs(e_end) >= 90)
    throw InputError(what + ": beam angles must stay within ±90 degrees (elevation0_deg " +
                     std::to_string(elevation0_deg) + " to " + std::to_string(e_end) + " over " +
                     std::to_string(n_elevation) + " planes of delevation_deg)");
}

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

struct Compounder::Impl {
  VolumeGrid grid;
  CompoundSettings settings;
  Device device;
  Mode mode = Mode::Mean;
  int64_t frames = 0;
  // CPU accumulators (CUDA: downloaded by volume()); stamps only in latest mode.
  std::unique_ptr<Accumulator[]> cells;
  std::unique_ptr<int32_t[]> stamp;
  size_t cell_count = 0;
#ifdef SONOSLICE_HAVE_CUDA
  std::unique_ptr<compound_impl::CudaCompounding> cuda;
#endif
  // Clip spans, cached for the last frame size and clip.
  int span_width = -1, span_height = -1;
  FrameClip span_clip;
  std::vector<RowSpans> spans;

  AccumulatorView view() {
    AccumulatorView v;
    v.nx = int(grid.dims[0]);
    v.ny = int(grid.dims[1]);
    v.nz = int(grid.dims[2]);
    v.cells = cells.get();
    v.stamp = stamp.get();
    return v;
  }

  void ensure_host_accumulators() {
    const size_t n = size_t(grid.voxel_count());
    if (cell_count == n) return;
    try {
      // Uninitialised, then filled by all threads: the first touch of a GiB-sized grid is
      // page faults, which parallelise.
      cells.reset(new Accumulator[n]);
      if (mode == Mode::Latest) stamp.reset(new int32_t[n]);
      cell_count = n;
      const Accumulator empty{compound_impl::empty_value(mode), 0.f};
      backend::parallel_for_chunks(int64_t(n), int64_t(1) << 18,
                                   [&](int64_t, int64_t b, int64_t e) {
                                     std::fill(cells.get() + b, cells.get() + e, empty);
                                     if (stamp) std::fill(stamp.get() + b, stamp.get() + e, -1);
                                   });
    } catch (const std::bad_alloc&) {
      throw ResourceError("compounding: out of memory allocating the accumulators (" +
                          format_bytes(uint64_t(n) * accumulator_bytes_per_voxel(settings)) + ")");
    }
  }

  const std::vector<RowSpans>& spans_for(int width, int height, const FrameClip& clip) {
    const bool same =
        width == span_width && height == span_height && clip.x == span_clip.x &&
        clip.y == span_clip.y && clip.width == span_clip.width && clip.height == span_clip.height &&
        clip.fan == span_clip.fan && clip.custom_mask == span_clip.custom_mask &&
        (!clip.fan ||
         (std::equal(clip.fan_angles_deg, clip.fan_angles_deg + 2, span_clip.fan_angles_deg) &&
          std::equal(clip.fan_origin_px, clip.fan_origin_px + 2, span_clip.fan_origin_px) &&
          std::equal(clip.fan_radius_px, clip.fan_radius_px + 2, span_clip.fan_radius_px)));
    if (!same) {
      spans = spans_from_mask(clip.mask(width, height), width, height);
      span_width = width;
      span_height = height;
      span_clip = clip;
    }
    return spans;
  }

  // Runs one batch on the chosen backend.
  void run(const FrameBatch& batch) {
#ifdef SONOSLICE_HAVE_CUDA
    if (cuda) {
      cuda->add(batch, settings.interpolation == Interpolation::Linear);
      return;
    }
#endif
    run_cpu(batch);
  }

  // CPU: owner-computes slabs over the batch's footprint. Each slab task walks every row that
  // can reach it, so the axis is chosen to keep rows in few slabs: a row crossing k slabs is
  // visited k times, and reading a row in pieces is slow. Cost of axis a with S slabs:
  //   rows + Σ_rows |row length along a| · S / (footprint extent along a).
  void run_cpu(const FrameBatch& b) {
    const AccumulatorView g = view();
    const int n[3] = {g.nx, g.ny, g.nz};
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    double along[3] = {0, 0, 0};  // summed row lengths along each axis (voxels)
    int64_t rows = 0;
    for (int f = 0; f < b.frames; ++f)
      for (int r = 0; r < b.rows; ++r) {
        const RowLine& l = b.lines[int64_t(f) * b.rows + r];
        const RowSpans& s = b.spans[r];
        for (int k = 0; k < kMaxSpans; ++k) {
          if (s.begin[k] >= s.end[k]) continue;
          ++rows;
          for (int a = 0; a < 3; ++a) {
            along[a] += std::fabs(double(l.dc[a])) * (s.end[k] - s.begin[k]);
            for (int u : {s.begin[k], s.end[k] - 1}) {
              const double c = double(l.c0[a]) + double(u) * l.dc[a];
              lo[a] = std::min(lo[a], c);
              hi[a] = std::max(hi[a], c);
            }
          }
        }
      }
    int first[3], last[3];
    for (int a = 0; a < 3; ++a) {
      if (!(lo[a] < n[a] && hi[a] > -1)) return;  // the batch misses the grid
      first[a] = int(std::max(0.0, std::floor(lo[a])));
      last[a] = int(std::min(double(n[a]), std::floor(hi[a]) + 2));
      if (first[a] >= last[a]) return;
    }
    const int threads = cpu_threads();
    // Two slabs per thread, handed out dynamically, even out the work of uneven slabs.
    int slabs = threads <= 1 ? 1 : 2 * threads;
    int axis = -1;
    while (axis < 0) {
      double best = 1e300;
      for (int a = 0; a < 3; ++a) {
        const int extent = last[a] - first[a];
        if (slabs > 1 && extent < 2 * slabs) continue;  // slabs of at least two voxels
        const double cost = double(rows) + along[a] * slabs / std::max(1, extent);
        if (cost < best) {
          best = cost;
          axis = a;
        }
      }
      if (axis < 0) slabs = std::max(1, slabs / 2);
    }
    compound_impl::compound_cpu(g, b, mode, settings.interpolation == Interpolation::Linear, axis,
                                first[axis], last[axis], slabs);
  }

  // Frames of other types travel as float32.
  const void* kernel_samples(const void* data, PixelType type, size_t count,
                             std::vector<float>& converted, PixelType* kernel_type) {
    if (kernel_sample_type(type)) {
      *kernel_type = type;
      return data;
    }
    converted.resize(count);
    visit_pixel_type(type, [&](auto zero) {
      using T = decltype(zero);
      const T* p = static_cast<const T*>(data);
      for (size_t i = 0; i < count; ++i) converted[i] = float(p[i]);
    });
    *kernel_type = PixelType::Float32;
    return converted.data();
  }

  // CUDA: copies the accumulators into host memory, where volume() finishes them.
  void accumulators_to_host() {
#ifdef SONOSLICE_HAVE_CUDA
    if (cuda) {
      ensure_host_accumulators();
      cuda->download(cells.get(), stamp.get());
    }
#endif
  }

  int64_t batch_samples() const {
    return device.type == DeviceType::CUDA ? kCudaBatchSamples : kCpuBatchSamples;
  }

  double line_offset() const {
    return settings.interpolation == Interpolation::Nearest ? 0.5 : 0.0;
  }

  void check_frames(const void* data, int64_t count, const Mat4* matrices, const char* what) const {
    if (count < 0) throw InputError("compounding: negative frame count");
    if (count > 0 && (!data || !matrices)) throw InputError("compounding: null frame data");
    for (int64_t f = 0; f < count; ++f)
      check_matrix(matrices[f],
                   std::string("compounding: ") + what + " of frame " + std::to_string(frames + f));
  }

  // `count` frames of rows × width samples, in batches: make_lines(f, lines) writes frame f's
  // rows in voxel-index space.
  template <typename MakeLines>
  void add_frames(const void* data, PixelType type, int64_t count, int rows, int width,
                  const std::vector<RowSpans>& spans, const MakeLines& make_lines) {
    const size_t frame_samples = size_t(rows) * width;
    const int64_t per_batch = std::max<int64_t>(1, batch_samples() / int64_t(frame_samples));
    std::vector<RowLine> lines;
    std::vector<float> converted;
    for (int64_t first = 0; first < count; first += per_batch) {
      const int64_t n = std::min(per_batch, count - first);
      lines.resize(size_t(n) * rows);
      for (int64_t f = 0; f < n; ++f) make_lines(first + f, lines.data() + size_t(f) * rows);
      FrameBatch b;
      b.first_frame_id = int32_t(frames);
      b.rejection_threshold = std::isfinite(settings.rejection_threshold)
                                  ? float(settings.rejection_threshold)
                                  : -std::numeric_limits<float>::infinity();
      const char* batch =
          static_cast<const char*>(data) + size_t(first) * frame_samples * pixel_size(type);
      b.samples = kernel_samples(batch, type, size_t(n) * frame_samples, converted, &b.type);
      b.frames = int(n);
      b.rows = rows;
      b.width = width;
      b.lines = lines.data();
      b.spans = spans.data();
      run(b);
      frames += n;
    }
  }
};

Compounder::Compounder(const VolumeGrid& grid, CompoundSettings settings, Device device,
                       uint64_t max_memory_bytes, PixelType output_type)
    : impl_(std::make_unique<Impl>()) {
  grid.validate("compounding output grid");
  for (int a = 0; a < 3; ++a)
    if (grid.dims[a] > (int64_t(1) << 20))
      throw InputError("compounding output grid: " + format_dims(grid.dims) + " voxels is absurd");
  if (!(settings.rejection_threshold == settings.rejection_threshold))
    throw InputError("compounding: the pixel rejection threshold is NaN");
  for (size_t k = 0; k < settings.hole_filling.size(); ++k)
    settings.hole_filling[k].validate("hole filling element " + std::to_string(k + 1));
  require_device(device);

  const uint64_t need = compounding_memory_bytes(grid, settings, output_type);
  const uint64_t limit = max_memory_bytes ? max_memory_bytes : available_memory_bytes();
  if (need > limit)
    throw ResourceError("compounding: the output grid (" + format_dims(grid.dims) + " voxels at " +
                        std::to_string(grid.spacing_mm[0]).substr(0, 5) + " mm) needs " +
                        format_bytes(need) + ", more than the " + format_bytes(limit) +
                        (max_memory_bytes ? " allowed (--max-memory)" : " available") + "; " +
                        suggest_spacing(grid, settings, output_type, limit));

  Impl& im = *impl_;
  im.grid = grid;
  im.settings = std::move(settings);
  im.device = device;
  im.mode = to_kernel_mode(im.settings.mode);
  if (device.type == DeviceType::CUDA) {
#ifdef SONOSLICE_HAVE_CUDA
    im.cuda = std::make_unique<compound_impl::CudaCompounding>(
        device.index, int(grid.dims[0]), int(grid.dims[1]), int(grid.dims[2]), im.mode);
#endif
  } else {
    im.ensure_host_accumulators();
  }
}

Compounder::~Compounder() = default;
Compounder::Compounder(Compounder&&) noexcept = default;

const VolumeGrid& Compounder::grid() const {
  return impl_->grid;
}
const CompoundSettings& Compounder::settings() const {
  return impl_->settings;
}
int64_t Compounder::frames_added() const {
  return impl_->frames;
}

void Compounder::add_image(const void* pixels, PixelType type, int width, int height,
                           const Mat4& image_to_reference, const FrameClip& clip) {
  add_images(pixels, type, width, height, 1, &image_to_reference, clip);
}

void Compounder::add_images(const void* pixels, PixelType type, int width, int height,
                            int64_t count, const Mat4* image_to_reference, const FrameClip& clip) {
  Impl& im = *impl_;
  if (width <= 0 || height <= 0 || int64_t(width) * height > (int64_t(1) << 28))
    throw InputError("compounding: frame size " + std::to_string(width) + "x" +
                     std::to_string(height) + " is not usable");
  im.check_frames(pixels, count, image_to_reference, "image-to-reference");
  if (count == 0) return;
  // Row v of a frame: pixel (u, v) at A·(u, v, 0).
  im.add_frames(pixels, type, count, height, width, im.spans_for(width, height, clip),
                [&](int64_t f, RowLine* lines) {
                  const Affine A = frame_to_index(im.grid, image_to_reference[f]);
                  const Vec3 dc = A.direction(1, 0, 0);
                  for (int v = 0; v < height; ++v)
                    lines[v] = make_line(A.apply(0, v, 0), dc, im.line_offset());
                });
}

void Compounder::add_beams(const void* samples, PixelType type, const BeamGeometry& geometry,
                           const Mat4& probe_to_reference) {
  add_beams(samples, type, geometry, 1, &probe_to_reference);
}

void Compounder::add_beams(const void* samples, PixelType type, const BeamGeometry& geometry,
                           int64_t count, const Mat4* probe_to_reference) {
  Impl& im = *impl_;
  geometry.validate("compounding: beam geometry");
  im.check_frames(samples, count, probe_to_reference, "probe-to-reference");
  if (count == 0) return;
  const int rows = geometry.n_elevation * geometry.n_azimuth, width = geometry.n_samples;
  std::vector<RowSpans> spans(static_cast<size_t>(rows));
  for (auto& s : spans) {
    for (int k = 0; k < kMaxSpans; ++k) s.begin[k] = s.end[k] = 0;
    s.end[0] = width;
  }
  const std::vector<Vec3> directions = beam_directions(geometry);
  // Beam r: sample s at beam_point(r0 + s·dr).
  im.add_frames(samples, type, count, rows, width, spans, [&](int64_t f, RowLine* lines) {
    const Affine A = frame_to_index(im.grid, probe_to_reference[f]);
    for (int r = 0; r < rows; ++r) {
      const Vec3& d = directions[size_t(r)];
      const Vec3 p0 = beam_point(geometry, d, geometry.r0_mm);
      const Vec3 c0 = A.apply(p0[0], p0[1], p0[2]);
      const Vec3 dc =
          A.direction(geometry.dr_mm * d[0], geometry.dr_mm * d[1], geometry.dr_mm * d[2]);
      lines[r] = make_line(c0, dc, im.line_offset());
    }
  });
}

Volume Compounder::volume(PixelType type) const {
  Impl& im = *impl_;
  im.accumulators_to_host();
  Volume out = Volume::allocate(type, im.grid);
  static const std::vector<HoleFillingKernel> no_kernels;
  compound_impl::finish_volume(im.view(), im.mode,
                               im.settings.fill_holes ? im.settings.hole_filling : no_kernels, type,
                               out.data());
  return out;
}

Volume Compounder::weights() const {
  Impl& im = *impl_;
  im.accumulators_to_host();
  Volume out = Volume::allocate(PixelType::Float32, im.grid);
  float* w = out.data_as<float>();
  const Accumulator* c = im.cells.get();
  const int64_t n = im.grid.voxel_count();
  for (int64_t i = 0; i < n; ++i) w[i] = c[i].weight;
  return out;
}

namespace {

// The box around the points given to add(): the grid PLUS fits around the frames.
struct Bounds {
  Vec3 lo{{1e300, 1e300, 1e300}}, hi{{-1e300, -1e300, -1e300}};
  bool empty = true;
  void add(const Vec3& p) {
    empty = false;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], p[a]);
      hi[a] = std::max(hi[a], p[a]);
    }
  }
  // Origin at the minimum, round((max - min) / spacing) + 1 voxels per axis.
  VolumeGrid grid(const Vec3& spacing_mm, const char* what) const {
    for (double s : spacing_mm)
      if (!(s > 0 && std::isfinite(s)))
        throw InputError(std::string(what) + ": output spacing must be a positive number of mm");
    if (empty)
      throw InputError(std::string(what) + ": no valid frame to compute the output extent from");
    VolumeGrid g;
    for (int a = 0; a < 3; ++a) {
      g.origin_mm[a] = lo[a];
      g.spacing_mm[a] = spacing_mm[a];
      g.dims[a] = int64_t(std::round((hi[a] - lo[a]) / spacing_mm[a])) + 1;
    }
    return g;
  }
};

}  // namespace

VolumeGrid Compounder::grid_around(const std::vector<Mat4>& image_to_reference, int width,
                                   int height, const FrameClip& clip, const Vec3& spacing_mm) {
  const auto r = clip.rectangle(width, height);
  if (r[0] >= r[2] || r[1] >= r[3])
    throw InputError("compounding: the clip rectangle leaves no pixel of the frame");
  // Corner pixel centres: first and last pixel of the clip rectangle.
  const double xs[2] = {double(r[0]), double(r[2] - 1)}, ys[2] = {double(r[1]), double(r[3] - 1)};
  Bounds box;
  for (const Mat4& m : image_to_reference) {
    check_matrix(m, "compounding: image-to-reference");
    for (double x : xs)
      for (double y : ys) box.add(m.transform_point(Vec3{{x, y, 0.0}}));
  }
  return box.grid(spacing_mm, "compounding");
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
  for (const Mat4& m : probe_to_reference) {
    check_matrix(m, "compounding: probe-to-reference");
    for (const Vec3& p : ends) box.add(m.transform_point(p));
  }
  return box.grid(spacing_mm, "compounding");
}

}  // namespace sonoslice
