#pragma once
// Internal: registration's optimisers. One optimisation moves a correction X (applied to the
// initial pose or poses, X·T) coarse to fine: Gauss–Newton / Levenberg–Marquardt from the
// analytic derivatives, or BOBYQA / Nelder–Mead (NLopt) from the metric alone, with multi-start
// (Optimizers.cpp); smooth-sweep refines every frame's correction jointly with a smoothness prior
// (SmoothSweep.cpp). The driver (Registration.cpp) says what is optimised.
#include <cstdint>
#include <functional>
#include <limits>
#include <utility>
#include <vector>

#include "sonoslice/register/Registration.h"

namespace sonoslice {
namespace register_impl {

/// What one optimisation of one item (a frame, or the sweep) needs, as functions of the
/// correction X: its terms (summed over its frames; SSD and NCC) and its cost (any metric).
struct Problem {
  std::function<PoseTerms(const Pose& correction, int level, const Vec3& centre, bool gradients)>
      terms;
  std::function<double(const Pose& correction, int level)> cost;
  int64_t frames_per_evaluation = 1;
  bool shared = false;  // one correction for a whole sweep: automatic starts want more evidence
};

struct Outcome {
  Pose correction;  // the increment applied to the initial pose(s), world frame
  double cost = std::numeric_limits<double>::infinity();
  int64_t evaluations = 0, iterations = 0;
  int starts = 1, agreeing_starts = 1;  // multi_start: optimisations run, and ending at the best
};

/// Terms whose derivatives are with respect to a world-frame increment ξ_w = (R·v, R·ω), turned
/// into derivatives with respect to (v, ω): J ↦ Mᵀ·J, J·Jᵀ ↦ Mᵀ·(J·Jᵀ)·M, M = diag(R, R).
PoseTerms turned_into(const PoseTerms& t, const Mat3& R);

/// The result's standard deviation from its terms (FrameReport::uncertainty_mm/_deg): {mm, deg},
/// NaN for metrics without derivatives or a singular Gauss–Newton matrix.
std::pair<double, double> pose_uncertainty(RegistrationMetric metric, const PoseTerms& t);

/// The angle (degrees) of the rotation a·bᵀ.
double rotation_angle_deg(const Mat3& a, const Mat3& b);

/// The best of the optimisations of `p` about `centre` (the frame's or the sweep's centre):
/// settings.starts of them, or, unset, until kAgreeingStarts agree (default_max_starts; for
/// a shared correction at most kAutoMaxSweepStarts); `item` seeds the
/// drawn starts (a frame's index, or 0 for a sweep).
Outcome multi_start(const Problem& p, const RegistrationSettings& s, size_t item,
                    const Vec3& centre);

/// Shapes a solved step ξ in place: halved `attempt` times for Gauss–Newton (backtracking), then
/// shrunk into the trust region (at most 2 mm and 2°, so that one step on a flat stretch of the
/// metric cannot throw the frame far away). Gives the step's length in mm and rad.
void limit_step(const RegistrationSettings& s, int attempt, double xi[6], double* mm, double* rad);

/// Inverts a 6×6 matrix (false when singular).
bool invert6(const double A[36], double out[36]);

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

SweepOutcome smooth_sweep(const SweepTerms& p, const RegistrationSettings& s, const Pose& start);

}  // namespace register_impl
}  // namespace sonoslice
