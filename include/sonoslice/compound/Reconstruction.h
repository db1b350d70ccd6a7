#pragma once
/// @file The reconstruction recipe: tracked frames + an optional PLUS configuration + the
/// caller's overrides → the output grid, the settings, the output type, a report, and the volume.
/// `sonoslice compound` and Python's `reconstruct_plus` are thin callers of this one recipe, so
/// they cannot drift apart (docs/compounding.md describes the rules for users).
///
/// Three steps, each usable alone:
///   1. FrameSource: views of the frames (a PLUS sequence, a stack of 2D frames with poses, or
///      3-D beam-space frames with poses); `read_frame_files` reads them from files.
///   2. Reconstruction(frames, config, options): resolves every setting (options win over the
///      configuration, which wins over the defaults), picks the frames and their transforms,
///      fits the grid and checks the memory, without allocating the volume.
///   3. run(): inserts the frames in batches and finishes the volume (and weights).
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/core/Error.h"  // ParameterNames: the CLI says "--spacing", Python "spacing"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

struct PlusSequence;
struct PlusReconstructionConfig;
struct StreamPlan;

/// Tracked frames, as views: the memory belongs to the caller and must outlive the
/// Reconstruction built from it.
struct FrameSource {
  enum class Kind {
    PlusSequence,  ///< frames and per-frame transforms of a PLUS sequence
    Images,        ///< `count` 2D frames (H×W, row-major) stored one after the other
    Beams          ///< `count` beam-space frames (n_elevation, n_azimuth, n_samples) likewise
  };
  Kind kind = Kind::Images;
  std::string name;                        ///< for messages and the report: a path, or "frames"
  const PlusSequence* sequence = nullptr;  ///< Kind::PlusSequence
  const void* pixels = nullptr;            ///< Images / Beams
  PixelType type = PixelType::UInt8;
  int64_t count = 0;
  int width = 0, height = 0;             ///< Images
  BeamGeometry beam_geometry;            ///< Beams, with n_elevation, n_azimuth, n_samples set
  std::vector<Pose> probe_to_reference;  ///< Images / Beams: one pose per frame (LPS)
  /// Images: the probe the frames were sliced with (its image grid gives pixel → probe mm, its
  /// fan the default clip); otherwise ReconstructionOptions::image_to_probe is needed.
  std::optional<ProbeGeometry> probe;

  static FrameSource plus(const PlusSequence& sequence);
  /// `frames`: a W×H×N volume (voxel (u, v, n) = pixel (u, v) of frame n), one pose per frame.
  static FrameSource images(const Volume& frames, std::vector<Pose> probe_to_reference,
                            std::string name = "frames");
  static FrameSource beams(const void* samples, PixelType type, int64_t count,
                           const BeamGeometry& geometry, std::vector<Pose> probe_to_reference,
                           std::string name = "frames");

  size_t samples_per_frame() const;
  int64_t frames_in_input() const;
};

/// Frame files as `sonoslice compound` takes them: exactly one of `sequence`, `frames` (with
/// `poses` and a `probe` or an image_to_probe option) or `beam_frames` (with `poses` and
/// `beam_geometry`).
struct FrameFiles {
  std::string sequence;        ///< PLUS sequence (.igs.mha, .seq.mha, .mha, .igs.nrrd, .nrrd)
  std::string frames;          ///< 2D frames: .nii/.mha/.nrrd (W×H×N) or .npy (N, H, W)
  std::string poses;           ///< probe → reference poses, one per frame
  std::string probe;           ///< the probe JSON or fan-slicer config the frames were made with
  int probe_downsampling = 1;  ///< the downsampling they were made at (`slice --downsampling`)
  std::string beam_frames;     ///< .npy (N, n_elevation, n_azimuth, n_samples)
  std::string beam_geometry;   ///< its geometry JSON
  WorldFrame world = WorldFrame::LPS;  ///< the frame `poses` are given in
};

/// Frames read from files, owning their memory; `source` views it.
struct LoadedFrames {
  FrameSource source;
  std::shared_ptr<const PlusSequence> sequence;
  Volume stack;
  std::shared_ptr<void> beam_samples;
  double read_seconds = 0;
};

