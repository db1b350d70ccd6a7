// Registration's settings: the spelling of its choices, the optimizer each metric gets by
// default, and the checks that name the setting (include/sonoslice/register/Registration.h).
#include <cmath>

#include "../core/Text.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/register/Registration.h"

namespace sonoslice {

RegistrationMetric parse_registration_metric(const std::string& name, const std::string& what) {
  if (const auto* m = text::find_named(kRegistrationMetrics, name)) return *m;
  throw InputError(what + " " + name + ": expected " + text::spellings(kRegistrationMetrics));
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
  if (const auto* o = text::find_named(kRegistrationOptimizers, name)) return *o;
  throw InputError(what + " " + name + ": expected " + text::spellings(kRegistrationOptimizers));
}

RegistrationMode parse_registration_mode(const std::string& name, const std::string& what) {
  if (const auto* m = text::find_named(kRegistrationModes, name)) return *m;
  throw InputError(what + " " + name + ": expected " + text::spellings(kRegistrationModes));
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
    case RegistrationMode::Calibration:
      return "calibration";
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

std::vector<int> default_pyramid(RegistrationMetric metric) {
  if (metric == RegistrationMetric::LC2) return {2, 1};
  return {8, 4, 2, 1};
}

int default_max_starts(RegistrationMetric metric) {
  return metric_has_derivatives(metric) ? kAutoMaxStartsWithDerivatives : kAutoMaxStarts;
}

RegistrationSettings RegistrationSettings::resolved() const {
  RegistrationSettings s = *this;
  if (!s.optimizer) s.optimizer = default_optimizer(metric);
  if (!s.pyramid) s.pyramid = default_pyramid(metric);
  if (!s.smoothness && mode == RegistrationMode::SmoothSweep) s.smoothness = kDefaultSmoothness;
  return s;
}

void RegistrationSettings::validate(const ParameterNames& names) const {
  const auto name = [&](const char* setting) { return spelled(names, setting); };
  // Each start is an optimisation with its own state: a million is a typo, not a search.
  constexpr int kMaxStarts = 100000;
  if (starts && *starts < 1)
    throw InputError(name("starts") + " " + std::to_string(*starts) + ": must be at least 1");
  if (starts && *starts > kMaxStarts)
    throw InputError(name("starts") + " " + std::to_string(*starts) + ": at most " +
                     std::to_string(kMaxStarts));
  if (!(search_rot_deg >= 0 && search_rot_deg <= 180))
    throw InputError(name("search_rot_deg") + " " + text::number(search_rot_deg) +
                     ": must be in [0, 180] degrees");
  if (!(search_trans_mm >= 0 && search_trans_mm <= kMaxGeometryMm))
    throw InputError(name("search_trans_mm") + " " + text::number(search_trans_mm) +
                     ": must be a distance from 0 to 1e9 mm");
  if (pyramid && pyramid->empty()) throw InputError(name("pyramid") + ": needs at least one level");
  if (pyramid) {
    std::string levels;
    for (int g : *pyramid) levels += (levels.empty() ? "" : ",") + std::to_string(g);
    for (size_t i = 0; i < pyramid->size(); ++i) {
      const int f = (*pyramid)[i];
      if (f < 1 || f > 64)
        throw InputError(name("pyramid") + " " + levels +
                         ": expected block sizes from 1 to 64, coarse to fine, e.g. 8,4,2,1");
      // Each level starts from the one before and the last gives the result: a level coarser
      // than the one before it would throw away the finer level's accuracy.
      if (i > 0 && f >= (*pyramid)[i - 1])
        throw InputError(name("pyramid") + " " + levels +
                         ": the block sizes must decrease, coarse to fine, e.g. 8,4,2,1");
    }
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
  if (smoothness && !(*smoothness >= 0 && std::isfinite(*smoothness)))
    throw InputError(name("smoothness") + " " + text::number(*smoothness) +
                     ": must be a finite weight >= 0");
  if (smoothness && mode != RegistrationMode::SmoothSweep)
    throw InputError(name("smoothness") + ": applies to " + name("mode") + " " +
                     to_string(RegistrationMode::SmoothSweep) +
                     " (the prior between neighbouring " + "frames' corrections), not " +
                     to_string(mode));
  if (mode == RegistrationMode::SmoothSweep &&
      !(metric_has_derivatives(metric) && derivative_based))
    throw InputError(name("mode") + " smooth-sweep: needs " + name("metric") + " ssd or ncc with " +
                     name("optimizer") +
                     " lm or gn (all frames are solved jointly from their analytic derivatives)");
}

}  // namespace sonoslice
