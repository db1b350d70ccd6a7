// Registration: the pyramid (block-averaged volume and frames), the metrics from the kernel's
// sums (RegisterImpl.h), and Gauss–Newton / Levenberg–Marquardt with multi-start per frame or
// for a whole sweep. docs/registration.md.
#include "sonoslice/register/Registration.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <limits>
#include <optional>
#include <sstream>

#include "../backend/ParallelFor.h"
#include "../core/Random.h"
#include "RegisterImpl.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

#ifdef SONOSLICE_HAVE_NLOPT
#include <nlopt.hpp>
#endif

namespace sonoslice {

RegistrationMetric parse_registration_metric(const std::string& name, const std::string& what) {
  for (RegistrationMetric m :
       {RegistrationMetric::SSD, RegistrationMetric::NCC, RegistrationMetric::LNCC,
        RegistrationMetric::MI, RegistrationMetric::LC2})
    if (name == to_string(m)) return m;
  throw InputError(what + " " + name + ": expected ssd, ncc, lncc, mi or lc2");
}

bool built_with_nlopt() {
#ifdef SONOSLICE_HAVE_NLOPT
  return true;
#else
  return false;
#endif
}

RegistrationOptimizer parse_registration_optimizer(const std::string& name,
                                                   const std::string& what) {
  for (RegistrationOptimizer o :
       {RegistrationOptimizer::GaussNewton, RegistrationOptimizer::LevenbergMarquardt,
        RegistrationOptimizer::Bobyqa, RegistrationOptimizer::NelderMead})
    if (name == to_string(o)) return o;
  throw InputError(what + " " + name + ": expected gn, lm, bobyqa or nelder-mead");
}

RegistrationMode parse_registration_mode(const std::string& name, const std::string& what) {
  for (RegistrationMode m :
       {RegistrationMode::PerFrame, RegistrationMode::RigidSweep, RegistrationMode::SmoothSweep})
    if (name == to_string(m)) return m;
  throw InputError(what + " " + name + ": expected per-frame, rigid-sweep or smooth-sweep");
}

const char* to_string(RegistrationMetric metric) {
  switch (metric) {
    case RegistrationMetric::SSD:
      return "ssd";
    case RegistrationMetric::NCC:
      return "ncc";
    case RegistrationMetric::LNCC:
      return "lncc";
    case RegistrationMetric::MI:
      return "mi";
    case RegistrationMetric::LC2:
      return "lc2";
  }
  return "?";
}

const char* to_string(RegistrationOptimizer optimizer) {
  switch (optimizer) {
    case RegistrationOptimizer::GaussNewton:
      return "gn";
    case RegistrationOptimizer::LevenbergMarquardt:
      return "lm";
    case RegistrationOptimizer::Bobyqa:
      return "bobyqa";
    case RegistrationOptimizer::NelderMead:
      return "nelder-mead";
  }
  return "?";
}

const char* to_string(RegistrationMode mode) {
  switch (mode) {
    case RegistrationMode::PerFrame:
      return "per-frame";
    case RegistrationMode::RigidSweep:
      return "rigid-sweep";
    case RegistrationMode::SmoothSweep:
      return "smooth-sweep";
  }
  return "?";
}

bool metric_has_derivatives(RegistrationMetric metric) {
  return metric == RegistrationMetric::SSD || metric == RegistrationMetric::NCC;
}

RegistrationOptimizer default_optimizer(RegistrationMetric metric) {
  return metric_has_derivatives(metric) ? RegistrationOptimizer::LevenbergMarquardt
                                        : RegistrationOptimizer::Bobyqa;
}

RegistrationSettings RegistrationSettings::resolved() const {
  RegistrationSettings s = *this;
  if (!s.optimizer) s.optimizer = default_optimizer(metric);
  return s;
}

void RegistrationSettings::validate(const ParameterNames& names) const {
  const auto name = [&](const char* setting) { return spelled(names, setting); };
  const auto number = [](double v) {
    std::ostringstream out;
    out << v;
    return out.str();
  };
  if (starts < 1)
    throw InputError(name("starts") + " " + std::to_string(starts) + ": must be at least 1");
  if (!(search_rot_deg >= 0 && search_rot_deg <= 180))
    throw InputError(name("search_rot_deg") + " " + number(search_rot_deg) +
                     ": must be in [0, 180] degrees");
  if (!(search_trans_mm >= 0 && std::isfinite(search_trans_mm)))
    throw InputError(name("search_trans_mm") + " " + number(search_trans_mm) +
                     ": must be a finite distance >= 0 mm");
  if (pyramid.empty()) throw InputError(name("pyramid") + ": needs at least one level");
  for (int f : pyramid)
    if (f < 1 || f > 64) {
      std::string levels;
      for (int g : pyramid) levels += (levels.empty() ? "" : ",") + std::to_string(g);
      throw InputError(name("pyramid") + " " + levels +
                       ": expected block sizes from 1 to 64, coarse to fine, e.g. 8,4,2,1");
    }
  if (max_iterations < 1) throw InputError(name("max_iterations") + ": must be at least 1");
  if (!(tolerance_mm > 0) || !(tolerance_deg > 0))
    throw InputError(name("tolerance_mm") + " and " + name("tolerance_deg") + ": must be > 0");
  const RegistrationOptimizer o = optimizer ? *optimizer : default_optimizer(metric);
  const bool derivative_based =
      o == RegistrationOptimizer::GaussNewton || o == RegistrationOptimizer::LevenbergMarquardt;
  if (!metric_has_derivatives(metric) && derivative_based)
    throw InputError(name("metric") + " " + to_string(metric) +
                     " has no analytic derivatives: use " + name("optimizer") +
                     " bobyqa or nelder-mead");
  if (!derivative_based && !built_with_nlopt())
    throw InputError(
        name("optimizer") + " " + to_string(o) +
        (optimizer ? "" : " (the default for " + name("metric") + " " + to_string(metric) + ")") +
        ": this sonoslice was built without NLopt (Debian: libnlopt-cxx-dev)");
  if (!(smoothness >= 0 && std::isfinite(smoothness)))
    throw InputError(name("smoothness") + " " + number(smoothness) +
                     ": must be a finite weight >= 0");
  if (mode == RegistrationMode::SmoothSweep &&
      !(metric_has_derivatives(metric) && derivative_based))
    throw InputError(name("mode") + " smooth-sweep: needs " + name("metric") + " ssd or ncc with " +
                     name("optimizer") +
                     " lm or gn (all frames are solved jointly from their analytic derivatives)");
}

void PoseTerms::add(const PoseTerms& o) {
  n += o.n;
  si += o.si;
  sf += o.sf;
  sii += o.sii;
  sff += o.sff;
  sif += o.sif;
  for (int k = 0; k < 6; ++k) {
    sj[k] += o.sj[k];
    sij[k] += o.sij[k];
    sfj[k] += o.sfj[k];
  }
  for (int k = 0; k < 21; ++k) sjj[k] += o.sjj[k];
}

namespace {

constexpr double kMinPixels = 16;

/// The full 6×6 Σ J·Jᵀ from its upper triangle.
void full_jj(const PoseTerms& t, double* out) {
  int e = 0;
  for (int r = 0; r < 6; ++r)
    for (int k = r; k < 6; ++k) out[6 * r + k] = out[6 * k + r] = t.sjj[e++];
}

}  // namespace

double metric_cost(RegistrationMetric metric, const PoseTerms& t, double* gradient,
                   double* hessian) {
  if (!metric_has_derivatives(metric))
    throw InputError(std::string("metric_cost: ") + to_string(metric) +
                     " is computed by FrameRegistration::cost");
  if (t.n < kMinPixels) return std::numeric_limits<double>::infinity();
  const double n = t.n;
  if (metric == RegistrationMetric::SSD) {
    // Σ(I − F)²/n; its gradient 2·Σ(I − F)·J/n; Gauss–Newton 2·Σ J·Jᵀ/n.
    const double cost = (t.sii - 2 * t.sif + t.sff) / n;
    if (gradient)
      for (int k = 0; k < 6; ++k) gradient[k] = 2 * (t.sij[k] - t.sfj[k]) / n;
    if (hessian) {
      full_jj(t, hessian);
      for (int k = 0; k < 36; ++k) hessian[k] *= 2 / n;
    }
    return cost;
  }
  // NCC: ρ = cov / sqrt(var_I · var_F) over the compared pixels (sums centred by n).
  const double cov = t.sif - t.si * t.sf / n;
  const double vi = t.sii - t.si * t.si / n;
  const double vf = t.sff - t.sf * t.sf / n;
  if (!(vi > 0) || !(vf > 0)) return std::numeric_limits<double>::infinity();  // flat: no signal
  const double root = std::sqrt(vi * vf);
  const double rho = cov / root;
  if (gradient)
    for (int k = 0; k < 6; ++k) {
      const double dcov = t.sfj[k] - t.sf * t.sj[k] / n;
      const double dvi = 2 * (t.sij[k] - t.si * t.sj[k] / n);
      gradient[k] = -(dcov / root - 0.5 * rho * dvi / vi);  // of 1 − ρ
    }
  if (hessian) {
    // 1 − ρ = Σ r²/(2n) with r = (I − Ī)/σ_I − (F − F̄)/σ_F; dr ≈ (J − J̄)/σ_I, so the
    // Gauss–Newton matrix is (Σ J·Jᵀ − n·J̄·J̄ᵀ)/var_I (σ_I² = var_I/n).
    full_jj(t, hessian);
    for (int r = 0; r < 6; ++r)
      for (int k = 0; k < 6; ++k)
        hessian[6 * r + k] = (hessian[6 * r + k] - t.sj[r] * t.sj[k] / n) / vi;
  }
  return 1 - rho;
}

Pose apply_increment(const Pose& pose, const double xi[6], const Vec3& c) {
  // Rotation by ω about c, then translation by v: w ↦ c + v + R(ω)·(w − c).
  const Mat3 R = rotation_from_vector({xi[3], xi[4], xi[5]});
  const Vec3 rc = R * c;
  const Vec3 shift = {c[0] + xi[0] - rc[0], c[1] + xi[1] - rc[1], c[2] + xi[2] - rc[2]};
  return Mat4::from_rotation_translation(R, shift) * pose;
}

namespace {

/// One pyramid level: every frame and the mask averaged over f² pixel blocks, the volume over
/// g³ voxel blocks, g the largest whole number of voxels within f pixels (at least 1): a volume
/// already coarser than the blocks is not averaged again.
struct Level {
  int f = 1, g = 1;
  std::vector<float> volume_copy;  // empty: the full-resolution float volume, shared
  const float* volume = nullptr;
  int nx = 0, ny = 0, nz = 0;
  std::vector<float> frames;   // count × w × h
  std::vector<uint8_t> masks;  // count × w × h (fan ∧ user ∧ finite)
  int width = 0, height = 0;
};

/// Solves the 6×6 system A·x = b (Gaussian elimination with partial pivoting); false when it is
/// singular.
bool solve6(double A[36], double b[6], double x[6]) {
  int order[6] = {0, 1, 2, 3, 4, 5};
  for (int col = 0; col < 6; ++col) {
    int best = col;
    for (int r = col + 1; r < 6; ++r)
      if (std::fabs(A[6 * order[r] + col]) > std::fabs(A[6 * order[best] + col])) best = r;
    std::swap(order[col], order[best]);
    const double pivot = A[6 * order[col] + col];
    if (!(std::fabs(pivot) > 1e-300)) return false;
    for (int r = col + 1; r < 6; ++r) {
      const double m = A[6 * order[r] + col] / pivot;
      for (int k = col; k < 6; ++k) A[6 * order[r] + k] -= m * A[6 * order[col] + k];
      b[order[r]] -= m * b[order[col]];
    }
  }
  for (int col = 5; col >= 0; --col) {
    double s = b[order[col]];
    for (int k = col + 1; k < 6; ++k) s -= A[6 * order[col] + k] * x[k];
    x[col] = s / A[6 * order[col] + col];
  }
  for (int k = 0; k < 6; ++k)
    if (!std::isfinite(x[k])) return false;
  return true;
}

/// Start k's increment: k = 0 none; else a rotation of up to rot_deg about a random axis and a
/// translation uniform in a ball of trans_mm, drawn from (seed, item, k).
void start_increment(const RegistrationSettings& s, size_t item, int k, double xi[6]) {
  for (int i = 0; i < 6; ++i) xi[i] = 0;
  if (k == 0) return;
  SplitMix64 rng(s.seed * 0x100000001B3ull + item * 1000003ull + uint64_t(k));
  double axis[3], t[3], n2;
  do {
    for (double& a : axis) a = 2 * rng.uniform() - 1;
    n2 = axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2];
  } while (n2 > 1 || n2 < 1e-6);
  do {
    for (double& a : t) a = 2 * rng.uniform() - 1;
  } while (t[0] * t[0] + t[1] * t[1] + t[2] * t[2] > 1);
  const double angle = rng.uniform() * s.search_rot_deg * kPi / 180;
  for (int i = 0; i < 3; ++i) {
    xi[i] = t[i] * s.search_trans_mm;
    xi[3 + i] = axis[i] / std::sqrt(n2) * angle;
  }
}

double rotation_angle_deg(const Mat3& a, const Mat3& b) {  // angle of a·bᵀ
  double trace = 0;
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) trace += a.m[i][k] * b.m[i][k];
  return std::acos(std::max(-1.0, std::min(1.0, (trace - 1) / 2))) * 180 / kPi;
}

}  // namespace

