#include "ReconstructionFlags.h"

#include <cctype>
#include <cmath>
#include <cstdlib>

#include "Common.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace cli {
namespace {

// "8G", "512M", "1.5GiB", "2000000000" → bytes.
uint64_t parse_bytes(const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  std::string unit(end);
  for (auto& c : unit) c = char(std::toupper(static_cast<unsigned char>(c)));
  double scale = 1;
  if (unit == "K" || unit == "KB" || unit == "KIB")
    scale = 1024.0;
  else if (unit == "M" || unit == "MB" || unit == "MIB")
    scale = 1024.0 * 1024;
  else if (unit == "G" || unit == "GB" || unit == "GIB")
    scale = 1024.0 * 1024 * 1024;
  else if (unit == "T" || unit == "TB" || unit == "TIB")
    scale = 1024.0 * 1024 * 1024 * 1024;
  else if (!unit.empty() && unit != "B")
    throw InputError("--max-memory " + text + ": expected a size such as 8G, 512M or 2000000000");
  if (end == text.c_str() || !(v > 0) || !std::isfinite(v))
    throw InputError("--max-memory " + text + ": expected a positive size such as 8G or 512M");
  return uint64_t(v * scale);
}

// "S" or "SX,SY,SZ" → mm (the recipe checks the values).
Vec3 parse_spacing(const std::string& text) {
  const bool one = text.find(',') == std::string::npos;
  const auto v = parse_numbers(text, one ? 1 : 3, "--spacing");
  return one ? Vec3{{v[0], v[0], v[0]}} : Vec3{{v[0], v[1], v[2]}};
}

std::array<int, 4> parse_clip_rect(const std::string& text) {
  const auto r = parse_numbers(text, 4, "--clip-rect");
  std::array<int, 4> out{};
  for (size_t i = 0; i < 4; ++i) {
    if (r[i] < 0 || r[i] != std::floor(r[i]) || r[i] > 1e9)
      throw InputError("--clip-rect " + text + ": expected four whole numbers X,Y,W,H >= 0");
    out[i] = int(r[i]);
  }
  return out;
}

}  // namespace

void ReconstructionFlags::add_to(CLI::App& cmd) {
  cmd.add_option("--spacing", spacing, "Voxel size in mm: S or SX,SY,SZ (default: the XML's)");
  cmd.add_option("--origin", origin,
                 "X,Y,Z: the centre of voxel (0,0,0) in mm, with --extent (default: the XML's "
                 "OutputOrigin/OutputExtent, else a grid around the frames)");
  cmd.add_option("--extent", extent, "NX,NY,NZ: voxels per axis, with --origin");
  cmd.add_option("--interp", interp, "nearest or linear splats (default: the XML's, else linear)");
  cmd.add_option("--compounding", compounding, "mean (default), max or latest");
  cmd.add_option("--fill-holes", fill_holes, "on or off (default: the XML's, else off)");
  cmd.add_option("--clip-rect", clip_rect, "X,Y,W,H: the W x H pixels from (X,Y) go in");
  cmd.add_option("--rejection-threshold", rejection_threshold,
                 "Pixels below this value are not inserted");
  cmd.add_option("--dtype", dtype, "Output type (default: the frames' type)");
  cmd.add_option("--max-memory", max_memory,
                 "Memory the reconstruction may use, e.g. 8G (default: what is available)");
  cmd.add_option("--device", device, "cpu (default), cuda or cuda:K");
  add_threads_option(cmd, threads);
}

void ReconstructionFlags::apply(ReconstructionOptions& o) const {
  if (!spacing.empty()) o.spacing_mm = parse_spacing(spacing);
  if (!origin.empty()) {
    const auto v = parse_numbers(origin, 3, "--origin");
    o.origin_mm = Vec3{{v[0], v[1], v[2]}};
  }
  if (!extent.empty()) {
    const auto v = parse_numbers(extent, 3, "--extent");
    std::array<int64_t, 3> e{};
    for (size_t a = 0; a < 3; ++a) {
      if (!(v[a] >= 1 && v[a] <= 1048576) || v[a] != std::floor(v[a]))
        throw InputError("--extent " + extent + ": expected three whole numbers 1 to 1048576");
      e[a] = int64_t(v[a]);
    }
    o.extent = e;
  }
  if (!interp.empty()) o.interpolation = parse_interpolation(interp, "--interp");
  if (!compounding.empty()) o.mode = parse_compounding_mode(compounding);
  if (!fill_holes.empty()) {
    if (fill_holes != "on" && fill_holes != "off")
      throw InputError("--fill-holes " + fill_holes + ": expected on or off");
    o.fill_holes = fill_holes == "on";
  }
  if (rejection_threshold) o.rejection_threshold = *rejection_threshold;
  if (!clip_rect.empty()) o.clip_rectangle = parse_clip_rect(clip_rect);
  if (!dtype.empty()) o.output_type = parse_pixel_type(dtype);
  if (!max_memory.empty()) o.max_memory_bytes = parse_bytes(max_memory);
}

}  // namespace cli
}  // namespace sonoslice
