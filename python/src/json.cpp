// Python values (dicts, lists, numbers, strings, NumPy arrays) as the JSON the library's parsers
// check, so that a dict of settings and a JSON/YAML file go through one key-checking path and
// no JSON text crosses between Python and C++.
#include <nanobind/stl/string.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "bindings.h"
#include "sonoslice/io/JsonDepth.h"

namespace sonoslice::bindings {
namespace {

nlohmann::json json_value(nb::handle value, const std::string& where, int depth = 0) {
  // The library refuses deeper documents anyway; here the limit also stops a list that holds
  // itself, which would recurse without end.
  if (depth > kMaxJsonDepth)
    throw InputError(where + ": nested deeper than " + std::to_string(kMaxJsonDepth) + " levels");
  if (value.is_none()) return nullptr;
  if (nb::isinstance<nb::bool_>(value)) return nb::cast<bool>(value);
  if (nb::isinstance<nb::int_>(value)) {
    int64_t i;
    if (nb::try_cast(value, i)) return i;
    uint64_t u;
    if (nb::try_cast(value, u)) return u;
    throw InputError(where + ": an integer out of range");
  }
  if (nb::isinstance<nb::float_>(value)) {
    const double v = nb::cast<double>(value);
    if (!std::isfinite(v)) throw InputError(where + ": expected a finite number");
    return v;
  }
  if (nb::isinstance<nb::str>(value)) return nb::cast<std::string>(value);
  if (nb::isinstance<nb::list>(value) || nb::isinstance<nb::tuple>(value)) {
    nlohmann::json out = nlohmann::json::array();
    size_t k = 0;
    for (nb::handle item : value)
      out.push_back(json_value(item, where + "[" + std::to_string(k++) + "]", depth + 1));
    return out;
  }
  // Mappings: dicts, and bound classes that read as one (Tissue).
  if (nb::isinstance<nb::dict>(value) || nb::hasattr(value, "keys")) {
    nlohmann::json out = nlohmann::json::object();
    for (nb::handle key : value.attr("keys")()) {
      if (!nb::isinstance<nb::str>(key))
        throw InputError(where + ": key " + nb::repr(key).c_str() + " is not a string");
      const std::string k = nb::cast<std::string>(key);
      out[k] = json_value(value[key], where + "." + k, depth + 1);
    }
    return out;
  }
  // NumPy arrays and scalars: their Python numbers and lists.
  if (nb::hasattr(value, "tolist") && !nb::isinstance<nb::str>(value))
    return json_value(value.attr("tolist")(), where, depth);
  throw InputError(where + ": a " + std::string(nb::type_name(value.type()).c_str()) +
                   " is not a setting value (expected numbers, strings, lists and dicts)");
}

}  // namespace

std::string json_text(nb::handle value, const std::string& where) {
  return json_value(value, where).dump();
}

}  // namespace sonoslice::bindings