struct FrameRegistration::State {
  ProbeGeometry probe;
  VolumeGrid grid;
  Mat3 L;  // world → index, linear (the gradients' chain rule)
  size_t count = 0;
  Volume volume;                  // float32: the caller's (shared) or a converted copy
  std::deque<Level> levels;       // only added to: references to a level stay valid
  std::vector<Vec3> mask_centre;  // per frame: the centroid of its compared pixels (probe mm)
  // MI's intensity ranges: the volume's and each frame's 1st and 99th percentiles.
  double volume_range[2] = {0, 1};
  std::vector<std::array<double, 2>> frame_range;

  const Level& level(int f) const {
    for (const Level& l : levels)
      if (l.f == f) return l;
    throw InputError("pyramid: level " + std::to_string(f) + " was not prepared");
  }
  /// Level f, made when first asked for: level 1 from the caller's frames and the H×W mask,
  /// the others from level 1.
  const Level& make_level(int f, const float* frames = nullptr, const uint8_t* mask = nullptr);
};

const Level& FrameRegistration::State::make_level(int f, const float* frames, const uint8_t* mask) {
  for (Level& l : levels)
    if (l.f == f) return l;
  levels.emplace_back();
  Level& l = levels.back();
  const Level& first = levels.front();  // level 1 (made first, by the constructor)
  const float* volume = this->volume.data_as<float>();
  l.f = f;
  const int W = probe.image.width, H = probe.image.height;
  const int64_t nx = grid.dims[0], ny = grid.dims[1], nz = grid.dims[2];
  const double pixel = std::min(probe.image.spacing_mm[0], probe.image.spacing_mm[1]);
  const double voxel = std::min({grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2]});
  l.g = std::max(1, int(std::floor(f * pixel / voxel + 1e-9)));
  if (l.g == 1) {
    l.volume = volume;
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
                s += volume[((z * g + dz) * ny + (int64_t(y) * g + dy)) * nx + int64_t(x) * g + dx];
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
  return l;
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
  // The kernels read float: a float32 volume is shared, others are converted once.
  if (volume.pixel_type() != PixelType::Float32) s.volume = volume.converted(PixelType::Float32);
  const float* full = s.volume.data_as<float>();
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
      if (std::isfinite(full[i])) sample.push_back(full[i]);
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

namespace {

/// The kernel's view of frame `frame` at `pose` on level `l`.
register_impl::TermsLaunch make_launch(const ProbeGeometry& probe, const VolumeGrid& grid,
                                       const Mat3& L_world, const Level& l, size_t frame,
                                       const Pose& pose, const Vec3& centre) {
  const int f = l.f, g = l.g;
  register_impl::TermsLaunch L;
  L.volume = l.volume;
  L.grid = geometry::VolumeView::of(l.nx, l.ny, l.nz);
  // The level's pixel (u, v) is the centre of a block of f × f full pixels; a level voxel the
  // centre of g³ full voxels: c_level = (c − (g − 1)/2) / g.
  const ImageGrid& img = probe.image;
  L.sx = img.spacing_mm[0] * f;
  L.sy = img.spacing_mm[1] * f;
  L.x0 = img.origin_mm[0] + 0.5 * (f - 1) * img.spacing_mm[0];
  L.y0 = img.origin_mm[1] + 0.5 * (f - 1) * img.spacing_mm[1];
  L.width = l.width;
  L.height = l.height;
  const size_t plane = size_t(l.width) * l.height;
  L.frame = l.frames.data() + frame * plane;
  L.mask = l.masks.data() + frame * plane;
  L.probe_to_index = grid.index_map(pose);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      L.probe_to_index.A[r][c] /= g;
      L.P[3 * r + c] = pose.m[r][c];
      L.G[3 * r + c] = L_world.m[c][r] / g;  // Lᵀ, per level index step
    }
    L.probe_to_index.a[r] = (L.probe_to_index.a[r] - 0.5 * (g - 1)) / g;
    L.p[r] = pose.m[r][3];
    L.centre[r] = centre[r];
  }
  L.curvilinear = probe.type == ProbeType::Curvilinear;
  L.apex_y = probe.face_y_mm - probe.radius_mm;
  return L;
}

