// The PlusSequence accessors (a frame's fields, image status, transforms, timestamp) and the frame
// fields' helpers the PLUS files share.
#include "sonoslice/plus/PlusSequence.h"

#include <cstdio>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

using namespace text;

namespace plus {

std::string frame_label(int frame) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%04d", frame);
  return buf;
}

const std::map<std::string, std::string>& fields_of(const PlusSequence& seq, int frame) {
  if (frame < 0 || frame >= seq.frame_count)
    throw InputError("PLUS sequence '" + seq.path + "': frame " + std::to_string(frame) +
                     " out of range (0.." + std::to_string(seq.frame_count - 1) + ")");
  static const std::map<std::string, std::string> no_fields;
  return size_t(frame) < seq.frame_fields.size() ? seq.frame_fields[size_t(frame)] : no_fields;
}

}  // namespace plus

using plus::fields_of;

bool PlusSequence::image_ok(int frame) const {
  const auto& fields = fields_of(*this, frame);
  auto it = fields.find("ImageStatus");
  if (it == fields.end()) it = fields.find("Status");  // NRRD's name, in sequences built by hand
  return it == fields.end() || iequals(trim(it->second), "OK");
}

std::vector<std::string> PlusSequence::transform_names(int frame) const {
  std::vector<std::string> names;
  for (const auto& [name, value] : fields_of(*this, frame))
    if (ends_with(name, "Transform") && name.size() > 9)
      names.push_back(name.substr(0, name.size() - 9));
  return names;
}

std::optional<Mat4> PlusSequence::transform(int frame, const std::string& name) const {
  const auto& fields = fields_of(*this, frame);
  auto it = fields.find(name + "Transform");
  if (it == fields.end()) return std::nullopt;
  auto status = fields.find(name + "TransformStatus");
  if (status != fields.end() && !iequals(trim(status->second), "OK")) return std::nullopt;
  Mat4 m;
  if (!parse_matrix16(it->second, &m))
    throw InputError(path + ": frame " + std::to_string(frame) + ": " + name +
                     "Transform: expected 16 finite numbers, got " + quote_value(it->second));
  return m;
}

double PlusSequence::timestamp(int frame) const {
  const auto& fields = fields_of(*this, frame);
  auto it = fields.find("Timestamp");
  if (it == fields.end()) return std::numeric_limits<double>::quiet_NaN();
  double t;
  if (!parse_double(trim(it->second), &t))
    throw InputError(path + ": frame " + std::to_string(frame) + ": Timestamp " +
                     quote_value(it->second) + " is not a number");
  return t;
}

}  // namespace sonoslice
