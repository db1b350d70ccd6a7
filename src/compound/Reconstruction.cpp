// The reconstruction recipe (include/sonoslice/compound/Reconstruction.h): one place that merges a
// PLUS configuration with the caller's overrides, picks the frames, fits the grid, chooses the
// output type and words the report. Built into sonoslice_io, since it reads files.
#include "sonoslice/compound/Reconstruction.h"
#include "../core/Text.h"

#include <cctype>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "PlusExact.h"
#include "sonoslice/compound/BeamGeometryFile.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/plus/FrameSelection.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice {
namespace {

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

std::string dims_text(int64_t a, int64_t b) {
  return std::to_string(a) + "x" + std::to_string(b);
}

// A calibration applies to every frame: an all-zero or degenerate one is refused, naming where it
// came from, rather than collapsing every frame onto a point (docs/compounding.md §3).
void check_image_to_probe(const Mat4& m, const std::string& name) {
  const std::string problem = transform_problem(m);
  if (!problem.empty()) throw InputError(name + ": the pixel-to-probe matrix " + problem);
}

// The default output type: the frames' own, except types the volume writers and most viewers
// handle poorly as a reconstruction (float64 is twice the memory for no gain over float32's
// precision of 8-16 bit ultrasound; int8 frames are rare and a mean needs the sign bit's range).
PixelType default_output_type(PixelType frames) {
  switch (frames) {
    case PixelType::Float64:
    case PixelType::Int8:
      return PixelType::Float32;
    case PixelType::UInt8:
    case PixelType::UInt16:
    case PixelType::Int16:
    case PixelType::UInt32:
    case PixelType::Int32:
    case PixelType::Float32:
      return frames;
  }
  return PixelType::Float32;
}

}  // namespace

std::pair<std::string, std::string> split_transform_name(const std::string& name) {
  const std::string suffix = "Transform";
  std::string n = name;
  if (n.size() > suffix.size() && n.compare(n.size() - suffix.size(), suffix.size(), suffix) == 0)
    n.resize(n.size() - suffix.size());
  return TransformRepository::split_name(n);
}

// ---- frame sources ----------------------------------------------------------------------------

FrameSource FrameSource::plus(const PlusSequence& sequence) {
  FrameSource s;
  s.kind = Kind::PlusSequence;
  s.name = sequence.path;
  s.sequence = &sequence;
  s.type = sequence.pixel_type;
  s.count = sequence.frame_count;
  s.width = sequence.width;
  s.height = sequence.height;
  return s;
}

FrameSource FrameSource::images(const Volume& frames, std::vector<Pose> probe_to_reference,
                                std::string name) {
  FrameSource s;
  s.kind = Kind::Images;
  s.name = std::move(name);
  const auto& d = frames.grid().dims;
  s.pixels = frames.data();
  s.type = frames.pixel_type();
  s.width = int(d[0]);
  s.height = int(d[1]);
  s.count = d[2];
  s.probe_to_reference = std::move(probe_to_reference);
  return s;
}

FrameSource FrameSource::beams(const void* samples, PixelType type, int64_t count,
                               const BeamGeometry& geometry, std::vector<Pose> probe_to_reference,
                               std::string name) {
  FrameSource s;
  s.kind = Kind::Beams;
  s.name = std::move(name);
  s.pixels = samples;
  s.type = type;
  s.count = count;
  s.beam_geometry = geometry;
  s.probe_to_reference = std::move(probe_to_reference);
  return s;
}

size_t FrameSource::samples_per_frame() const {
  if (kind == Kind::Beams)
    return size_t(beam_geometry.n_elevation) * size_t(beam_geometry.n_azimuth) *
           size_t(beam_geometry.n_samples);
  return size_t(width) * size_t(height);
}

int64_t FrameSource::frames_in_input() const {
  return count;
}

