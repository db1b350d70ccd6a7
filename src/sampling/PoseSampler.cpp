// Pose samplers (docs/datasets.md §2): where a sample's probe goes, as a pure function of its
// seed. The expensive part (the skin surface of a CT, a mesh's area table, a region's voxels)
// is built once per sampler; a candidate pose then costs a handful of random numbers.
#include "sonoslice/sampling/PoseSampler.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <type_traits>

#include "../backend/ParallelFor.h"
#include "../core/Random.h"
#include "../core/Text.h"
#include "../geometry/Sampling.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

namespace {

/// The random numbers of one candidate: splitmix64 seeded from (seed, try).
struct Rng : SplitMix64 {
  Rng(uint64_t seed, uint64_t attempt)
      : SplitMix64(mix64(seed ^ mix64(attempt + 0x632BE59BD9B4E019ull))) {}
  double in(const Interval& i) { return i.lo + (i.hi - i.lo) * uniform(); }
};

constexpr double kDeg = kPi / 180;

/// A lateral axis perpendicular to the beam: the world's z (the body axis) crossed with the beam,
/// or x when the beam runs along z.
Vec3 lateral_for(const Vec3& beam) {
  Vec3 x = cross(beam, Vec3{0, 0, 1});
  if (norm(x) < 1e-6) x = cross(beam, Vec3{1, 0, 0});
  return normalized(x);
}

/// The probe's rotation with beam ŷ = `beam`, turned by `spin` (rad) about it.
Mat3 frame_for(const Vec3& beam, double spin) {
  const Vec3 x0 = lateral_for(beam);
  const Vec3 x = rotation_about(beam, spin) * x0;
  const Vec3 z = cross(x, beam);
  Mat3 r;
  for (int i = 0; i < 3; ++i) {
    r.m[i][0] = x[i];
    r.m[i][1] = beam[i];
    r.m[i][2] = z[i];
  }
  return r;
}

/// The pose whose probe point `anchor` (probe mm) lies at world `at`, with rotation R.
Pose place(const Mat3& R, const Vec3& anchor, const Vec3& at) {
  return Mat4::from_rotation_translation(R, at - R * anchor);
}

/// Multiplies R by a rotation about the probe's own axis `axis` (0: x̂, 1: ŷ, 2: ẑ).
Mat3 turn_local(const Mat3& R, int axis, double angle) {
  Vec3 k{0, 0, 0};
  k[size_t(axis)] = 1;
  return R * rotation_about(k, angle);
}

/// Uniform random rotation (three draws, in this order).
Mat3 random_rotation(Rng& rng) {
  const double u1 = rng.uniform(), u2 = rng.uniform(), u3 = rng.uniform();
  return uniform_rotation(u1, u2, u3);
}

/// Reads voxel i of any pixel type as double.
std::function<double(int64_t)> voxel_reader(const Volume& v) {
  return visit_pixel_type(v.pixel_type(), [&](auto zero) -> std::function<double(int64_t)> {
    using T = decltype(zero);
    const T* data = v.data_as<T>();
    return [data](int64_t i) { return double(data[i]); };
  });
}

/// f(i, double(voxel i)) for the voxels of z-slice z, the pixel type dispatched once (not per
/// voxel, as `read` does).
template <typename F>
void for_slice_values(const Volume& v, int64_t z, F&& f) {
  const int64_t slice = v.grid().dims[0] * v.grid().dims[1];
  visit_pixel_type(v.pixel_type(), [&](auto zero) {
    using T = decltype(zero);
    const T* data = v.data_as<T>();
    for (int64_t i = z * slice; i < (z + 1) * slice; ++i) f(i, double(data[i]));
  });
}

/// A volume read as double at any pixel type, with its world → index map kept (VolumeGrid
/// computes it by inverting).
struct VoxelSource {
  Volume volume;
  std::function<double(int64_t)> read;
  Mat3 L;
  Vec3 o{0, 0, 0};
  geometry::VolumeView view;

