// PLUS's transform repository: named transforms, chained and inverted on request.
#include "sonoslice/plus/TransformRepository.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <deque>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/plus/PlusSequence.h"

namespace sonoslice {

using namespace text;
using plus::fields_of;

std::pair<std::string, std::string> TransformRepository::split_name(const std::string& name) {
  // PLUS names are <From>To<To> with capitalised frame names; "To" followed by a capital letter
  // (or digit) separates them, e.g. StylusTipToStylus, ToolToTracker.
  std::vector<size_t> splits;
  for (size_t p = 1; p + 2 < name.size(); ++p)
    if (name.compare(p, 2, "To") == 0 && (std::isupper(static_cast<unsigned char>(name[p + 2])) ||
                                          std::isdigit(static_cast<unsigned char>(name[p + 2]))))
      splits.push_back(p);
  if (splits.empty())
    throw InputError("transform name " + quote_value(name) +
                     " is not of the form <From>To<To> "
                     "(e.g. ImageToReference)");
  if (splits.size() > 1)
    throw InputError("transform name " + quote_value(name) +
                     " is ambiguous: more than one 'To' "
                     "followed by a capital letter");
  return {name.substr(0, splits[0]), name.substr(splits[0] + 2)};
}

void TransformRepository::set(const std::string& from, const std::string& to, const Mat4& m,
                              bool valid) {
  if (from.empty() || to.empty() || from == to)
    throw InputError("transform " + quote_value(from + "To" + to) +
                     ": needs two different, non-empty coordinate frame names");
  transforms_.erase({to, from});  // one direction per pair: the newest wins
  transforms_[{from, to}] = Entry{m, valid};
}

void TransformRepository::set_frame(const PlusSequence& sequence, int frame) {
  const auto& fields = fields_of(sequence, frame);
  for (const std::string& name : sequence.transform_names(frame)) {
    std::pair<std::string, std::string> ends;
    try {
      ends = split_name(name);
    } catch (const InputError&) {
      continue;  // a field ending in "Transform" that is not a PLUS transform name
    }
    if (ends.first == ends.second) continue;
    std::optional<Mat4> m = sequence.transform(frame, name);
    if (m) {
      set(ends.first, ends.second, *m, true);
    } else {
      Mat4 stored;  // kept for completeness; a chain through it is reported invalid
      parse_matrix16(fields.at(name + "Transform"), &stored);
      set(ends.first, ends.second, stored, false);
    }
  }
}

std::optional<std::vector<TransformRepository::Link>> TransformRepository::chain(
    const std::string& from, const std::string& to) const {
  if (from == to) return std::vector<Link>{};
  struct Edge {
    std::string next;
    const std::pair<std::string, std::string>* key;  // as stored
    const Entry* entry;
    bool inverse;
  };
  std::map<std::string, std::vector<Edge>> graph;
  for (const auto& [key, entry] : transforms_) {
    graph[key.first].push_back({key.second, &key, &entry, false});
    graph[key.second].push_back({key.first, &key, &entry, true});
  }
  // Breadth-first: the chain with the fewest transforms; valid transforms only first, so that a
  // valid chain is found even when an equally short one passes through an invalid transform.
  auto search = [&](bool valid_only) -> std::optional<std::vector<const Edge*>> {
    std::map<std::string, const Edge*> came_by;
    std::map<std::string, std::string> came_from;
    std::deque<std::string> queue{from};
    came_from[from] = "";
    while (!queue.empty()) {
      const std::string node = queue.front();
      queue.pop_front();
      if (node == to) break;
      auto it = graph.find(node);
      if (it == graph.end()) continue;
      for (const Edge& e : it->second) {
        if (valid_only && !e.entry->valid) continue;
        if (came_from.count(e.next)) continue;
        came_from[e.next] = node;
        came_by[e.next] = &e;
        queue.push_back(e.next);
      }
    }
    if (!came_from.count(to)) return std::nullopt;
    std::vector<const Edge*> path;
    for (std::string node = to; node != from; node = came_from[node]) path.push_back(came_by[node]);
    std::reverse(path.begin(), path.end());
    return path;
  };
  std::optional<std::vector<const Edge*>> path = search(true);
  if (!path) {
    if (search(false)) return std::nullopt;  // only through an invalid transform
    std::string known;
    for (const auto& [key, entry] : transforms_)
      known += (known.empty() ? "" : ", ") + key.first + "To" + key.second +
               (entry.valid ? "" : " (invalid)");
    throw InputError("no chain of transforms from '" + from + "' to '" + to +
                     "' (known: " + (known.empty() ? "none" : known) + ")");
  }
  std::vector<Link> links;
  for (const Edge* e : *path) links.push_back({e->key->first, e->key->second, e->inverse});
  return links;
}

std::optional<Mat4> TransformRepository::get(const std::string& from, const std::string& to) const {
  const std::optional<std::vector<Link>> links = chain(from, to);
  if (!links) return std::nullopt;
  Mat4 result = Mat4::identity();
  for (const Link& link : *links) {
    Mat4 step = transforms_.at({link.from, link.to}).matrix;
    if (link.inverse) {
      std::optional<Mat4> inv = invert(step);
      if (!inv)
        throw InputError("transform " + link.from + "To" + link.to + " is not invertible, so " +
                         from + "To" + to + " cannot be computed through it");
      step = *inv;
    }
    result = step * result;
  }
  return result;
}

std::string transform_problem(const Mat4& m) {
  bool zero = true;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(m.m[r][c])) return "has a non-finite entry";
      zero = zero && m.m[r][c] == 0;
    }
  if (zero) return "is all zero";
  if (m.m[3][0] != 0 || m.m[3][1] != 0 || m.m[3][2] != 0 || m.m[3][3] != 1) {
    std::ostringstream s;
    s << "has the last row " << m.m[3][0] << " " << m.m[3][1] << " " << m.m[3][2] << " "
      << m.m[3][3] << " (expected 0 0 0 1)";
    return s.str();
  }
  const Vec3 x = m.column3(0), y = m.column3(1);
  const double nx = norm(x), ny = norm(y);
  if (nx == 0 || ny == 0)
    return std::string("maps the image's ") + (nx == 0 ? "x" : "y") + " axis to a point (column " +
           (nx == 0 ? "0" : "1") + " is zero)";
  // Pixel axes at less than about 2.5 degrees from each other put a frame's pixels on a line.
  if (std::fabs(dot(x, y)) > 0.999 * nx * ny) return "maps the image's x and y axes onto one line";
  return "";
}

}  // namespace sonoslice
