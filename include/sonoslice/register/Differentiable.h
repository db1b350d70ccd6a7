#pragma once
/// @file Differentiable slicing: the images `slice --interpolation linear`
/// makes, in float64, and, given dL/d(image), dL/d(pose) and dL/d(volume), computed in the
/// kernel from the trilinear interpolant's exact derivatives: no per-pixel grid is stored, so
/// memory is O(batch) beyond the images themselves. sonoslice.torch wraps these as a
/// torch.autograd.Function (docs/registration.md §7).
#include <cstddef>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

/// The linear slice of `count` poses into `out` ((count, H, W) float64): docs/conventions.md §5's
/// rule (inside the volume: −0.5 ≤ index < n − 0.5 on every axis, neighbours clamped), `fill`
/// outside the probe's fan or the volume. Poses are checked (InputError naming "pose <i>").
void slice_linear_f64(const Volume& volume, const ProbeGeometry& probe, const Pose* poses,
                      size_t count, double fill, double* out);

/// The backward pass of slice_linear_f64 for `grad_images` = dL/d(images) ((count, H, W)):
/// dL/d(pose) into `grad_poses` ((count, 4, 4) row-major; the last row is 0: it does not move a
/// pixel) and, when `grad_volume` is not null, dL/d(voxel) added into it (voxel_count values, x
/// fastest). Without a volume gradient the poses run in parallel; with one, pose by pose in
/// order: both give the same sums on any thread count.
void slice_linear_backward(const Volume& volume, const ProbeGeometry& probe, const Pose* poses,
                           size_t count, const double* grad_images, double* grad_poses,
                           double* grad_volume);

}  // namespace sonoslice
