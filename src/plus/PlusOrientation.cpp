// Ultrasound image orientation of PLUS sequences: the flips between a file's orientation and MF.
//
// Image orientation (IGSIO, Source/IGSIOCommon/igsioVideoFrame.h and igsioVideoFrame.cxx,
// igsioVideoFrame::GetFlipAxes):
//   - the first letter names the transducer side image x points to: M = marked, U = unmarked;
//   - the second letter names where image y points: F = far (away from the transducer), N = near;
//   - an optional third letter (A = ascending, D = descending) orders the slices of 3D frames;
//     IGSIO defines MFA = MF, UFD = UF, UNA = UN, MND = MN, and a z flip of a one-slice 2D frame
//     changes nothing, so for 2D frames the third letter never moves a pixel.
//   Converting to MF: U <-> M reverses each row (hFlip, "flip x"); N <-> F reverses the order of
//   the rows (vFlip, "flip y"); UN needs both. Each flip is its own inverse, so the writer applies
//   the same flips to go from MF back to the file's orientation. The RF orientations (FM, NM, FU,
//   NU: image x along the beam) are a transpose, which PLUS reserves for RF data; we refuse them.
//   A file without the field is MF (PLUS's default for B-mode images).
#include <algorithm>
#include <string>

#include "../io/TextParse.h"
#include "PlusFormat.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace plus {

using namespace text;

Flips orientation_flips(const std::string& orientation, const std::string& where) {
  const std::string o = upper(trim(orientation));
  const bool ok = (o.size() == 2 || o.size() == 3) && (o[0] == 'M' || o[0] == 'U') &&
                  (o[1] == 'F' || o[1] == 'N') && (o.size() == 2 || o[2] == 'A' || o[2] == 'D');
  if (!ok)
    throw InputError(where + ": unsupported ultrasound image orientation " +
                     quote_value(orientation) +
                     " (accepted: MF, MN, UF, UN, optionally followed by A or D; the RF "
                     "orientations FM, FU, NM, NU are not supported)");
  return Flips{o[0] == 'U', o[1] == 'N'};
}

namespace {

template <size_t N>
void flip_frame_bytes(uint8_t* frame, int width, int height, Flips flips) {
  struct Px {
    uint8_t b[N];
  };
  Px* p = reinterpret_cast<Px*>(frame);
  const size_t w = size_t(width), h = size_t(height);
  if (flips.x)
    for (size_t y = 0; y < h; ++y) std::reverse(p + y * w, p + (y + 1) * w);
  if (flips.y)
    for (size_t y = 0; y < h / 2; ++y)
      std::swap_ranges(p + y * w, p + (y + 1) * w, p + (h - 1 - y) * w);
}

}  // namespace

void flip_frame(uint8_t* frame, int width, int height, size_t pixel_bytes, Flips flips) {
  if (!flips.x && !flips.y) return;
  switch (pixel_bytes) {
    case 1:
      return flip_frame_bytes<1>(frame, width, height, flips);
    case 2:
      return flip_frame_bytes<2>(frame, width, height, flips);
    case 4:
      return flip_frame_bytes<4>(frame, width, height, flips);
    default:
      return flip_frame_bytes<8>(frame, width, height, flips);
  }
}

}  // namespace plus
}  // namespace sonoslice
