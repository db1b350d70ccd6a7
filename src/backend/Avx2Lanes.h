#pragma once
/// @file Eight float lanes for the CPU's AVX2 fast paths: just enough vector arithmetic for the
/// shared per-element formulas (they are templates over the lane type, so float on CUDA and in
/// scalar code, Vec8f here) plus the gathers that load voxel pairs. Only the translation unit
/// built with -mavx2 -mfma includes this.
#if !defined(__AVX2__) || !defined(__FMA__)
#error "Avx2Lanes.h needs -mavx2 -mfma"
#endif
#include <immintrin.h>

#include <cstdint>
#include <type_traits>

#include "sonoslice/backend/HostDevice.h"

namespace sonoslice {
namespace backend {
inline namespace SONOSLICE_KERNEL_ISA {

struct Vec8f {
  __m256 v;
  Vec8f() = default;
  Vec8f(__m256 x) : v(x) {}
  explicit Vec8f(float x) : v(_mm256_set1_ps(x)) {}
  static Vec8f iota(float first) {
    return _mm256_add_ps(_mm256_set1_ps(first), _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7));
  }
  void store(float* p) const { _mm256_storeu_ps(p, v); }
};
inline Vec8f operator+(Vec8f a, Vec8f b) {
  return _mm256_add_ps(a.v, b.v);
}
inline Vec8f operator-(Vec8f a, Vec8f b) {
  return _mm256_sub_ps(a.v, b.v);
}
inline Vec8f operator*(Vec8f a, Vec8f b) {
  return _mm256_mul_ps(a.v, b.v);
}
/// a + t·(b − a), the lerp every interpolation formula uses (fused on AVX2).
inline Vec8f lerp(Vec8f a, Vec8f b, Vec8f t) {
  return _mm256_fmadd_ps(t.v, _mm256_sub_ps(b.v, a.v), a.v);
}

/// Bit mask of the lanes with lo <= x < hi.
inline int lanes_in_range(Vec8f x, float lo, float hi) {
  const __m256 ge = _mm256_cmp_ps(x.v, _mm256_set1_ps(lo), _CMP_GE_OQ);
  const __m256 lt = _mm256_cmp_ps(x.v, _mm256_set1_ps(hi), _CMP_LT_OQ);
  return _mm256_movemask_ps(_mm256_and_ps(ge, lt));
}

/// Bit mask of the lanes whose mask byte is non-zero (eight bytes from p).
inline int lanes_set(const uint8_t* p) {
  const __m128i bytes = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(p));
  return _mm_movemask_epi8(_mm_cmpgt_epi8(bytes, _mm_setzero_si128())) & 0xff;
}

struct Vec8i {
  __m256i v;
};
inline Vec8i floor_to_int(Vec8f x) {
  return {_mm256_cvttps_epi32(_mm256_floor_ps(x.v))};
}
inline Vec8f to_float(Vec8i i) {
  return _mm256_cvtepi32_ps(i.v);
}
/// z·sz + y·sy + x, in elements (the caller guarantees it fits in int32).
inline Vec8i offsets(Vec8i x, Vec8i y, Vec8i z, int32_t sy, int32_t sz) {
  return {_mm256_add_epi32(_mm256_add_epi32(_mm256_mullo_epi32(z.v, _mm256_set1_epi32(sz)),
                                            _mm256_mullo_epi32(y.v, _mm256_set1_epi32(sy))),
                           x.v)};
}
inline Vec8i operator+(Vec8i a, int32_t b) {
  return {_mm256_add_epi32(a.v, _mm256_set1_epi32(b))};
}

/// Loads voxel[i] and voxel[i + 1] for the eight offsets i (both must be inside the buffer, and
/// for types narrower than 4 bytes so must the bytes up to voxel[i] + 4). Narrow types load a
/// pair with one 32-bit gather, which is why int16 volumes slice faster than float ones.
template <typename T>
inline void gather_pair(const T* base, Vec8i i, Vec8f& lo, Vec8f& hi);

template <>
inline void gather_pair<float>(const float* base, Vec8i i, Vec8f& lo, Vec8f& hi) {
  lo = _mm256_i32gather_ps(base, i.v, 4);
  hi = _mm256_i32gather_ps(base + 1, i.v, 4);
}
template <>
inline void gather_pair<int16_t>(const int16_t* base, Vec8i i, Vec8f& lo, Vec8f& hi) {
  const __m256i p = _mm256_i32gather_epi32(reinterpret_cast<const int*>(base), i.v, 2);
  lo = _mm256_cvtepi32_ps(_mm256_srai_epi32(_mm256_slli_epi32(p, 16), 16));
  hi = _mm256_cvtepi32_ps(_mm256_srai_epi32(p, 16));
}
template <>
inline void gather_pair<uint16_t>(const uint16_t* base, Vec8i i, Vec8f& lo, Vec8f& hi) {
  const __m256i p = _mm256_i32gather_epi32(reinterpret_cast<const int*>(base), i.v, 2);
  lo = _mm256_cvtepi32_ps(_mm256_and_si256(p, _mm256_set1_epi32(0xffff)));
  hi = _mm256_cvtepi32_ps(_mm256_srli_epi32(p, 16));
}
template <>
inline void gather_pair<uint8_t>(const uint8_t* base, Vec8i i, Vec8f& lo, Vec8f& hi) {
  const __m256i p = _mm256_i32gather_epi32(reinterpret_cast<const int*>(base), i.v, 1);
  lo = _mm256_cvtepi32_ps(_mm256_and_si256(p, _mm256_set1_epi32(0xff)));
  hi = _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32(p, 8), _mm256_set1_epi32(0xff)));
}
template <>
inline void gather_pair<int8_t>(const int8_t* base, Vec8i i, Vec8f& lo, Vec8f& hi) {
  const __m256i p = _mm256_i32gather_epi32(reinterpret_cast<const int*>(base), i.v, 1);
  lo = _mm256_cvtepi32_ps(_mm256_srai_epi32(_mm256_slli_epi32(p, 24), 24));
  hi = _mm256_cvtepi32_ps(_mm256_srai_epi32(_mm256_slli_epi32(p, 16), 24));
}

/// Which voxel types have an AVX2 pair gather (others take the scalar path).
template <typename T>
struct has_gather_pair {
  static constexpr bool value = std::is_same<T, float>::value || std::is_same<T, int16_t>::value ||
                                std::is_same<T, uint16_t>::value ||
                                std::is_same<T, uint8_t>::value || std::is_same<T, int8_t>::value;
};

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace backend
}  // namespace sonoslice
