// The Compounder (the dispatch layer of compounding): checks inputs once, turns frames into rows
// in voxel-index space (CompoundTypes.h), picks the CPU slabs, and finishes the volume
// (Finish.cpp). Frame clips, beam geometry and the output grid live beside it (FrameClip.cpp,
// BeamGeometry.cpp, CompoundGrid.cpp).
#include "sonoslice/compound/Compounder.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "../backend/LargeBuffer.h"
#include "../backend/ParallelFor.h"
#include "BeamPoints.h"
#include "ClipSpans.h"
#include "CompoundBackends.h"
#include "CompoundGrid.h"
#include "Finish.h"
#include "PlusExact.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

using compound_impl::Accumulator;
using compound_impl::AccumulatorView;
using compound_impl::FrameBatch;
using compound_impl::kMaxSpans;
using compound_impl::Mode;
using compound_impl::RowLine;
using compound_impl::RowSpans;

using compound_impl::accumulator_bytes_per_voxel;
using compound_impl::beam_directions;
using compound_impl::beam_point;
using compound_impl::check_matrix;
using compound_impl::format_bytes;
using compound_impl::format_dims;
using compound_impl::spans_from_mask;

namespace {

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

// Frames of these types go to the kernels as they are; others are converted to float first.
bool kernel_sample_type(PixelType t) {
  return t == PixelType::UInt8 || t == PixelType::UInt16 || t == PixelType::Int16 ||
         t == PixelType::Float32;
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

// Frames go to the kernels in batches. CPU: about a million samples, one parallel pass over the
// output each, small enough to stay in cache while every slab task reads it. CUDA: 32 M samples
// per upload and launch, so that launches and copies are few.
constexpr int64_t kCpuBatchSamples = int64_t(1) << 20;
constexpr int64_t kCudaBatchSamples = int64_t(1) << 25;

}  // namespace

struct Compounder::Impl {
  VolumeGrid grid;
  CompoundSettings settings;
  Device device;
  Mode mode = Mode::Mean;
  int64_t frames = 0;
  // CPU accumulators (CUDA: downloaded by volume()); stamps only in latest mode.
  backend::LargeArray<Accumulator> cells;
  backend::LargeArray<int32_t> stamp;
  size_t cell_count = 0;
#ifdef SONOSLICE_HAVE_CUDA
  std::unique_ptr<compound_impl::CudaCompounding> cuda;
#endif
  // Clip spans, cached for the last frame size and clip.
  int span_width = -1, span_height = -1;
  FrameClip span_clip;
  std::vector<RowSpans> spans;
  // PLUS-exact: the frames' type (the volume's), fixed by the first frame.
  std::optional<PixelType> plus_frame_type;

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
      cells = backend::make_large_array<Accumulator>(n);
      if (mode == Mode::Latest && !settings.plus_exact)
        stamp = backend::make_large_array<int32_t>(n);
      cell_count = n;
      // PLUS-exact: PLUS's zeroed volume and accumulation buffer.
      const Accumulator empty{settings.plus_exact ? 0.f : compound_impl::empty_value(mode), 0.f};
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
    compound_impl::compound_cpu(cpu_kernel_isa(), g, b, mode,
                                settings.interpolation == Interpolation::Linear, axis, first[axis],
                                last[axis], slabs);
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

  // `axes`: the matrix columns a frame uses (2: an image's pixel x and y; 3: a probe's axes).
  void check_frames(const void* data, int64_t count, const Mat4* matrices, const char* what,
                    int axes) const {
    if (count < 0) throw InputError("compounding: negative frame count");
    if (count > 0 && (!data || !matrices)) throw InputError("compounding: null frame data");
    for (int64_t f = 0; f < count; ++f)
      check_matrix(matrices[f],
                   std::string("compounding: ") + what + " of frame " + std::to_string(frames + f),
                   axes);
  }

  // PLUS-exact insertion of `count` 2D frames (PlusExact.cpp), in batches of ~64 frames.
  void add_plus_exact(const void* data, PixelType type, int width, int height, int64_t count,
                      const Mat4* image_to_reference, const FrameClip& clip) {
    if (!compound_impl::plus_exact_frame_type(type))
      throw InputError(std::string("PLUS-exact compounding: ") + to_string(type) +
                       " frames are not supported (uint8, int16, uint16 or float32)");
    if (plus_frame_type && *plus_frame_type != type)
      throw InputError(std::string("PLUS-exact compounding: ") + to_string(type) +
                       " frames after " + to_string(*plus_frame_type) +
                       " ones (PLUS keeps the volume in the frames' type)");
    if (!clip.custom_mask.empty())
      throw InputError("PLUS-exact compounding: a custom pixel mask is not a PLUS clip");
    plus_frame_type = type;
    compound_impl::PlusExactBatch b;
    b.type = type;
    b.width = width;
    b.height = height;
    b.linear = settings.interpolation == Interpolation::Linear;
    b.mode = mode;
    b.optimization = settings.plus_optimization;
    b.filter = plus_filter(clip, width, height);
    const size_t frame_bytes = size_t(width) * height * pixel_size(type);
    std::vector<IndexMap> matrices;
    for (int64_t first = 0; first < count; first += 64) {
      const int64_t n = std::min<int64_t>(64, count - first);
      matrices.resize(size_t(n));
      for (int64_t f = 0; f < n; ++f)
        matrices[size_t(f)] = grid.index_map(image_to_reference[first + f]);
      b.pixels = static_cast<const char*>(data) + size_t(first) * frame_bytes;
      b.count = n;
      b.matrices = matrices.data();
      compound_impl::plus_exact_insert(view(), b);
      frames += n;
    }
  }