/// LC2 and local NCC patches: 11 full-resolution pixels a side (2.7 mm on W1), at least 3 level
/// pixels.
int patch_side(int f) {
  return std::max(3, (11 + f / 2) / f);
}

}  // namespace

PoseTerms FrameRegistration::terms(size_t frame, const Pose& pose, int level, const Vec3& centre,
                                   bool gradients) const {
  const State& s = *state_;
  register_impl::TermsLaunch L =
      make_launch(s.probe, s.grid, s.L, s.level(level), frame, pose, centre);
  L.gradients = gradients;
  PoseTerms total;
  for (int v = 0; v < L.height; ++v) {
    PoseTerms row;
    register_impl::accumulate_row(L, v, row);
    total.add(row);
  }
  return total;
}

std::pair<double, double> FrameRegistration::patch_score(size_t frame, const Pose& pose, int level,
                                                         RegistrationMetric metric) const {
  const State& s = *state_;
  register_impl::TermsLaunch L =
      make_launch(s.probe, s.grid, s.L, s.level(level), frame, pose, Vec3{0, 0, 0});
  L.patch = patch_side(s.level(level).f);
  L.patches_x = (L.width + L.patch - 1) / L.patch;
  const int patches_y = (L.height + L.patch - 1) / L.patch;
  std::vector<double> sums(size_t(L.patches_x) * patches_y * register_impl::kLc2Sums, 0.0);
  for (int v = 0; v < L.height; ++v) register_impl::accumulate_lc2_row(L, v, sums.data());
  double weighted = 0, weight = 0;
  for (size_t k = 0; k < sums.size(); k += register_impl::kLc2Sums) {
    const double* t = &sums[k];
    const double n = t[0];
    if (n < 8) continue;  // too few pixels for a 3-parameter fit or a local correlation
    const double mu = t[1] / n, mp = t[2] / n, mg = t[3] / n;
    const double vu = t[4] / n - mu * mu;
    if (!(vu > 1e-12)) continue;  // flat frame patch: nothing to explain
    double cpp = t[5] / n - mp * mp, cgg = t[6] / n - mg * mg;
    const double bup = t[7] / n - mu * mp;
    if (metric == RegistrationMetric::LNCC) {
      // The patch's NCC of frame and volume, every patch alike; a flat volume patch scores 0.
      if (cpp > 1e-12) weighted += bup / std::sqrt(vu * cpp);
      weight += 1;
      continue;
    }
    // LC2: the least-squares fit U ≈ α·p + β·g + γ, R² = bᵀ·C⁻¹·b / var U with C the covariance
    // of (p, g) and b their covariances with U (a small ridge keeps a flat p or g solvable).
    const double cpg = t[9] / n - mp * mg, bug = t[8] / n - mu * mg;
    const double ridge = 1e-9 * (cpp + cgg) + 1e-12;
    cpp += ridge;
    cgg += ridge;
    const double det = cpp * cgg - cpg * cpg;
    double r2 =
        det > 0 ? (bup * (cgg * bup - cpg * bug) + bug * (cpp * bug - cpg * bup)) / det / vu : 0;
    r2 = std::min(1.0, std::max(0.0, r2));
    const double sigma = std::sqrt(vu);
    weighted += sigma * r2;
    weight += sigma;
  }
  return {weighted, weight};
}