  VoxelSource() = default;
  explicit VoxelSource(const Volume& v)
      : volume(v),
        read(voxel_reader(v)),
        L(v.grid().world_to_index_linear()),
        o(v.grid().world_to_index_offset()),
        view(geometry::VolumeView::of(v.grid().dims[0], v.grid().dims[1], v.grid().dims[2])) {}
  bool empty() const { return volume.empty(); }
  Vec3 index_of(const Vec3& p) const { return L * p + o; }
  /// The nearest voxel's flat index (conventions.md §5 `nearest`), or −1 outside.
  int64_t nearest(const Vec3& p) const {
    const Vec3 c = index_of(p);
    if (!geometry::inside(view, c[0], c[1], c[2])) return -1;
    return geometry::nearest_offset(view, c[0], c[1], c[2]);
  }
};

/// Floods the 6-connected region of voxels equal to `from` around `seed` with `to`; its size.
/// Span by span along x (a scanline fill): each run is filled at once, and the rows beside it
/// (y ± 1, z ± 1) get one seed per run of `from` they hold.
int64_t flood(std::vector<uint8_t>& mask, const int64_t dims[3], int64_t seed, uint8_t from,
              uint8_t to, std::vector<int64_t>& stack) {
  const int64_t nx = dims[0], ny = dims[1], nz = dims[2];
  int64_t size = 0;
  stack.assign(1, seed);
  while (!stack.empty()) {
    const int64_t i = stack.back();
    stack.pop_back();
    if (mask[size_t(i)] != from) continue;
    const int64_t row = i - i % nx, y = (i / nx) % ny, z = i / (nx * ny);
    int64_t lo = i, hi = i;
    while (lo > row && mask[size_t(lo - 1)] == from) --lo;
    while (hi + 1 < row + nx && mask[size_t(hi + 1)] == from) ++hi;
    std::fill(mask.begin() + lo, mask.begin() + hi + 1, to);
    size += hi - lo + 1;
    const int64_t offsets[4] = {y > 0 ? -nx : 0, y + 1 < ny ? nx : 0, z > 0 ? -nx * ny : 0,
                                z + 1 < nz ? nx * ny : 0};
    for (int64_t off : offsets) {
      if (off == 0) continue;
      bool in_run = false;
      for (int64_t j = lo + off; j <= hi + off; ++j) {
        const bool match = mask[size_t(j)] == from;
        if (match && !in_run) stack.push_back(j);
        in_run = match;
      }
    }
  }
  return size;
}

/// Keeps the largest 6-connected component of `mask` (1 = in) as 1; everything else becomes 0.
void keep_largest_component(std::vector<uint8_t>& mask, const int64_t dims[3]) {
  const int64_t n = dims[0] * dims[1] * dims[2];
  std::vector<int64_t> stack;
  int64_t best_seed = -1, best_size = 0;
  for (int64_t i = 0; i < n; ++i)
    if (mask[size_t(i)] == 1) {
      const int64_t size = flood(mask, dims, i, 1, 2, stack);
      if (size > best_size) {
        best_size = size;
        best_seed = i;
      }
    }
  if (best_seed >= 0) flood(mask, dims, best_seed, 2, 3, stack);
  for (auto& m : mask) m = m == 3 ? 1 : 0;
}

/// Sets to 1 every voxel of `mask` not connected to the volume's border through 0 voxels: the
/// body's internal cavities.
void fill_cavities(std::vector<uint8_t>& mask, const int64_t dims[3]) {
  const int64_t nx = dims[0], ny = dims[1], nz = dims[2];
  std::vector<int64_t> stack;
  // The border voxels only (x == 0 or nx − 1 on every row; whole rows where y or z is at an end).
  for (int64_t z = 0; z < nz; ++z)
    for (int64_t y = 0; y < ny; ++y) {
      const bool whole = y == 0 || z == 0 || y == ny - 1 || z == nz - 1;
      const int64_t row = (z * ny + y) * nx;
      for (int64_t x = 0; x < nx; x += whole || x == nx - 1 ? 1 : nx - 1)
        if (mask[size_t(row + x)] == 0) flood(mask, dims, row + x, 0, 2, stack);
    }
  for (auto& m : mask) m = m == 2 ? 0 : 1;
}

}  // namespace

