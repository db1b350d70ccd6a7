#pragma once
/// @file Voxel and pixel types kept natively in memory (never a float copy of a CT).
#include <cstddef>
#include <cstdint>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>

namespace sonoslice {

enum class PixelType { UInt8, Int8, UInt16, Int16, UInt32, Int32, Float32, Float64 };

size_t pixel_size(PixelType type);
std::string to_string(PixelType type);                ///< "uint8", "int16", "float32", ...
PixelType parse_pixel_type(const std::string& name);  ///< inverse of to_string; InputError
/// Error("<what>: no kernel for <type> values"): a type that reached a kernel dispatch unchecked.
[[noreturn]] void throw_no_kernel(const char* what, PixelType type);

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

/// Calls f(T{}) with T the C++ type of `type`: the one switch every type-dispatching site goes
/// through (directly, or through the subset form below).
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

/// A set of pixel types, for the subset form of visit_pixel_type.
template <typename... T>
struct PixelTypes {};
/// The types the kernels are instantiated for: slicing's outputs and compounding's samples
/// (other types are converted before they reach a kernel, or refused).
using KernelPixelTypes = PixelTypes<uint8_t, int16_t, uint16_t, float>;

/// Calls f(T{}) with T the C++ type of `type` when T is one of `Ts`; otherwise throws an Error
/// that says `what` has no kernel for the type (a dispatch layer checks types before this).
template <typename... Ts, typename F>
decltype(auto) visit_pixel_type(PixelTypes<Ts...>, PixelType type, F&& f, const char* what) {
  return visit_pixel_type(
      type,
      [&](auto zero) -> decltype(f(std::declval<std::tuple_element_t<0, std::tuple<Ts...>>>())) {
        using T = decltype(zero);
        if constexpr ((std::is_same<T, Ts>::value || ...)) {
          return f(T{});
        } else {
          throw_no_kernel(what, type);
        }
      });
}

/// Calls f(i, double(value i)) for each of the `n` values of `type` at `data`, in order.
template <typename F>
void for_each_value(const void* data, PixelType type, size_t n, F&& f) {
  visit_pixel_type(type, [&](auto zero) {
    using T = decltype(zero);
    const T* p = static_cast<const T*>(data);
    for (size_t i = 0; i < n; ++i) f(i, double(p[i]));
  });
}

/// Pixels of several components (RGB or RGBA frames from a video grabber) to one intensity: the
/// first component of each of `count` pixels of `components` interleaved values, from `in` to
/// `out` (`out` may be `in`: the values move forwards). That is what PLUS's volume
/// reconstruction writes of such frames (vtkPlusVolumeReconstructor::ExtractGrayLevels keeps
/// component 0), and grey frames stored as RGB hold it in every component. Returns how many
/// pixels have colour components (the first three) that differ, for the caller to report.
int64_t first_component(const uint8_t* in, PixelType type, int64_t count, int components,
                        uint8_t* out);

}  // namespace sonoslice