double FrameRegistration::mutual_information(size_t frame, const Pose& pose, int level) const {
  const State& s = *state_;
  const register_impl::TermsLaunch L =
      make_launch(s.probe, s.grid, s.L, s.level(level), frame, pose, Vec3{0, 0, 0});
  constexpr int B = register_impl::kMiBins;
  std::vector<double> joint(size_t(B) * B, 0.0);
  const double vol_lo = s.volume_range[0],
               vol_scale = (B - 1) / (s.volume_range[1] - s.volume_range[0]);
  const double fr_lo = s.frame_range[frame][0],
               fr_scale = (B - 1) / (s.frame_range[frame][1] - s.frame_range[frame][0]);
  for (int v = 0; v < L.height; ++v)
    register_impl::accumulate_mi_row(L, v, joint.data(), vol_lo, vol_scale, fr_lo, fr_scale);
  double total = 0;
  for (double h : joint) total += h;
  if (total < kMinPixels) return std::numeric_limits<double>::quiet_NaN();
  double pi[B] = {}, pf[B] = {};
  for (int i = 0; i < B; ++i)
    for (int j = 0; j < B; ++j) {
      pi[i] += joint[size_t(i) * B + j] / total;
      pf[j] += joint[size_t(i) * B + j] / total;
    }
  double mi = 0;
  for (int i = 0; i < B; ++i)
    for (int j = 0; j < B; ++j) {
      const double p = joint[size_t(i) * B + j] / total;
      if (p > 0) mi += p * std::log(p / (pi[i] * pf[j]));
    }
  return mi;
}

double FrameRegistration::cost(size_t frame, const Pose& pose, int level,
                               RegistrationMetric metric) const {
  const double inf = std::numeric_limits<double>::infinity();
  if (metric == RegistrationMetric::LC2 || metric == RegistrationMetric::LNCC) {
    const auto [weighted, weight] = patch_score(frame, pose, level, metric);
    return weight > 0 ? 1 - weighted / weight : inf;
  }
  if (metric == RegistrationMetric::MI) {
    const double mi = mutual_information(frame, pose, level);
    return std::isfinite(mi) ? -mi : inf;
  }
  return metric_cost(metric, terms(frame, pose, level, centre(frame, pose), false));
}

