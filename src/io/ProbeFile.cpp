#include "sonoslice/io/ProbeFile.h"

#include <cmath>
#include <fstream>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>

#include "JsonFile.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

using json = nlohmann::json;

// Reads keys from one JSON object. Keys outside `allowed` are rejected before anything is read,
// so a typo ("sector" for "sector_deg") is reported as itself, not as a missing key.
class Keys {
 public:
  Keys(const json& object, std::string where, std::initializer_list<const char*> allowed)
      : object_(object), where_(std::move(where)) {
    if (!object_.is_object()) throw InputError(where_ + ": expected a JSON object");
    for (auto it = object_.begin(); it != object_.end(); ++it) {
      bool ok = false;
      std::string expected;
      for (const char* a : allowed) {
        ok |= it.key() == a;
        expected += (expected.empty() ? "" : ", ") + std::string(a);
      }
      if (!ok)
        throw InputError(where_ + ": unknown key '" + it.key() + "' (expected: " + expected + ")");
    }
  }
  bool has(const char* key) const { return object_.contains(key); }
  const json& get(const char* key) {
    if (!object_.contains(key)) throw InputError(where_ + ": missing key '" + key + "'");
    return object_.at(key);
  }
  double number(const char* key) {
    const json& v = get(key);
    if (!v.is_number()) throw InputError(where_ + ": '" + key + "' must be a number");
    return v.get<double>();
  }
  int integer(const char* key) {
    const json& v = get(key);
    if (!v.is_number_integer() &&
        !(v.is_number() && v.get<double>() == std::floor(v.get<double>())))
      throw InputError(where_ + ": '" + key + "' must be an integer");
    const double d = v.get<double>();
    if (std::fabs(d) > 1e9) throw InputError(where_ + ": '" + key + "' is absurdly large");
    return int(d);
  }
  std::vector<double> numbers(const char* key, size_t count) {
    const json& v = get(key);
    if (!v.is_array() || v.size() != count)
      throw InputError(where_ + ": '" + key + "' must be a list of " + std::to_string(count) +
                       " numbers");
    std::vector<double> out;
    for (const json& e : v) {
      if (!e.is_number())
        throw InputError(where_ + ": '" + key + "' must be a list of " + std::to_string(count) +
                         " numbers");
      out.push_back(e.get<double>());
    }
    return out;
  }
  std::string string(const char* key) {
    const json& v = get(key);
    if (!v.is_string()) throw InputError(where_ + ": '" + key + "' must be a string");
    return v.get<std::string>();
  }

 private:
  const json& object_;
  std::string where_;
};

// The "image" block, downsampled: floor(W/ds) × floor(H/ds) pixels of ds·(sx, sy).
ImageGrid parse_image(const json& root, const std::string& where, int ds) {
  if (!root.contains("image")) throw InputError(where + ": missing key 'image'");
  Keys im(root["image"], where + ": image", {"width", "height", "spacing_mm", "origin_mm"});
  const int width = im.integer("width"), height = im.integer("height");
  const auto spacing = im.numbers("spacing_mm", 2);
  ImageGrid image = ImageGrid::centred(width / ds, height / ds, spacing[0] * ds, spacing[1] * ds);
  if (im.has("origin_mm")) {
    const auto origin = im.numbers("origin_mm", 2);
    image.origin_mm[0] = origin[0];
    image.origin_mm[1] = origin[1];
  }
  return image;
}

ProbeGeometry parse_native(const json& root, const std::string& source, int ds) {
  const std::string where = "probe '" + source + "'";
  if (!root.contains("type") || !root["type"].is_string())
    throw InputError(where + ": missing key 'type' (curvilinear or linear)");
  const std::string type = root["type"].get<std::string>();
  if (type == "curvilinear") {
    Keys k(root, where, {"type", "radius_mm", "depth_mm", "sector_deg", "face_y_mm", "image"});
    const double radius = k.number("radius_mm");
    const double depth = k.number("depth_mm");
    const double sector = k.number("sector_deg");
    const double face_y = k.has("face_y_mm") ? k.number("face_y_mm") : 0.0;
    return ProbeGeometry::curvilinear(radius, depth, sector, parse_image(root, where, ds), face_y);
  }
  if (type == "linear") {
    Keys k(root, where, {"type", "width_mm", "depth_mm", "face_y_mm", "image"});
    const auto optional = [&](const char* key) {
      return k.has(key) ? std::optional<double>(k.number(key)) : std::nullopt;
    };
    const std::optional<double> width = optional("width_mm");
    const std::optional<double> depth = optional("depth_mm");
    const double face_y = k.has("face_y_mm") ? k.number("face_y_mm") : 0.0;
    return ProbeGeometry::linear(parse_image(root, where, ds), width, depth, face_y);
  }
  throw InputError(where + ": type '" + type + "' (expected curvilinear or linear)");
}