void SamplerSettings::validate(const std::string& where) const {
  const auto interval = [&](const Interval& i, const char* name) {
    if (!std::isfinite(i.lo) || !std::isfinite(i.hi) || i.lo > i.hi)
      throw InputError(where + ": " + name + ": expected [lo, hi] with lo <= hi");
  };
  interval(rotation_deg, "rotation_deg");
  interval(tilt_deg, "tilt_deg");
  interval(heel_toe_deg, "heel_toe_deg");
  interval(depth_mm, "depth_mm");
  if (std::max(std::fabs(depth_mm.lo), std::fabs(depth_mm.hi)) > kMaxGeometryMm)
    throw InputError(where + ": depth_mm: beyond any body (at most 1e9 mm)");
  if (std::max(std::fabs(tilt_deg.lo), std::fabs(tilt_deg.hi)) > 89 ||
      std::max(std::fabs(heel_toe_deg.lo), std::fabs(heel_toe_deg.hi)) > 89)
    throw InputError(where + ": tilt_deg and heel_toe_deg must stay within ±89 degrees");
  if (intensity) interval(*intensity, "intensity");
  if (!std::isfinite(threshold_hu)) throw InputError(where + ": threshold_hu: must be finite");
  if (!(cone_deg > 0 && cone_deg <= 180))
    throw InputError(where + ": cone_deg: must be in (0, 180]");
  if (!(norm(direction) > 0) || !std::isfinite(norm(direction)))
    throw InputError(where + ": direction: must be a non-zero vector");
  if (type == SamplerType::Region && label < 0 && !intensity)
    throw InputError(where + ": region: give its \"label\" or \"intensity\" range (for example " +
                     "{\"type\": \"region\", \"label\": 3}; a label among the rejection rules does "
                     "not choose the region)");
  if (type == SamplerType::Sweep) {
    if (frames < 1 || frames > 100000)
      throw InputError(where + ": frames: must be from 1 to 100000");
    if (!std::isfinite(step)) throw InputError(where + ": step: must be finite");
    if (!(jitter_mm >= 0 && std::isfinite(jitter_mm)) ||
        !(jitter_deg >= 0 && std::isfinite(jitter_deg)))
      throw InputError(where + ": jitter_mm and jitter_deg: must be finite and >= 0");
    if (!start && !base)
      throw InputError(where + ": sweep: give its \"start\" pose or a base sampler as \"from\" " +
                       "(for example {\"type\": \"sweep\", \"from\": {\"type\": \"skin\"}})");
    if (start && base) throw InputError(where + ": sweep: give \"start\" or \"from\", not both");
    if (base) {
      if (base->type == SamplerType::Sweep)
        throw InputError(where + ": sweep: its base sampler cannot be another sweep");
      base->validate(where + ": from");
    }
    if (start) validate_poses(&*start, 1, where + ": start");
  }
  const RejectionRules& r = reject;
  for (const auto& [key, f] : {std::pair<const char*, double>{"min_inside", r.min_inside},
                               {"min_body", r.min_body},
                               {"min_label", r.min_label}})
    if (!(f >= 0 && f <= 1))
      throw InputError(where + ": reject." + key + " " + text::number(f) +
                       ": must be a fraction in [0, 1]");
  if (r.min_label > 0 && r.label < 0) throw InputError(where + ": reject: min_label needs a label");
  // A label alone rejects nothing: it only says which label min_label counts.
  if (r.label >= 0 && !(r.min_label > 0))
    throw InputError(where + ": reject.label " + std::to_string(r.label) +
                     ": needs min_label, the fraction of the fan that must lie in that label");
  if (!(r.gas_depth_mm >= 1 && r.gas_depth_mm <= 100) || !std::isfinite(r.gas_hu))
    throw InputError(where + ": reject: gas_depth_mm must be in [1, 100] mm, gas_hu finite");
  if (max_tries < 1 || max_tries > 10000000)
    throw InputError(where + ": max_tries: must be from 1 to 10000000");
}

std::vector<uint64_t> sample_seeds(uint64_t base, uint64_t stream, uint64_t first, size_t count) {
  std::vector<uint64_t> seeds(count);
  const uint64_t key = mix64(mix64(base) ^ (stream * 0xD1B54A32D192ED03ull + 1));
  for (size_t i = 0; i < count; ++i) seeds[i] = mix64(key + (first + i) * kGoldenGamma);
  return seeds;
}

namespace {

/// Frame k of a sweep from `start`: the motion's offset (centred on the start), then jitter.
Pose sweep_frame(const SamplerSettings& s, const Vec3& face, const Pose& start, uint64_t seed,
                 int k) {
  const double offset = (k - 0.5 * (s.frames - 1)) * s.step;
  Mat3 R = start.linear();
  const Vec3 at = start.transform_point(face);  // the face centre stays put (fan, rotational)
  Vec3 moved = at;
  switch (s.motion) {
    case SweepMotion::Linear:
      moved = at + offset * R.column(2);
      break;
    case SweepMotion::Fan:
      R = turn_local(R, 0, offset * kDeg);
      break;
    case SweepMotion::Rotational:
      R = turn_local(R, 1, offset * kDeg);
      break;
  }
  if (s.jitter_mm > 0 || s.jitter_deg > 0) {
    Rng rng(seed, 0x5EED0000ull + uint64_t(k));
    const Vec3 dt{rng.normal() * s.jitter_mm, rng.normal() * s.jitter_mm,
                  rng.normal() * s.jitter_mm};
    const Vec3 w{rng.normal(), rng.normal(), rng.normal()};
    const double angle = s.jitter_deg * kDeg * norm(w) / std::sqrt(3.0);
    if (angle > 0) R = rotation_about(normalized(w), angle) * R;
    moved = moved + dt;
  }
  return place(R, face, moved);
}

}  // namespace

