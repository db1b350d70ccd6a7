#pragma once
/// @file Colour images from label images, fan-slicer style.
#include <array>
#include <cstdint>
#include <vector>

#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

/// (count, H, W) labels (uint8 or uint16) → (count, H, W, 3) RGB: label k takes colors[k - 1],
/// 0 is black, and pixels outside the probe `mask` are grey 210 (fan-slicer's fan outline).
/// Labels beyond the table are white.
void colorize(const void* labels, PixelType type, int64_t count, int width, int height,
              const uint8_t* mask, const std::vector<std::array<uint8_t, 3>>& colors, uint8_t* rgb);

}  // namespace sonoslice
