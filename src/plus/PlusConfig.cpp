// A PLUS configuration XML's calibration (CoordinateDefinitions) and volume-reconstruction
// settings, read as PLUS reads them (IGSIO, Source/VolumeReconstruction/
// vtkIGSIOVolumeReconstructor.cxx ReadConfiguration, vtkIGSIOFillHolesInVolume.cxx
// ReadConfiguration, vtkIGSIOPasteSliceIntoVolume.cxx):
//   - enumerated values are compared case-insensitively (igsioXmlUtils.h XML_READ_ENUM*);
//   - absent CompoundingMode: MAXIMUM if the deprecated Calculation is MAXIMUM, else LATEST if
//     the deprecated Compounding is OFF, else MEAN, with a warning;
//   - absent Interpolation: NEAREST_NEIGHBOR (vtkIGSIOPasteSliceIntoVolume's default);
//   - the deprecated FanAngles / FanOrigin / FanDepth are read first and overridden by
//     FanAnglesDeg / FanOriginPixel / FanRadiusStopPixel;
//   - fan clipping applies when either fan angle is non-zero (FanClippingApplied()); the fan
//     radius defaults to 0 .. 500 pixels;
//   - the clip rectangle applies only when both of its sizes are positive.
// Where PLUS logs an error and carries on with a default (an unparsable number, an unknown
// enumerated value), we stop with an InputError naming the file, element and attribute.
#include "sonoslice/plus/PlusConfig.h"

#include <filesystem>
#include <set>

#ifdef SONOSLICE_HAVE_PUGIXML
#include <pugixml.hpp>
#endif

#include "../io/TextParse.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

std::optional<VolumeGrid> PlusReconstructionConfig::output_grid() const {
  if (!output_spacing_mm || !output_origin_mm || !output_extent) return std::nullopt;
  const Vec3& spacing = *output_spacing_mm;
  const std::array<int, 6>& e = *output_extent;
  VolumeGrid grid;
  for (int a = 0; a < 3; ++a) {
    grid.spacing_mm[a] = spacing[a];
    grid.origin_mm[a] = (*output_origin_mm)[a] + e[2 * a] * spacing[a];
    grid.dims[a] = int64_t(e[2 * a + 1]) - e[2 * a] + 1;
  }
  return grid;
}

#ifndef SONOSLICE_HAVE_PUGIXML

PlusReconstructionConfig read_plus_config(const std::string& path) {
  throw Error("cannot read PLUS configuration '" + path +
              "': sonoslice was built without pugixml (install libpugixml-dev and rebuild)");
}

PlusReconstructionConfig read_plus_output_grid(const std::string&, const std::string& source) {
  throw Error("cannot read " + source +
              ": sonoslice was built without pugixml (install libpugixml-dev and rebuild)");
}

#else

namespace {

using namespace text;

/// Reads the attributes of one element, remembering which ones were looked at.
class Attributes {
 public:
  Attributes(const pugi::xml_node& node, std::string file, std::string where)
      : node_(node), file_(std::move(file)), where_(std::move(where)) {}

  bool has(const char* name) {
    seen_.insert(name);
    return !node_.attribute(name).empty();
  }
  std::string text(const char* name) {
    seen_.insert(name);
    return node_.attribute(name).value();
  }
  std::string label(const char* name) const { return where_ + "/@" + name; }
  [[noreturn]] void fail(const char* name, const std::string& why) const {
    throw InputError(file_ + ": " + label(name) + ": " + why);
  }

  template <size_t N>
  std::array<double, N> numbers(const char* name) {
    const std::string value = text(name);
    const std::vector<std::string> tokens = split_ws(value);
    std::array<double, N> out{};
    bool ok = tokens.size() == N;
    for (size_t i = 0; ok && i < N; ++i) ok = parse_double(tokens[i], &out[i]);
    if (!ok)
      fail(name, "expected " + std::to_string(N) + (N == 1 ? " number" : " numbers") + ", got " +
                     quote_value(value));
    return out;
  }
  double number(const char* name) { return numbers<1>(name)[0]; }