struct PoseSampler::State {
  SamplerSettings s;
  ProbeGeometry probe;
  Vec3 face{0, 0, 0};      // the face centre, probe mm
  Vec3 centre{0, 0, 0};    // the fan's centre, probe mm
  VoxelSource ct, labels;  // either may be empty
  // Skin: surface points and outward normals. Mesh: triangles' corners, normals, area CDF.
  std::vector<Vec3> points, normals;
  std::vector<std::array<Vec3, 3>> triangles;
  std::vector<double> area_cdf;
  // Region: the voxels (flat indices) to draw from.
  std::vector<int64_t> region;
  // Rejection: the fan's coarse points and the points under the face (probe mm).
  std::vector<Vec3> fan_points, gas_points;
  std::unique_ptr<PoseSampler> base;  // sweep: the sampler of its start poses

  double ct_value(const Vec3& p, bool* inside) const;
  void build_skin();
  void build_mesh(const TriangleMesh& mesh);
  void build_region();
  void build_rejection_points();
  Pose candidate(uint64_t seed, uint64_t attempt) const;
  Pose draw(Rng& rng) const;
  bool accepts(const Pose& pose) const;
  /// The poses of `seed` (poses_per_seed of them) into out; false when max_tries candidates
  /// all failed the rules.
  bool sample_one(uint64_t seed, Pose* out) const;
};

double PoseSampler::State::ct_value(const Vec3& p, bool* inside) const {
  // Registration's edge rule (conventions.md §5): the skin search needs the CT to vary across
  // every sample it bisects, which the clamped half-voxel rim does not.
  using geometry::EdgeRule;
  const Vec3 c = ct.index_of(p);
  *inside = geometry::inside<EdgeRule::Interior>(ct.view, c[0], c[1], c[2]);
  if (!*inside) return 0;
  return geometry::linear_value<double>(
      ct.read, geometry::linear_cell<EdgeRule::Interior>(ct.view, c[0], c[1], c[2]));
}

