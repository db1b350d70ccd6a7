// Registration's driver (docs/registration.md): what is optimised in each mode (each frame on its
// own, one correction for the sweep, then smooth-sweep's per-frame corrections) and the report.
// The stages live beside it: settings (RegistrationSettings.cpp), the pyramid (Pyramid.cpp), the
// metrics (Metrics.cpp, from the kernel RegisterImpl.h), the optimisers (Optimizers.cpp,
// SmoothSweep.cpp).
#include "sonoslice/register/Registration.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <tuple>
#include <utility>
#include <vector>

#include "../backend/ParallelFor.h"
#include "Optimizers.h"
#include "RegistrationState.h"

namespace sonoslice {

using register_impl::Outcome;
using register_impl::Problem;
using register_impl::rotation_angle_deg;
using register_impl::SweepOutcome;
using register_impl::SweepTerms;

namespace {
/// Per frame of level `l` (1: full resolution): whether its compared pixels are constant, or
/// fewer than 16.
std::vector<bool> flat_frames(const register_impl::Level& l, size_t count) {
  const size_t plane = size_t(l.width) * l.height;
  std::vector<bool> flat(count);
  for (size_t k = 0; k < count; ++k) {
    const float* f = l.frames.data() + k * plane;
    const uint8_t* m = l.masks.data() + k * plane;
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    size_t n = 0;
    for (size_t i = 0; i < plane; ++i)
      if (m[i]) {
        lo = std::min(lo, double(f[i]));
        hi = std::max(hi, double(f[i]));
        ++n;
      }
    flat[k] = n < 16 || !(hi > lo);
  }
  return flat;
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
  for (int f : *settings.pyramid) prepare_level(f);
  // Frames without contrast (constant over their compared pixels, or none left) have nothing to
  // register against: per frame they keep their pose, and the warning says why.
  const std::vector<bool> flat = flat_frames(s.level(1), s.count);

  std::vector<Pose> refined(s.count);
  std::vector<FrameReport> frames(s.count);
  std::optional<Pose> correction;  // the sweep modes' shared one
  std::optional<double> sweep_metric;
  // `metric`: the frame's own final cost (per frame: the optimisation's; a sweep's is shared).
  // `pose`: the refined pose, when not the world-side correction's o.correction · initial.
  const auto describe = [&](size_t k, const Outcome& o, int64_t evaluations,
                            std::optional<double> metric, std::optional<Pose> pose = {}) {
    FrameReport& r = frames[k];
    r.index = k;
    refined[k] = pose ? *pose : o.correction * initial[k];
    r.metric = metric ? *metric : cost(k, refined[k], 1, settings.metric);
    r.evaluations = evaluations;
    r.iterations = o.iterations;
    double d = 0;
    for (int i = 0; i < 3; ++i) d += std::pow(refined[k].m[i][3] - initial[k].m[i][3], 2);
    r.translation_change_mm = std::sqrt(d);
    r.rotation_change_deg = rotation_angle_deg(refined[k].linear(), initial[k].linear());
    r.starts = o.starts;
    r.agreeing_starts = o.agreeing_starts;
    if (settings.mode == RegistrationMode::PerFrame)
      std::tie(r.uncertainty_mm, r.uncertainty_deg) = register_impl::pose_uncertainty(
          settings.metric, terms(k, refined[k], 1, centre(k, refined[k]), true));
    r.converged = o.agreeing_starts >= kAgreeingStarts && std::isfinite(r.metric);
  };
  // A frame without contrast keeps its pose; so does every frame of a sweep none of whose frames
  // has any (its cost is the same everywhere: the search would wander on round-off).
  const auto keep = [&](size_t k) {
    Outcome none;
    none.starts = none.agreeing_starts = 0;
    describe(k, none, 0, std::numeric_limits<double>::infinity());
  };
  const bool nothing_steers = std::all_of(flat.begin(), flat.end(), [](bool f) { return f; });
  if (settings.mode == RegistrationMode::PerFrame) {
    backend::parallel_for(int64_t(s.count), [&](int64_t k) {
      if (flat[size_t(k)]) {
        keep(size_t(k));
        return;
      }
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
  } else if (nothing_steers) {
    for (size_t k = 0; k < s.count; ++k) keep(k);
  } else {
    // One correction X for the sweep. rigid-sweep and smooth-sweep's first stage: world side,
    // poses X·T_k, turning about the mean of the frames' centres. calibration: probe side, poses
    // T_k·X, turning about the mean of the frames' centres in probe mm; an increment ξ of X there
    // is frame k's world increment R_k·ξ about T_k·c (R_k: T_k's rotation), so each frame's
    // derivatives are turned into the probe frame before they are summed. Each evaluation sums
    // every frame's terms (in parallel, then in frame order).
    const bool probe_side = settings.mode == RegistrationMode::Calibration;
    const auto pose_of = [&](const Pose& X, size_t k) {
      return probe_side ? initial[k] * X : X * initial[k];
    };
    Vec3 mean = {0, 0, 0};
    for (size_t k = 0; k < s.count; ++k) {
      const Vec3 c = probe_side ? s.mask_centre[k] : centre(k, initial[k]);
      for (int i = 0; i < 3; ++i) mean[i] += c[i] / double(s.count);
    }
    Problem p;
    p.frames_per_evaluation = int64_t(s.count);
    p.shared = true;
    p.terms = [&](const Pose& X, int f, const Vec3& c, bool g) {
      std::vector<PoseTerms> each(s.count);
      backend::parallel_for(int64_t(s.count), [&](int64_t k) {
        const Pose& T = initial[size_t(k)];
        if (!probe_side) {
          each[size_t(k)] = terms(size_t(k), X * T, f, c, g);
          return;
        }
        each[size_t(k)] = terms(size_t(k), T * X, f, T.transform_point(c), g);
        if (g) each[size_t(k)] = register_impl::turned_into(each[size_t(k)], T.linear());
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
        const Pose pose = pose_of(X, size_t(k));
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
    correction = o.correction;
    sweep_metric = o.cost;  // every optimisation ends with p.cost(X, 1), the full-resolution cost
    // The shared correction's uncertainty, from the sweep's summed terms.
    const auto [sweep_mm, sweep_deg] =
        metric_has_derivatives(settings.metric)
            ? register_impl::pose_uncertainty(
                  settings.metric,
                  p.terms(o.correction, 1, o.correction.transform_point(mean), true))
            : std::pair<double, double>{std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::quiet_NaN()};
    if (settings.mode != RegistrationMode::SmoothSweep) {
      for (size_t k = 0; k < s.count; ++k) {
        describe(k, o, o.evaluations / int64_t(s.count), std::nullopt, pose_of(o.correction, k));
        frames[k].uncertainty_mm = sweep_mm;
        frames[k].uncertainty_deg = sweep_deg;
      }
    } else {
      // smooth-sweep: from the shared correction, each frame its own, tied to its neighbours.
      SweepTerms sweep;
      sweep.terms = [&](size_t k, const Pose& X, int f, const Vec3& c, bool g) {
        return terms(k, X * initial[k], f, c, g);
      };
      for (size_t k = 0; k < s.count; ++k) sweep.centres.push_back(centre(k, initial[k]));
      const SweepOutcome smooth = smooth_sweep(sweep, settings, o.correction);
      for (size_t k = 0; k < s.count; ++k) {
        Outcome frame = o;  // the starts and their agreement are the rigid stage's
        frame.correction = smooth.corrections[k];
        frame.iterations = o.iterations + smooth.iterations;
        describe(k, frame, o.evaluations / int64_t(s.count) + smooth.evaluations, smooth.costs[k]);
      }
    }
  }
  std::string flat_list;
  size_t flat_count = 0, unconverged = 0;
  for (size_t k = 0; k < s.count; ++k) {
    if (!flat[k]) {
      unconverged += !frames[k].converged;
      continue;
    }
    if (++flat_count <= 10) flat_list += (flat_list.empty() ? "" : ", ") + std::to_string(k);
  }
  if (flat_count > 10) flat_list += ", ...";
  if (flat_count > 0)
    warn("registration: frame" + std::string(flat_count > 1 ? "s " : " ") + flat_list + " (" +
         std::to_string(flat_count) + " of " + std::to_string(s.count) +
         ") constant over the compared pixels: nothing to register against" +
         (settings.mode == RegistrationMode::PerFrame || nothing_steers
              ? "; poses left as given"
              : "; they do not steer the sweep"));
  if (unconverged > 0)
    warn("registration: " + std::to_string(unconverged) + " of " + std::to_string(frames.size()) +
         " frames not converged (their best pose was reached from fewer than " +
         std::to_string(kAgreeingStarts) +
         " of the starts; "
         "the report's converged and agreeing_starts say which): more starts, a wider search, or "
         "a better initial pose may help");
  if (report) {
    report->settings = settings;
    report->frames = frames;
    report->correction = correction;
    report->sweep_metric = sweep_metric;
    report->evaluations = 0;
    for (const FrameReport& r : frames) report->evaluations += r.evaluations;
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - clock).count();
  }
  return refined;
}

}  // namespace sonoslice
