#include "sonoslice/surface/Colorize.h"

#include "../backend/ParallelFor.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

void colorize(const void* labels, PixelType type, int64_t count, int width, int height,
              const uint8_t* mask, const std::vector<std::array<uint8_t, 3>>& colors,
              uint8_t* rgb) {
  if (type != PixelType::UInt8 && type != PixelType::UInt16)
    throw InputError("colour images: labels must be uint8 or uint16");
  const size_t pixels = size_t(width) * size_t(height);
  backend::parallel_for(count, [&](int64_t n) {
    for (size_t i = 0; i < pixels; ++i) {
      const size_t at = size_t(n) * pixels + i;
      const int label = type == PixelType::UInt8 ? static_cast<const uint8_t*>(labels)[at]
                                                 : static_cast<const uint16_t*>(labels)[at];
      std::array<uint8_t, 3> c{0, 0, 0};
      if (!mask[i])
        c = {210, 210, 210};
      else if (label > 0)
        c = size_t(label) <= colors.size() ? colors[size_t(label - 1)]
                                           : std::array<uint8_t, 3>{255, 255, 255};
      uint8_t* out = rgb + 3 * at;
      out[0] = c[0];
      out[1] = c[1];
      out[2] = c[2];
    }
  });
}

}  // namespace sonoslice
