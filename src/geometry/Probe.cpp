#include "sonoslice/geometry/Probe.h"

#include <cmath>
#include <sstream>

#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {
namespace {
// One image larger than this many pixels is a typo, not a probe (2^31: also the kernels' limit).
constexpr int64_t kMaxPixelsPerImage = int64_t(1) << 31;

bool positive(double v) {
  return std::isfinite(v) && v > 0;
}
}  // namespace

void ProbeGeometry::validate(const std::string& what) const {
  auto fail = [&](const std::string& why) { throw InputError(what + ": " + why); };
  if (image.width <= 0 || image.height <= 0) {
    std::ostringstream s;
    s << "image size " << image.width << "x" << image.height << " (width and height must be > 0)";
    fail(s.str());
  }
  if (image.pixel_count() >= kMaxPixelsPerImage) fail("image size is absurdly large");
  if (!positive(image.spacing_mm[0]) || !positive(image.spacing_mm[1]))
    fail("pixel spacing must be > 0 mm");
  if (!std::isfinite(image.origin_mm[0]) || !std::isfinite(image.origin_mm[1]))
    fail("image origin must be finite");
  if (!std::isfinite(face_y_mm)) fail("face_y_mm must be finite");
  if (type == ProbeType::Curvilinear) {
    if (!positive(radius_mm)) fail("radius_mm must be > 0");
    if (!positive(depth_mm)) fail("depth_mm must be > 0");
    if (!positive(sector_deg) || sector_deg > 360) fail("sector_deg must be in (0, 360]");
  } else {
    if (has_width && !positive(width_mm)) fail("width_mm must be > 0");
    if (has_depth && !positive(depth_mm)) fail("depth_mm must be > 0");
  }
}

bool ProbeGeometry::inside(double x, double y) const {
  if (type == ProbeType::Curvilinear) {
    const double apex_y = face_y_mm - radius_mm;
    const double dy = y - apex_y;
    const double r = std::sqrt(x * x + dy * dy);
    const double phi = std::atan2(x, dy);
    return r >= radius_mm && r <= radius_mm + depth_mm &&
           std::fabs(phi) <= sector_deg * kPi / 360.0;
  }
  if (has_width && std::fabs(x) > width_mm / 2) return false;
  if (has_depth && !(y - face_y_mm >= 0 && y - face_y_mm <= depth_mm)) return false;
  return true;
}

std::vector<uint8_t> ProbeGeometry::mask() const {
  std::vector<uint8_t> m(size_t(image.pixel_count()));
  for (int v = 0; v < image.height; ++v) {
    const double y = image.origin_mm[1] + v * image.spacing_mm[1];
    for (int u = 0; u < image.width; ++u) {
      const double x = image.origin_mm[0] + u * image.spacing_mm[0];
      m[size_t(v) * image.width + u] = inside(x, y) ? 1 : 0;
    }
  }
  return m;
}

const char* to_string(ProbeType type) {
  switch (type) {
    case ProbeType::Curvilinear:
      return "curvilinear";
    case ProbeType::Linear:
      return "linear";
  }
  return "?";
}

ProbeType parse_probe_type(const std::string& name) {
  if (name == to_string(ProbeType::Curvilinear)) return ProbeType::Curvilinear;
  if (name == to_string(ProbeType::Linear)) return ProbeType::Linear;
  throw InputError("probe type '" + name + "': expected curvilinear or linear");
}

std::string ProbeGeometry::describe() const {
  std::ostringstream s;
  if (type == ProbeType::Curvilinear)
    s << "curvilinear R=" << radius_mm << " mm, depth=" << depth_mm << " mm, sector=" << sector_deg
      << " deg, face_y=" << face_y_mm << " mm";
  else
    s << "linear";
  s << "; image " << image.width << "x" << image.height << " px at " << image.spacing_mm[0] << "x"
    << image.spacing_mm[1] << " mm, origin (" << image.origin_mm[0] << ", " << image.origin_mm[1]
    << ") mm";
  return s.str();
}

}  // namespace sonoslice
