// Registration's optimisers (Optimizers.h): Gauss–Newton / Levenberg–Marquardt with a trust
// region, BOBYQA and Nelder–Mead through NLopt, and multi-start from drawn increments.
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "../backend/ParallelFor.h"
#include "../core/Random.h"
#include "Optimizers.h"

#ifdef SONOSLICE_HAVE_NLOPT
#include <nlopt.hpp>
#endif

namespace sonoslice {

Pose apply_increment(const Pose& pose, const double xi[6], const Vec3& c) {
  // Rotation by ω about c, then translation by v: w ↦ c + v + R(ω)·(w − c).
  const Mat3 R = rotation_from_vector({xi[3], xi[4], xi[5]});
  const Vec3 rc = R * c;
  const Vec3 shift = {c[0] + xi[0] - rc[0], c[1] + xi[1] - rc[1], c[2] + xi[2] - rc[2]};
  return Mat4::from_rotation_translation(R, shift) * pose;
}

namespace register_impl {
namespace {

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

/// The trust region: at most this far (mm) and this much turn (degrees) per step.
constexpr double kMaxStepMm = 2, kMaxStepDeg = 2;

/// The pyramid levels first..last (indices into settings.pyramid) of one optimisation; its end's
/// cost is taken at the last of them.
struct Levels {
  size_t first = 0, last = 0;
};

/// BOBYQA or Nelder–Mead (NLopt) on the correction X, level by level: the metric alone, as a
/// function of an increment about the frame's centre; the pyramid's first level's initial step
/// is kMaxStepMm and kMaxStepDeg, halved at each finer level. An evaluation is an iteration.
Outcome optimise_derivative_free(const Problem& p, const RegistrationSettings& s, const Pose& start,
                                 const Vec3& centre, Levels levels) {
  Outcome out;
  Pose X = start;
#ifdef SONOSLICE_HAVE_NLOPT
  const double halving = std::pow(0.5, double(levels.first));
  double step_mm = kMaxStepMm * halving, step_rad = kMaxStepDeg * kPi / 180 * halving;
  for (size_t level = levels.first; level <= levels.last; ++level) {
    const int f = (*s.pyramid)[level];
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
  (void)levels;
  throw InputError("optimizer: this sonoslice was built without NLopt");
#endif
  out.correction = X;
  out.cost = p.cost(X, (*s.pyramid)[levels.last]);
  out.evaluations += p.frames_per_evaluation;
  return out;
}

/// Gauss–Newton or Levenberg–Marquardt on the correction X (poses X·T), level by level.
Outcome optimise(const Problem& p, const RegistrationSettings& s, const Pose& start,
                 const Vec3& centre, Levels levels) {
  if (s.optimizer == RegistrationOptimizer::Bobyqa ||
      s.optimizer == RegistrationOptimizer::NelderMead)
    return optimise_derivative_free(p, s, start, centre, levels);
  Outcome out;
  Pose X = start;
  const double tol_rad = s.tolerance_deg * kPi / 180;
  for (size_t level = levels.first; level <= levels.last; ++level) {
    const int f = (*s.pyramid)[level];
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
  out.cost = p.cost(X, (*s.pyramid)[levels.last]);
  out.evaluations += p.frames_per_evaluation;
  return out;
}

/// Candidate starting points screened per start: the metric alone (no derivatives) at the
/// coarsest level is cheap, so many draws are ranked and the best settings.starts optimised.
constexpr int kCandidatesPerStart = 64;

}  // namespace

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

PoseTerms turned_into(const PoseTerms& t, const Mat3& R) {
  // M = diag(R, R): (Mᵀ·x)_i = Σ_j M_ji x_j.
  double M[6][6] = {};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) M[i][j] = M[3 + i][3 + j] = R.m[i][j];
  const auto turn = [&](const double* x, double* out) {
    for (int i = 0; i < 6; ++i) {
      out[i] = 0;
      for (int j = 0; j < 6; ++j) out[i] += M[j][i] * x[j];
    }
  };
  PoseTerms out = t;
  turn(t.sj, out.sj);
  turn(t.sij, out.sij);
  turn(t.sfj, out.sfj);
  double S[6][6];  // the full symmetric Σ J·Jᵀ from its upper triangle
  for (int i = 0, k = 0; i < 6; ++i)
    for (int j = i; j < 6; ++j, ++k) S[i][j] = S[j][i] = t.sjj[k];
  for (int i = 0, k = 0; i < 6; ++i)
    for (int j = i; j < 6; ++j, ++k) {
      double v = 0;
      for (int a = 0; a < 6; ++a)
        for (int b = 0; b < 6; ++b) v += M[a][i] * S[a][b] * M[b][j];
      out.sjj[k] = v;
    }
  return out;
}

std::pair<double, double> pose_uncertainty(RegistrationMetric metric, const PoseTerms& t) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (!metric_has_derivatives(metric)) return {nan, nan};
  double g[6], H[36], inverse[36];
  const double cost = metric_cost(metric, t, g, H);
  if (!std::isfinite(cost) || !invert6(H, inverse)) return {nan, nan};
  const double scale = 2 * std::max(cost, 0.0) / t.n;
  double translation = 0, rotation = 0;
  for (int k = 0; k < 3; ++k) {
    translation += scale * inverse[7 * k];
    rotation += scale * inverse[7 * (k + 3)];
  }
  if (!(translation >= 0) || !(rotation >= 0)) return {nan, nan};
  return {std::sqrt(translation), std::sqrt(rotation) * 180 / kPi};
}

double rotation_angle_deg(const Mat3& a, const Mat3& b) {
  double trace = 0;
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) trace += a.m[i][k] * b.m[i][k];
  return std::acos(std::max(-1.0, std::min(1.0, (trace - 1) / 2))) * 180 / kPi;
}

Outcome multi_start(const Problem& p, const RegistrationSettings& s, size_t item,
                    const Vec3& centre) {
  const bool automatic = !s.starts;
  const int most =
      !automatic ? *s.starts : (p.shared ? kAutoMaxSweepStarts : default_max_starts(s.metric));
  int64_t evaluations = 0, iterations = 0;
  const int draws = most == 1 ? 1 : most * kCandidatesPerStart;
  std::vector<std::pair<double, Pose>> candidates(size_t(draws), {0.0, Pose::identity()});
  for (int k = 0; k < draws; ++k) {
    double xi[6];
    start_increment(s, item, k, xi);
    candidates[size_t(k)].second = apply_increment(Pose::identity(), xi, centre);
  }
  if (draws > 1) {
    // The draws are independent: ranked on every thread when this problem has them to itself
    // (one frame, or a sweep); inside a per-frame loop they run on the frame's thread.
    backend::parallel_for(draws, [&](int64_t k) {
      const double cost = p.cost(candidates[size_t(k)].second, s.pyramid->front());
      candidates[size_t(k)].first = std::isfinite(cost) ? cost : std::numeric_limits<double>::max();
    });
    evaluations += int64_t(draws) * p.frames_per_evaluation;
  }
  // Stable: equal costs keep their draw order (the initial pose first).
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  // How many ends reached the best one: its centre moved by at most kAgreementMm from theirs,
  // its rotation at most kAgreementDeg from theirs.
  const auto apart = [&](const Pose& a, const Pose& b, double mm, double deg) {
    return norm(a.transform_point(centre) - b.transform_point(centre)) > mm ||
           rotation_angle_deg(a.linear(), b.linear()) > deg;
  };
  // The starts in start order: where each began, its coarse end, its outcome (after its coarse
  // levels, then its end) and whether it runs the finest level (below).
  struct Start {
    Pose from, coarse_end;
    Outcome outcome;
    bool coarse_done = false, fine = true, done = false;
  };
  std::vector<Start> started;
  size_t decided = 0, taken = 0;  // starts whose finest level is decided; whose end is taken
  Outcome best;
  const auto agreeing = [&] {
    int n = 0;
    for (size_t k = 0; k < taken; ++k)
      n += started[k].fine &&
           !apart(best.correction, started[k].outcome.correction, kAgreementMm, kAgreementDeg);
    return n;
  };
  // Automatic starts: the initial pose first, then the best-ranked points at least half the
  // search spread from every point already started from, so that two starts that agree came
  // from different places (neighbouring points of one basin would agree on its minimum, right
  // or wrong).
  if (automatic)
    std::stable_partition(candidates.begin(), candidates.end(), [&](const auto& c) {
      return !apart(c.second, Pose::identity(), 1e-9, 1e-9);
    });
  // Automatic starts also run coarse first. The finest level costs most (on LC2's 2, 1 six in
  // ten of a frame's evaluation time), and most starts of a hard frame end in other basins. So a
  // start runs the finest level only when its end at the level above is the best such end so far
  // (by that level's cost; an end whose cost is not a number too), or lies within twice the
  // agreement of the coarse end of a start that ran it (its finest level may bring it to agree).
  // The others keep their coarse end, count as starts that did not agree, and cannot be the
  // best. On docs/registration.md §5's frames this changed 10 of 280 frames' poses (none from a
  // hit to a miss or back) and took 9 % to half off a frame's time, half or more off a sweep's.
  const size_t levels = s.pyramid->size();
  const bool coarse_first = automatic && levels > 1;
  double best_coarse = std::numeric_limits<double>::infinity();
  // A frame that has the threads to itself runs its starts side by side, one phase (coarse, or
  // finest) per thread, the next start's coarse levels on a thread that no finest level needs.
  // The ends are taken in start order, as one thread would take them, and starts past the
  // stopping point are dropped (not counted): the same result, evaluations and report on any
  // thread count, since which starts run the finest level depends only on the coarse ends of
  // the starts before them. A sweep's evaluations are already spread over its frames.
  const size_t width = p.shared ? 1 : size_t(backend::parallel_width());
  size_t next = 0;
  bool stop = false;
  while (!stop) {
    // This round's phases: the finest levels decided on, in start order, then new starts.
    std::vector<std::pair<size_t, bool>> phases;  // (start, its finest level)
    for (size_t k = taken; k < decided && phases.size() < width; ++k)
      if (!started[k].done) phases.emplace_back(k, true);
    while (phases.size() < width && int(started.size()) < most && next < candidates.size()) {
      const Pose& from = candidates[next++].second;
      if (automatic) {
        bool far = true;
        for (const Start& b : started)
          far = far && apart(from, b.from, s.search_trans_mm / 2, s.search_rot_deg / 2);
        if (!far) continue;
      }
      started.push_back({from, from, {}, false, true, false});
      phases.emplace_back(started.size() - 1, false);
    }
    if (phases.empty()) break;
    backend::parallel_for(int64_t(phases.size()), [&](int64_t q) {
      Start& t = started[phases[size_t(q)].first];
      if (!phases[size_t(q)].second) {
        t.outcome = optimise(p, s, t.from, centre, {0, coarse_first ? levels - 2 : levels - 1});
        t.coarse_done = true;
        t.done = !coarse_first;
        return;
      }
      Outcome end = optimise(p, s, t.outcome.correction, centre, {levels - 1, levels - 1});
      end.evaluations += t.outcome.evaluations;
      end.iterations += t.outcome.iterations;
      t.outcome = end;
      t.done = true;
    });
    for (; decided < started.size() && started[decided].coarse_done; ++decided) {
      Start& t = started[decided];
      if (!coarse_first) continue;
      t.coarse_end = t.outcome.correction;
      bool refine = !(t.outcome.cost > best_coarse);
      for (size_t k = 0; k < decided && !refine; ++k)
        refine = started[k].fine &&
                 !apart(started[k].coarse_end, t.coarse_end, 2 * kAgreementMm, 2 * kAgreementDeg);
      best_coarse = std::min(best_coarse, t.outcome.cost);
      t.fine = refine;
      if (!refine) {
        t.outcome.cost = std::numeric_limits<double>::infinity();
        t.done = true;
      }
    }
    while (!stop && taken < decided && started[taken].done) {
      const Outcome& o = started[taken++].outcome;
      evaluations += o.evaluations;
      iterations += o.iterations;
      if (taken == 1 || o.cost < best.cost) best = o;
      stop = automatic && std::isfinite(best.cost) && agreeing() >= kAgreeingStarts;
    }
    stop = stop || (int(taken) >= most);
  }
  best.evaluations = evaluations;
  best.iterations = iterations;
  best.starts = int(taken);
  best.agreeing_starts = agreeing();
  return best;
}

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

}  // namespace register_impl
}  // namespace sonoslice