// docs/conventions.md §4: fan-slicer's "simulation" block.
ProbeGeometry parse_fanslicer(const json& root, const std::string& source, int ds) {
  // "models" (surface files) is read by the surface module; it does not change the probe.
  Keys top(root, "fan-slicer config '" + source + "'", {"simulation", "models"});
  const std::string where = "fan-slicer config '" + source + "': simulation";
  // simulation_models, colors and opacity configure surface rendering, not the probe.
  Keys sim(top.get("simulation"), where,
           {"transducer", "fan_geometry", "image_dimensions", "pixel_size", "simulation_models",
            "colors", "opacity"});

  FanSlicerProbe fs;
  // Early fan-slicer configs (e.g. its EUS example) have no "transducer": they are fans.
  const std::string transducer = sim.has("transducer") ? sim.string("transducer") : "curvilinear";
  const auto dims = sim.numbers("image_dimensions", 2);
  const auto pixel = sim.numbers("pixel_size", 2);
  for (double d : dims)
    if (d != std::floor(d) || d <= 0 || d > 1e6)
      throw InputError(where + ": 'image_dimensions' must be two positive integers");
  for (int a = 0; a < 2; ++a) {
    fs.image_dimensions[a] = int(dims[size_t(a)]);
    fs.pixel_size_mm[a] = pixel[size_t(a)];
  }
  if (transducer == "curvilinear") {
    fs.transducer = ProbeType::Curvilinear;
    const auto fan = sim.numbers("fan_geometry", 6);
    std::copy(fan.begin(), fan.end(), fs.fan_geometry);
  } else if (transducer == "linear") {
    fs.transducer = ProbeType::Linear;  // a fan_geometry, if present, is unused
  } else {
    throw InputError(where + ": transducer '" + transducer + "' (expected curvilinear or linear)");
  }
  return probe_from_fanslicer(fs, ds);
}

}  // namespace

ProbeGeometry parse_probe_json(const std::string& text, const std::string& source,
                               int downsampling) {
  if (downsampling < 1 || downsampling > 64)
    throw ParameterError("downsampling", std::to_string(downsampling) + ": must be in 1..64");
  const json root = parse_json<FileError>(text, "probe '" + source + "'");
  if (!root.is_object()) throw InputError("probe '" + source + "': expected a JSON object");
  ProbeGeometry p = with_json_errors_named("probe '" + source + "'", [&] {
    return root.contains("simulation") ? parse_fanslicer(root, source, downsampling)
                                       : parse_native(root, source, downsampling);
  });
  p.validate("probe '" + source + "'");
  return p;
}

ProbeGeometry read_probe(const std::string& path, int downsampling) {
  std::ifstream in = open_text_file(path, "probe file");
  std::stringstream text;
  text << in.rdbuf();
  return parse_probe_json(text.str(), path, downsampling);
}

std::string probe_to_json(const ProbeGeometry& probe) {
  json j;
  if (probe.type == ProbeType::Curvilinear) {
    j["type"] = to_string(probe.type);
    j["radius_mm"] = probe.radius_mm;
    j["depth_mm"] = probe.depth_mm;
    j["sector_deg"] = probe.sector_deg;
  } else {
    j["type"] = to_string(probe.type);
    if (probe.has_width) j["width_mm"] = probe.width_mm;
    if (probe.has_depth) j["depth_mm"] = probe.depth_mm;
  }
  j["face_y_mm"] = probe.face_y_mm;
  j["image"] = {{"width", probe.image.width},
                {"height", probe.image.height},
                {"spacing_mm", {probe.image.spacing_mm[0], probe.image.spacing_mm[1]}},
                {"origin_mm", {probe.image.origin_mm[0], probe.image.origin_mm[1]}}};
  return j.dump(2);
}

}  // namespace sonoslice
