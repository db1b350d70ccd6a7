#pragma once
/// @file PLUS toolkit tracked-frame sequences (docs/conventions.md §7): .igs.mha / .seq.mha /
/// .mha, .igs.nrrd / .seq.nrrd / .nrrd; zlib/gzip-compressed or raw. Each frame's transforms
/// keep PLUS's naming (`AToB` maps coordinates in A to B); TransformRepository.h chains them.
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

class OutputSet;

/// A tracked-frame sequence with its frames converted to MF orientation.
struct PlusSequence {
  std::string path;
  int width = 0, height = 0;  ///< pixels per frame (after orientation, which keeps the size)
  int frame_count = 0;        ///< every frame in the file, valid or not
  PixelType pixel_type = PixelType::UInt8;
  /// As written in the file (e.g. "MFA", "UN"); frames are stored here flipped to MF.
  std::string orientation = "MF";
  /// frame_count × height × width pixels, row-major, frame after frame, MF orientation.
  std::vector<uint8_t> pixels;
  /// Per frame: every `Seq_FrameNNNN_<Field> = value` of the header, keyed by <Field>
  /// (e.g. "ProbeToTrackerTransform", "ProbeToTrackerTransformStatus", "ImageStatus"). NRRD
  /// sequences' `Status` is stored as "ImageStatus" (and written back as `Status`), so the fields
  /// mean the same in both formats. Frames without fields have an empty map.
  std::vector<std::map<std::string, std::string>> frame_fields;

  size_t frame_bytes() const { return size_t(width) * height * pixel_size(pixel_type); }
  const void* frame_pixels(int frame) const {
    return pixels.data() + frame_bytes() * size_t(frame);
  }
  /// False when the frame's `ImageStatus` (or NRRD `Status`) field exists and is not "OK"
  /// (case-insensitive). InputError when `frame` is out of range (as for the accessors below).
  bool image_ok(int frame) const;
  /// The names of the transforms a frame carries ("ProbeToTracker", ...).
  std::vector<std::string> transform_names(int frame) const;
  /// Frame `frame`'s `<name>Transform` (name like "ProbeToTracker"); std::nullopt when the
  /// field is missing or its `<name>TransformStatus` is present and not "OK".
  std::optional<Mat4> transform(int frame, const std::string& name) const;
  /// Seconds, from `Timestamp` (NaN when absent).
  double timestamp(int frame) const;
};

/// Reads a PLUS sequence file (the format from its content: NRRD magic or MetaImage header).
/// Errors name the file and say why: FileError when missing, not a PLUS sequence, truncated or
/// corrupt (short raw data, zlib error, wrong decompressed size); InputError for what sonoslice
/// does not support (pixel types beyond 8-64 bit scalars, big-endian data, RF orientations, 3D
/// frames, 2 or more than 4 components a pixel) and for a transform of frame N that is not 16
/// numbers; RGB and RGBA frames are read as their first component (first_component(), as PLUS's
/// reconstruction writes them), with a warning when some pixels' components differ;
/// ResourceError when the frames do not fit in memory; Error for compressed data in a build
/// without ITK/zlib (raw sequences are read in every build).
PlusSequence read_plus_sequence(const std::string& path);

/// Writes a PLUS sequence file atomically (.mha: MetaImage with `ElementDataFile = LOCAL`;
/// .nrrd: NRRD with `key:=value` fields), compressed (zlib for .mha, gzip for .nrrd) or raw.
/// The frames are written in the sequence's `orientation` (flipped back from MF). With
/// `together`, the file goes into place with that set's commit().
void write_plus_sequence(const std::string& path, const PlusSequence& sequence,
                         bool compress = true, OutputSet* together = nullptr);

/// Throws InputError naming `path` unless it ends in a sequence format write_plus_sequence
/// writes (.mha or .nrrd): for callers that write one at the end of a long run.
void check_plus_sequence_name(const std::string& path);

}  // namespace sonoslice
