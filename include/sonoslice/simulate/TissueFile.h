#pragma once
/// @file Tissue tables as JSON (docs/simulation.md §1): {"tissues": [{"name": "liver",
/// "label": 4, "impedance_mrayl": 1.65, "attenuation_db_cm_mhz": 0.5, "scatter_mean": 0.025,
/// "scatter_density": 10}, ...]}. Extra keys are allowed and ignored (a user's notes, a
/// colour); scatter_density may be left out (default: fully developed speckle).
#include <string>
#include <vector>

#include "sonoslice/simulate/Simulator.h"

namespace sonoslice {

/// Reads and checks a tissue table. FileError when the file cannot be opened or is not JSON;
/// InputError naming the file and the entry for a missing key, a wrong type, or a value
/// validate_tissues refuses.
std::vector<Tissue> read_tissue_table(const std::string& path);

/// The same from JSON text; errors name `where`.
std::vector<Tissue> parse_tissue_table(const std::string& text, const std::string& where);

/// The table as JSON text (two-space indent, one tissue per object, a trailing newline).
std::string tissue_table_json(const std::vector<Tissue>& tissues);

}  // namespace sonoslice
