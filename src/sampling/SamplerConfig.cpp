// Sampler settings from JSON: the one parser behind dataset SPECs, `sonoslice poses` and
// sonoslice.PoseSampler, so a key means the same everywhere.
#include "sonoslice/sampling/SamplerConfig.h"

#include <algorithm>
#include <fstream>
#include <iterator>
#include <map>
#include <set>

#include <nlohmann/json.hpp>

#include "../core/Text.h"
#include "../io/JsonFile.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

namespace {

using nlohmann::json;

double number(const json& j, const std::string& where) {
  if (!j.is_number()) throw InputError(where + ": expected a number");
  const double v = j.get<double>();
  if (!std::isfinite(v)) throw InputError(where + ": expected a finite number");
  return v;
}

/// [lo, hi], or one number for a fixed value.
Interval interval(const json& j, const std::string& where) {
  if (j.is_number()) {
    const double v = number(j, where);
    return {v, v};
  }
  if (!j.is_array() || j.size() != 2) throw InputError(where + ": expected [lo, hi] or a number");
  const Interval i{number(j[0], where), number(j[1], where)};
  if (i.lo > i.hi) throw InputError(where + ": expected lo <= hi");
  return i;
}

int integer(const json& j, const std::string& where) {
  if (!j.is_number_integer()) throw InputError(where + ": expected an integer");
  const int64_t v = j.get<int64_t>();
  if (v < -2147483647 || v > 2147483647) throw InputError(where + ": out of range");
  return int(v);
}

/// A 4×4 pose: nested rows, or 16 numbers row by row.
Pose pose(const json& j, const std::string& where) {
  const std::string expected = where + ": expected a 4x4 matrix (nested lists) or 16 numbers";
  if (!j.is_array()) throw InputError(expected);
  std::vector<double> v;
  const bool nested = !j.empty() && j[0].is_array();
  for (const json& item : j) {
    if (nested != item.is_array() || (nested && item.size() != 4)) throw InputError(expected);
    if (!nested) v.push_back(number(item, where));
    for (const json& x : nested ? item : json::array()) v.push_back(number(x, where));
  }
  if (v.size() != 16 || (nested && j.size() != 4)) throw InputError(expected);
  return Mat4::from_row_major(v.data());
}

const SamplerType kTypes[] = {SamplerType::Skin, SamplerType::Mesh, SamplerType::Region,
                              SamplerType::Sweep};
const SweepMotion kMotions[] = {SweepMotion::Linear, SweepMotion::Fan, SweepMotion::Rotational};

/// The keys each type takes (besides type, reject and max_tries).
const std::map<SamplerType, std::set<std::string>> kSamplerKeys = {
    {SamplerType::Skin, {"threshold_hu", "rotation_deg", "tilt_deg", "heel_toe_deg", "depth_mm"}},
    {SamplerType::Mesh, {"rotation_deg", "tilt_deg", "heel_toe_deg", "depth_mm", "threshold_hu"}},
    {SamplerType::Region,
     {"label", "intensity", "cone_deg", "direction", "rotation_deg", "anchor", "threshold_hu"}},
    {SamplerType::Sweep,
     {"motion", "step", "frames", "jitter_mm", "jitter_deg", "start", "from", "threshold_hu"}}};

std::string key_list(const std::set<std::string>& keys) {
  std::string out;
  for (const std::string& k : keys) out += (out.empty() ? "" : ", ") + k;
  return out;
}

RejectionRules rejection(const json& j, const std::string& where) {
  if (!j.is_object()) throw InputError(where + ": expected an object");
  RejectionRules r;
  for (const auto& [key, value] : j.items()) {
    const std::string at = where + "." + key;
    if (key == "min_inside")
      r.min_inside = number(value, at);
    else if (key == "min_body")
      r.min_body = number(value, at);
    else if (key == "label")
      r.label = integer(value, at);
    else if (key == "min_label")
      r.min_label = number(value, at);
    else if (key == "no_gas") {
      if (!value.is_boolean()) throw InputError(at + ": expected true or false");
      r.no_gas = value.get<bool>();
    } else if (key == "gas_hu")
      r.gas_hu = number(value, at);
    else if (key == "gas_depth_mm")
      r.gas_depth_mm = number(value, at);
    else
      throw InputError(where + ": unknown key '" + key +
                       "' (expected min_inside, min_body, label, min_label, no_gas, gas_hu, "
                       "gas_depth_mm)");
  }
  return r;
}

SamplerSettings from_json(const json& j, const std::string& where) {
  if (!j.is_object()) throw InputError(where + ": expected a JSON object");
  if (!j.contains("type") || !j["type"].is_string())
    throw InputError(where + ": needs \"type\": skin, mesh, region or sweep");
  const std::string type = j["type"].get<std::string>();
  const SamplerType* t = text::find_named(kTypes, type);
  if (!t) throw InputError(where + ": type '" + type + "': expected " + text::spellings(kTypes));
  SamplerSettings s;
  s.type = *t;
  const std::set<std::string>& keys = kSamplerKeys.at(s.type);
  for (const auto& [key, value] : j.items()) {
    const std::string at = where + "." + key;
    if (key == "type") continue;
    if (key == "reject") {
      s.reject = rejection(value, at);
      continue;
    }
    if (key == "max_tries") {
      s.max_tries = integer(value, at);
      continue;
    }
    if (!keys.count(key)) {
      bool known = false;
      for (const auto& [other, other_keys] : kSamplerKeys) known = known || other_keys.count(key);
      throw InputError(where + ": " +
                       (known ? "key '" + key + "' does not apply to a " + type + " sampler"
                              : "unknown key '" + key + "'") +
                       " (a " + type + " sampler takes " + key_list(keys) + ", reject, max_tries)");
    }
    if (key == "threshold_hu")
      s.threshold_hu = number(value, at);
    else if (key == "rotation_deg")
      s.rotation_deg = interval(value, at);
    else if (key == "tilt_deg")
      s.tilt_deg = interval(value, at);
    else if (key == "heel_toe_deg")
      s.heel_toe_deg = interval(value, at);
    else if (key == "depth_mm")
      s.depth_mm = interval(value, at);
    else if (key == "label")
      s.label = integer(value, at);
    else if (key == "intensity")
      s.intensity = interval(value, at);
    else if (key == "cone_deg")
      s.cone_deg = number(value, at);
    else if (key == "direction") {
      if (!value.is_array() || value.size() != 3) throw InputError(at + ": expected [x, y, z]");
      s.direction = {number(value[0], at), number(value[1], at), number(value[2], at)};
    } else if (key == "anchor") {
      const std::string a = value.is_string() ? value.get<std::string>() : "";
      if (a != "face" && a != "centre" && a != "center")
        throw InputError(at + ": expected \"face\" or \"centre\"");
      s.anchor_at_centre = a != "face";
    } else if (key == "motion") {
      const std::string m = value.is_string() ? value.get<std::string>() : "";
      const SweepMotion* motion = text::find_named(kMotions, m);
      if (!motion) throw InputError(at + ": expected " + text::spellings(kMotions));
      s.motion = *motion;
    } else if (key == "step")
      s.step = number(value, at);
    else if (key == "frames")
      s.frames = integer(value, at);
    else if (key == "jitter_mm")
      s.jitter_mm = number(value, at);
    else if (key == "jitter_deg")
      s.jitter_deg = number(value, at);
    else if (key == "start")
      s.start = pose(value, at);
    else if (key == "from")
      s.base = std::make_shared<SamplerSettings>(from_json(value, at));
  }
  s.validate(where);
  return s;
}

}  // namespace