  template <size_t N>
  std::array<int, N> integers(const char* name) {
    const std::string value = text(name);
    const std::vector<std::string> tokens = split_ws(value);
    std::array<int, N> out{};
    bool ok = tokens.size() == N;
    for (size_t i = 0; ok && i < N; ++i) ok = parse_int(tokens[i], &out[i]);
    if (!ok)
      fail(name, "expected " + std::to_string(N) + (N == 1 ? " integer" : " integers") + ", got " +
                     quote_value(value));
    return out;
  }
  int integer(const char* name) { return integers<1>(name)[0]; }

  /// The value upper-cased, which must be one of `accepted`.
  std::string choice(const char* name, const std::vector<std::string>& accepted) {
    const std::string value = upper(trim(text(name)));
    for (const std::string& a : accepted)
      if (value == a) return value;
    std::string list;
    for (const std::string& a : accepted) list += (list.empty() ? "" : ", ") + a;
    fail(name, quote_value(text(name)) + " is not one of " + list);
  }

  /// Attributes present that were never looked at.
  std::vector<std::string> unseen() const {
    std::vector<std::string> out;
    for (const pugi::xml_attribute& a : node_.attributes())
      if (!seen_.count(a.name())) out.push_back(a.name());
    return out;
  }

 private:
  pugi::xml_node node_;
  std::string file_, where_;
  std::set<std::string> seen_;
};

/// The calibration: every CoordinateDefinitions/Transform, its matrix checked (transform_problem).
void read_coordinate_definitions(const pugi::xml_node& root, const std::string& path,
                                 PlusReconstructionConfig* config) {
  const pugi::xml_node definitions = root.child("CoordinateDefinitions");
  if (!definitions) return;
  int index = 0;
  for (const pugi::xml_node& t : definitions.children("Transform")) {
    ++index;
    const std::string where =
        path + ": CoordinateDefinitions/Transform[" + std::to_string(index) + "]";
    const std::string from = trim(t.attribute("From").value()),
                      to = trim(t.attribute("To").value());
    if (from.empty() || to.empty()) throw InputError(where + ": needs From and To attributes");
    if (t.attribute("Matrix").empty())
      throw InputError(where + " (" + from + "To" + to + "): no Matrix attribute");
    Mat4 m;
    if (!parse_matrix16(t.attribute("Matrix").value(), &m))
      throw InputError(where + " (" + from + "To" + to +
                       ")/@Matrix: expected 16 finite numbers, got " +
                       quote_value(trim(t.attribute("Matrix").value())));
    // An all-zero calibration (or one whose axes collapse) would place every frame's pixels on
    // a point or a line: the reconstruction would be empty or absurd, without a word.
    const std::string problem = transform_problem(m);
    if (!problem.empty())
      throw InputError(where + " (" + from + "To" + to + ")/@Matrix " + problem);
    config->coordinate_definitions.set(from, to, m);
  }
}

/// One HoleFillingElement with the attributes its Type needs; other attributes PLUS knows are
/// noted as ignored, the rest as unknown.
HoleFillingKernel read_hole_filling_element(const pugi::xml_node& node, int index,
                                            const std::string& path,
                                            PlusReconstructionConfig* config) {
  const std::string where =
      "VolumeReconstruction/HoleFilling/HoleFillingElement[" + std::to_string(index) + "]";
  Attributes a(node, path, where);
  std::vector<std::string> types;  // PLUS's spellings: upper case
  for (HoleFillingKernel::Type t : kHoleFillingTypes) types.push_back(upper(to_string(t)));
  if (!a.has("Type"))
    throw InputError(path + ": " + where + ": no Type (" + plus_hole_filling_names() + ")");
  const std::string type = a.choice("Type", types);
  HoleFillingKernel k;
  k.type = parse_hole_filling_type(type);
  auto require = [&](const char* name) {
    if (!a.has(name)) a.fail(name, "required for a " + type + " element");
  };
  auto read_size_and_ratio = [&] {
    require("Size");
    k.size = a.integer("Size");
    if (k.size < 1)
      a.fail("Size", "must be a positive number of voxels, got " + std::to_string(k.size));
    require("MinimumKnownVoxelsRatio");
    k.minimum_known_ratio = a.number("MinimumKnownVoxelsRatio");
    if (k.minimum_known_ratio < 0 || k.minimum_known_ratio > 1)
      a.fail("MinimumKnownVoxelsRatio", "must be in [0, 1]");
  };
  std::vector<const char*> used;
  if (k.type == HoleFillingKernel::Gaussian || k.type == HoleFillingKernel::GaussianAccumulation) {
    require("Stdev");
    k.stdev = a.number("Stdev");
    if (!(k.stdev > 0)) a.fail("Stdev", "must be positive");
    read_size_and_ratio();
    used = {"Stdev", "Size", "MinimumKnownVoxelsRatio"};
  } else if (k.type == HoleFillingKernel::NearestNeighbor ||
             k.type == HoleFillingKernel::DistanceWeightInverse) {
    read_size_and_ratio();
    used = {"Size", "MinimumKnownVoxelsRatio"};
  } else {
    require("StickLengthLimit");
    k.stick_length_limit = a.integer("StickLengthLimit");
    if (k.stick_length_limit < 1) a.fail("StickLengthLimit", "must be at least 1");
    require("NumberOfSticksToUse");
    k.sticks_to_use = a.integer("NumberOfSticksToUse");
    if (k.sticks_to_use < 1) a.fail("NumberOfSticksToUse", "must be at least 1");
    used = {"StickLengthLimit", "NumberOfSticksToUse"};
  }
  // Attributes PLUS knows for other element types are read by PLUS but not used for this one.
  for (const char* name :
       {"Stdev", "Size", "MinimumKnownVoxelsRatio", "StickLengthLimit", "NumberOfSticksToUse"}) {
    bool is_used = false;
    for (const char* u : used) is_used = is_used || std::string(u) == name;
    if (!is_used && a.has(name)) config->ignored_attributes.push_back(a.label(name));
  }
  for (const std::string& name : a.unseen())
    config->unknown_attributes.push_back(where + "/@" + name);
  return k;
}

// The stages of read_plus_config, called in the order below: the order fixes which of several
// problems an error names, and the order of the warnings.

/// Loads the XML; FileError for a missing, unreadable or malformed file.
void load_document(const std::string& path, pugi::xml_document* doc) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec))
    throw FileError("PLUS configuration '" + path + "' not found");
  if (std::filesystem::is_directory(path, ec))
    throw FileError("cannot read PLUS configuration '" + path + "': it is a directory");
  const pugi::xml_parse_result parsed = doc->load_file(path.c_str());
  if (!parsed) {
    if (parsed.status == pugi::status_file_not_found || parsed.status == pugi::status_io_error)
      throw FileError("cannot read PLUS configuration '" + path + "': " + parsed.description());
    throw FileError("PLUS configuration '" + path + "': malformed XML at byte " +
                    std::to_string(parsed.offset) + ": " + parsed.description());
  }
}

