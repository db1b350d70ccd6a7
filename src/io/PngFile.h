#pragma once
// Internal: PNG images written with libpng directly, so that every write error (a full disk, a
// file-size limit) comes back as a FileError rather than a crash inside a library that does not
// check its writes (ITK's 2-D writer crashed on a full disk).
#include <cstdint>
#include <string>
#include <vector>

#include "sonoslice/io/Png.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

/// Encodes a width×height image (rows top to bottom, `components` = 1 grey or 3 RGB, uint8 or
/// uint16 samples in native byte order) into `fd`, which must be open for writing and empty.
/// `spacing_mm` goes into the sCAL chunk as ITK writes it, so readers get the spacing back.
/// FileError naming `path` when encoding or writing fails.
void write_png(int fd, const std::string& path, const void* pixels, PixelType type, int width,
               int height, int components, const double spacing_mm[2]);

/// A PNG file of any layout (grey, grey+alpha, RGB, RGBA; palettes expanded to RGB, transparency
/// to alpha, 1- to 4-bit grey to 8 bits, interlacing undone), through libpng with its errors
/// caught: FileError naming the file for a corrupt one. (ITK's PNG reader lets libpng abort the
/// process on a corrupt header.)
DecodedPng read_png_file(const std::string& path);

}  // namespace sonoslice