LoadedFrames read_frame_files(const FrameFiles& f, const ParameterNames& names) {
  const auto name = [&](const char* p) { return spelled(names, p); };
  const int inputs = !f.sequence.empty() + !f.frames.empty() + !f.beam_frames.empty();
  if (inputs != 1)
    throw InputError("give exactly one of " + name("sequence") + ", " + name("frames") + ", " +
                     name("beam_frames"));
  const auto start = std::chrono::steady_clock::now();
  LoadedFrames out;
  if (!f.sequence.empty()) {
    if (!f.poses.empty() || !f.probe.empty() || !f.beam_geometry.empty())
      throw InputError(name("sequence") + ": a PLUS sequence carries its own transforms; " +
                       name("poses") + ", " + name("probe") + " and " + name("beam_geometry") +
                       " go with " + name("frames") + " or " + name("beam_frames"));
    out.sequence = std::make_shared<PlusSequence>(read_plus_sequence(f.sequence));
    out.source = FrameSource::plus(*out.sequence);
  } else if (!f.frames.empty()) {
    if (f.poses.empty()) throw InputError(name("frames") + " needs " + name("poses"));
    // The frames' own voxel geometry is not used (the probe or image-to-probe places the
    // pixels), so they are read as any image stack: a folder of PNGs as `slice` writes it too.
    out.stack = read_image_stack(f.frames, name("frames"));
    if (const int64_t bad = out.stack.non_finite_count())
      warn(name("frames") + " '" + f.frames + "': " + std::to_string(bad) + " of " +
           std::to_string(out.stack.grid().voxel_count()) +
           " pixels are NaN or infinite; they are compounded as they are");
    std::vector<Pose> poses = read_poses(f.poses, f.world);
    out.source = FrameSource::images(out.stack, std::move(poses), f.frames);
    if (!f.probe.empty())
      out.source.probe = read_probe(f.probe, f.probe_downsampling);
    else if (f.probe_downsampling != 1)
      throw InputError(name("probe_downsampling") + " applies to " + name("probe"));
  } else {
    if (f.poses.empty() || f.beam_geometry.empty())
      throw InputError(name("beam_frames") + " needs " + name("poses") + " and " +
                       name("beam_geometry"));
    if (file_extension(f.beam_frames) != ".npy")
      throw InputError(name("beam_frames") + " '" + f.beam_frames +
                       "': expected a .npy of shape (N, n_elevation, n_azimuth, n_samples)");
    NpyArray a = read_npy(f.beam_frames);
    const auto& sh = a.shape;
    if ((sh.size() != 4 && sh.size() != 3) || a.fortran_order)
      throw InputError(name("beam_frames") + " '" + f.beam_frames +
                       "': expected a C-order array of shape (N, n_elevation, n_azimuth, "
                       "n_samples)");
    const size_t o = sh.size() == 4 ? 1 : 0;
    BeamGeometry g = read_beam_geometry(f.beam_geometry);
    g.n_elevation = int(sh[o]);
    g.n_azimuth = int(sh[o + 1]);
    g.n_samples = int(sh[o + 2]);
    g.validate(name("beam_geometry") + " '" + f.beam_geometry + "'");
    out.beam_samples = a.data;
    out.source = FrameSource::beams(a.data.get(), a.type, sh.size() == 4 ? sh[0] : 1, g,
                                    read_poses(f.poses, f.world), f.beam_frames);
  }
  if (out.source.kind != FrameSource::Kind::PlusSequence &&
      int64_t(out.source.probe_to_reference.size()) != out.source.count)
    throw InputError(name("poses") + " '" + f.poses + "' has " +
                     std::to_string(out.source.probe_to_reference.size()) + " poses but " +
                     out.source.name + " has " + std::to_string(out.source.count) + " frames");
  out.read_seconds = seconds_since(start);
  return out;
}

// ---- the recipe -------------------------------------------------------------------------------

std::string ReconstructionReport::skipped_reason() const {
  std::string out;
  if (skipped_bad_transform)
    out += std::to_string(skipped_bad_transform) + " with an invalid " + transform + " transform";
  if (skipped_unusable_transform)
    out += (out.empty() ? "" : ", ") + std::to_string(skipped_unusable_transform) +
           " whose transforms cannot place them (" + skipped_frames + ")";
  if (skipped_bad_image)
    out += (out.empty() ? "" : ", ") + std::to_string(skipped_bad_image) +
           " with an image status not OK";
  return out;
}

struct Reconstruction::Impl {
  FrameSource source;
  ParameterNames names;
  VolumeGrid grid;
  CompoundSettings settings;
  FrameClip clip;
  PixelType output_type = PixelType::UInt8;
  Device device;
  uint64_t max_memory_bytes = 0;
  ReconstructionReport report;
  std::vector<int64_t> frames;
  std::vector<Mat4> to_reference;
  std::vector<Mat4> all_to_reference;  // skip interval: every usable frame (PLUS's grid rules)
  Compounder::GridFit grid_fit = Compounder::GridFit::Round;  // PLUS's under plus_exact
  std::unique_ptr<Compounder> compounder;