/// The VolumeReconstruction element: the root's child, else the first one anywhere below the
/// root; InputError when there is none (not a reconstruction configuration).
pugi::xml_node find_volume_reconstruction(const pugi::xml_node& root, const std::string& path) {
  pugi::xml_node recon = root.child("VolumeReconstruction");
  if (!recon)
    recon = root.find_node(
        [](const pugi::xml_node& n) { return std::string(n.name()) == "VolumeReconstruction"; });
  if (!recon)
    throw InputError(path +
                     ": no VolumeReconstruction element (not a PLUS volume reconstruction "
                     "configuration)");
  return recon;
}

/// The coordinate frames the reconstruction maps between (default Image → Reference).
void read_coordinate_frames(Attributes& a, PlusReconstructionConfig* config) {
  if (a.has("ImageCoordinateFrame")) config->image_frame = trim(a.text("ImageCoordinateFrame"));
  if (a.has("ReferenceCoordinateFrame"))
    config->reference_frame = trim(a.text("ReferenceCoordinateFrame"));
  if (config->image_frame.empty()) a.fail("ImageCoordinateFrame", "is empty");
  if (config->reference_frame.empty()) a.fail("ReferenceCoordinateFrame", "is empty");
}

/// OutputSpacing, OutputOrigin and OutputExtent, each optional (output_grid() needs all three).
void read_output_grid(Attributes& a, PlusReconstructionConfig* config) {
  if (a.has("OutputSpacing")) {
    const auto v = a.numbers<3>("OutputSpacing");
    for (double d : v)
      if (!(d > 0))
        a.fail("OutputSpacing",
               "spacings must be positive, got " + quote_value(a.text("OutputSpacing")));
    config->output_spacing_mm = Vec3{v[0], v[1], v[2]};
  }
  if (a.has("OutputOrigin")) {
    const auto v = a.numbers<3>("OutputOrigin");
    config->output_origin_mm = Vec3{v[0], v[1], v[2]};
  }
  if (a.has("OutputExtent")) {
    const auto v = a.integers<6>("OutputExtent");
    for (int i = 0; i < 3; ++i)
      if (v[2 * i] > v[2 * i + 1])
        a.fail("OutputExtent", "each minimum must not exceed its maximum, got " +
                                   quote_value(a.text("OutputExtent")));
    config->output_extent = v;
  }
}