namespace {

/// What one optimisation of one item (a frame, or the sweep) needs, as functions of the
/// correction X: its terms (summed over its frames; SSD and NCC) and its cost (any metric).
struct Problem {
  std::function<PoseTerms(const Pose& correction, int level, const Vec3& centre, bool gradients)>
      terms;
  std::function<double(const Pose& correction, int level)> cost;
  int64_t frames_per_evaluation = 1;
};

struct Outcome {
  Pose correction;  // the increment applied to the initial pose(s), world frame
  double cost = std::numeric_limits<double>::infinity();
  int64_t evaluations = 0, iterations = 0;
};

constexpr double kMaxStepMm = 2, kMaxStepDeg = 2;

/// Shapes a solved step ξ in place: halved `attempt` times for Gauss–Newton (backtracking), then
/// shrunk into the trust region (at most kMaxStepMm and kMaxStepDeg, so that one step on a flat
/// stretch of the metric cannot throw the frame far away). Gives the step's length in mm and rad.
void limit_step(const RegistrationSettings& s, int attempt, double xi[6], double* mm, double* rad) {
  if (s.optimizer == RegistrationOptimizer::GaussNewton)
    for (int k = 0; k < 6; ++k) xi[k] *= std::pow(0.5, attempt);
  const double t_len = std::sqrt(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2]);
  const double r_len = std::sqrt(xi[3] * xi[3] + xi[4] * xi[4] + xi[5] * xi[5]);
  const double shrink = std::min({1.0, kMaxStepMm / std::max(t_len, 1e-300),
                                  kMaxStepDeg * kPi / 180 / std::max(r_len, 1e-300)});
  for (int k = 0; k < 6; ++k) xi[k] *= shrink;
  *mm = t_len * shrink;
  *rad = r_len * shrink;
}

/// BOBYQA or Nelder–Mead (NLopt) on the correction X, level by level: the metric alone, as a
/// function of an increment about the frame's centre; the first level's initial step is
/// kMaxStepMm and kMaxStepDeg, halved at each finer level. An evaluation is an iteration.
Outcome optimise_derivative_free(const Problem& p, const RegistrationSettings& s, const Pose& start,
                                 const Vec3& centre) {
  Outcome out;
  Pose X = start;
#ifdef SONOSLICE_HAVE_NLOPT
  double step_mm = kMaxStepMm, step_rad = kMaxStepDeg * kPi / 180;
  for (int f : s.pyramid) {
    const Pose level_start = X;
    const Vec3 c = X.transform_point(centre);
    nlopt::opt opt(
        s.optimizer == RegistrationOptimizer::Bobyqa ? nlopt::LN_BOBYQA : nlopt::LN_NELDERMEAD, 6);
    struct Context {
      const Problem* p;
      const RegistrationSettings* s;
      const Pose* base;
      Vec3 c;
      int f;
      Outcome* out;
    } ctx{&p, &s, &level_start, c, f, &out};
    opt.set_min_objective(
        [](unsigned, const double* x, double*, void* data) {
          const Context& k = *static_cast<Context*>(data);
          k.out->evaluations += k.p->frames_per_evaluation;
          ++k.out->iterations;
          const double cost = k.p->cost(apply_increment(*k.base, x, k.c), k.f);
          return std::isfinite(cost) ? cost : 1e30;  // NLopt's models need finite values
        },
        &ctx);
    opt.set_initial_step(
        std::vector<double>{step_mm, step_mm, step_mm, step_rad, step_rad, step_rad});
    const double tol_rad = s.tolerance_deg * kPi / 180;
    opt.set_xtol_abs(std::vector<double>{s.tolerance_mm, s.tolerance_mm, s.tolerance_mm, tol_rad,
                                         tol_rad, tol_rad});
    opt.set_maxeval(20 * s.max_iterations);
    std::vector<double> x(6, 0.0);
    double best = 0;
    try {
      opt.optimize(x, best);
    } catch (const std::exception&) {
      // NLopt reports a stop it cannot explain (round-off, a forced stop) as an exception; the
      // best point it found is in x either way.
    }
    X = apply_increment(level_start, x.data(), c);
    step_mm /= 2;
    step_rad /= 2;
  }
#else
  (void)p;
  (void)centre;
  throw InputError("optimizer: this sonoslice was built without NLopt");
#endif
  out.correction = X;
  out.cost = p.cost(X, 1);
  out.evaluations += p.frames_per_evaluation;
  return out;
}

/// Gauss–Newton or Levenberg–Marquardt on the correction X (poses X·T), level by level.
Outcome optimise(const Problem& p, const RegistrationSettings& s, const Pose& start,
                 const Vec3& centre) {
  if (s.optimizer == RegistrationOptimizer::Bobyqa ||
      s.optimizer == RegistrationOptimizer::NelderMead)
    return optimise_derivative_free(p, s, start, centre);
  Outcome out;
  Pose X = start;
  const double tol_rad = s.tolerance_deg * kPi / 180;
  for (int f : s.pyramid) {
    double lambda = 1e-3;
    for (int it = 0; it < s.max_iterations; ++it) {
      // The centre moves with the correction: turn about where the frame now is.
      const Vec3 c = X.transform_point(centre);
      double g[6], H[36];
      const PoseTerms t = p.terms(X, f, c, true);
      out.evaluations += p.frames_per_evaluation;
      const double cost = metric_cost(s.metric, t, g, H);
      if (!std::isfinite(cost)) break;
      ++out.iterations;
      bool moved = false, converged = false;
      for (int attempt = 0; attempt < 12; ++attempt) {
        double A[36], b[6], xi[6];
        const double damping =
            s.optimizer == RegistrationOptimizer::LevenbergMarquardt ? lambda : 0;
        for (int k = 0; k < 36; ++k) A[k] = H[k];
        for (int k = 0; k < 6; ++k) {
          A[7 * k] += damping * H[7 * k] + 1e-12 * (1 + std::fabs(H[7 * k]));
          b[k] = -g[k];
        }
        if (!solve6(A, b, xi)) {
          lambda *= 10;
          continue;
        }
        double step_mm, step_rad;
        limit_step(s, attempt, xi, &step_mm, &step_rad);
        const Pose candidate = apply_increment(X, xi, c);
        const double tried = p.cost(candidate, f);
        out.evaluations += p.frames_per_evaluation;
        if (tried < cost) {
          X = candidate;
          lambda = std::max(lambda / 3, 1e-9);
          moved = true;
          converged = step_mm < s.tolerance_mm && step_rad < tol_rad;
          break;
        }
        if (step_mm < s.tolerance_mm && step_rad < tol_rad) {
          converged = true;  // no better point within the tolerance
          break;
        }
        lambda *= 4;
      }
      if (!moved || converged) break;
    }
  }
  out.correction = X;
  out.cost = p.cost(X, 1);
  out.evaluations += p.frames_per_evaluation;
  return out;
}

