#pragma once
/// @file Where the samples of a 3D beam-space frame lie (docs/conventions.md §7).
#include <string>

namespace sonoslice {

/// A 3D beam-space frame's geometry (docs/conventions.md §7): sample s of the beam at azimuth
/// α = α0 + a·dα and elevation β = β0 + e·dβ lies at probe coordinates
/// apex + (r0 + s·dr)·(sin α, cos α·cos β, cos α·sin β), apex = (0, -apex_offset_mm, 0).
struct BeamGeometry {
  int n_elevation = 0, n_azimuth = 0, n_samples = 0;
  double r0_mm = 0, dr_mm = 1;
  double azimuth0_deg = 0, dazimuth_deg = 1;
  double elevation0_deg = 0, delevation_deg = 1;
  double apex_offset_mm = 0;
  void validate(const std::string& what) const;
};

}  // namespace sonoslice