/// The clip rectangle, used only when both sizes are positive (PLUS), converted from PLUS's
/// inclusive size to FrameClip's pixel count.
void read_clip_rectangle(Attributes& a, FrameClip* clip) {
  std::array<int, 2> clip_origin{0, 0}, clip_size{0, 0};
  if (a.has("ClipRectangleOrigin")) clip_origin = a.integers<2>("ClipRectangleOrigin");
  if (a.has("ClipRectangleSize")) clip_size = a.integers<2>("ClipRectangleSize");
  if (clip_origin[0] < 0 || clip_origin[1] < 0)
    a.fail("ClipRectangleOrigin",
           "must not be negative, got " + quote_value(a.text("ClipRectangleOrigin")));
  if (clip_size[0] < 0 || clip_size[1] < 0)
    a.fail("ClipRectangleSize",
           "must not be negative, got " + quote_value(a.text("ClipRectangleSize")));
  if (clip_size[0] > 0 && clip_size[1] > 0) {
    // PLUS inserts pixels x0 .. x0 + w inclusive (vtkIGSIOPasteSliceIntoVolume's clip extent is
    // [ceil(x0), floor(x0 + w)]): w + 1 of them. FrameClip counts pixels.
    clip->x = clip_origin[0];
    clip->y = clip_origin[1];
    clip->width = clip_size[0] + 1;
    clip->height = clip_size[1] + 1;
  }
}

/// Warns that a deprecated attribute was used (PLUS still reads it).
void warn_deprecated(const Attributes& a, const std::string& path, const char* old_name,
                     const char* new_name) {
  warn(path + ": " + a.label(old_name) + " is deprecated (PLUS: use " + new_name +
       " with the same value)");
}

/// The fan (angles, origin, radii), which applies when either angle is non-zero, as in PLUS.
void read_fan(Attributes& a, const std::string& path, FrameClip* clip) {
  // Fan: deprecated names first, then their replacements (as PLUS reads them).
  std::array<double, 2> fan_angles{0, 0}, fan_origin{0, 0};
  double fan_start = 0, fan_stop = 500;  // vtkIGSIOPasteSliceIntoVolume's defaults
  if (a.has("FanAngles")) {
    warn_deprecated(a, path, "FanAngles", "FanAnglesDeg");
    fan_angles = a.numbers<2>("FanAngles");
  }
  if (a.has("FanAnglesDeg")) fan_angles = a.numbers<2>("FanAnglesDeg");
  if (a.has("FanOrigin")) {
    warn_deprecated(a, path, "FanOrigin", "FanOriginPixel");
    fan_origin = a.numbers<2>("FanOrigin");
  }
  if (a.has("FanOriginPixel")) fan_origin = a.numbers<2>("FanOriginPixel");
  if (a.has("FanDepth")) {
    warn_deprecated(a, path, "FanDepth", "FanRadiusStopPixel");
    fan_stop = a.number("FanDepth");
  }
  if (a.has("FanRadiusStartPixel")) fan_start = a.number("FanRadiusStartPixel");
  if (a.has("FanRadiusStopPixel")) fan_stop = a.number("FanRadiusStopPixel");
  if (fan_angles[0] != 0.0 || fan_angles[1] != 0.0) {
    if (fan_angles[0] > fan_angles[1])
      a.fail(a.has("FanAnglesDeg") ? "FanAnglesDeg" : "FanAngles",
             "the first (minimum) angle exceeds the second");
    if (fan_start < 0 || fan_stop <= fan_start)
      a.fail(a.has("FanRadiusStopPixel") ? "FanRadiusStopPixel" : "FanRadiusStartPixel",
             "the fan radius range must satisfy 0 <= start < stop");
    clip->fan = true;
    clip->fan_angles_deg[0] = fan_angles[0];
    clip->fan_angles_deg[1] = fan_angles[1];
    clip->fan_origin_px[0] = fan_origin[0];
    clip->fan_origin_px[1] = fan_origin[1];
    clip->fan_radius_px[0] = fan_start;
    clip->fan_radius_px[1] = fan_stop;
  }
}