/// Candidate starting points screened per start: the metric alone (no derivatives) at the
/// coarsest level is cheap, so many draws are ranked and the best settings.starts optimised.
constexpr int kCandidatesPerStart = 64;

/// The best of settings.starts optimisations. With one start: from the initial pose. With more:
/// the initial pose and kCandidatesPerStart·starts − 1 drawn increments about the centre are
/// ranked by the metric at the coarsest level, and the best `starts` of them are optimised.
Outcome multi_start(const Problem& p, const RegistrationSettings& s, size_t item,
                    const Vec3& centre) {
  int64_t evaluations = 0, iterations = 0;
  std::vector<std::pair<double, Pose>> candidates;
  const int draws = s.starts == 1 ? 1 : s.starts * kCandidatesPerStart;
  for (int k = 0; k < draws; ++k) {
    double xi[6];
    start_increment(s, item, k, xi);
    const Pose X = apply_increment(Pose::identity(), xi, centre);
    double cost = 0;
    if (draws > 1) {
      cost = p.cost(X, s.pyramid.front());
      evaluations += p.frames_per_evaluation;
    }
    candidates.emplace_back(std::isfinite(cost) ? cost : std::numeric_limits<double>::max(), X);
  }
  // Stable: equal costs keep their draw order (the initial pose first).
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  Outcome best;
  for (int k = 0; k < s.starts && k < int(candidates.size()); ++k) {
    const Outcome o = optimise(p, s, candidates[size_t(k)].second, centre);
    evaluations += o.evaluations;
    iterations += o.iterations;
    if (k == 0 || o.cost < best.cost) best = o;
  }
  best.evaluations = evaluations;
  best.iterations = iterations;
  return best;
}

/// Inverts a 6×6 matrix (false when singular).
bool invert6(const double A[36], double out[36]) {
  for (int c = 0; c < 6; ++c) {
    double M[36], b[6] = {0, 0, 0, 0, 0, 0}, x[6];
    std::copy(A, A + 36, M);
    b[c] = 1;
    if (!solve6(M, b, x)) return false;
    for (int r = 0; r < 6; ++r) out[6 * r + c] = x[r];
  }
  return true;
}

/// smooth-sweep: per-frame corrections X_i, refined jointly. The cost is Σ cost_i(X_i) plus the
/// prior Σ_i (d_{i+1} − d_i)ᵀ·W·(d_{i+1} − d_i), d_i = (X_i·c_i − c_i, rotation vector of X_i)
/// with c_i frame i's centre. A Gauss–Newton step moves frame i by ξ_i about its current centre,
/// which changes d_i by (v_i, ≈ ω_i), so the linearised system is block tridiagonal:
/// (H_i + 2·deg_i·W)·ξ_i − 2W·(ξ_{i−1} + ξ_{i+1}) = −g_i − 2W·Σ_j (d_i − d_j), solved exactly by
/// block elimination along the sweep. Frames outside the volume (infinite cost) follow their
/// neighbours. Per level, W = smoothness × the mean of the frames' Gauss–Newton diagonals.
struct SweepTerms {
  std::function<PoseTerms(size_t frame, const Pose& correction, int level, const Vec3& centre,
                          bool gradients)>
      terms;
  std::vector<Vec3> centres;  // each frame's centre at its initial pose (world)
};

struct SweepOutcome {
  std::vector<Pose> corrections;
  std::vector<double> costs;                // each frame's own final cost at full resolution
  int64_t evaluations = 0, iterations = 0;  // per frame
};