void PoseSampler::State::build_skin() {
  const VolumeGrid& g = ct.volume.grid();
  const int64_t nx = g.dims[0], ny = g.dims[1], nz = g.dims[2], n = g.voxel_count();
  std::vector<uint8_t> body(size_t(n), 0);
  backend::parallel_for(nz, [&](int64_t z) {
    for_slice_values(ct.volume, z,
                     [&](int64_t i, double v) { body[size_t(i)] = v > s.threshold_hu ? 1 : 0; });
  });
  keep_largest_component(body, g.dims.data());
  fill_cavities(body, g.dims.data());  // lungs and bowel gas are inside, not skin
  // Surface voxels: in the body with a 6-neighbour (inside the volume) outside it.
  std::vector<std::vector<int64_t>> surface_of(static_cast<size_t>(nz));  // per slice, in order
  backend::parallel_for(nz, [&](int64_t z) {
    for (int64_t y = 0; y < ny; ++y)
      for (int64_t x = 0; x < nx; ++x) {
        const int64_t i = (z * ny + y) * nx + x;
        if (!body[size_t(i)]) continue;
        const bool edge =
            (x > 0 && !body[size_t(i - 1)]) || (x + 1 < nx && !body[size_t(i + 1)]) ||
            (y > 0 && !body[size_t(i - nx)]) || (y + 1 < ny && !body[size_t(i + nx)]) ||
            (z > 0 && !body[size_t(i - nx * ny)]) || (z + 1 < nz && !body[size_t(i + nx * ny)]);
        if (edge) surface_of[size_t(z)].push_back(i);
      }
  });
  std::vector<int64_t> surface;
  for (const auto& in_slice : surface_of)
    surface.insert(surface.end(), in_slice.begin(), in_slice.end());
  if (surface.empty())
    throw InputError("skin sampler: no body surface at threshold_hu " +
                     std::to_string(s.threshold_hu) + " (is the volume a CT in HU?)");
  // Outward normal: minus the gradient of a soft body mask, Gaussian-weighted over 9³ voxels (in
  // world mm). The soft mask follows the CT's partial-volume ramp across the threshold (so the
  // normal is not the staircase of a binary mask), with cavities counted as body and other
  // bright objects (a table) as outside. Then the point itself: where the trilinear CT crosses
  // the threshold along that normal, within two voxels of the voxel centre.
  const double h = std::max({g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]});
  const auto soft_of = [&](bool in_body, double v) {  // 0..255
    const double ramp = std::min(1.0, std::max(0.0, (v - s.threshold_hu) / 1000 + 0.5));
    const double f =
        in_body ? (v > s.threshold_hu ? ramp : 1.0) : (v > s.threshold_hu ? 0.0 : ramp);
    return uint8_t(255 * f + 0.5);
  };
  std::unique_ptr<uint8_t[]> soft(new uint8_t[size_t(n)]);  // every voxel written below
  visit_pixel_type(ct.volume.pixel_type(), [&](auto zero) {
    using T = decltype(zero);
    const T* data = ct.volume.data_as<T>();
    const int64_t slice = nx * ny;
    if constexpr (std::is_integral_v<T> && sizeof(T) <= 2) {
      // A CT's usual types: every value's soft mask once (the same formula), then a table
      // lookup per voxel.
      constexpr int64_t lo = std::numeric_limits<T>::min(),
                        count = int64_t(std::numeric_limits<T>::max()) - lo + 1;
      std::vector<uint8_t> table(size_t(2 * count));
      for (int64_t k = 0; k < count; ++k) {
        table[size_t(k)] = soft_of(false, double(lo + k));
        table[size_t(count + k)] = soft_of(true, double(lo + k));
      }
      backend::parallel_for(nz, [&](int64_t z) {
        for (int64_t j = z * slice; j < (z + 1) * slice; ++j)
          soft[size_t(j)] = table[size_t(body[size_t(j)] * count + (int64_t(data[j]) - lo))];
      });
    } else {
      backend::parallel_for(nz, [&](int64_t z) {
        for (int64_t j = z * slice; j < (z + 1) * slice; ++j)
          soft[size_t(j)] = soft_of(body[size_t(j)] != 0, double(data[j]));
      });
    }
  });
  constexpr int r = 4;  // σ = 1.5 voxels, cut at 2.7σ
  double weight[2 * r + 1];
  for (int d = -r; d <= r; ++d) weight[d + r] = std::exp(-0.5 * d * d / (1.5 * 1.5));
  // The 9³ taps once, in the order they are summed: weight (wx·wy)·wz, world offset, and flat
  // index offset (the same products per voxel as computing them in the loop, so the same bits).
  struct Tap {
    int dx, dy, dz;
    int64_t offset;
    double w;
    Vec3 o;
  };
  std::vector<Tap> taps;
  for (int dz = -r; dz <= r; ++dz)
    for (int dy = -r; dy <= r; ++dy)
      for (int dx = -r; dx <= r; ++dx)
        taps.push_back(
            {dx, dy, dz, (dz * ny + dy) * nx + dx, weight[dx + r] * weight[dy + r] * weight[dz + r],
             g.direction * Vec3{dx * g.spacing_mm[0], dy * g.spacing_mm[1], dz * g.spacing_mm[2]}});
  std::vector<Vec3> point(surface.size()), normal(surface.size());
  std::vector<uint8_t> ok(surface.size(), 0);
  backend::parallel_for_chunks(int64_t(surface.size()), 256, [&](int64_t, int64_t b, int64_t e) {
    for (int64_t k = b; k < e; ++k) {
      const int64_t i = surface[size_t(k)];
      const int64_t x = i % nx, y = (i / nx) % ny, z = i / (nx * ny);
      Vec3 sum{0, 0, 0};
      if (x >= r && y >= r && z >= r && x + r < nx && y + r < ny && z + r < nz) {
        const uint8_t* around = soft.get() + i;
        for (const Tap& t : taps) sum = sum - (t.w * around[t.offset]) * t.o;
      } else {  // near the volume's border: the taps inside it
        for (const Tap& t : taps) {
          const int64_t xx = x + t.dx, yy = y + t.dy, zz = z + t.dz;
          if (xx < 0 || yy < 0 || zz < 0 || xx >= nx || yy >= ny || zz >= nz) continue;
          sum = sum - (t.w * soft[size_t(i + t.offset)]) * t.o;
        }
      }
      if (!(norm(sum) > 0)) continue;
      const Vec3 nrm = normalized(sum);
      const Vec3 p0 = g.index_to_world(Vec3{double(x), double(y), double(z)});
      // From inside (above threshold) to outside (below), the crossing nearest the voxel.
      double best = std::numeric_limits<double>::infinity(), at = 0;
      constexpr int steps = 16;
      double prev_t = -2 * h, prev_v = 0;
      bool prev_in = false;
      prev_v = ct_value(p0 + prev_t * nrm, &prev_in);
      for (int j = 1; j <= steps; ++j) {
        const double t = -2 * h + 4 * h * j / steps;
        bool in = false;
        const double v = ct_value(p0 + t * nrm, &in);
        if (in && prev_in && prev_v > s.threshold_hu && v <= s.threshold_hu) {
          double lo = prev_t, hi = t;     // bisection on the sign change
          for (int b = 0; b < 12; ++b) {  // to 0.4 µm on 1.5 mm voxels
            const double mid = 0.5 * (lo + hi);
            bool mid_in = false;
            (ct_value(p0 + mid * nrm, &mid_in) > s.threshold_hu ? lo : hi) = mid;
          }
          const double c = 0.5 * (lo + hi);
          if (std::fabs(c) < best) {
            best = std::fabs(c);
            at = c;
          }
        }
        prev_t = t;
        prev_v = v;
        prev_in = in;
      }
      if (!std::isfinite(best)) continue;
      const Vec3 q = p0 + at * nrm;
      point[size_t(k)] = q;
      normal[size_t(k)] = nrm;
      ok[size_t(k)] = 1;
    }
  });
  for (size_t k = 0; k < surface.size(); ++k)
    if (ok[k]) {
      points.push_back(point[k]);
      normals.push_back(normal[k]);
    }
  if (points.empty())
    throw InputError("skin sampler: the body surface has no threshold crossing inside the volume");
}

