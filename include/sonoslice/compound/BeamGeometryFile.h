#pragma once
/// @file The geometry file of 3-D beam-space frames (docs/conventions.md §7): a JSON object
///   {"r0_mm": 0.3, "dr_mm": 0.3, "azimuth0_deg": -18.7, "dazimuth_deg": 0.45,
///    "elevation0_deg": -9.2, "delevation_deg": 0.88, "apex_offset_mm": 0}
/// (apex_offset_mm optional, default 0). The frame sizes come from the frames' array.
#include <string>

#include "sonoslice/compound/BeamGeometry.h"

namespace sonoslice {

/// Reads the geometry; n_elevation/n_azimuth/n_samples are left 0 for the caller to fill.
/// FileError for a missing or malformed file, InputError for a missing, unknown or bad key.
BeamGeometry read_beam_geometry(const std::string& path);

/// Writes the geometry (without the sizes) atomically.
void write_beam_geometry(const std::string& path, const BeamGeometry& geometry);

}  // namespace sonoslice
