#pragma once
/// @file Probe descriptions: sonoslice's native probe JSON (docs/conventions.md §3) and fan-slicer
/// configuration files, accepted unchanged (docs/conventions.md §4).
#include <string>

#include "sonoslice/geometry/Probe.h"

namespace sonoslice {

/// Reads a probe file. A JSON object with a "simulation" key is a fan-slicer configuration;
/// otherwise it is a native probe file. `downsampling` K divides the image size (floor) and
/// multiplies the pixel spacing, as fan-slicer does. Unknown or missing keys, wrong types and
/// bad values throw InputError naming the file and the key; unreadable files throw FileError.
ProbeGeometry read_probe(const std::string& path, int downsampling = 1);

/// Same, from JSON text; `source` names it in messages.
ProbeGeometry parse_probe_json(const std::string& text, const std::string& source,
                               int downsampling = 1);

/// The native JSON of a probe (round-trips through parse_probe_json).
std::string probe_to_json(const ProbeGeometry& probe);

}  // namespace sonoslice
