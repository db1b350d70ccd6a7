// Freehand 3D reconstruction (docs/conventions.md §7): the Compounder and the small classes it
// takes (CompoundSettings, HoleFillingElement, FrameClip, BeamGeometry), each built from keywords
// and checked by the library's validate() when constructed.
#include <nanobind/stl/array.h>
#include <nanobind/stl/filesystem.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <memory>
#include <mutex>

#include "bindings.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/compound/BeamGeometryFile.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/geometry/VolumeGrid.h"

namespace sonoslice::bindings {
namespace {

using namespace nb::literals;
using Pair = std::array<double, 2>;

std::tuple<double, double> pair_tuple(const double (&v)[2]) {
  return {v[0], v[1]};
}

// ---- hole filling
bool same_kernel(const HoleFillingKernel& a, const HoleFillingKernel& b) {
  return a.type == b.type && a.size == b.size && a.stdev == b.stdev &&
         a.minimum_known_ratio == b.minimum_known_ratio &&
         a.stick_length_limit == b.stick_length_limit && a.sticks_to_use == b.sticks_to_use;
}

// The fields the element's type uses.
std::string kernel_repr(const HoleFillingKernel& k) {
  std::string s = "HoleFillingElement(type=" + repr(std::string(to_string(k.type)));
  switch (k.type) {
    case HoleFillingKernel::Stick:
      return s + ", stick_length_limit=" + repr(k.stick_length_limit) +
             ", sticks_to_use=" + repr(k.sticks_to_use) + ")";
    case HoleFillingKernel::Gaussian:
    case HoleFillingKernel::GaussianAccumulation:
      return s + ", size=" + repr(k.size) + ", stdev=" + repr(k.stdev) +
             ", minimum_known_ratio=" + repr(k.minimum_known_ratio) + ")";
    case HoleFillingKernel::NearestNeighbor:
    case HoleFillingKernel::DistanceWeightInverse:
      break;
  }
  return s + ", size=" + repr(k.size) + ", minimum_known_ratio=" + repr(k.minimum_known_ratio) +
         ")";
}

// ---- settings
std::optional<double> rejection_threshold_or_none(const CompoundSettings& s) {
  const double t = s.rejection_threshold;
  if (std::isinf(t) && t < 0) return std::nullopt;
  return t;
}

std::string settings_repr(const CompoundSettings& s) {
  std::string r =
      "CompoundSettings(interpolation=" + repr(std::string(to_string(s.interpolation))) +
      ", compounding=" + repr(std::string(to_string(s.mode))) +
      ", fill_holes=" + repr(s.fill_holes);
  if (s.fill_holes) {
    r += ", hole_filling=[";
    for (size_t k = 0; k < s.hole_filling.size(); ++k)
      r += (k ? ", " : "") + kernel_repr(s.hole_filling[k]);
    r += "]";
  }
  if (const auto t = rejection_threshold_or_none(s)) r += ", rejection_threshold=" + repr(*t);
  return r + ")";
}

// ---- frame clips
bool same_clip(const FrameClip& a, const FrameClip& b) {
  const auto pair = [](const double(&v)[2]) { return Pair{v[0], v[1]}; };
  return a.x == b.x && a.y == b.y && a.width == b.width && a.height == b.height && a.fan == b.fan &&
         pair(a.fan_angles_deg) == pair(b.fan_angles_deg) &&
         pair(a.fan_origin_px) == pair(b.fan_origin_px) &&
         pair(a.fan_radius_px) == pair(b.fan_radius_px) && a.custom_mask == b.custom_mask;
}

// The fields that differ from "every pixel goes in".
std::string clip_repr(const FrameClip& c) {
  const FrameClip d;
  if (!c.custom_mask.empty()) {
    size_t inside = 0;
    for (uint8_t v : c.custom_mask) inside += v != 0;
    return "FrameClip(mask: " + std::to_string(inside) + " of " +
           std::to_string(c.custom_mask.size()) + " pixels go in)";
  }
  std::string s;
  const auto field = [&s](const char* name, const std::string& value) {
    s += std::string(s.empty() ? "" : ", ") + name + "=" + value;
  };
  if (c.x != d.x) field("x", repr(c.x));
  if (c.y != d.y) field("y", repr(c.y));
  if (c.width != d.width) field("width", repr(c.width));
  if (c.height != d.height) field("height", repr(c.height));
  if (c.fan) {
    field("fan_angles_deg", repr(Pair{c.fan_angles_deg[0], c.fan_angles_deg[1]}));
    field("fan_origin_px", repr(Pair{c.fan_origin_px[0], c.fan_origin_px[1]}));
    field("fan_radius_px", repr(Pair{c.fan_radius_px[0], c.fan_radius_px[1]}));
  }
  return "FrameClip(" + s + ")";
}

// ---- beam-space frames
constexpr const char* kBeamDoc =
    "Geometry of 3D beam-space frames (docs/conventions.md §7): sample s of the beam at azimuth "
    "α = azimuth0_deg + a·dazimuth_deg and elevation β = elevation0_deg + e·delevation_deg lies "
    "at probe coordinates apex + (r0_mm + s·dr_mm)·(sin α, cos α·cos β, cos α·sin β), with apex = "
    "(0, -apex_offset_mm, 0) (0 for phased arrays). The frame sizes come from the arrays.";

bool same_beams(const BeamGeometry& a, const BeamGeometry& b) {
  return a.r0_mm == b.r0_mm && a.dr_mm == b.dr_mm && a.azimuth0_deg == b.azimuth0_deg &&
         a.dazimuth_deg == b.dazimuth_deg && a.elevation0_deg == b.elevation0_deg &&
         a.delevation_deg == b.delevation_deg && a.apex_offset_mm == b.apex_offset_mm;
}

std::string beams_repr(const BeamGeometry& g) {
  return "BeamGeometry(r0_mm=" + repr(g.r0_mm) + ", dr_mm=" + repr(g.dr_mm) +
         ", azimuth0_deg=" + repr(g.azimuth0_deg) + ", dazimuth_deg=" + repr(g.dazimuth_deg) +
         ", elevation0_deg=" + repr(g.elevation0_deg) +
         ", delevation_deg=" + repr(g.delevation_deg) +
         ", apex_offset_mm=" + repr(g.apex_offset_mm) + ")";
}

// `g` for frames of n_elevation × n_azimuth × n_samples samples.
BeamGeometry sized(BeamGeometry g, int64_t n_elevation, int64_t n_azimuth, int64_t n_samples) {
  const int64_t limit = std::numeric_limits<int>::max();
  if (n_elevation > limit || n_azimuth > limit || n_samples > limit)
    throw InputError("beam-space frames: " + std::to_string(n_elevation) + "x" +
                     std::to_string(n_azimuth) + "x" + std::to_string(n_samples) +
                     " samples is absurd");
  g.n_elevation = int(n_elevation);
  g.n_azimuth = int(n_azimuth);
  g.n_samples = int(n_samples);
  return g;
}

// ---- the compounder
// Frames (2D: (H, W) or (N, H, W); beams: (E, A, S) or (N, E, A, S)): their count and type.
int64_t frame_count(const HostPixels& a, size_t frame_ndim, const std::string& what,
                    const char* layout, PixelType* type) {
  *type = pixel_type_of(a.dtype(), what);
  if (a.ndim() != frame_ndim && a.ndim() != frame_ndim + 1)
    throw InputError(what + " has shape " + shape_text(a) + "; expected " + layout);
  return a.ndim() == frame_ndim ? 1 : int64_t(a.shape(0));
}

// One matrix per frame.
std::vector<Mat4> matrices_for(const Matrices& a, int64_t frames, bool single,
                               const std::string& what) {
  if (int64_t(a.shape(0)) != frames)
    throw InputError(what + " has shape " + shape_text(a) + " for " +
                     (single ? "1 frame; expected (4, 4)"
                             : std::to_string(frames) + " frames; expected (" +
                                   std::to_string(frames) + ", 4, 4)"));
  return matrices_from(a);
}

void check_clip_fits(const FrameClip& clip, int64_t width, int64_t height,
                     const std::string& what) {
  if (!clip.custom_mask.empty() && int64_t(clip.custom_mask.size()) != width * height)
    throw InputError(what + ": the clip mask has " + std::to_string(clip.custom_mask.size()) +
                     " pixels but frames have " + std::to_string(height) + "x" +
                     std::to_string(width));
}

// A Compounder with a lock: Python threads may share one, and its methods run without the GIL.
// The GIL is always released before the lock is taken (a warning raised while the lock is held
// takes the GIL).
struct PyCompounder {
  Compounder compounder;
  PixelType dtype;
  std::mutex mutex;
  PyCompounder(const VolumeGrid& grid, CompoundSettings settings, Device device,
               uint64_t max_memory, PixelType type)
      : compounder(grid, std::move(settings), device, max_memory, type), dtype(type) {}
};

}  // namespace

void bind_compounding(nb::module_& m) {
  const HoleFillingKernel hole;
  nb::class_<HoleFillingKernel>(
      m, "HoleFillingElement",
      "One hole-filling element (PLUS's HoleFillingElement): a voxel no sample reached takes the "
      "first element of the list that can fill it. Types: gaussian, gaussian_accumulation, "
      "distance_weight_inverse, nearest_neighbor (size, minimum_known_ratio; Gaussians also "
      "stdev, voxels) and stick (stick_length_limit, sticks_to_use).")
      .def(
          "__init__",
          [](HoleFillingKernel* self, const std::string& type, int size, double stdev,
             double minimum_known_ratio, int stick_length_limit, int sticks_to_use) {
            HoleFillingKernel k;
            k.type = parse_hole_filling_type(type);
            k.size = size;
            k.stdev = stdev;
            k.minimum_known_ratio = minimum_known_ratio;
            k.stick_length_limit = stick_length_limit;
            k.sticks_to_use = sticks_to_use;
            k.validate("HoleFillingElement");
            new (self) HoleFillingKernel(k);
          },
          "type"_a = to_string(hole.type), nb::kw_only(), "size"_a = hole.size,
          "stdev"_a = hole.stdev, "minimum_known_ratio"_a = hole.minimum_known_ratio,
          "stick_length_limit"_a = hole.stick_length_limit, "sticks_to_use"_a = hole.sticks_to_use)
      .def_prop_rw(
          "type", [](const HoleFillingKernel& k) { return to_string(k.type); },
          [](HoleFillingKernel& k, const std::string& type) {
            k.type = parse_hole_filling_type(type);
          })
      .def_rw("size", &HoleFillingKernel::size, "cube edge, voxels (odd)")
      .def_rw("stdev", &HoleFillingKernel::stdev, "Gaussian standard deviation, voxels")
      .def_rw("minimum_known_ratio", &HoleFillingKernel::minimum_known_ratio)
      .def_rw("stick_length_limit", &HoleFillingKernel::stick_length_limit)
      .def_rw("sticks_to_use", &HoleFillingKernel::sticks_to_use)
      .def("validate", &HoleFillingKernel::validate, "what"_a = "HoleFillingElement",
           "ValueError naming the field when a value is out of range (fields set one by one are "
           "checked here or when a Compounder takes the element).")
      .def("__eq__", &same_kernel, nb::is_operator())
      .def("__repr__", &kernel_repr);

  const CompoundSettings settings;
  nb::class_<CompoundSettings>(m, "CompoundSettings",
                               "How samples are splatted, combined and holes filled.")
      .def(
          "__init__",
          [](CompoundSettings* self, const std::string& interpolation,
             const std::string& compounding, bool fill_holes,
             std::optional<std::vector<HoleFillingKernel>> hole_filling,
             std::optional<double> rejection_threshold) {
            CompoundSettings s;
            s.interpolation = parse_interpolation(interpolation);
            s.mode = parse_compounding_mode(compounding);
            s.fill_holes = fill_holes;
            if (hole_filling && !hole_filling->empty()) s.hole_filling = std::move(*hole_filling);
            if (rejection_threshold) s.rejection_threshold = *rejection_threshold;
            new (self) CompoundSettings(std::move(s));
          },
          nb::kw_only(), "interpolation"_a = to_string(settings.interpolation),
          "compounding"_a = to_string(settings.mode), "fill_holes"_a = settings.fill_holes,
          "hole_filling"_a = nb::none(), "rejection_threshold"_a = nb::none(),
          "hole_filling: elements tried in order (None or []: one Gaussian 3³, the default); "
          "rejection_threshold: samples below it are not inserted (None: all are).")
      .def_prop_ro("interpolation",
                   [](const CompoundSettings& s) { return to_string(s.interpolation); })
      .def_prop_ro("compounding", [](const CompoundSettings& s) { return to_string(s.mode); })
      .def_ro("fill_holes", &CompoundSettings::fill_holes)
      .def_ro("hole_filling", &CompoundSettings::hole_filling)
      .def_prop_ro("rejection_threshold", &rejection_threshold_or_none)
      .def("__repr__", &settings_repr);

  const FrameClip clip;
  nb::class_<FrameClip>(
      m, "FrameClip",
      "Which pixels of a 2D frame go in (MF-oriented pixels): the width x height pixels from "
      "(x, y) (-1: to the frame's edge) and, optionally, a fan (PLUS's conventions: angles from "
      "the +y (depth) axis towards +x, inclusive; origin and radii in pixels); or an (H, W) mask.")
      .def(
          "__init__",
          [](FrameClip* self, int x, int y, int width, int height,
             std::optional<Pair> fan_angles_deg, std::optional<Pair> fan_origin_px,
             std::optional<Pair> fan_radius_px, std::optional<Mask> mask) {
            const FrameClip d;
            FrameClip c;
            c.x = x;
            c.y = y;
            c.width = width;
            c.height = height;
            if (fan_angles_deg) {
              c.fan = true;
              c.fan_angles_deg[0] = (*fan_angles_deg)[0];
              c.fan_angles_deg[1] = (*fan_angles_deg)[1];
            } else if (fan_origin_px || fan_radius_px) {
              throw InputError(
                  "FrameClip: a fan needs fan_angles_deg (degrees from +y towards +x)");
            }
            if (fan_origin_px) {
              c.fan_origin_px[0] = (*fan_origin_px)[0];
              c.fan_origin_px[1] = (*fan_origin_px)[1];
            }
            if (fan_radius_px) {
              c.fan_radius_px[0] = (*fan_radius_px)[0];
              c.fan_radius_px[1] = (*fan_radius_px)[1];
            }
            if (mask) {
              if (c.fan || x != d.x || y != d.y || width != d.width || height != d.height)
                throw InputError("FrameClip: give a mask or a rectangle/fan, not both");
              if (mask->size() == 0) throw InputError("FrameClip: the mask is empty");
              c.custom_mask.resize(mask->size());
              for (size_t i = 0; i < c.custom_mask.size(); ++i)
                c.custom_mask[i] = mask->data()[i] != 0;
            }
            c.validate("FrameClip");
            new (self) FrameClip(std::move(c));
          },
          nb::kw_only(), "x"_a = clip.x, "y"_a = clip.y, "width"_a = clip.width,
          "height"_a = clip.height, "fan_angles_deg"_a = nb::none(), "fan_origin_px"_a = nb::none(),
          "fan_radius_px"_a = nb::none(), "mask"_a = nb::none())
      .def_ro("x", &FrameClip::x)
      .def_ro("y", &FrameClip::y)
      .def_ro("width", &FrameClip::width)
      .def_ro("height", &FrameClip::height)
      .def_ro("fan", &FrameClip::fan, "whether the fan applies")
      .def_prop_ro("fan_angles_deg",
                   [](const FrameClip& c) { return pair_tuple(c.fan_angles_deg); })
      .def_prop_ro("fan_origin_px", [](const FrameClip& c) { return pair_tuple(c.fan_origin_px); })
      .def_prop_ro("fan_radius_px", [](const FrameClip& c) { return pair_tuple(c.fan_radius_px); })
      .def_prop_ro("mask_pixels", [](const FrameClip& c) { return c.custom_mask.size(); })
      .def(
          "mask",
          [](const FrameClip& c, int width, int height) {
            auto keep = std::make_shared<std::vector<uint8_t>>(c.mask(width, height));
            return numpy_view(keep->data(), {size_t(height), size_t(width)}, PixelType::UInt8,
                              keep);
          },
          "width"_a, "height"_a,
          "The (H, W) uint8 mask (1: inserted) for frames of width x height pixels.")
      .def("rectangle", &FrameClip::rectangle, "width"_a, "height"_a,
           "Pixels [x0, x1) x [y0, y1) of the clip rectangle within the frame: (x0, y0, x1, y1).")
      .def("__eq__", &same_clip, nb::is_operator())
      .def("__repr__", &clip_repr);

  const BeamGeometry beams;
  nb::class_<BeamGeometry>(m, "BeamGeometry", kBeamDoc)
      .def(
          "__init__",
          [](BeamGeometry* self, double r0_mm, double dr_mm, double azimuth0_deg,
             double dazimuth_deg, double elevation0_deg, double delevation_deg,
             double apex_offset_mm) {
            BeamGeometry g;
            g.r0_mm = r0_mm;
            g.dr_mm = dr_mm;
            g.azimuth0_deg = azimuth0_deg;
            g.dazimuth_deg = dazimuth_deg;
            g.elevation0_deg = elevation0_deg;
            g.delevation_deg = delevation_deg;
            g.apex_offset_mm = apex_offset_mm;
            // The frame sizes come with the frames (add_beams checks them all); on its own the
            // geometry is checked as frames of one beam of one sample: every value, the first
            // beam's angles.
            sized(g, 1, 1, 1).validate("BeamGeometry");
            new (self) BeamGeometry(g);
          },
          nb::kw_only(), "r0_mm"_a = beams.r0_mm, "dr_mm"_a = beams.dr_mm,
          "azimuth0_deg"_a = beams.azimuth0_deg, "dazimuth_deg"_a = beams.dazimuth_deg,
          "elevation0_deg"_a = beams.elevation0_deg, "delevation_deg"_a = beams.delevation_deg,
          "apex_offset_mm"_a = beams.apex_offset_mm)
      .def_rw("r0_mm", &BeamGeometry::r0_mm, "depth of the first sample (mm)")
      .def_rw("dr_mm", &BeamGeometry::dr_mm, "sample spacing along a beam (mm)")
      .def_rw("azimuth0_deg", &BeamGeometry::azimuth0_deg)
      .def_rw("dazimuth_deg", &BeamGeometry::dazimuth_deg)
      .def_rw("elevation0_deg", &BeamGeometry::elevation0_deg)
      .def_rw("delevation_deg", &BeamGeometry::delevation_deg)
      .def_rw("apex_offset_mm", &BeamGeometry::apex_offset_mm)
      .def_static(
          "from_file",
          [](const std::filesystem::path& path) { return read_beam_geometry(path.string()); },
          "path"_a, "Reads the geometry JSON ({\"r0_mm\": ..., \"dr_mm\": ..., ...}).")
      .def(
          "save",
          [](const BeamGeometry& g, const std::filesystem::path& path) {
            write_beam_geometry(path.string(), g);
          },
          "path"_a, "Writes the geometry JSON atomically.")
      .def("__eq__", &same_beams, nb::is_operator())
      .def("__repr__", &beams_repr);

  nb::class_<PyCompounder> compounder(
      m, "Compounder", "Tracked frames compounded into one voxel grid (use sonoslice.Compounder).");
  compounder
      .def(
          "__init__",
          [](PyCompounder* self, const VolumeGrid& grid, const CompoundSettings& settings,
             const std::string& device, uint64_t max_memory, const std::string& dtype) {
            const PixelType t = parse_pixel_type(dtype);
            const Device d = Device::parse(device);
            nb::gil_scoped_release release;  // allocating and clearing a large grid takes a while
            new (self) PyCompounder(grid, settings, d, max_memory, t);
          },
          "grid"_a, "settings"_a = CompoundSettings(), "device"_a = "cpu", "max_memory"_a = 0,
          "dtype"_a = "float32", "max_memory: bytes (0: what the machine has).")
      .def(
          "add_images",
          [](PyCompounder& self, HostPixels frames, Matrices image_to_reference,
             const FrameClip& clip) {
            PixelType type;
            const int64_t n = frame_count(frames, 2, "add: frames", "(H, W) or (N, H, W)", &type);
            const size_t nd = frames.ndim();
            const int64_t height = int64_t(frames.shape(nd - 2)),
                          width = int64_t(frames.shape(nd - 1));
            if (width > (int64_t(1) << 28) || height > (int64_t(1) << 28))
              throw InputError("add: frames of " + std::to_string(width) + "x" +
                               std::to_string(height) + " pixels are too large");
            const std::vector<Mat4> m =
                matrices_for(image_to_reference, n, nd == 2, "add: image_to_reference");
            check_clip_fits(clip, width, height, "add");
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            self.compounder.add_images(frames.data(), type, int(width), int(height), n, m.data(),
                                       clip);
          },
          "frames"_a, "image_to_reference"_a, "clip"_a = FrameClip(),
          "frames: (H, W) or (N, H, W), C-order, MF-oriented; image_to_reference: (N, 4, 4), pixel "
          "(i, j) at (i, j, 0) to reference mm.")
      .def(
          "add_beams",
          [](PyCompounder& self, HostPixels frames, Matrices probe_to_reference,
             const BeamGeometry& g) {
            PixelType type;
            const int64_t n = frame_count(
                frames, 3, "add_beams: frames",
                "(n_elevation, n_azimuth, n_samples) or (N, n_elevation, n_azimuth, n_samples)",
                &type);
            const size_t nd = frames.ndim();
            const BeamGeometry geometry =
                sized(g, int64_t(frames.shape(nd - 3)), int64_t(frames.shape(nd - 2)),
                      int64_t(frames.shape(nd - 1)));
            geometry.validate("add_beams: geometry");
            const std::vector<Mat4> m =
                matrices_for(probe_to_reference, n, nd == 3, "add_beams: probe_to_reference");
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            self.compounder.add_beams(frames.data(), type, geometry, n, m.data());
          },
          "frames"_a, "probe_to_reference"_a, "geometry"_a,
          "frames: (E, A, S) or (N, E, A, S), samples along each beam fastest.")
      .def(
          "volume",
          [](PyCompounder& self, std::optional<std::string> dtype) {
            const PixelType t = dtype ? parse_pixel_type(*dtype) : self.dtype;
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            return self.compounder.volume(t);
          },
          "dtype"_a = nb::none(),
          "The reconstruction so far (empty voxels 0; integers round and saturate).")
      .def(
          "weights",
          [](PyCompounder& self) {
            nb::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(self.mutex);
            return self.compounder.weights();
          },
          "The summed splat weight per voxel (float32; 0 where no sample arrived).")
      .def_prop_ro("frames_added",
                   [](PyCompounder& self) {
                     nb::gil_scoped_release release;
                     std::lock_guard<std::mutex> lock(self.mutex);
                     return self.compounder.frames_added();
                   })
      .def_prop_ro("grid", [](PyCompounder& self) { return self.compounder.grid(); })
      .def_prop_ro("settings", [](PyCompounder& self) { return self.compounder.settings(); })
      .def_prop_ro("dtype", [](PyCompounder& self) { return to_string(self.dtype); });

  m.def(
      "compound_grid_around",
      [](Matrices image_to_reference, int width, int height, const FrameClip& clip,
         const Vec3& spacing) {
        check_clip_fits(clip, width, height, "grid_around");
        return Compounder::grid_around(matrices_from(image_to_reference), width, height, clip,
                                       spacing);
      },
      "image_to_reference"_a, "width"_a, "height"_a, "clip"_a, "spacing"_a,
      "PLUS's output grid around clipped frames.");
  m.def(
      "compound_grid_around_beams",
      [](Matrices probe_to_reference, const BeamGeometry& g,
         const std::array<int64_t, 3>& beam_shape, const Vec3& spacing) {
        return Compounder::grid_around_beams(matrices_from(probe_to_reference),
                                             sized(g, beam_shape[0], beam_shape[1], beam_shape[2]),
                                             spacing);
      },
      "probe_to_reference"_a, "geometry"_a, "beam_shape"_a, "spacing"_a,
      "The grid around every beam's first and last sample; beam_shape: (n_elevation, n_azimuth, "
      "n_samples).");
  m.def(
      "compounding_memory_bytes",
      [](const std::array<int64_t, 3>& dims, const std::string& compounding,
         const std::string& dtype) {
        VolumeGrid g;
        g.dims = dims;
        CompoundSettings s;
        s.mode = parse_compounding_mode(compounding);
        return compounding_memory_bytes(g, s, parse_pixel_type(dtype));
      },
      "dims"_a, "compounding"_a = to_string(settings.mode), "dtype"_a = "float32");
}

}  // namespace sonoslice::bindings