/// Which samples and frames go in: PixelRejectionThreshold and SkipInterval (below 1: 1, as PLUS).
void read_rejection_and_skip(Attributes& a, const std::string& path,
                             PlusReconstructionConfig* config) {
  if (a.has("PixelRejectionThreshold"))
    config->settings.rejection_threshold = a.number("PixelRejectionThreshold");
  if (a.has("SkipInterval")) {
    config->skip_interval = a.integer("SkipInterval");
    if (config->skip_interval < 1) {
      warn(path + ": " + a.label("SkipInterval") + " = " + std::to_string(config->skip_interval) +
           " must be at least 1; using 1 (as PLUS does)");
      config->skip_interval = 1;
    }
  }
}

/// Interpolation and CompoundingMode, with PLUS's defaults and its deprecated spellings.
void read_compounding(Attributes& a, const std::string& path, CompoundSettings* s) {
  s->interpolation = Interpolation::Nearest;  // PLUS's default
  if (a.has("Interpolation"))
    s->interpolation = a.choice("Interpolation", {"LINEAR", "NEAREST_NEIGHBOR"}) == "LINEAR"
                           ? Interpolation::Linear
                           : Interpolation::Nearest;

  // Compounding: CompoundingMode, else the deprecated Calculation / Compounding.
  std::string calculation, compounding;
  if (a.has("Calculation")) {
    warn_deprecated(a, path, "Calculation", "CompoundingMode");
    calculation = a.choice("Calculation", {"WEIGHTED_AVERAGE", "MAXIMUM"});
  }
  if (a.has("Compounding")) {
    warn_deprecated(a, path, "Compounding", "CompoundingMode");
    compounding = a.choice("Compounding", {"ON", "OFF"});
  }
  if (a.has("CompoundingMode")) {
    const std::string mode = upper(trim(a.text("CompoundingMode")));
    if (mode == "IMPORTANCE_MASK")
      a.fail("CompoundingMode",
             "IMPORTANCE_MASK compounding is not supported (use MEAN, MAXIMUM "
             "or LATEST)");
    const std::string m = a.choice("CompoundingMode", {"MEAN", "MAXIMUM", "LATEST"});
    s->mode = m == "MEAN"      ? CompoundingMode::Mean
              : m == "MAXIMUM" ? CompoundingMode::Max
                               : CompoundingMode::Latest;
  } else {
    std::string assumed = "MEAN";
    s->mode = CompoundingMode::Mean;
    if (calculation == "MAXIMUM") {
      s->mode = CompoundingMode::Max;
      assumed = "MAXIMUM";
    } else if (compounding == "OFF") {
      s->mode = CompoundingMode::Latest;
      assumed = "LATEST";
    }
    warn(path + ": VolumeReconstruction has no CompoundingMode; assuming " + assumed +
         " (as PLUS does)");
  }
}

/// FillHoles and, when ON, the HoleFilling element's HoleFillingElements in order.
void read_hole_filling(const pugi::xml_node& recon, Attributes& a, const std::string& path,
                       PlusReconstructionConfig* config) {
  CompoundSettings& s = config->settings;
  if (a.has("FillHoles")) s.fill_holes = a.choice("FillHoles", {"ON", "OFF"}) == "ON";
  if (!s.fill_holes) return;
  const pugi::xml_node holes = recon.child("HoleFilling");
  if (!holes)
    throw InputError(path +
                     ": VolumeReconstruction/@FillHoles is ON but there is no "
                     "HoleFilling element");
  s.hole_filling.clear();
  int index = 0;
  for (const pugi::xml_node& e : holes.children()) {
    if (e.type() != pugi::node_element) continue;
    if (upper(e.name()) != "HOLEFILLINGELEMENT") continue;  // PLUS skips other elements
    s.hole_filling.push_back(read_hole_filling_element(e, ++index, path, config));
  }
  for (const pugi::xml_attribute& attr : holes.attributes())
    config->unknown_attributes.push_back(std::string("VolumeReconstruction/HoleFilling/@") +
                                         attr.name());
  if (s.hole_filling.empty()) {
    warn(path + ": FillHoles is ON but HoleFilling has no HoleFillingElement; no holes are filled");
    s.fill_holes = false;
  }
}

