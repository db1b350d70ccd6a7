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
  for (const auto& [name, length] :
       {std::pair<const char*, double>{"pixel spacing", image.spacing_mm[0]},
        {"pixel spacing", image.spacing_mm[1]},
        {"image origin", image.origin_mm[0]},
        {"image origin", image.origin_mm[1]},
        {"face_y_mm", face_y_mm},
        {"radius_mm", radius_mm},
        {"depth_mm", depth_mm},
        {"width_mm", width_mm}})
    if (std::fabs(length) > kMaxGeometryMm) {
      std::ostringstream s;
      s << name << " " << length << " mm is beyond any probe's extent (at most 1e9 mm)";
      fail(s.str());
    }
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

Mat4 ProbeGeometry::pixel_to_probe() const {
  Mat4 m;
  m.m[0][0] = image.spacing_mm[0];
  m.m[1][1] = image.spacing_mm[1];
  m.m[0][3] = image.origin_mm[0];
  m.m[1][3] = image.origin_mm[1];
  return m;
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

ImageGrid ImageGrid::centred(int width, int height, double sx_mm, double sy_mm) {
  ImageGrid g;
  g.width = width;
  g.height = height;
  g.spacing_mm[0] = sx_mm;
  g.spacing_mm[1] = sy_mm;
  g.set_default_origin();
  return g;
}

ProbeGeometry ProbeGeometry::curvilinear(double radius_mm, double depth_mm, double sector_deg,
                                         const ImageGrid& image, double face_y_mm) {
  ProbeGeometry p;
  p.type = ProbeType::Curvilinear;
  p.image = image;
  p.radius_mm = radius_mm;
  p.depth_mm = depth_mm;
  p.sector_deg = sector_deg;
  p.face_y_mm = face_y_mm;
  return p;
}

ProbeGeometry ProbeGeometry::linear(const ImageGrid& image, std::optional<double> width_mm,
                                    std::optional<double> depth_mm, double face_y_mm) {
  ProbeGeometry p;
  p.type = ProbeType::Linear;
  p.image = image;
  p.has_width = width_mm.has_value();
  p.width_mm = width_mm.value_or(0.0);
  p.has_depth = depth_mm.has_value();
  p.depth_mm = depth_mm.value_or(0.0);
  p.face_y_mm = face_y_mm;
  return p;
}

ProbeGeometry probe_from_fanslicer(const FanSlicerProbe& fs, int ds) {
  ImageGrid image;
  image.width = fs.image_dimensions[0] / ds;
  image.height = fs.image_dimensions[1] / ds;
  image.spacing_mm[0] = fs.pixel_size_mm[0] * ds;
  image.spacing_mm[1] = fs.pixel_size_mm[1] * ds;
  const double sx = image.spacing_mm[0];
  switch (fs.transducer) {
    case ProbeType::Curvilinear: {
      image.origin_mm[0] = -image.width * sx / 2.0;
      const double da = fs.fan_geometry[1];
      return ProbeGeometry::curvilinear(fs.fan_geometry[4] * da, fs.fan_geometry[3] * da,
                                        fs.fan_geometry[2], image, fs.fan_geometry[5] * da);
    }
    case ProbeType::Linear:
      image.origin_mm[0] = -double(image.width / 2) * sx;
      return ProbeGeometry::linear(image);
  }
  return ProbeGeometry{};
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