void PoseSampler::State::build_mesh(const TriangleMesh& mesh) {
  mesh.validate();
  // A closed mesh wound inward (negative signed volume) has its normals flipped, so that they
  // point out of the organ.
  double signed_volume = 0;
  for (const auto& t : mesh.triangles) {
    const Vec3 &a = mesh.vertices[size_t(t[0])], &b = mesh.vertices[size_t(t[1])],
               &c = mesh.vertices[size_t(t[2])];
    signed_volume += dot(a, cross(b, c)) / 6;
  }
  const double flip = mesh_topology(mesh).closed() && signed_volume < 0 ? -1 : 1;
  double total = 0;
  for (const auto& t : mesh.triangles) {
    const Vec3 &a = mesh.vertices[size_t(t[0])], &b = mesh.vertices[size_t(t[1])],
               &c = mesh.vertices[size_t(t[2])];
    const Vec3 n = cross(b - a, c - a);
    const double area = norm(n) / 2;
    if (!(area > 1e-12)) continue;  // degenerate: no normal, never drawn
    triangles.push_back({a, b, c});
    normals.push_back((flip / (2 * area)) * n);
    total += area;
    area_cdf.push_back(total);
  }
  if (triangles.empty()) throw InputError("mesh sampler: mesh '" + mesh.name + "' has no area");
  for (double& a : area_cdf) a /= total;
}

void PoseSampler::State::build_region() {
  const bool by_label = s.label >= 0;
  if (by_label && labels.empty())
    throw InputError("region sampler: label " + std::to_string(s.label) + " needs a label volume");
  const VoxelSource& v = by_label ? labels : ct;
  const int64_t n = v.volume.grid().voxel_count();
  for (int64_t i = 0; i < n; ++i) {
    const double x = v.read(i);
    if (by_label ? x == double(s.label) : (x >= s.intensity->lo && x <= s.intensity->hi))
      region.push_back(i);
  }
  if (region.empty())
    throw InputError(by_label ? "region sampler: no voxel has label " + std::to_string(s.label)
                              : "region sampler: no voxel lies in the intensity range");
}

void PoseSampler::State::build_rejection_points() {
  // About 16 × 16 pixel centres of the image inside the fan.
  const ImageGrid& img = probe.image;
  const int su = std::max(1, img.width / 16), sv = std::max(1, img.height / 16);
  for (int v = sv / 2; v < img.height; v += sv)
    for (int u = su / 2; u < img.width; u += su) {
      const double x = img.origin_mm[0] + u * img.spacing_mm[0];
      const double y = img.origin_mm[1] + v * img.spacing_mm[1];
      if (probe.inside(x, y)) fan_points.push_back({x, y, 0});
    }
  if (fan_points.empty()) fan_points.push_back(centre);
  // Under the central half of the face: 9 beams, from 1 mm to gas_depth_mm deep, 1 mm apart.
  const double depth = s.reject.gas_depth_mm;
  for (int b = 0; b < 9; ++b) {
    const double f = (b - 4) / 16.0;  // −1/4 … 1/4 of the aperture
    for (double d = 1; d <= depth + 1e-9; d += 1) {
      if (probe.type == ProbeType::Curvilinear) {
        const double a = f * probe.sector_deg * kDeg, r = probe.radius_mm + d;
        gas_points.push_back(
            {r * std::sin(a), probe.face_y_mm - probe.radius_mm + r * std::cos(a), 0});
      } else {
        gas_points.push_back({f * probe.width_mm, probe.face_y_mm + d, 0});
      }
    }
  }
}