/// The Optimization attribute, upper-cased for the reconstruction recipe (and in the settings
/// when it names one of PLUS's CPU paths).
void read_optimization(Attributes& a, const std::string& path, PlusReconstructionConfig* config) {
  // Only --plus-exact acts on it; absent: FULL, PLUS's default. GPU (PLUS's OpenCL path) stops
  // a --plus-exact run there (the recipe parses it again) and nothing else; a value PLUS does
  // not know is refused here, as the other enumerated attributes are.
  if (!a.has("Optimization")) return;
  config->optimization = upper(trim(a.text("Optimization")));
  if (config->optimization == "GPU") return;
  config->settings.plus_optimization =
      parse_plus_optimization(config->optimization, path + ": " + a.label("Optimization"));
}

/// Attributes PLUS reads that sonoslice does not act on; a warning for those switched on.
void collect_ignored_attributes(Attributes& a, const std::string& path,
                                PlusReconstructionConfig* config) {
  for (const char* name :
       {"NumberOfThreads", "ImportanceMaskFilename", "FanAnglesAutoDetectBrightnessThreshold",
        "FanAnglesAutoDetectFilterRadiusPixel"})
    if (a.has(name)) config->ignored_attributes.push_back(name);
  for (const char* name : {"EnableFanAnglesAutoDetect", "RecomputeOutputSpacing"}) {
    if (!a.has(name)) continue;
    config->ignored_attributes.push_back(name);
    const std::string v = upper(trim(a.text(name)));
    if (v == "TRUE" || v == "ON" || v == "1")
      warn(path + ": " + a.label(name) + " = " + a.text(name) + " is not supported and is ignored" +
           (std::string(name) == "EnableFanAnglesAutoDetect"
                ? " (the fan angles are used as given)"
                : " (OutputSpacing is used as given)"));
  }
}

/// Attributes PLUS does not define: VolumeReconstruction's first, then those of its hole-filling
/// elements, in one warning. Runs last: every other stage has marked what it read.
void collect_unknown_attributes(const Attributes& a, const std::string& path,
                                PlusReconstructionConfig* config) {
  std::vector<std::string> unknown = a.unseen();
  unknown.insert(unknown.end(), config->unknown_attributes.begin(),
                 config->unknown_attributes.end());
  config->unknown_attributes = unknown;
  if (!unknown.empty()) {
    std::string list;
    for (const std::string& u : unknown) list += (list.empty() ? "" : ", ") + u;
    warn(path + ": unknown VolumeReconstruction attributes ignored (not PLUS settings): " + list);
  }
}

}  // namespace

PlusReconstructionConfig read_plus_config(const std::string& path) {
  pugi::xml_document doc;
  load_document(path, &doc);
  const pugi::xml_node root = doc.document_element();
  PlusReconstructionConfig config;
  config.path = path;
  read_coordinate_definitions(root, path, &config);

  const pugi::xml_node recon = find_volume_reconstruction(root, path);
  Attributes a(recon, path, "VolumeReconstruction");
  read_coordinate_frames(a, &config);
  read_output_grid(a, &config);
  read_clip_rectangle(a, &config.clip);
  read_fan(a, path, &config.clip);
  read_rejection_and_skip(a, path, &config);
  read_compounding(a, path, &config.settings);
  read_hole_filling(recon, a, path, &config);
  read_optimization(a, path, &config);
  collect_ignored_attributes(a, path, &config);
  collect_unknown_attributes(a, path, &config);
  return config;
}

PlusReconstructionConfig read_plus_output_grid(const std::string& element_xml,
                                               const std::string& source) {
  pugi::xml_document doc;
  if (!doc.load_buffer(element_xml.data(), element_xml.size()))
    throw InputError(source + ": malformed XML");
  const pugi::xml_node element = doc.document_element();
  Attributes a(element, source, element.name());
  PlusReconstructionConfig config;
  read_output_grid(a, &config);
  return config;
}

#endif  // SONOSLICE_HAVE_PUGIXML

}  // namespace sonoslice
