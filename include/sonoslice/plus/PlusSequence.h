#pragma once
/// @file PLUS toolkit files (docs/conventions.md §7): tracked-frame sequences (.igs.mha / .seq.mha
/// / .mha, .igs.nrrd / .seq.nrrd / .nrrd; zlib/gzip-compressed or raw) and the coordinate
/// definitions of a PLUS configuration XML, with PLUS's transform naming (`AToB` maps coordinates
/// in A to B).
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/geometry/Math.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

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
/// frames, several channels) and for a transform of frame N that is not 16 numbers;
/// ResourceError when the frames do not fit in memory; Error for compressed data in a build
/// without ITK/zlib (raw sequences are read in every build).
PlusSequence read_plus_sequence(const std::string& path);

/// Writes a PLUS sequence file atomically (.mha: MetaImage with `ElementDataFile = LOCAL`;
/// .nrrd: NRRD with `key:=value` fields), compressed (zlib for .mha, gzip for .nrrd) or raw.
/// The frames are written in the sequence's `orientation` (flipped back from MF).
void write_plus_sequence(const std::string& path, const PlusSequence& sequence,
                         bool compress = true);

/// A set of named transforms (PLUS's transform repository): the configuration's
/// CoordinateDefinitions plus one frame's transforms. Any transform that is a chain of known
/// ones and their inverses can be asked for.
class TransformRepository {
 public:
  /// Adds or replaces `from`To`to` (e.g. set("Image", "Probe", m)); `valid` false records a
  /// transform whose status is not OK (a chain through it is invalid).
  void set(const std::string& from, const std::string& to, const Mat4& from_to_to,
           bool valid = true);
  /// Adds every transform of a sequence frame ("ProbeToTracker" → set("Probe", "Tracker", ...)),
  /// invalid ones marked as such.
  void set_frame(const PlusSequence& sequence, int frame);
  /// The transform from `from` to `to` through the shortest chain of known transforms;
  /// std::nullopt when a chain exists but passes through an invalid transform. Throws InputError
  /// naming both frames and the known transforms when no chain exists at all.
  std::optional<Mat4> get(const std::string& from, const std::string& to) const;
  /// Splits "ImageToReference" into {"Image", "Reference"}; InputError when not of that form.
  static std::pair<std::string, std::string> split_name(const std::string& transform_name);

 private:
  struct Entry {
    Mat4 matrix;
    bool valid;
  };
  std::map<std::pair<std::string, std::string>, Entry> transforms_;
};

/// Why `m` cannot place image pixels (or probe points) in space, "" when it can: a non-finite
/// entry, a last row other than 0 0 0 1 (an all-zero matrix), or columns 0 and 1 (the image's x
/// and y axes) that are zero or parallel, which would put a frame's pixels on a line or a point.
std::string transform_problem(const Mat4& m);

/// The frames of a sequence that go into a reconstruction, as PLUS picks them.
struct PlusFrameSelection {
  std::vector<int> frames;         ///< indices into the sequence
  std::vector<Mat4> to_reference;  ///< their `from`→`to` transforms
  int bad_image = 0;               ///< frames whose image status is not OK
  int bad_transform = 0;           ///< frames whose chain passes through an invalid transform
  /// Frames left out because their own transforms cannot place them, with the reason: no chain
  /// (a transform missing from the frame), a link that cannot be inverted, or a `from`→`to`
  /// transform with a transform_problem() (an all-zero ProbeToTracker).
  std::vector<std::pair<int, std::string>> unusable;
  /// "2 with an invalid ImageToReference transform, 1 with an image status not OK" ("" if none).
  std::string skipped_reason(const std::string& from, const std::string& to) const;
};

/// Every `skip`-th frame (0, skip, 2·skip, ...) whose image status is OK and whose `from`→`to`
/// chain, through the frame's transforms and `calibration` (e.g. a configuration's
/// CoordinateDefinitions), has no invalid link and gives a usable transform; the others are
/// counted or listed (`unusable`, with the frame). InputError (prefixed with the sequence's path
/// and the first frame, followed by `hint`) when no considered frame has a chain at all.
PlusFrameSelection select_plus_frames(const PlusSequence& sequence,
                                      const TransformRepository& calibration,
                                      const std::string& from, const std::string& to, int skip = 1,
                                      const std::string& hint = "");

}  // namespace sonoslice
