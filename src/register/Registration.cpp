// Registration's driver (docs/registration.md): what is optimised in each mode (each frame on its
// own, one correction for the sweep, then smooth-sweep's per-frame corrections) and the report.
// The stages live beside it: settings (RegistrationSettings.cpp), the pyramid (Pyramid.cpp), the
// metrics (Metrics.cpp, from the kernel RegisterImpl.h), the optimisers (Optimizers.cpp,
// SmoothSweep.cpp).
#include "sonoslice/register/Registration.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <memory>
#include <numeric>
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
/// Per frame of level `l` (1: full resolution): whether its compared pixels in columns
/// [first, end) are constant, or fewer than 16.
std::vector<bool> flat_frames(const register_impl::Level& l, size_t count, size_t first = 0,
                              size_t end = std::numeric_limits<size_t>::max()) {
  const size_t width = size_t(l.width), plane = width * l.height;
  end = std::min(end, width);
  std::vector<bool> flat(count);
  for (size_t k = 0; k < count; ++k) {
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    size_t n = 0;
    for (size_t row = k * plane; row < (k + 1) * plane; row += width)
      for (size_t i = row + first; i < row + end; ++i)
        if (l.masks[i]) {
          lo = std::min(lo, double(l.frames[i]));
          hi = std::max(hi, double(l.frames[i]));
          ++n;
        }
    flat[k] = n < 16 || !(hi > lo);
  }
  return flat;
}

/// How far a sweep's frames move through their image planes and within them (mm): the largest
/// distance of a frame's centre from another frame's plane, and the largest distance between two
/// centres along another frame's plane.
std::pair<double, double> sweep_extent(const std::vector<Vec3>& centres,
                                       const std::vector<Vec3>& normals) {
  double through = 0, within = 0;
  for (size_t j = 0; j < centres.size(); ++j)
    for (size_t k = 0; k < centres.size(); ++k) {
      const Vec3 d = centres[k] - centres[j];
      const double off = std::fabs(dot(normals[j], d));
      through = std::max(through, off);
      within = std::max(within, std::sqrt(std::max(0.0, dot(d, d) - off * off)));
    }
  return {through, within};
}

/// The column that splits the `steering` frames' compared pixels of level 1 in halves: the
/// first column right of the median.
size_t median_column(const register_impl::Level& full, const std::vector<size_t>& steering) {
  const size_t width = size_t(full.width), plane = width * size_t(full.height);
  std::vector<int64_t> columns(width, 0);
  for (size_t k : steering)
    for (size_t i = 0; i < plane; ++i) columns[i % width] += full.masks[k * plane + i];
  const int64_t total = std::accumulate(columns.begin(), columns.end(), int64_t(0));
  size_t split = 0;
  for (int64_t below = 0; split < width && 2 * (below + columns[split]) <= total; ++split)
    below += columns[split];
  return split;
}