  // PLUS's pixel selection: the clip rectangle as the inclusive extent GetClipExtent makes of it
  // (read_plus_config already turned PLUS's size s into s + 1 pixels), the fan test of
  // vtkUnoptimizedInsertSlice (on when either angle is not 0) and the rejection threshold.
  compound_impl::plus_exact::PixelFilter plus_filter(const FrameClip& clip, int width,
                                                     int height) const {
    compound_impl::plus_exact::PixelFilter f;
    f.x0 = std::max(0, clip.x);
    f.y0 = std::max(0, clip.y);
    f.x1 = clip.width < 0 ? width - 1 : std::min(width - 1, clip.x + clip.width - 1);
    f.y1 = clip.height < 0 ? height - 1 : std::min(height - 1, clip.y + clip.height - 1);
    if (clip.fan) {
      constexpr double kRadiansPerDegree = 0.017453292519943295;  // vtkMath::RadiansFromDegrees
      double l = std::tan(clip.fan_angles_deg[0] * kRadiansPerDegree);
      double r = std::tan(clip.fan_angles_deg[1] * kRadiansPerDegree);
      if (l > r) std::swap(l, r);
      f.fan = l != 0 || r != 0;
      f.tan_left = l;
      f.tan_right = r;
      f.fan_origin[0] = clip.fan_origin_px[0];
      f.fan_origin[1] = clip.fan_origin_px[1];
      f.radius2_start = clip.fan_radius_px[0] * clip.fan_radius_px[0];
      f.radius2_stop = clip.fan_radius_px[1] * clip.fan_radius_px[1];
    }
    f.reject = std::isfinite(settings.rejection_threshold);
    f.threshold = settings.rejection_threshold;
    return f;
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
  if (settings.plus_exact && device.type != DeviceType::CPU)
    throw InputError("PLUS-exact compounding runs on the CPU (device " + device.to_string() + ")");

  compound_impl::check_fits_in_memory(grid, settings, output_type, max_memory_bytes);

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
  im.check_frames(pixels, count, image_to_reference, "image-to-reference", 2);
  if (count == 0) return;
  if (im.settings.plus_exact)
    return im.add_plus_exact(pixels, type, width, height, count, image_to_reference, clip);
  // Row v of a frame: pixel (u, v) at A·(u, v, 0).
  im.add_frames(pixels, type, count, height, width, im.spans_for(width, height, clip),
                [&](int64_t f, RowLine* lines) {
                  const IndexMap A = im.grid.index_map(image_to_reference[f]);
                  const Vec3 dc = A.direction({1, 0, 0});
                  for (int v = 0; v < height; ++v)
                    lines[v] = make_line(A({0, double(v), 0}), dc, im.line_offset());
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
  if (im.settings.plus_exact)
    throw InputError("PLUS-exact compounding takes 2D frames, not beam-space frames");
  im.check_frames(samples, count, probe_to_reference, "probe-to-reference", 3);
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
    const IndexMap A = im.grid.index_map(probe_to_reference[f]);
    for (int r = 0; r < rows; ++r) {
      const Vec3& d = directions[size_t(r)];
      const Vec3 c0 = A(beam_point(geometry, d, geometry.r0_mm));
      const Vec3 dc = A.direction(geometry.dr_mm * d);
      lines[r] = make_line(c0, dc, im.line_offset());
    }
  });
}

Volume Compounder::volume(PixelType type) const {
  Impl& im = *impl_;
  Volume out = Volume::allocate(type, im.grid);
  static const std::vector<HoleFillingKernel> no_kernels;
  const auto& kernels = im.settings.fill_holes ? im.settings.hole_filling : no_kernels;
#ifdef SONOSLICE_HAVE_CUDA
  if (im.cuda) {  // finished on the GPU: only the output type travels back
    im.cuda->finish(kernels, type, out.data());
    return out;
  }
#endif
  im.accumulators_to_host();
  if (im.settings.plus_exact) {
    if (im.plus_frame_type && *im.plus_frame_type != type)
      throw InputError(std::string("PLUS-exact compounding: the volume is in the frames' type (") +
                       to_string(*im.plus_frame_type) + "), not " + to_string(type));
    // The voxels are final values (max: taken as they are). Without hole filling PLUS's volume
    // is written as it is, also where the buffer rounded to 0; with it, those voxels are holes.
    if (kernels.empty()) {
      visit_pixel_type(type, [&](auto zero) {
        using T = decltype(zero);
        T* o = out.data_as<T>();
        const Accumulator* c = im.cells.get();
        backend::parallel_for_chunks(im.grid.voxel_count(), int64_t(1) << 18,
                                     [&](int64_t, int64_t b, int64_t e) {
                                       for (int64_t i = b; i < e; ++i) o[i] = T(c[i].value);
                                     });
      });
      return out;
    }
    compound_impl::finish_volume(im.view(), Mode::Max, kernels, type, out.data());
    return out;
  }
  compound_impl::finish_volume(im.view(), im.mode, kernels, type, out.data());
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

}  // namespace sonoslice
