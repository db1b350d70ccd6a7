#pragma once
/// @file The probes of the benchmark workloads and the demo, identical to the fan-slicer files in
/// data/fanslicer (docs/conventions.md §4 mapping), so they need no file at run time:
///   W1 = models_intensity_LUS_config.json with downsampling 2: a 334×272 fan at 0.247 mm
///        (36° sector, R = 46.93 mm, depth 64.96 mm);
///   W2 = linear_config.json: a 400×500 linear image at 0.1235 mm.
///
/// And the compounding workloads:
///   Jauer = Jauer et al. 2015's 3-D reconstruction: 814 beam-space frames of 185 samples
///           (0.3 mm) × 84 azimuth (0.45°) × 22 elevation (0.88°) beams, a slow sweep along the
///           grid's long axis, into 300×1000×600 voxels of 0.5 mm;
///   Sweep2D = 1000 frames of 820×616 pixels of 0.085 mm (the size and spacing of the PLUS
///           sample sweeps), a slow tilted sweep, into the grid around them at 0.5 mm.
/// Frame contents are deterministic speckle-like noise with bright reflectors.
#include <cstdint>
#include <vector>

#include "sonoslice/compound/Compounder.h"
#include "sonoslice/geometry/Probe.h"

namespace sonoslice {

ProbeGeometry workload_w1_fan_probe();
ProbeGeometry workload_w2_linear_probe();

struct BeamSweepWorkload {
  BeamGeometry geometry;
  std::vector<Mat4> probe_to_reference;
  VolumeGrid grid;
};
BeamSweepWorkload workload_jauer_beam_sweep(int frames = 814);

struct ImageSweepWorkload {
  int width = 0, height = 0;
  std::vector<Mat4> image_to_reference;
  VolumeGrid grid;
};
ImageSweepWorkload workload_2d_sweep(int frames = 1000, double spacing_mm = 0.5);

/// `count` frames of `samples_per_frame` uint8 samples, frame after frame (deterministic).
std::vector<uint8_t> workload_frames(int64_t count, int64_t samples_per_frame, uint32_t seed = 1);

}  // namespace sonoslice