  std::string name(const std::string& parameter) const { return spelled(names, parameter); }
  void resolve_settings(const PlusReconstructionConfig* config, const ReconstructionOptions& o);
  void resolve_plus_exact(const PlusReconstructionConfig* config, const ReconstructionOptions& o);
  void select_frames(const PlusReconstructionConfig* config, const ReconstructionOptions& o);
  void fit_grid(const PlusReconstructionConfig* config, const ReconstructionOptions& o,
                const std::optional<Vec3>& spacing);
  void warn_if_no_frame_reaches(const VolumeGrid& fixed) const;
  const void* frame_data(int64_t k) const {
    return source.kind == FrameSource::Kind::PlusSequence
               ? source.sequence->frame_pixels(int(k))
               : static_cast<const char*>(source.pixels) +
                     size_t(k) * source.samples_per_frame() * pixel_size(source.type);
  }
};

void Reconstruction::Impl::resolve_settings(const PlusReconstructionConfig* config,
                                            const ReconstructionOptions& o) {
  settings = config ? config->settings : CompoundSettings{};
  if (o.interpolation) settings.interpolation = *o.interpolation;
  if (o.mode) settings.mode = *o.mode;
  if (o.rejection_threshold) {
    if (std::isnan(*o.rejection_threshold))
      throw InputError(name("rejection_threshold") + ": NaN (give a number)");
    settings.rejection_threshold = *o.rejection_threshold;
  }
  if (o.hole_filling) {
    if (o.hole_filling->empty())
      throw InputError(name("hole_filling") + ": give at least one element");
    for (size_t i = 0; i < o.hole_filling->size(); ++i)
      (*o.hole_filling)[i].validate(name("hole_filling") + "[" + std::to_string(i) + "]");
    settings.hole_filling = *o.hole_filling;
    if (!o.fill_holes) settings.fill_holes = true;
  }
  if (o.fill_holes) {
    settings.fill_holes = *o.fill_holes;
    if (settings.fill_holes && settings.hole_filling.empty())
      settings.hole_filling = CompoundSettings{}.hole_filling;
  }

  clip = config ? config->clip : FrameClip{};
  if (o.clip && o.clip_rectangle)
    throw InputError("give " + name("clip") + " or " + name("clip_rectangle") + ", not both");
  if (o.clip) {
    clip = *o.clip;
    clip.validate(name("clip"));
  } else if (o.clip_rectangle) {
    const auto& r = *o.clip_rectangle;
    if (r[0] < 0 || r[1] < 0 || r[2] < 0 || r[3] < 0)
      throw InputError(name("clip_rectangle") + " " + std::to_string(r[0]) + "," +
                       std::to_string(r[1]) + "," + std::to_string(r[2]) + "," +
                       std::to_string(r[3]) + ": expected X,Y,W,H >= 0");
    clip.x = r[0];
    clip.y = r[1];
    clip.width = r[2];
    clip.height = r[3];
  } else if (source.kind == FrameSource::Kind::Images && source.probe) {
    clip.custom_mask = source.probe->mask();  // only the probe's fan goes in
  }
  if (!clip.custom_mask.empty() && source.kind == FrameSource::Kind::Images &&
      clip.custom_mask.size() != source.samples_per_frame())
    throw InputError(name(o.clip ? "clip" : "probe") + ": its mask is " +
                     (o.clip || !source.probe
                          ? std::to_string(clip.custom_mask.size()) + " pixels"
                          : dims_text(source.probe->image.width, source.probe->image.height)) +
                     ", the frames of '" + source.name + "' are " +
                     dims_text(source.width, source.height) +
                     (o.clip ? ""
                             : " (the probe the frames were sliced with, and the " +
                                   name("probe_downsampling") + " they were sliced at)"));

  if (source.kind != FrameSource::Kind::Beams && clip.custom_mask.empty())
    clip.require_pixels(source.width, source.height,
                        o.clip             ? name("clip")
                        : o.clip_rectangle ? name("clip_rectangle")
                                           : std::string("the configuration's clip rectangle"),
                        source.name);

  output_type = o.output_type ? *o.output_type : default_output_type(source.type);
  if (o.plus_exact) resolve_plus_exact(config, o);
}