SweepOutcome smooth_sweep(const SweepTerms& p, const RegistrationSettings& s, const Pose& start) {
  const size_t n = p.centres.size();
  SweepOutcome out;
  std::vector<Pose> X(n, start);
  const double tol_rad = s.tolerance_deg * kPi / 180;
  // The sweep's cost at corrections Y: frames outside the volume counted first (fewer is
  // better), then the frames' costs plus the prior.
  struct Total {
    size_t outside = 0;
    double value = 0;
    bool operator<(const Total& o) const {
      return outside != o.outside ? outside < o.outside : value < o.value;
    }
  };
  const auto descriptor = [&](const std::vector<Pose>& Y, size_t k, double d[6]) {
    const Vec3 moved = Y[k].transform_point(p.centres[k]);
    for (int i = 0; i < 3; ++i) d[i] = moved[i] - p.centres[k][i];
    const Vec3 r = rotation_vector(Y[k].linear());
    for (int i = 0; i < 3; ++i) d[3 + i] = r[i];
  };
  const auto prior = [&](const std::vector<Pose>& Y, const double w[6]) {
    double total = 0, a[6], b[6];
    for (size_t k = 0; k + 1 < n; ++k) {
      descriptor(Y, k, a);
      descriptor(Y, k + 1, b);
      for (int i = 0; i < 6; ++i) total += w[i] * (b[i] - a[i]) * (b[i] - a[i]);
    }
    return total;
  };
  const auto costs = [&](const std::vector<Pose>& Y, int f, std::vector<double>& each) {
    each.assign(n, 0.0);
    backend::parallel_for(int64_t(n), [&](int64_t k) {
      const Vec3 c = Y[size_t(k)].transform_point(p.centres[size_t(k)]);
      each[size_t(k)] = metric_cost(s.metric, p.terms(size_t(k), Y[size_t(k)], f, c, false));
    });
    out.evaluations += 1;
  };
  const auto total = [&](const std::vector<double>& each, const std::vector<Pose>& Y,
                         const double w[6]) {
    Total t;
    for (double c : each) {
      if (std::isfinite(c))
        t.value += c;
      else
        ++t.outside;
    }
    t.value += prior(Y, w);
    return t;
  };

  for (int f : s.pyramid) {
    double lambda = 1e-3, w[6] = {0, 0, 0, 0, 0, 0};
    for (int it = 0; it < s.max_iterations; ++it) {
      // Every frame's gradient and Gauss–Newton matrix, about its current centre.
      std::vector<double> each(n), g(6 * n, 0.0), H(36 * n, 0.0);
      backend::parallel_for(int64_t(n), [&](int64_t k) {
        const size_t i = size_t(k);
        const Vec3 c = X[i].transform_point(p.centres[i]);
        each[i] = metric_cost(s.metric, p.terms(i, X[i], f, c, true), &g[6 * i], &H[36 * i]);
        if (!std::isfinite(each[i])) {
          std::fill(&g[6 * i], &g[6 * i] + 6, 0.0);
          std::fill(&H[36 * i], &H[36 * i] + 36, 0.0);
        }
      });
      out.evaluations += 1;
      if (it == 0) {
        // The prior's weight for this level, from the frames' own curvature.
        double sum[2] = {0, 0};
        size_t used = 0;
        for (size_t i = 0; i < n; ++i)
          if (std::isfinite(each[i])) {
            ++used;
            for (int k = 0; k < 6; ++k) sum[k / 3] += H[36 * i + 7 * k] / 3;
          }
        if (used == 0) break;  // no frame inside the volume at this level
        for (int k = 0; k < 6; ++k) w[k] = s.smoothness * sum[k / 3] / double(used);
      }
      const Total current = total(each, X, w);
      ++out.iterations;
      std::vector<double> d(6 * n);
      for (size_t i = 0; i < n; ++i) descriptor(X, i, &d[6 * i]);
      bool moved = false, converged = false;
      for (int attempt = 0; attempt < 12; ++attempt) {
        const double damping =
            s.optimizer == RegistrationOptimizer::LevenbergMarquardt ? lambda : 0;
        // Block elimination along the sweep: D'_i = D_i − B·D'_{i−1}⁻¹·B, b'_i likewise, with
        // the off-diagonal blocks B = −2W (diagonal).
        std::vector<double> inverse(36 * n), rhs(6 * n), xi(6 * n);
        bool ok = true;
        for (size_t i = 0; i < n && ok; ++i) {
          double D[36], b[6];
          for (int k = 0; k < 36; ++k) D[k] = H[36 * i + k];
          for (int k = 0; k < 6; ++k) {
            const int degree = (i > 0) + (i + 1 < n);
            D[7 * k] += damping * H[36 * i + 7 * k] + 2 * degree * w[k] +
                        1e-12 * (1 + std::fabs(H[36 * i + 7 * k]));
            b[k] = -g[6 * i + k];
            if (i > 0) b[k] -= 2 * w[k] * (d[6 * i + k] - d[6 * (i - 1) + k]);
            if (i + 1 < n) b[k] -= 2 * w[k] * (d[6 * i + k] - d[6 * (i + 1) + k]);
          }
          if (i > 0) {
            const double* P = &inverse[36 * (i - 1)];  // D'_{i−1}⁻¹
            for (int r = 0; r < 6; ++r) {
              for (int c = 0; c < 6; ++c) D[6 * r + c] -= 4 * w[r] * P[6 * r + c] * w[c];
              double a = 0;
              for (int c = 0; c < 6; ++c) a += P[6 * r + c] * rhs[6 * (i - 1) + c];
              b[r] += 2 * w[r] * a;  // − B·D'⁻¹·b' with B = −2W
            }
          }
          ok = invert6(D, &inverse[36 * i]);
          std::copy(b, b + 6, &rhs[6 * i]);
        }
        if (!ok) {
          lambda *= 10;
          continue;
        }
        for (size_t i = n; i-- > 0;) {
          double b[6];
          for (int k = 0; k < 6; ++k)
            b[k] = rhs[6 * i + k] + (i + 1 < n ? 2 * w[k] * xi[6 * (i + 1) + k] : 0);
          for (int r = 0; r < 6; ++r) {
            double a = 0;
            for (int c = 0; c < 6; ++c) a += inverse[36 * i + 6 * r + c] * b[c];
            xi[6 * i + r] = a;
          }
        }
        // Each frame's step: backtracking for Gauss–Newton, inside the trust region.
        std::vector<Pose> candidate(n);
        double largest_mm = 0, largest_rad = 0;
        for (size_t i = 0; i < n; ++i) {
          double* x = &xi[6 * i];
          double step_mm, step_rad;
          limit_step(s, attempt, x, &step_mm, &step_rad);
          largest_mm = std::max(largest_mm, step_mm);
          largest_rad = std::max(largest_rad, step_rad);
          candidate[i] = apply_increment(X[i], x, X[i].transform_point(p.centres[i]));
        }
        std::vector<double> tried_each;
        costs(candidate, f, tried_each);
        const Total tried = total(tried_each, candidate, w);
        if (tried < current) {
          X = std::move(candidate);
          lambda = std::max(lambda / 3, 1e-9);
          moved = true;
          converged = largest_mm < s.tolerance_mm && largest_rad < tol_rad;
          break;
        }
        if (largest_mm < s.tolerance_mm && largest_rad < tol_rad) {
          converged = true;
          break;
        }
        lambda *= 4;
      }
      if (!moved || converged) break;
    }
  }
  out.corrections = X;
  costs(X, 1, out.costs);
  return out;
}

}  // namespace

