#pragma once
/// @file Voxel and pixel types kept natively in memory (never a float copy of a CT).
#include <cstddef>
#include <cstdint>
#include <string>

namespace sonoslice {

enum class PixelType { UInt8, Int8, UInt16, Int16, UInt32, Int32, Float32, Float64 };

size_t pixel_size(PixelType type);
std::string to_string(PixelType type);                ///< "uint8", "int16", "float32", ...
PixelType parse_pixel_type(const std::string& name);  ///< inverse of to_string; InputError

template <typename T>
struct PixelTypeOf;
template <>
struct PixelTypeOf<uint8_t> {
  static constexpr PixelType value = PixelType::UInt8;
};
template <>
struct PixelTypeOf<int8_t> {
  static constexpr PixelType value = PixelType::Int8;
};
template <>
struct PixelTypeOf<uint16_t> {
  static constexpr PixelType value = PixelType::UInt16;
};
template <>
struct PixelTypeOf<int16_t> {
  static constexpr PixelType value = PixelType::Int16;
};
template <>
struct PixelTypeOf<uint32_t> {
  static constexpr PixelType value = PixelType::UInt32;
};
template <>
struct PixelTypeOf<int32_t> {
  static constexpr PixelType value = PixelType::Int32;
};
template <>
struct PixelTypeOf<float> {
  static constexpr PixelType value = PixelType::Float32;
};
template <>
struct PixelTypeOf<double> {
  static constexpr PixelType value = PixelType::Float64;
};

/// Calls f(T{}) with T the C++ type of `type` (one switch for every type-dispatching site).
template <typename F>
decltype(auto) visit_pixel_type(PixelType type, F&& f) {
  switch (type) {
    case PixelType::UInt8:
      return f(uint8_t{});
    case PixelType::Int8:
      return f(int8_t{});
    case PixelType::UInt16:
      return f(uint16_t{});
    case PixelType::Int16:
      return f(int16_t{});
    case PixelType::UInt32:
      return f(uint32_t{});
    case PixelType::Int32:
      return f(int32_t{});
    case PixelType::Float32:
      return f(float{});
    case PixelType::Float64:
      break;
  }
  return f(double{});
}

}  // namespace sonoslice