Pose PoseSampler::State::draw(Rng& rng) const {
  switch (s.type) {
    case SamplerType::Skin:
    case SamplerType::Mesh: {
      Vec3 at, outward;
      if (s.type == SamplerType::Skin) {
        const size_t k = size_t(rng.next() % points.size());
        at = points[k];
        outward = normals[k];
      } else {
        const double u = rng.uniform();
        const size_t k =
            size_t(std::lower_bound(area_cdf.begin(), area_cdf.end(), u) - area_cdf.begin());
        const auto& t = triangles[std::min(k, triangles.size() - 1)];
        double a = rng.uniform(), b = rng.uniform();
        if (a + b > 1) {  // fold into the triangle: uniform by area
          a = 1 - a;
          b = 1 - b;
        }
        at = t[0] + a * (t[1] - t[0]) + b * (t[2] - t[0]);
        outward = normals[std::min(k, normals.size() - 1)];
      }
      Mat3 R = frame_for((-1.0) * outward, rng.in(s.rotation_deg) * kDeg);
      R = turn_local(R, 0, rng.in(s.tilt_deg) * kDeg);      // fanning, about x̂
      R = turn_local(R, 2, rng.in(s.heel_toe_deg) * kDeg);  // heel-toe, about ẑ
      const double depth = rng.in(s.depth_mm);
      return place(R, face, at + depth * R.column(1));
    }
    case SamplerType::Region: {
      const VolumeGrid& g = (s.label >= 0 ? labels : ct).volume.grid();
      const int64_t i = region[size_t(rng.next() % region.size())];
      const Vec3 c{double(i % g.dims[0]) + rng.uniform() - 0.5,
                   double((i / g.dims[0]) % g.dims[1]) + rng.uniform() - 0.5,
                   double(i / (g.dims[0] * g.dims[1])) + rng.uniform() - 0.5};
      const Vec3 at = g.index_to_world(c);
      Mat3 R;
      if (s.cone_deg >= 180) {
        R = random_rotation(rng);
      } else {
        // The beam uniform on the cap within cone_deg of `direction`, then a spin about it.
        const Vec3 d = normalized(s.direction);
        const double cos_max = std::cos(s.cone_deg * kDeg);
        const double cz = 1 - rng.uniform() * (1 - cos_max), phi = 2 * kPi * rng.uniform();
        const double sz = std::sqrt(std::max(0.0, 1 - cz * cz));
        const Vec3 e1 = lateral_for(d), e2 = cross(d, e1);
        const Vec3 beam = cz * d + (sz * std::cos(phi)) * e1 + (sz * std::sin(phi)) * e2;
        R = frame_for(normalized(beam), rng.in(s.rotation_deg) * kDeg);
      }
      return place(R, s.anchor_at_centre ? centre : face, at);
    }
    case SamplerType::Sweep:
      break;
  }
  throw InputError("sampler: a sweep is drawn through its frames");
}

Pose PoseSampler::State::candidate(uint64_t seed, uint64_t attempt) const {
  Rng rng(seed, attempt);
  return draw(rng);
}

bool PoseSampler::State::accepts(const Pose& pose) const {
  const RejectionRules& r = s.reject;
  if (!r.any()) return true;
  const Mat3 R = pose.linear();
  const Vec3 t = pose.column3(3);
  if (r.min_inside > 0 || r.min_body > 0 || r.min_label > 0) {
    int inside = 0, in_body = 0, in_label = 0;
    for (const Vec3& p : fan_points) {
      const Vec3 w = R * p + t;
      if (!ct.empty()) {
        const int64_t i = ct.nearest(w);
        if (i >= 0) {
          ++inside;
          in_body += ct.read(i) > s.threshold_hu;
        }
      }
      if (r.min_label > 0) {
        const int64_t i = labels.nearest(w);
        in_label += i >= 0 && labels.read(i) == double(r.label);
      }
    }
    const double n = double(fan_points.size());
    if (r.min_inside > 0 && inside < r.min_inside * n) return false;
    if (r.min_body > 0 && in_body < r.min_body * n) return false;
    if (r.min_label > 0 && in_label < r.min_label * n) return false;
  }
  if (r.no_gas)
    for (const Vec3& p : gas_points) {
      const int64_t i = ct.nearest(R * p + t);
      if (i < 0 || ct.read(i) < r.gas_hu) return false;
    }
  return true;
}