std::vector<Pose> FrameRegistration::run(const std::vector<Pose>& initial,
                                         const RegistrationSettings& requested,
                                         RegistrationReport* report) const {
  const auto clock = std::chrono::steady_clock::now();
  requested.validate();
  const RegistrationSettings settings = requested.resolved();
  State& s = *state_;
  if (initial.size() != s.count)
    throw InputError("poses: " + std::to_string(initial.size()) + " poses for " +
                     std::to_string(s.count) + " frames");
  validate_poses(initial.data(), initial.size(), "poses");
  for (int f : settings.pyramid) s.make_level(f);

  std::vector<Pose> refined(s.count);
  std::vector<FrameReport> frames(s.count);
  // `metric`: the frame's own final cost (per frame: the optimisation's; a sweep's is shared).
  const auto describe = [&](size_t k, const Outcome& o, int64_t evaluations,
                            std::optional<double> metric) {
    FrameReport& r = frames[k];
    r.index = k;
    refined[k] = o.correction * initial[k];
    r.metric = metric ? *metric : cost(k, refined[k], 1, settings.metric);
    r.evaluations = evaluations;
    r.iterations = o.iterations;
    double d = 0;
    for (int i = 0; i < 3; ++i) d += std::pow(refined[k].m[i][3] - initial[k].m[i][3], 2);
    r.translation_change_mm = std::sqrt(d);
    r.rotation_change_deg = rotation_angle_deg(refined[k].linear(), initial[k].linear());
  };
  if (settings.mode == RegistrationMode::PerFrame) {
    backend::parallel_for(int64_t(s.count), [&](int64_t k) {
      Problem p;
      p.terms = [&, k](const Pose& X, int f, const Vec3& c, bool g) {
        return terms(size_t(k), X * initial[size_t(k)], f, c, g);
      };
      p.cost = [&, k](const Pose& X, int f) {
        return cost(size_t(k), X * initial[size_t(k)], f, settings.metric);
      };
      const Outcome o = multi_start(p, settings, size_t(k), centre(size_t(k), initial[size_t(k)]));
      describe(size_t(k), o, o.evaluations, o.cost);
    });
  } else {
    // rigid-sweep, and smooth-sweep's first stage. One correction for the sweep: each evaluation
    // sums every frame's terms (in parallel, then in frame order), turning about the mean of the
    // frames' centres.
    Vec3 mean = {0, 0, 0};
    for (size_t k = 0; k < s.count; ++k) {
      const Vec3 c = centre(k, initial[k]);
      for (int i = 0; i < 3; ++i) mean[i] += c[i] / double(s.count);
    }
    Problem p;
    p.frames_per_evaluation = int64_t(s.count);
    p.terms = [&](const Pose& X, int f, const Vec3& c, bool g) {
      std::vector<PoseTerms> each(s.count);
      backend::parallel_for(int64_t(s.count), [&](int64_t k) {
        each[size_t(k)] = terms(size_t(k), X * initial[size_t(k)], f, c, g);
      });
      PoseTerms sum;
      for (const PoseTerms& t : each) sum.add(t);
      return sum;
    };
    // The sweep's cost: SSD and NCC over all its pixels together; LC2 and LNCC over all its
    // patches; MI the mean of the frames' (each frame has its own intensity range).
    p.cost = [&](const Pose& X, int f) {
      if (settings.metric == RegistrationMetric::SSD || settings.metric == RegistrationMetric::NCC)
        return metric_cost(settings.metric, p.terms(X, f, mean, false));
      std::vector<std::pair<double, double>> each(s.count);
      backend::parallel_for(int64_t(s.count), [&](int64_t k) {
        const Pose pose = X * initial[size_t(k)];
        if (settings.metric == RegistrationMetric::MI)
          each[size_t(k)] = {cost(size_t(k), pose, f, settings.metric), 1.0};
        else
          each[size_t(k)] = patch_score(size_t(k), pose, f, settings.metric);
      });
      double weighted = 0, weight = 0;
      for (const auto& [a, b] : each) {
        weighted += a;
        weight += b;
      }
      if (!(weight > 0)) return std::numeric_limits<double>::infinity();
      return settings.metric == RegistrationMetric::MI ? weighted / weight : 1 - weighted / weight;
    };
    const Outcome o = multi_start(p, settings, 0, mean);
    if (settings.mode == RegistrationMode::RigidSweep) {
      for (size_t k = 0; k < s.count; ++k)
        describe(k, o, o.evaluations / int64_t(s.count), std::nullopt);
    } else {
      // smooth-sweep: from the shared correction, each frame its own, tied to its neighbours.
      SweepTerms sweep;
      sweep.terms = [&](size_t k, const Pose& X, int f, const Vec3& c, bool g) {
        return terms(k, X * initial[k], f, c, g);
      };
      for (size_t k = 0; k < s.count; ++k) sweep.centres.push_back(centre(k, initial[k]));
      const SweepOutcome smooth = smooth_sweep(sweep, settings, o.correction);
      for (size_t k = 0; k < s.count; ++k) {
        Outcome frame;
        frame.correction = smooth.corrections[k];
        frame.iterations = o.iterations + smooth.iterations;
        describe(k, frame, o.evaluations / int64_t(s.count) + smooth.evaluations, smooth.costs[k]);
      }
    }
  }
  if (report) {
    report->settings = settings;
    report->frames = frames;
    report->evaluations = 0;
    for (const FrameReport& r : frames) report->evaluations += r.evaluations;
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - clock).count();
  }
  return refined;
}

}  // namespace sonoslice