// --plus-exact: PLUS's volume is in the frames' type, of 2D frames, with PLUS's clip.
void Reconstruction::Impl::resolve_plus_exact(const PlusReconstructionConfig* config,
                                              const ReconstructionOptions& o) {
  settings.plus_exact = true;
  if (source.kind == FrameSource::Kind::Beams)
    throw InputError(name("plus_exact") + ": PLUS reconstructs 2D frames, not beam-space frames");
  if (!compound_impl::plus_exact_frame_type(source.type))
    throw InputError(name("plus_exact") + ": " + source.name + " has " + to_string(source.type) +
                     " frames; PLUS-exact takes uint8, int16, uint16 or float32");
  if (o.output_type && *o.output_type != source.type)
    throw InputError(name("output_type") + " " + to_string(*o.output_type) + " with " +
                     name("plus_exact") + ": PLUS's volume is in the frames' type (" +
                     to_string(source.type) + ")");
  output_type = source.type;
  if (!clip.custom_mask.empty())
    throw InputError(name("plus_exact") + ": the probe's fan mask is not a PLUS clip; give " +
                     name("clip_rectangle") + " (or a PLUS configuration)");
  if (o.device.type != DeviceType::CPU)
    throw InputError(name("plus_exact") + " runs on the CPU, not " + o.device.to_string());
  // PLUS's insertion path: the caller's, else the configuration's Optimization, else FULL.
  if (o.plus_optimization)
    settings.plus_optimization =
        parse_plus_optimization(*o.plus_optimization, name("plus_optimization"));
  else if (config && !config->optimization.empty())
    settings.plus_optimization = parse_plus_optimization(
        config->optimization, config->path + ": VolumeReconstruction Optimization");
  else
    settings.plus_optimization = PlusOptimization::Full;
  // PLUS's grid around the frames (used when the configuration does not fix the grid).
  const std::string fit = o.plus_grid ? text::lower(*o.plus_grid) : "legacy";
  if (fit == "legacy")
    grid_fit = Compounder::GridFit::PlusLegacy;
  else if (fit == "lattice")
    grid_fit = Compounder::GridFit::PlusLattice;
  else
    throw InputError(name("plus_grid") + " \"" + *o.plus_grid + "\": not legacy or lattice");
}