PoseSampler::PoseSampler(const SamplerSettings& settings, const ProbeGeometry& probe,
                         const Volume* volume, const Volume* labels, const TriangleMesh* mesh)
    : state_(std::make_unique<State>()) {
  settings.validate("sampler");
  probe.validate("probe");
  State& st = *state_;
  st.s = settings;
  st.probe = probe;
  st.face = {0, probe.face_y_mm, 0};
  st.centre = {0, probe.face_y_mm + 0.5 * probe.depth_mm, 0};
  if (volume) st.ct = VoxelSource(*volume);
  if (labels) {
    check_label_values(*labels, "labels");
    st.labels = VoxelSource(*labels);
  }
  const RejectionRules& r = settings.reject;
  const bool needs_volume = settings.type == SamplerType::Skin ||
                            (settings.type == SamplerType::Region && settings.label < 0) ||
                            r.min_inside > 0 || r.min_body > 0 || r.no_gas;
  if (needs_volume && st.ct.empty())
    throw InputError(
        "sampler: needs the CT volume (skin sampler, intensity region or the "
        "min_inside, min_body and no_gas rules)");
  if (r.min_label > 0 && st.labels.empty())
    throw InputError("sampler: reject.min_label needs a label volume");
  switch (settings.type) {
    case SamplerType::Skin:
      st.build_skin();
      break;
    case SamplerType::Mesh:
      if (!mesh) throw InputError("mesh sampler: needs a mesh");
      st.build_mesh(*mesh);
      break;
    case SamplerType::Region:
      st.build_region();
      break;
    case SamplerType::Sweep:
      if (settings.base)
        st.base = std::make_unique<PoseSampler>(*settings.base, probe, volume, labels, mesh);
      break;
  }
  st.build_rejection_points();
}

PoseSampler::~PoseSampler() = default;
PoseSampler::PoseSampler(PoseSampler&&) noexcept = default;

int PoseSampler::poses_per_seed() const {
  return state_->s.type == SamplerType::Sweep ? state_->s.frames : 1;
}

const std::vector<Vec3>& PoseSampler::surface_points() const {
  return state_->points;
}
const std::vector<Vec3>& PoseSampler::surface_normals() const {
  return state_->normals;
}

bool PoseSampler::accepts(const Pose& pose) const {
  validate_poses(&pose, 1, "pose");  // NaN or a non-rigid matrix is bad input, not a rejection
  return state_->accepts(pose);
}

bool PoseSampler::State::sample_one(uint64_t seed, Pose* out) const {
  for (int attempt = 0; attempt < s.max_tries; ++attempt) {
    if (s.type != SamplerType::Sweep) {
      *out = candidate(seed, uint64_t(attempt));
      if (accepts(*out)) return true;
      continue;
    }
    // A sweep is one candidate: its start (the base sampler's, with the base's own rules),
    // then every frame must pass this sampler's rules.
    Pose start = s.start ? *s.start : Pose::identity();
    if (!s.start && !base->state_->sample_one(
                        mix64(seed ^ (uint64_t(attempt) * 0xA24BAED4963EE407ull)), &start))
      continue;
    bool ok = true;
    for (int f = 0; f < s.frames && ok; ++f) {
      out[f] = sweep_frame(s, face, start, seed, f);
      ok = accepts(out[f]);
    }
    if (ok) return true;
  }
  return false;
}

namespace {
constexpr int64_t kSeedsPerTask = 1024;  // parallel items must be coarse (ParallelFor.h)
}  // namespace

std::vector<Pose> PoseSampler::sample(const uint64_t* seeds, size_t count) const {
  const State& st = *state_;
  const size_t per = size_t(poses_per_seed());
  std::vector<Pose> out(count * per);
  // The first seed (by index) whose candidates all fail. Any failure ends in an error, so once
  // one is known only the seeds before it still matter: impossible rules fail after a few
  // seeds' tries instead of every seed's, and the seed named is the same on every run.
  std::atomic<int64_t> first_failed{int64_t(count)};
  backend::parallel_for_chunks(int64_t(count), kSeedsPerTask, [&](int64_t, int64_t b, int64_t e) {
    for (int64_t k = b; k < e && k < first_failed.load(std::memory_order_relaxed); ++k)
      if (!st.sample_one(seeds[size_t(k)], &out[size_t(k) * per])) {
        int64_t seen = first_failed.load();
        while (k < seen && !first_failed.compare_exchange_weak(seen, k)) {
        }
        return;
      }
  });
  const int64_t k = first_failed.load();
  if (k < int64_t(count))
    throw InputError("sampler: no pose of seed " + std::to_string(seeds[size_t(k)]) +
                     " passed the rejection rules in " + std::to_string(st.s.max_tries) +
                     " tries: the rules (reject) may be impossible for this volume and probe");
  return out;
}

std::vector<Pose> PoseSampler::candidates(const uint64_t* seeds, size_t count) const {
  const State& st = *state_;
  if (st.s.type == SamplerType::Sweep) return sample(seeds, count);
  std::vector<Pose> out(count);
  backend::parallel_for_chunks(int64_t(count), kSeedsPerTask, [&](int64_t, int64_t b, int64_t e) {
    for (int64_t k = b; k < e; ++k) out[size_t(k)] = st.candidate(seeds[size_t(k)], 0);
  });
  return out;
}

}  // namespace sonoslice
