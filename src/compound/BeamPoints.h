#pragma once
// Internal: where the samples of a 3D beam-space frame lie in the probe frame
// (docs/conventions.md §7), for the dispatch layer and the grid fitted around beams.
#include <vector>

#include "sonoslice/compound/BeamGeometry.h"
#include "sonoslice/geometry/Math.h"

namespace sonoslice {
namespace compound_impl {

/// The unit directions of the beams, elevation slowest: (sin α, cos α·cos β, cos α·sin β).
std::vector<Vec3> beam_directions(const BeamGeometry& g);

/// The probe-frame point at depth r along the beam of direction d: apex + r·d, with
/// apex = (0, -apex_offset, 0).
Vec3 beam_point(const BeamGeometry& g, const Vec3& d, double r);

}  // namespace compound_impl
}  // namespace sonoslice
