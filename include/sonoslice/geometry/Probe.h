#pragma once
/// @file Probe shapes and the output image grid (docs/conventions.md §3).
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/geometry/Math.h"

namespace sonoslice {

/// The output image grid in probe coordinates (mm). Pixel (u, v) (column u, row v) has its
/// centre at x = origin_mm[0] + u·spacing_mm[0], y = origin_mm[1] + v·spacing_mm[1], z = 0.
/// Row 0 is nearest the probe; rows grow with depth (the probe's axial axis ŷ).
struct ImageGrid {
  int width = 0;                      ///< columns (lateral, along x̂)
  int height = 0;                     ///< rows (depth, along ŷ)
  double spacing_mm[2] = {1.0, 1.0};  ///< (sx, sy) mm
  double origin_mm[2] = {0.0, 0.0};   ///< probe coordinates of pixel (0, 0)'s centre

  int64_t pixel_count() const { return int64_t(width) * int64_t(height); }
  /// The default origin, docs/conventions.md §3: (-(W-1)·sx/2, 0), i.e. centred laterally.
  void set_default_origin() {
    origin_mm[0] = -(width - 1) * spacing_mm[0] / 2.0;
    origin_mm[1] = 0.0;
  }
  /// A width × height grid of sx × sy mm pixels at the default origin.
  static ImageGrid centred(int width, int height, double sx_mm, double sy_mm);
};

enum class ProbeType {
  Curvilinear,  ///< convex / fan: a sector about a virtual apex behind the face
  Linear        ///< a rectangle (optionally limited in width and depth)
};
const char* to_string(ProbeType type);                ///< "curvilinear" / "linear"
ProbeType parse_probe_type(const std::string& name);  ///< the names above; InputError otherwise

/// A probe: its shape (which pixels the beam covers) and its image grid.
struct ProbeGeometry {
  ProbeType type = ProbeType::Linear;
  ImageGrid image;

  // curvilinear (convex fan)
  double radius_mm = 0.0;   ///< R: virtual apex to transducer face
  double depth_mm = 0.0;    ///< D: imaging depth along a beam (curvilinear), or linear depth
  double sector_deg = 0.0;  ///< Θ: full opening angle
  double face_y_mm = 0.0;   ///< axial coordinate of the face centre; apex at (0, face_y - R)

  // linear: optional limits; without them the whole image is inside
  bool has_width = false;
  double width_mm = 0.0;   ///< inside iff |x| <= width_mm / 2
  bool has_depth = false;  ///< linear: inside iff 0 <= y - face_y <= depth_mm

  /// Throws InputError naming `what` for non-positive or non-finite sizes and angles.
  void validate(const std::string& what) const;

  /// docs/conventions.md §3 inside test at probe coordinates (x, y) mm, evaluated in double
  /// precision.
  bool inside(double x, double y) const;

  /// The H×W uint8 mask (row-major, row 0 first): 1 where the pixel centre is inside.
  std::vector<uint8_t> mask() const;
  /// Pixel (u, v) at (u, v, 0) → probe mm, from the image grid (docs/conventions.md §3): what a
  /// pose is multiplied with to place an image in the world.
  Mat4 pixel_to_probe() const;

  std::string describe() const;

  /// A convex fan (docs/conventions.md §3) on `image`: apex at (0, face_y_mm − radius_mm).
  static ProbeGeometry curvilinear(double radius_mm, double depth_mm, double sector_deg,
                                   const ImageGrid& image, double face_y_mm = 0.0);
  /// A linear array on `image`, optionally limited to |x| ≤ width_mm / 2 and to depth_mm below
  /// the face; without limits the whole image is inside.
  static ProbeGeometry linear(const ImageGrid& image, std::optional<double> width_mm = std::nullopt,
                              std::optional<double> depth_mm = std::nullopt,
                              double face_y_mm = 0.0);
};

/// A probe as fan-slicer describes it (its configuration's "simulation" block), in its units.
struct FanSlicerProbe {
  ProbeType transducer = ProbeType::Curvilinear;
  /// Curvilinear: [dθ (deg), da (mm), Θ (deg), A, C, B], with A, C, B in units of da.
  double fan_geometry[6] = {0, 0, 0, 0, 0, 0};
  int image_dimensions[2] = {0, 0};      ///< W, H
  double pixel_size_mm[2] = {1.0, 1.0};  ///< (px, py)
};
/// docs/conventions.md §4: fan-slicer's probe at `downsampling`, as sonoslice's geometry (grid
/// floor(W/ds) × floor(H/ds) at ds·(px, py); fan-slicer's lateral origin).
ProbeGeometry probe_from_fanslicer(const FanSlicerProbe& probe, int downsampling = 1);

}  // namespace sonoslice