/// The frames of level 1 with only the compared pixels left (`left`) or right of column `split`;
/// NaN (not compared) elsewhere.
std::vector<float> side_frames(const register_impl::Level& full, size_t count, size_t split,
                               bool left) {
  const size_t width = size_t(full.width), plane = width * size_t(full.height);
  std::vector<float> side(count * plane, std::numeric_limits<float>::quiet_NaN());
  for (size_t k = 0; k < count; ++k)
    for (size_t i = 0; i < plane; ++i)
      if (full.masks[k * plane + i] && (i % width < split) == left)
        side[k * plane + i] = full.frames[k * plane + i];
  return side;
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
  // Said here, not when the frames are taken: the sweep checks make registrations of their own
  // whose frames hold NaN for the pixels they leave out.
  if (s.non_finite_pixels > 0)
    warn("frames: " + std::to_string(s.non_finite_pixels) + " of the " +
         std::to_string(s.masked_pixels) +
         " pixels inside the fan and the mask are NaN or infinite; they are left out");
  for (int f : *settings.pyramid) prepare_level(f);
  // Frames without contrast (constant over their compared pixels, or none left) have nothing to
  // register against: per frame they keep their pose, and the warning says why.
  const std::vector<bool> flat = flat_frames(s.level(1), s.count);

  std::vector<Pose> refined(s.count);
  std::vector<FrameReport> frames(s.count);
  std::optional<Pose> correction;  // the sweep modes' shared one
  std::optional<double> sweep_metric;
  // The sweep modes' halves check (kHalvesAgreementMm): the frames' halves, their pixels' sides.
  std::optional<double> halves_mm, sides_mm;
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
    r.converged = o.agreeing_starts >= kAgreeingStarts && std::isfinite(r.metric) &&
                  !(halves_mm && *halves_mm > kHalvesAgreementMm) &&
                  !(sides_mm && *sides_mm > kHalvesAgreementMm);
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
    // derivatives are turned into the probe frame before they are summed.
    const bool probe_side = settings.mode == RegistrationMode::Calibration;
    // The sweep's problem over the frames `members` at the poses `base`: each evaluation sums
    // those frames' terms (in parallel, then in frame order), turning about `mean`.
    const auto pose_of = [&](const Pose& X, const Pose& T) { return probe_side ? T * X : X * T; };
    const auto sweep_problem = [&](const std::vector<Pose>& base,
                                   const std::vector<size_t>& members, const Vec3& mean,
                                   const FrameRegistration& r) {
      Problem p;
      p.frames_per_evaluation = int64_t(members.size());
      p.shared = true;
      p.terms = [&, probe_side](const Pose& X, int f, const Vec3& c, bool g) {
        std::vector<PoseTerms> each(members.size());
        backend::parallel_for(int64_t(members.size()), [&](int64_t i) {
          const size_t k = members[size_t(i)];
          const Pose& T = base[k];
          if (!probe_side) {
            each[size_t(i)] = r.terms(k, X * T, f, c, g);
            return;
          }
          each[size_t(i)] = r.terms(k, T * X, f, T.transform_point(c), g);
          if (g) each[size_t(i)] = register_impl::turned_into(each[size_t(i)], T.linear());
        });
        PoseTerms sum;
        for (const PoseTerms& t : each) sum.add(t);
        return sum;
      };
      // The sweep's cost: SSD and NCC over all its pixels together; LC2 and LNCC over all its
      // patches; MI the mean of the frames' (each frame has its own intensity range).
      p.cost = [&, terms_of = p.terms](const Pose& X, int f) {
        if (settings.metric == RegistrationMetric::SSD ||
            settings.metric == RegistrationMetric::NCC)
          return metric_cost(settings.metric, terms_of(X, f, mean, false));
        std::vector<std::pair<double, double>> each(members.size());
        backend::parallel_for(int64_t(members.size()), [&](int64_t i) {
          const size_t k = members[size_t(i)];
          const Pose pose = pose_of(X, base[k]);
          if (settings.metric == RegistrationMetric::MI)
            each[size_t(i)] = {r.cost(k, pose, f, settings.metric), 1.0};
          else
            each[size_t(i)] = r.patch_score(k, pose, f, settings.metric);
        });
        double weighted = 0, weight = 0;
        for (const auto& [a, b] : each) {
          weighted += a;
          weight += b;
        }
        if (!(weight > 0)) return std::numeric_limits<double>::infinity();
        return settings.metric == RegistrationMetric::MI ? weighted / weight
                                                         : 1 - weighted / weight;
      };
      return p;
    };
    // The frames' mean centre (probe side: in probe mm), which the sweep turns about.
    const auto mean_centre = [&](const std::vector<Pose>& base,
                                 const std::vector<size_t>& members) {
      Vec3 mean = {0, 0, 0};
      for (size_t k : members) {
        const Vec3 c = probe_side ? s.mask_centre[k] : centre(k, base[k]);
        for (int i = 0; i < 3; ++i) mean[i] += c[i] / double(members.size());
      }
      return mean;
    };
    std::vector<size_t> all(s.count);
    for (size_t k = 0; k < s.count; ++k) all[k] = k;
    const Vec3 mean = mean_centre(initial, all);
    const Problem p = sweep_problem(initial, all, mean, *this);
    Outcome o = multi_start(p, settings, 0, mean);
    correction = o.correction;
    sweep_metric = o.cost;  // every optimisation ends with p.cost(X, 1), the full-resolution cost
    // What agreeing starts cannot see: a wrong optimum that every start reaches. The sweep is
    // split in two, twice: its first and second halves (of its frames with contrast), and the
    // left and right halves of its frames' pixels. Each half, refined alone from the sweep's
    // result, must end within kHalvesAgreementMm of the other at every frame's centre: a right
    // answer fits both halves, a wrong one that the whole sweep prefers usually pulls its halves
    // apart, since each sees other tissue. The frames' halves catch wrong answers through the
    // image plane; the pixels' halves those of a sweep that slides across it (whose frames all
    // see much the same tissue), mostly a turn about the sweep line.
    std::vector<size_t> steering;
    for (size_t k = 0; k < s.count; ++k)
      if (!flat[k]) steering.push_back(k);
    // Not in smooth-sweep mode, whose frames need not share one correction.
    if (settings.mode != RegistrationMode::SmoothSweep && steering.size() >= 4 &&
        std::isfinite(o.cost)) {
      std::vector<Pose> at_result(s.count);
      for (size_t k = 0; k < s.count; ++k) at_result[k] = pose_of(o.correction, initial[k]);
      RegistrationSettings local = settings;
      local.starts = 1;
      local.pyramid = std::vector<int>{1};
      // Compared at half a millimetre: steps of 0.01 mm and 0.01° are fine enough, and fewer.
      local.tolerance_mm = std::max(local.tolerance_mm, 0.01);
      local.tolerance_deg = std::max(local.tolerance_deg, 0.01);
      // The two halves' corrections, each refined over `members[h]` of the registration `by(h)`
      // (asked for in turn); how far apart they end.
      const auto halves_apart = [&](const std::function<const FrameRegistration&(int)>& by,
                                    const std::vector<size_t>(&members)[2]) {
        Pose ends[2];
        for (int h = 0; h < 2; ++h) {
          const Vec3 c = mean_centre(at_result, members[h]);
          const Outcome e =
              multi_start(sweep_problem(at_result, members[h], c, by(h)), local, 0, c);
          ends[h] = e.correction;
          o.evaluations += e.evaluations;
        }
        double apart = 0;
        for (size_t k : steering) {
          const Vec3 c = probe_side ? s.mask_centre[k] : centre(k, at_result[k]);
          apart = std::max(apart, norm(ends[0].transform_point(c) - ends[1].transform_point(c)));
        }
        return apart;
      };
      const size_t half = steering.size() / 2;
      const auto whole = [this](int) -> const FrameRegistration& { return *this; };
      halves_mm = halves_apart(whole, {{steering.begin(), steering.begin() + std::ptrdiff_t(half)},
                                       {steering.begin() + std::ptrdiff_t(half), steering.end()}});
      // The pixels' halves, where the frames' halves are blind: a sweep that moves more within
      // its image plane than through it (or not at all) shows both halves of its frames much the
      // same tissue.
      std::vector<Vec3> centres, normals;
      for (size_t k : steering) {
        centres.push_back(centre(k, initial[k]));
        normals.push_back(initial[k].linear().column(2));
      }
      const auto [through, within] = sweep_extent(centres, normals);
      if (through <= within) {
        // Either side of the compared pixels' median column, as a registration of the same
        // volume (shared) and frames, the other side's pixels not compared; one side's copy of
        // the frames at a time. Only frames with contrast on both sides take part.
        const register_impl::Level& full = s.level(1);
        const size_t split = median_column(full, steering);
        const std::vector<bool> flat_left = flat_frames(full, s.count, 0, split),
                                flat_right = flat_frames(full, s.count, split);
        std::vector<size_t> both;
        for (size_t k : steering)
          if (!flat_left[k] && !flat_right[k]) both.push_back(k);
        std::unique_ptr<FrameRegistration> side;
        const auto side_of = [&](int h) -> const FrameRegistration& {
          side.reset();
          const std::vector<float> frames = side_frames(full, s.count, split, h == 0);
          side = std::make_unique<FrameRegistration>(s.volume, s.probe, frames.data(), s.count);
          return *side;
        };
        try {
          if (both.size() >= 4) sides_mm = halves_apart(side_of, {both, both});
        } catch (const InputError&) {
          // A frame (without contrast) with no compared pixel on one side: not split by pixels.
        }
      }
    }
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
        describe(k, o, o.evaluations / int64_t(s.count), std::nullopt,
                 pose_of(o.correction, initial[k]));
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
      unconverged +=
          frames[k].agreeing_starts < kAgreeingStarts || !std::isfinite(frames[k].metric);
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
  // One warning naming each split whose halves end too far apart.
  std::string apart;
  for (const auto& [split, mm, field] :
       {std::tuple{"its first and second halves", halves_mm, "halves_mm"},
        std::tuple{"the left and right halves of its frames", sides_mm, "sides_mm"}}) {
    if (!mm || *mm <= kHalvesAgreementMm) continue;
    char text[160];
    std::snprintf(text, sizeof(text), "%s%s end %.2f mm apart (the report's %s)",
                  apart.empty() ? "" : ", and ", split, *mm, field);
    apart += text;
  }
  if (!apart.empty()) {
    char bound[64];
    std::snprintf(bound, sizeof(bound), ", more than %g mm", kHalvesAgreementMm);
    warn("registration: the sweep is not converged: refined alone from its result, " + apart +
         bound +
         ": a wrong optimum of the whole sweep, or frames that do not share one correction (a "
         "tracking jump; a drift: smooth-sweep)");
  }
  if (report) {
    report->settings = settings;
    report->frames = frames;
    report->correction = correction;
    report->sweep_metric = sweep_metric;
    report->halves_mm = halves_mm;
    report->sides_mm = sides_mm;
    report->evaluations = 0;
    for (const FrameReport& r : frames) report->evaluations += r.evaluations;
    report->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - clock).count();
  }
  return refined;
}

}  // namespace sonoslice
