// Registration's metrics from the kernel's sums (RegisterImpl.h): SSD and NCC with their pose
// derivatives, the patch metrics LC2 and LNCC, and mutual information (docs/registration.md §2).
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "RegisterBackends.h"
#include "RegistrationState.h"

namespace sonoslice {

using register_impl::Level;

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

namespace {

/// The kernel's view of frame `frame` at `pose` on level `l`.
register_impl::TermsLaunch make_launch(const ProbeGeometry& probe, const VolumeGrid& grid,
                                       const Mat3& L_world, const Level& l, size_t frame,
                                       const Pose& pose, const Vec3& centre) {
  const int f = l.f, g = l.g;
  register_impl::TermsLaunch L;
  L.volume = l.volume;
  L.volume16 = l.volume16;
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
  L.spans = l.spans.data() + frame * size_t(l.height) * 2;
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

/// LC2 and local NCC patches: centred on each pixel, 2·half + 1 level pixels a side. 11 pixels
/// (2.7 mm on W1) at full resolution; the same pixel count at coarser levels, so that a patch
/// covers more of the frame where the frame is smoother (a wider basin, docs/registration.md §1).
constexpr int kPatchHalf = 5;

}  // namespace

PoseTerms FrameRegistration::terms(size_t frame, const Pose& pose, int level, const Vec3& centre,
                                   bool gradients) const {
  const State& s = *state_;
  register_impl::TermsLaunch L =
      make_launch(s.probe, s.grid, s.L, s.level(level), frame, pose, centre);
  L.gradients = gradients;
  PoseTerms total;
  register_impl::terms_cpu(cpu_kernel_isa(), L, total);
  return total;
}

std::pair<double, double> FrameRegistration::patch_score(size_t frame, const Pose& pose, int level,
                                                         RegistrationMetric metric) const {
  const State& s = *state_;
  const register_impl::TermsLaunch L =
      make_launch(s.probe, s.grid, s.L, s.level(level), frame, pose, Vec3{0, 0, 0});
  // A patch counts when at least half its window is compared (the fan's edge and the volume's
  // border leave fits of a few pixels that would be noise).
  const double least = std::max(8.0, 0.5 * (2 * kPatchHalf + 1) * (2 * kPatchHalf + 1));
  double weighted = 0, weight = 0;
  register_impl::patch_score_cpu(cpu_kernel_isa(), L, kPatchHalf, least,
                                 metric == RegistrationMetric::LNCC, weighted, weight);
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

}  // namespace sonoslice
