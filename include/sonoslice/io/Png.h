#pragma once
/// @file PNG images in memory through libpng (dataset shards' members: docs/datasets.md). Files
/// are written by the stack and volume writers.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

/// True when this build reads and writes PNGs (libpng was found).
bool built_with_png();

/// A width×height image (rows top to bottom, `components` = 1 grey or 3 RGB, uint8 or uint16
/// samples in native byte order) as PNG bytes; `spacing_mm` goes into the sCAL chunk as ITK
/// writes it. Deterministic: the same pixels give the same bytes.
std::vector<uint8_t> encode_png(const void* pixels, PixelType type, int width, int height,
                                int components, const double spacing_mm[2]);

/// A decoded PNG: grey or RGB, 8 or 16 bits (16-bit samples in native byte order).
struct DecodedPng {
  int width = 0, height = 0, components = 1, bit_depth = 8;
  std::vector<uint8_t> pixels;
  double spacing_mm[2] = {1, 1};  ///< the sCAL chunk's values (ITK's convention), else 1
};
/// Decodes PNG bytes (palette and grey-alpha images are refused: no sonoslice writes them);
/// InputError naming `what` for bytes that are not a PNG it can read.
DecodedPng decode_png(const uint8_t* data, size_t size, const std::string& what);

}  // namespace sonoslice