FrameSelection select_frames(const FrameSource& source, const PlusReconstructionConfig* config,
                             const ReconstructionOptions& o) {
  const auto name = [&](const char* p) { return spelled(o.names, p); };
  FrameSelection out;
  ReconstructionReport& report = out.report;
  const int skip = o.skip ? *o.skip : config ? config->skip_interval : 1;
  if (skip < 1)
    throw InputError(name("skip") + " " + std::to_string(skip) +
                     ": must be >= 1 (every K-th frame)");
  report.skip = skip;
  report.frames_in_input = source.count;
  report.frames_considered = (source.count + skip - 1) / skip;

  if (source.kind == FrameSource::Kind::PlusSequence) {
    TransformRepository calibration =
        config ? config->coordinate_definitions : TransformRepository{};
    std::string from = config ? config->image_frame : "Image";
    std::string to = config ? config->reference_frame : "Reference";
    if (o.transform) std::tie(from, to) = split_transform_name(*o.transform);
    if (o.image_to_probe) {
      check_image_to_probe(*o.image_to_probe, name("image_to_probe"));
      calibration.set("Image", "Probe", *o.image_to_probe);
    }
    const std::string hint =
        config || o.image_to_probe
            ? ""
            : "; give the calibration with " + name("config") + " or " + name("image_to_probe");
    const PlusSequence& s = *source.sequence;
    const PlusFrameSelection sel = select_plus_frames(s, calibration, from, to, skip, hint);
    out.indices.assign(sel.frames.begin(), sel.frames.end());
    out.to_reference = sel.to_reference;
    if (skip > 1) {
      try {
        out.all_to_reference = select_plus_frames(s, calibration, from, to, 1, hint).to_reference;
      } catch (const InputError&) {  // only the left-out frames lack a chain: fit the used ones
      }
    }
    report.transform = from + "To" + to;
    report.skipped_bad_image = sel.bad_image;
    report.skipped_bad_transform = sel.bad_transform;
    report.skipped_unusable_transform = int64_t(sel.unusable.size());
    // The frames named, a few of them: enough to find them in the file.
    for (size_t i = 0; i < sel.unusable.size() && i < 3; ++i)
      report.skipped_frames += (i ? "; " : "") + std::string("frame ") +
                               std::to_string(sel.unusable[i].first) + ": " +
                               sel.unusable[i].second;
    if (sel.unusable.size() > 3)
      report.skipped_frames += "; " + std::to_string(sel.unusable.size() - 3) + " more";
    report.input = source.name + ": " + std::to_string(s.frame_count) + " frames of " +
                   dims_text(s.width, s.height) + " " + to_string(s.pixel_type) + " (orientation " +
                   s.orientation + ")";
  } else {
    if (o.transform)
      throw InputError(name("transform") +
                       " applies to PLUS sequences; frames with poses are placed by their poses");
    Mat4 image_to_probe;  // identity: beam-space frames' poses are probe → reference already
    if (source.kind == FrameSource::Kind::Images) {
      if (o.image_to_probe) {
        check_image_to_probe(*o.image_to_probe, name("image_to_probe"));
        image_to_probe = *o.image_to_probe;
      } else if (source.probe) {
        image_to_probe = source.probe->pixel_to_probe();
      } else
        throw InputError(source.name + ": 2D frames need the pixel-to-probe mapping (" +
                         name("image_to_probe") + " or " + name("probe") + ")");
    } else if (o.image_to_probe) {
      throw InputError(name("image_to_probe") +
                       " applies to 2D frames; beam-space frames are placed by their geometry");
    }
    if (int64_t(source.probe_to_reference.size()) != source.count)
      throw InputError(source.name + ": " + std::to_string(source.probe_to_reference.size()) +
                       " poses for " + std::to_string(source.count) + " frames");
    // Poses from files were checked when read; this names the source for in-memory ones.
    validate_poses(source.probe_to_reference.data(), source.probe_to_reference.size(), source.name,
                   0, false);
    for (int64_t k = 0; k < source.count; k += skip) {
      const Pose& p = source.probe_to_reference[size_t(k)];
      out.indices.push_back(k);
      out.to_reference.push_back(source.kind == FrameSource::Kind::Images ? p * image_to_probe : p);
    }
    report.input =
        source.kind == FrameSource::Kind::Images
            ? source.name + ": " + std::to_string(source.count) + " frames of " +
                  dims_text(source.width, source.height) + " " + to_string(source.type)
            : source.name + ": " + std::to_string(source.count) + " beam-space frames of " +
                  std::to_string(source.beam_geometry.n_elevation) + "x" +
                  dims_text(source.beam_geometry.n_azimuth, source.beam_geometry.n_samples) + " " +
                  to_string(source.type);
  }
  if (skip > 1 && source.count > 1)
    report.input += ", one frame in " + std::to_string(skip) + " used";
  report.frames_used = int64_t(out.indices.size());
  return out;
}

void Reconstruction::Impl::select_frames(const PlusReconstructionConfig* config,
                                         const ReconstructionOptions& o) {
  FrameSelection sel = sonoslice::select_frames(source, config, o);
  frames = std::move(sel.indices);
  to_reference = std::move(sel.to_reference);
  all_to_reference = std::move(sel.all_to_reference);
  report = std::move(sel.report);
  const std::string why = report.skipped_reason();
  if (!why.empty())
    warn(source.name + ": skipped " +
         std::to_string(report.frames_considered - report.frames_used) + " of " +
         std::to_string(report.frames_considered) + " frames: " + why);
  if (frames.empty())
    throw InputError(source.name + ": no frame can be used (" + (why.empty() ? "no frames" : why) +
                     ")");
}

