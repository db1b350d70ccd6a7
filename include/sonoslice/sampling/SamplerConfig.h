#pragma once
/// @file Pose sampler settings as JSON (docs/datasets.md §2): the `samplers` entries of a
/// dataset SPEC and `sonoslice poses --sampler`. Every key is checked: an unknown key, a key
/// that does not apply to the sampler's type, or a bad value is an InputError naming it.
#include <string>

#include "sonoslice/sampling/PoseSampler.h"

namespace sonoslice {

/// The spelling of the "type" and "motion" keys: "skin", "mesh", "region", "sweep"; "linear",
/// "fan", "rotational".
const char* to_string(SamplerType type);
const char* to_string(SweepMotion motion);

/// Settings from a JSON object's text; `where` names it in messages (e.g. "samplers[0]").
SamplerSettings parse_sampler_json(const std::string& text, const std::string& where);

/// The same with `overrides`, a JSON object's text, laid over the settings' object first: each
/// of its keys replaces the settings' own, except "reject", whose rules are replaced one by one.
/// How `sonoslice poses` lays its flags over a sampler file: an override is checked like a key of
/// the file (a tilt for a region sampler is refused).
SamplerSettings parse_sampler_json(const std::string& text, const std::string& where,
                                   const std::string& overrides);

/// The same read from the JSON file `path`; `what` names it in messages ("--sampler" →
/// "--sampler 'p.json': invalid JSON (...)"), FileError when it cannot be opened or is a folder.
SamplerSettings read_sampler_json(const std::string& path, const std::string& what,
                                  const std::string& overrides = "{}");

}  // namespace sonoslice