const char* to_string(SamplerType type) {
  switch (type) {
    case SamplerType::Skin:
      return "skin";
    case SamplerType::Mesh:
      return "mesh";
    case SamplerType::Region:
      return "region";
    case SamplerType::Sweep:
      return "sweep";
  }
  return "?";
}

const char* to_string(SweepMotion motion) {
  switch (motion) {
    case SweepMotion::Linear:
      return "linear";
    case SweepMotion::Fan:
      return "fan";
    case SweepMotion::Rotational:
      return "rotational";
  }
  return "?";
}

SamplerSettings parse_sampler_json(const std::string& text, const std::string& where) {
  return from_json(parse_json(text, where), where);
}

SamplerSettings read_sampler_json(const std::string& path, const std::string& what,
                                  const std::string& overrides) {
  std::ifstream in = open_text_file(path, what);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw FileError("cannot read " + what + " '" + path + "'");
  return parse_sampler_json(text, what + " '" + path + "'", overrides);
}

SamplerSettings parse_sampler_json(const std::string& text, const std::string& where,
                                   const std::string& overrides) {
  json j = parse_json(text, where);
  if (!j.is_object()) throw InputError(where + ": expected a JSON object");
  const json laid_over = parse_json(overrides, "sampler overrides");
  for (const auto& [key, value] : laid_over.items()) {
    json& mine = j[key];
    if (key == "reject" && mine.is_object() && value.is_object()) {
      for (const auto& [rule, setting] : value.items()) mine[rule] = setting;
    } else if (key != "reject" || mine.is_null()) {
      mine = value;
    }  // else a "reject" that is not an object: from_json names it
  }
  return from_json(j, where);
}

}  // namespace sonoslice