namespace {

// The spacing: the caller's, else the configuration's OutputSpacing.
Vec3 resolve_spacing(const PlusReconstructionConfig* config, const ReconstructionOptions& o) {
  const std::optional<Vec3> spacing = o.spacing_mm ? o.spacing_mm
                                      : config     ? config->output_spacing_mm
                                                   : std::nullopt;
  if (!spacing)
    throw InputError("give " + spelled(o.names, "spacing") + " (mm) or a PLUS configuration (" +
                     spelled(o.names, "config") + ") with OutputSpacing");
  for (double s : *spacing)
    if (!(s >= kMinSpacingMm && s <= kMaxGeometryMm)) {
      std::ostringstream why;
      why << (o.spacing_mm ? spelled(o.names, "spacing") : "the configuration's OutputSpacing")
          << " " << s << " mm: expected a spacing from 1e-06 to 1e+09 mm";
      throw InputError(why.str());
    }
  return *spacing;
}

// The grid the caller (origin and extent) or the configuration (OutputOrigin/Extent, unless the
// caller chose a spacing) fixes; std::nullopt when it is to be fitted around the frames.
std::optional<VolumeGrid> fixed_grid(const PlusReconstructionConfig* config,
                                     const ReconstructionOptions& o, const Vec3& spacing) {
  if (bool(o.origin_mm) != bool(o.extent))
    throw InputError("give " + spelled(o.names, "origin_mm") + " and " +
                     spelled(o.names, "extent") + " together");
  if (o.origin_mm) {
    VolumeGrid grid;
    grid.spacing_mm = spacing;
    grid.origin_mm = *o.origin_mm;
    for (int a = 0; a < 3; ++a) grid.dims[a] = (*o.extent)[a];
    for (int a = 0; a < 3; ++a)
      if (grid.dims[a] < 1 || grid.dims[a] > (int64_t(1) << 20) ||
          !(std::fabs(grid.origin_mm[a]) <= kMaxGeometryMm))
        throw InputError(spelled(o.names, "extent") + " / " + spelled(o.names, "origin_mm") +
                         ": expected an origin within 1e9 mm and 1 to 1048576 voxels per axis");
    return grid;
  }
  return config && !o.spacing_mm ? config->output_grid() : std::nullopt;
}

}  // namespace

StreamPlan plan_stream(PixelType frame_type, int width, int height,
                       const PlusReconstructionConfig* config, const ReconstructionOptions& o) {
  Reconstruction::Impl im;
  im.source.kind = FrameSource::Kind::Images;
  im.source.name = "frames";
  im.source.type = frame_type;
  im.source.width = width;
  im.source.height = height;
  im.names = o.names;
  StreamPlan plan;
  plan.spacing_mm = resolve_spacing(config, o);
  im.resolve_settings(config, o);
  plan.settings = im.settings;
  plan.clip = im.clip;
  plan.output_type = im.output_type;
  plan.grid = fixed_grid(config, o, plan.spacing_mm);
  return plan;
}

void Reconstruction::Impl::fit_grid(const PlusReconstructionConfig* config,
                                    const ReconstructionOptions& o,
                                    const std::optional<Vec3>& spacing) {
  const std::optional<VolumeGrid> fixed = fixed_grid(config, o, *spacing);
  report.grid_from_config = fixed && !o.origin_mm;
  report.grid_given = fixed && o.origin_mm;
  if (fixed)
    grid = *fixed;
  else if (source.kind == FrameSource::Kind::Beams)
    grid = Compounder::grid_around_beams(to_reference, source.beam_geometry, *spacing);
  else
    // PLUS's rules fit the box around every usable frame, also those a skip interval leaves out
    // (vtkIGSIOVolumeReconstructor::SetOutputExtentFromFrameList walks all of them).
    grid = Compounder::grid_around(
        grid_fit != Compounder::GridFit::Round && !all_to_reference.empty() ? all_to_reference
                                                                            : to_reference,
        source.width, source.height, clip, *spacing, grid_fit);
}

// A grid that is given (flags, the configuration) and that no frame reaches gives an empty volume:
// said, with both boxes, rather than written as if it were a result.
void Reconstruction::Impl::warn_if_no_frame_reaches(const VolumeGrid& fixed) const {
  std::optional<VolumeGrid> around;
  try {
    around =
        source.kind == FrameSource::Kind::Beams
            ? Compounder::grid_around_beams(to_reference, source.beam_geometry, fixed.spacing_mm)
            : Compounder::grid_around(to_reference, source.width, source.height, clip,
                                      fixed.spacing_mm, Compounder::GridFit::Round);
  } catch (const Error&) {
    return;  // frames whose box cannot be taken: the grid is the caller's to judge
  }
  std::ostringstream why;
  why << std::fixed << std::setprecision(2);
  for (int a = 0; a < 3 && why.str().empty(); ++a) {
    const double half = fixed.spacing_mm[a] / 2;
    const double lo = fixed.origin_mm[a] - half;
    const double hi = fixed.origin_mm[a] + double(fixed.dims[a] - 1) * fixed.spacing_mm[a] + half;
    const double frames_lo = around->origin_mm[a];
    const double frames_hi = frames_lo + double(around->dims[a] - 1) * around->spacing_mm[a];
    if (frames_hi < lo || frames_lo > hi)
      why << "along "
          << "xyz"[a] << " the grid spans " << lo << " to " << hi << " mm, the frames " << frames_lo
          << " to " << frames_hi << " mm";
  }
  if (!why.str().empty())
    warn("compounding: no frame reaches the output grid (" + why.str() +
         "): the volume will be empty; check the grid's origin and extent");
}

