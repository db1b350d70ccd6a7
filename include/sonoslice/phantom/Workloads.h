#pragma once
/// @file The probes of the benchmark workloads and the demo, identical to the fan-slicer files in
/// shared/data/fanslicer (SPEC §4 mapping), so they need no file at run time:
///   W1 = models_intensity_LUS_config.json with downsampling 2: a 334×272 fan at 0.247 mm
///        (36° sector, R = 46.93 mm, depth 64.96 mm);
///   W2 = linear_config.json: a 400×500 linear image at 0.1235 mm.
#include "sonoslice/geometry/Probe.h"

namespace sonoslice {

ProbeGeometry workload_w1_fan_probe();
ProbeGeometry workload_w2_linear_probe();

}  // namespace sonoslice
