#pragma once
// Internal: what the PLUS sequence files share (reader, writer, accessors, transform repository).
#include <cstddef>
#include <cstdint>
#include <map>
#include <string>

#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/volume/PixelType.h"

#ifdef SONOSLICE_HAVE_ITK  // ITK builds find and link zlib (src/CMakeLists.txt)
#define SONOSLICE_PLUS_HAVE_ZLIB 1
#endif

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "PLUS sequence I/O assumes a little-endian host"
#endif

namespace sonoslice {
namespace plus {

/// The size of zlib's input and output buffers.
constexpr size_t kChunk = size_t(1) << 20;

/// "0012": the frame number of `Seq_Frame0012_<Field>`.
std::string frame_label(int frame);

/// A frame's fields (InputError when `frame` is out of range).
const std::map<std::string, std::string>& fields_of(const PlusSequence& seq, int frame);

/// The reversals that take a frame from a file's orientation to MF, and back (each is its own
/// inverse); PlusOrientation.cpp.
struct Flips {
  bool x = false, y = false;
};
/// InputError naming `where` for an orientation sonoslice does not read (the RF ones).
Flips orientation_flips(const std::string& orientation, const std::string& where);
/// Applies `flips` in place to one width × height frame of `pixel_bytes`-byte pixels.
void flip_frame(uint8_t* frame, int width, int height, size_t pixel_bytes, Flips flips);

/// Pixel type names (PlusPixelTypes.cpp): MetaImage's ElementType and NRRD's type field.
PixelType meta_pixel_type(const std::string& name, const std::string& where);
std::string meta_type_name(PixelType t);
PixelType nrrd_pixel_type(const std::string& name, const std::string& where);
std::string nrrd_type_name(PixelType t);

}  // namespace plus
}  // namespace sonoslice