/// Reads `files` (errors name the parameters as `names` spells them).
LoadedFrames read_frame_files(const FrameFiles& files, const ParameterNames& names = {});

/// What the caller sets; anything left unset comes from the PLUS configuration, else the
/// default named here.
struct ReconstructionOptions {
  /// Voxel size (mm). Default: the configuration's OutputSpacing; required without one. Giving
  /// it also drops the configuration's OutputOrigin/OutputExtent (the grid is fitted instead).
  std::optional<Vec3> spacing_mm;
  /// The grid itself, axes parallel to the reference frame: voxel (0,0,0)'s centre (mm) and the
  /// voxels per axis; both or neither. They replace the configuration's OutputOrigin/OutputExtent
  /// and the grid fitted around the frames.
  std::optional<Vec3> origin_mm;
  std::optional<std::array<int64_t, 3>> extent;
  std::optional<Interpolation> interpolation;  ///< default: the configuration's, else linear
  std::optional<CompoundingMode> mode;         ///< default: the configuration's, else mean
  /// Default: the configuration's; true when `hole_filling` is given; else false.
  std::optional<bool> fill_holes;
  /// Default: the configuration's elements, else one Gaussian 3³ (CompoundSettings).
  std::optional<std::vector<HoleFillingKernel>> hole_filling;
  std::optional<double> rejection_threshold;  ///< samples below it are not inserted
  /// Which pixels of a 2D frame go in, replacing the configuration's clip (and a probe's fan).
  std::optional<FrameClip> clip;
  /// Only the clip rectangle (x, y, width, height), keeping the configuration's fan.
  std::optional<std::array<int, 4>> clip_rectangle;
  std::optional<int> skip;  ///< every skip-th frame; default the configuration's SkipInterval, 1
  /// PLUS sequences: the transform to reconstruct with, e.g. "ImageToTracker" (a trailing
  /// "Transform" is allowed). Default: the configuration's ImageToReference.
  std::optional<std::string> transform;
  /// PLUS sequences: the calibration (pixel → probe mm), replacing the configuration's
  /// ImageToProbe. 2D frame stacks: pixel → probe mm, replacing the probe's image grid.
  std::optional<Mat4> image_to_probe;
  /// Default: the frames' type, except float64 and int8 frames, which give float32.
  std::optional<PixelType> output_type;
  /// PLUS's arithmetic bit for bit (CompoundSettings::plus_exact, docs/compounding.md §4b): 2D
  /// frames of uint8/int16/uint16/float32, output in the frames' type, on the CPU.
  bool plus_exact = false;
  /// With plus_exact: PLUS's insertion path ("none", "partial" or "full", any case). Default:
  /// the configuration's Optimization attribute, else FULL (PLUS's default).
  std::optional<std::string> plus_optimization;
  /// With plus_exact, how PLUS fits the grid around the frames when the configuration does not
  /// fix it: "legacy" (default; PLUS 2.x, as its NWire reference: origin at the corners'
  /// minimum, int((max - min) / spacing) + 1 voxels) or "lattice" (current PLUS/IGSIO: origin on
  /// a multiple of the spacing, ceil). Compounder::GridFit.
  std::optional<std::string> plus_grid;
  Device device = Device::cpu();
  uint64_t max_memory_bytes = 0;  ///< 0: what the machine has
  ParameterNames names;           ///< spelling of parameters in messages (default: as above)
};

/// What a reconstruction used and did.
struct ReconstructionReport {
  std::string input;              ///< "<name>: 97 frames of 820x616 uint8 (orientation MF)"
  int64_t frames_in_input = 0;    ///< every frame, valid or not
  int64_t frames_considered = 0;  ///< after the skip interval
  int64_t frames_used = 0;
  int64_t skipped_bad_image = 0;      ///< image status not OK (PLUS)
  int64_t skipped_bad_transform = 0;  ///< transform chain through an invalid link (PLUS)
  /// PLUS frames whose own transforms cannot place them: one missing, not invertible, or a
  /// result that is all zero, non-finite or collapses the image axes (docs/compounding.md §3).
  int64_t skipped_unusable_transform = 0;
  std::string skipped_frames;  ///< the first of those, named: "frame 5: its ImageToReference ..."
  int skip = 1;
  std::string transform;          ///< PLUS: "ImageToReference"; others: ""
  bool grid_from_config = false;  ///< the configuration's OutputOrigin/Extent, not fitted
  bool grid_given = false;        ///< the options' origin and extent, not fitted
  /// "2 with an invalid ImageToReference transform, 1 with an image status not OK" ("" if none).
  std::string skipped_reason() const;
  double splat_seconds = 0, finish_seconds = 0;  ///< filled by run()
};

