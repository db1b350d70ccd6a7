#include "sonoslice/phantom/Workloads.h"

namespace sonoslice {

ProbeGeometry workload_w1_fan_probe() {
  // fan_geometry [0.05, 0.1235, 36, 526, 380, 17]: [dθ, da, Θ, A, C, B], A, C, B in units of da;
  // 668×544 px of 0.1235 mm, downsampled by 2.
  const double da = 0.1235;
  ProbeGeometry p;
  p.type = ProbeType::Curvilinear;
  p.sector_deg = 36;
  p.depth_mm = 526 * da;
  p.radius_mm = 380 * da;
  p.face_y_mm = 17 * da;
  p.image.width = 668 / 2;
  p.image.height = 544 / 2;
  p.image.spacing_mm[0] = p.image.spacing_mm[1] = 2 * da;
  p.image.origin_mm[0] = -p.image.width * p.image.spacing_mm[0] / 2;  // −W'·sx/2
  p.image.origin_mm[1] = 0;
  return p;
}

ProbeGeometry workload_w2_linear_probe() {
  ProbeGeometry p;
  p.type = ProbeType::Linear;  // no width/depth limits: the whole image is inside
  p.image.width = 400;
  p.image.height = 500;
  p.image.spacing_mm[0] = p.image.spacing_mm[1] = 0.1235;
  p.image.origin_mm[0] = -double(p.image.width / 2) * p.image.spacing_mm[0];  // −floor(W'/2)·sx
  p.image.origin_mm[1] = 0;
  return p;
}

}  // namespace sonoslice