Reconstruction::Reconstruction(const FrameSource& frames, const PlusReconstructionConfig* config,
                               const ReconstructionOptions& o)
    : impl_(std::make_unique<Impl>()) {
  Impl& im = *impl_;
  im.source = frames;
  im.names = o.names;
  im.device = o.device;
  im.max_memory_bytes = o.max_memory_bytes;
  const std::optional<Vec3> spacing = resolve_spacing(config, o);
  im.resolve_settings(config, o);
  im.select_frames(config, o);
  im.fit_grid(config, o, spacing);
  // Checks the memory (ResourceError naming a spacing that fits) before allocating anything.
  im.compounder = std::make_unique<Compounder>(im.grid, im.settings, im.device, im.max_memory_bytes,
                                               im.output_type);
  // After the checks, so that a grid refused (too large) gets its one error line only.
  if (im.report.grid_from_config || im.report.grid_given) im.warn_if_no_frame_reaches(im.grid);
}

Reconstruction::~Reconstruction() = default;
Reconstruction::Reconstruction(Reconstruction&&) noexcept = default;

const VolumeGrid& Reconstruction::grid() const {
  return impl_->grid;
}
const CompoundSettings& Reconstruction::settings() const {
  return impl_->settings;
}
const FrameClip& Reconstruction::clip() const {
  return impl_->clip;
}
PixelType Reconstruction::output_type() const {
  return impl_->output_type;
}
const Device& Reconstruction::device() const {
  return impl_->device;
}
const ReconstructionReport& Reconstruction::report() const {
  return impl_->report;
}
const std::vector<int64_t>& Reconstruction::frame_indices() const {
  return impl_->frames;
}
const std::vector<Mat4>& Reconstruction::frames_to_reference() const {
  return impl_->to_reference;
}

ReconstructionResult Reconstruction::run(bool with_weights,
                                         const std::function<void(int64_t, int64_t)>& progress) {
  Impl& im = *impl_;
  if (!im.compounder) throw Error("Reconstruction::run: already ran (build a new Reconstruction)");
  const std::unique_ptr<Compounder> compounder = std::move(im.compounder);
  const FrameSource& s = im.source;
  const size_t frame_bytes = s.samples_per_frame() * pixel_size(s.type);
  const int64_t n = int64_t(im.frames.size());
  const int64_t chunk = chunk_images(frame_bytes, n);
  const auto splat_start = std::chrono::steady_clock::now();
  // Runs of consecutive frames go in together (skipped frames break a run), at most ~64 MiB.
  for (int64_t first = 0; first < n;) {
    int64_t count = 1;
    while (first + count < n && count < chunk &&
           im.frames[size_t(first + count)] == im.frames[size_t(first)] + count)
      ++count;
    const void* data = im.frame_data(im.frames[size_t(first)]);
    if (s.kind == FrameSource::Kind::Beams)
      compounder->add_beams(data, s.type, s.beam_geometry, count, im.to_reference.data() + first);
    else
      compounder->add_images(data, s.type, s.width, s.height, count, im.to_reference.data() + first,
                             im.clip);
    first += count;
    if (progress) progress(first, n);
  }
  im.report.splat_seconds = seconds_since(splat_start);
  const auto finish_start = std::chrono::steady_clock::now();
  ReconstructionResult r;
  r.volume = compounder->volume(im.output_type);
  if (with_weights) r.weights = compounder->weights();
  im.report.finish_seconds = seconds_since(finish_start);
  return r;
}

}  // namespace sonoslice