/// The frames a reconstruction uses, and why the others are left out.
struct FrameSelection {
  std::vector<int64_t> indices;    ///< frames of the source, in order
  std::vector<Mat4> to_reference;  ///< per frame: image (beams: probe) → reference mm
  /// PLUS sequences with a skip interval: the transforms of every usable frame, also those the
  /// interval leaves out (PLUS fits its output box around all of them; `--plus-exact` does too).
  std::vector<Mat4> all_to_reference;
  ReconstructionReport report;  ///< input, counts and the transform (no timings)
};

/// Step 2a alone: every skip-th frame whose image status is OK and whose transform chain (PLUS:
/// the frame's transforms, the configuration's CoordinateDefinitions and image_to_probe) is
/// valid, with its transform; 2D frame stacks: pose · image_to_probe (or the probe's grid).
/// Uses only the frame-related options (skip, transform, image_to_probe). Warns of nothing and
/// may return no frame; InputError (naming parameters) when no transform chain exists at all.
FrameSelection select_frames(const FrameSource& frames, const PlusReconstructionConfig* config,
                             const ReconstructionOptions& options);

struct ReconstructionResult {
  Volume volume;   ///< in output_type()
  Volume weights;  ///< float32 splat weights, when asked for (else empty)
};

/// One reconstruction, resolved. Warns (sonoslice::warn) once when frames are skipped; throws
/// InputError naming the parameter for contradictory or bad settings, and when no frame can be
/// used; ResourceError (with a spacing that fits) when the grid does not fit in memory.
class Reconstruction {
 public:
  Reconstruction(const FrameSource& frames, const PlusReconstructionConfig* config,
                 const ReconstructionOptions& options);
  ~Reconstruction();
  Reconstruction(Reconstruction&&) noexcept;

  const VolumeGrid& grid() const;
  const CompoundSettings& settings() const;
  const FrameClip& clip() const;
  PixelType output_type() const;
  const Device& device() const;
  const ReconstructionReport& report() const;
  /// Per frame used: the frame's index in the source and its image (beams: probe) → reference.
  const std::vector<int64_t>& frame_indices() const;
  const std::vector<Mat4>& frames_to_reference() const;

  /// Inserts every frame (in batches of about 64 MiB; `progress(done, total)` after each) and
  /// finishes the volume. Runs once; a second call throws.
  ReconstructionResult run(bool with_weights = false,
                           const std::function<void(int64_t, int64_t)>& progress = {});

 private:
  friend StreamPlan plan_stream(PixelType, int, int, const PlusReconstructionConfig*,
                                const ReconstructionOptions&);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// What a reconstruction of 2D frames arriving one at a time (live, docs/live.md) uses, resolved
/// by the same rules as Reconstruction from the first frame's type and size: the settings, the
/// clip, the output type, the spacing, and the grid when the options or the configuration fix it
/// (std::nullopt: the caller grows one around the frames).
struct StreamPlan {
  CompoundSettings settings;
  FrameClip clip;
  PixelType output_type = PixelType::UInt8;
  Vec3 spacing_mm{{1, 1, 1}};
  std::optional<VolumeGrid> grid;
};
StreamPlan plan_stream(PixelType frame_type, int width, int height,
                       const PlusReconstructionConfig* config,
                       const ReconstructionOptions& options);

/// The transform name `name` (e.g. "ImageToReference" or "ImageToReferenceTransform") split into
/// its frames ("Image", "Reference"); InputError otherwise.
std::pair<std::string, std::string> split_transform_name(const std::string& name);

}  // namespace sonoslice
