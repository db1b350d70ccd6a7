// 3D beam-space frames: their geometry's checks and the directions and points of their beams.
#include "sonoslice/compound/BeamGeometry.h"

#include <cmath>
#include <cstdint>
#include <string>
#include <utility>

#include "BeamPoints.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

namespace compound_impl {

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

Vec3 beam_point(const BeamGeometry& g, const Vec3& d, double r) {
  return {r * d[0], r * d[1] - g.apex_offset_mm, r * d[2]};
}

}  // namespace compound_impl

// Far beyond any 3-D probe (a 4D probe's frame is about 100 x 100 beams of 1,000 samples): larger
// sizes come from a corrupt header and would overflow the sample counts.
constexpr int64_t kMaxBeamsPerFrame = int64_t(1) << 28;
constexpr int64_t kMaxSamplesPerBeam = int64_t(1) << 24;

void BeamGeometry::validate(const std::string& what) const {
  if (n_elevation <= 0 || n_azimuth <= 0 || n_samples <= 0)
    throw InputError(what + ": beam-space frame size " + std::to_string(n_elevation) + "x" +
                     std::to_string(n_azimuth) + "x" + std::to_string(n_samples) +
                     " must be positive");
  if (int64_t(n_elevation) * n_azimuth > kMaxBeamsPerFrame || n_samples > kMaxSamplesPerBeam)
    throw InputError(what + ": beam-space frame size " + std::to_string(n_elevation) + "x" +
                     std::to_string(n_azimuth) + "x" + std::to_string(n_samples) +
                     " is absurd (at most " + std::to_string(kMaxBeamsPerFrame) + " beams of " +
                     std::to_string(kMaxSamplesPerBeam) + " samples)");
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

}  // namespace sonoslice
