#include "sonoslice/volume/PixelType.h"

#include <algorithm>
#include <cstring>

#include "sonoslice/core/Error.h"

namespace sonoslice {

size_t pixel_size(PixelType type) {
  return visit_pixel_type(type, [](auto zero) { return sizeof(zero); });
}

std::string to_string(PixelType type) {
  switch (type) {
    case PixelType::UInt8:
      return "uint8";
    case PixelType::Int8:
      return "int8";
    case PixelType::UInt16:
      return "uint16";
    case PixelType::Int16:
      return "int16";
    case PixelType::UInt32:
      return "uint32";
    case PixelType::Int32:
      return "int32";
    case PixelType::Float32:
      return "float32";
    case PixelType::Float64:
      return "float64";
  }
  return "unknown";
}

PixelType parse_pixel_type(const std::string& name) {
  for (PixelType t : {PixelType::UInt8, PixelType::Int8, PixelType::UInt16, PixelType::Int16,
                      PixelType::UInt32, PixelType::Int32, PixelType::Float32, PixelType::Float64})
    if (to_string(t) == name) return t;
  if (name == "float") return PixelType::Float32;
  if (name == "double") return PixelType::Float64;
  throw InputError("pixel type '" + name +
                   "': expected one of uint8, int8, uint16, int16, uint32, "
                   "int32, float32, float64");
}

void throw_no_kernel(const char* what, PixelType type) {
  throw Error(std::string(what) + ": no kernel for " + to_string(type) + " values");
}

int64_t first_component(const uint8_t* in, PixelType type, int64_t count, int components,
                        uint8_t* out) {
  const size_t size = pixel_size(type), stride = size * size_t(components);
  int64_t differing = 0;
  for (int64_t i = 0; i < count; ++i) {
    const uint8_t* pixel = in + stride * size_t(i);
    bool same = true;
    for (int c = 1; c < std::min(components, 3) && same; ++c)  // RGB; an alpha is no colour
      same = std::memcmp(pixel, pixel + size * size_t(c), size) == 0;
    differing += same ? 0 : 1;
    std::memmove(out + size * size_t(i), pixel, size);  // in place: never ahead of the reading
  }
  return differing;
}

}  // namespace sonoslice
