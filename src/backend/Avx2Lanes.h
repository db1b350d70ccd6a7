#pragma once
/// @file Eight float lanes for the CPU's AVX2 fast paths: just enough vector arithmetic for the
/// shared per-element formulas (they are templates over the lane type, so float on CUDA and in
/// scalar code, Vec8f here), the gathers that load voxel pairs (slicing) and the sample loads,
/// blends and interleaved adds of the compounding splats. Only translation units built with
/// -mavx2 -mfma include this; kernels use these lanes rather than raw intrinsics.
#if !defined(__AVX2__) || !defined(__FMA__)
#error "Avx2Lanes.h needs -mavx2 -mfma"
#endif
#include <immintrin.h>

#include <cstring>

#include <cstdint>
#include <limits>
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

/// The lanes of bit mask `bits` (lanes_in_range's form) as a lane mask (all bits set).
inline Vec8f lane_mask(int bits) {
  const __m256i lane = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
  return _mm256_castsi256_ps(
      _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(bits), lane), lane));
}

/// Bit mask of the lanes whose mask byte is non-zero (eight bytes from p).
inline int lanes_set(const uint8_t* p) {
  const __m128i bytes = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(p));
  return _mm_movemask_epi8(_mm_cmpgt_epi8(bytes, _mm_setzero_si128())) & 0xff;
}

/// Lane k of b where bit k of Mask is set, of a elsewhere.
template <int Mask>
inline Vec8f blend(Vec8f a, Vec8f b) {
  return _mm256_blend_ps(a.v, b.v, Mask);
}

/// Eight consecutive samples from p, as floats (unaligned; integers converted exactly).
inline Vec8f load_as_float(const uint8_t* p) {
  return _mm256_cvtepi32_ps(
      _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p))));
}
inline Vec8f load_as_float(const uint16_t* p) {
  return _mm256_cvtepi32_ps(
      _mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p))));
}
inline Vec8f load_as_float(const int16_t* p) {
  return _mm256_cvtepi32_ps(
      _mm256_cvtepi16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p))));
}
inline Vec8f load_as_float(const float* p) {
  return _mm256_loadu_ps(p);
}

/// Adds the lanes of a and b, interleaved in pairs, to four places in memory (arrays of
/// {a, b} structs): d01 += (a0 b0 a1 b1), d23 += (a2 b2 a3 b3), d45 += (a4 b4 a5 b5),
/// d67 += (a6 b6 a7 b7). Unaligned.
inline void add_interleaved(Vec8f a, Vec8f b, float* d01, float* d23, float* d45, float* d67) {
  const __m256 lo = _mm256_unpacklo_ps(a.v, b.v);  // lanes 0 1 | 4 5
  const __m256 hi = _mm256_unpackhi_ps(a.v, b.v);  // lanes 2 3 | 6 7
  _mm_storeu_ps(d01, _mm_add_ps(_mm_loadu_ps(d01), _mm256_castps256_ps128(lo)));
  _mm_storeu_ps(d23, _mm_add_ps(_mm_loadu_ps(d23), _mm256_castps256_ps128(hi)));
  _mm_storeu_ps(d45, _mm_add_ps(_mm_loadu_ps(d45), _mm256_extractf128_ps(lo, 1)));
  _mm_storeu_ps(d67, _mm_add_ps(_mm_loadu_ps(d67), _mm256_extractf128_ps(hi, 1)));
}

/// Pairs as add_interleaved, for running maxima: the first of each pair becomes the larger of the
/// two (a > d ? a : d, as a scalar maximum writes it) and the second the sum.
inline void max_add_interleaved(Vec8f a, Vec8f b, float* d01, float* d23, float* d45, float* d67) {
  const __m256 lo = _mm256_unpacklo_ps(a.v, b.v);  // lanes 0 1 | 4 5
  const __m256 hi = _mm256_unpackhi_ps(a.v, b.v);  // lanes 2 3 | 6 7
  const auto update = [](float* d, __m128 x) {
    const __m128 old = _mm_loadu_ps(d);
    _mm_storeu_ps(d, _mm_blend_ps(_mm_max_ps(x, old), _mm_add_ps(old, x), 0xA));
  };
  update(d01, _mm256_castps256_ps128(lo));
  update(d23, _mm256_castps256_ps128(hi));
  update(d45, _mm256_extractf128_ps(lo, 1));
  update(d67, _mm256_extractf128_ps(hi, 1));
}

/// Latest mode's add_interleaved: lane k of a (value) and b (weight) goes to the pair at d_k as
/// there, but where the voxel's stamp (int32 per voxel, at the same offsets from s01 as d_k from
/// d01, in voxels) is not `frame` and b's lane is > 0, the pair is first cleared to +0 and the
/// stamp set to frame: the voxel's first write by this frame replaces older frames' samples.
SONOSLICE_INLINE void restart_add_interleaved(Vec8f a, Vec8f b, int32_t frame, float* d01,
                                              float* d23, float* d45, float* d67, int32_t* s01,
                                              int32_t* s23, int32_t* s45, int32_t* s67) {
  const auto pair = [](const int32_t* p) {
    int64_t v;
    std::memcpy(&v, p, sizeof v);
    return v;
  };
  const __m256i stamps = _mm256_setr_epi64x(pair(s01), pair(s23), pair(s45), pair(s67));
  const __m256i now = _mm256_set1_epi32(frame);
  const __m256i touched = _mm256_castps_si256(_mm256_cmp_ps(b.v, _mm256_setzero_ps(), _CMP_GT_OQ));
  const __m256i restart = _mm256_andnot_si256(_mm256_cmpeq_epi32(stamps, now), touched);
  const __m256i updated = _mm256_blendv_epi8(stamps, now, touched);
  alignas(32) int64_t out[4];
  _mm256_store_si256(reinterpret_cast<__m256i*>(out), updated);
  std::memcpy(s01, &out[0], 8);
  std::memcpy(s23, &out[1], 8);
  std::memcpy(s45, &out[2], 8);
  std::memcpy(s67, &out[3], 8);
  // Lane k's mask for both floats of pair k, in add_interleaved's unpacked order.
  const __m256 r = _mm256_castsi256_ps(restart);
  const __m256 rlo = _mm256_unpacklo_ps(r, r), rhi = _mm256_unpackhi_ps(r, r);
  const __m256 lo = _mm256_unpacklo_ps(a.v, b.v), hi = _mm256_unpackhi_ps(a.v, b.v);
  const auto update = [](float* d, __m128 x, __m128 clear) {
    _mm_storeu_ps(d, _mm_add_ps(_mm_andnot_ps(clear, _mm_loadu_ps(d)), x));
  };
  update(d01, _mm256_castps256_ps128(lo), _mm256_castps256_ps128(rlo));
  update(d23, _mm256_castps256_ps128(hi), _mm256_castps256_ps128(rhi));
  update(d45, _mm256_extractf128_ps(lo, 1), _mm256_extractf128_ps(rlo, 1));
  update(d67, _mm256_extractf128_ps(hi, 1), _mm256_extractf128_ps(rhi, 1));
}

/// a > b ? a : b per lane (NaN in b: b; in a: b).
inline Vec8f maximum(Vec8f a, Vec8f b) {
  return _mm256_max_ps(a.v, b.v);
}
/// All ones in the lanes where x >= t, zero elsewhere.
inline Vec8f lanes_at_least(Vec8f x, float t) {
  return _mm256_cmp_ps(x.v, _mm256_set1_ps(t), _CMP_GE_OQ);
}
/// a where the mask's lane is all ones, b where it is zero.
inline Vec8f select(Vec8f mask, Vec8f a, Vec8f b) {
  return _mm256_blendv_ps(b.v, a.v, mask.v);
}
inline Vec8f operator&(Vec8f a, Vec8f b) {
  return _mm256_and_ps(a.v, b.v);
}

struct Vec8i {
  __m256i v;
  void store(int32_t* p) const { _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), v); }
};
/// floor(x) for |x| < 2^31 (NaN and values beyond give INT32_MIN).
inline Vec8i floor_to_int(Vec8f x) {
  return {_mm256_cvttps_epi32(_mm256_floor_ps(x.v))};
}
/// x rounded towards zero, for |x| < 2^31 (NaN and values beyond give INT32_MIN).
inline Vec8i truncate_to_int(Vec8f x) {
  return {_mm256_cvttps_epi32(x.v)};
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

/// The lane operations the simulation's speckle crossings need (SimulateImpl.h layer_cells),
/// named as their scalar counterparts there so that one template serves both.
inline Vec8f operator/(Vec8f a, Vec8f b) {
  return _mm256_div_ps(a.v, b.v);
}
inline Vec8f abs(Vec8f a) {
  return _mm256_andnot_ps(_mm256_set1_ps(-0.0f), a.v);
}
inline Vec8f min(Vec8f a, Vec8f b) {
  return _mm256_min_ps(a.v, b.v);
}
inline Vec8f max(Vec8f a, Vec8f b) {
  return _mm256_max_ps(a.v, b.v);
}
inline Vec8f sqrt(Vec8f a) {
  return _mm256_sqrt_ps(a.v);
}
/// 1 / √x for x > 0: the 12-bit estimate and one Newton step (relative error about 1e-7).
inline Vec8f inverse_sqrt(Vec8f x) {
  const __m256 r = _mm256_rsqrt_ps(x.v);
  const __m256 half_x_r2 =
      _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(0.5f), x.v), _mm256_mul_ps(r, r));
  return _mm256_mul_ps(r, _mm256_sub_ps(_mm256_set1_ps(1.5f), half_x_r2));
}
inline Vec8i operator+(Vec8i a, Vec8i b) {
  return {_mm256_add_epi32(a.v, b.v)};
}
inline Vec8i operator*(Vec8i a, Vec8i b) {
  return {_mm256_mullo_epi32(a.v, b.v)};
}
inline Vec8i operator*(Vec8i a, int32_t b) {
  return {_mm256_mullo_epi32(a.v, _mm256_set1_epi32(b))};
}
/// Wrapping (mod 2^32) product and sum with an unsigned constant (hashes).
inline Vec8i operator*(Vec8i a, uint32_t b) {
  return {_mm256_mullo_epi32(a.v, _mm256_set1_epi32(int32_t(b)))};
}
inline Vec8i operator+(Vec8i a, uint32_t b) {
  return {_mm256_add_epi32(a.v, _mm256_set1_epi32(int32_t(b)))};
}
inline Vec8i operator^(Vec8i a, Vec8i b) {
  return {_mm256_xor_si256(a.v, b.v)};
}
inline Vec8i operator&(Vec8i a, int32_t b) {
  return {_mm256_and_si256(a.v, _mm256_set1_epi32(b))};
}
/// Logical (unsigned) right shift.
inline Vec8i shift_right(Vec8i a, int n) {
  return {_mm256_srli_epi32(a.v, n)};
}
/// table[i] for lane indices i in 0..7 (a register permute, not a gather).
inline Vec8f lookup8(const float* table, Vec8i i) {
  return _mm256_permutevar8x32_ps(_mm256_loadu_ps(table), i.v);
}
inline Vec8i load_int(const int32_t* p) {
  return {_mm256_loadu_si256(reinterpret_cast<const __m256i*>(p))};
}

inline Vec8f operator-(Vec8f a) {
  return _mm256_xor_ps(a.v, _mm256_set1_ps(-0.0f));
}
/// 2^n for integer lanes n in [−126, 127], exactly (the exponent field).
inline Vec8f exp2_of_int(Vec8i n) {
  return _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_add_epi32(n.v, _mm256_set1_epi32(127)), 23));
}
/// Masks: all bits set where the comparison holds.
inline Vec8f operator<(Vec8f a, Vec8f b) {
  return _mm256_cmp_ps(a.v, b.v, _CMP_LT_OQ);
}
inline Vec8f operator>(Vec8f a, Vec8f b) {
  return _mm256_cmp_ps(a.v, b.v, _CMP_GT_OQ);
}
inline Vec8f operator|(Vec8f a, Vec8f b) {
  return _mm256_or_ps(a.v, b.v);
}
inline Vec8f and_not(Vec8f mask, Vec8f a) {  // a where mask is clear
  return _mm256_andnot_ps(mask.v, a.v);
}
inline int lanes_of(Vec8f mask) {
  return _mm256_movemask_ps(mask.v);
}

/// Eight consecutive integer samples from p as int32 lanes (sign- or zero-extended).
inline Vec8i load_as_int(const uint8_t* p) {
  return {_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)))};
}
inline Vec8i load_as_int(const uint16_t* p) {
  return {_mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)))};
}
inline Vec8i load_as_int(const int16_t* p) {
  return {_mm256_cvtepi16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)))};
}

/// Running sums: lane k = carry + x0 + ... + xk (wrapping int32).
inline Vec8i inclusive_sums(Vec8i x, int32_t carry) {
  __m256i v = _mm256_add_epi32(x.v, _mm256_slli_si256(x.v, 4));  // per 128-bit half
  v = _mm256_add_epi32(v, _mm256_slli_si256(v, 8));
  // The low half's total (its lane 3) into every lane of the high half.
  const __m256i low_total = _mm256_permute2x128_si256(_mm256_shuffle_epi32(v, 0xff), v, 0x08);
  return {_mm256_add_epi32(_mm256_add_epi32(v, low_total), _mm256_set1_epi32(carry))};
}
inline int32_t last_lane(Vec8i x) {
  return _mm256_extract_epi32(x.v, 7);
}

/// All bits set in the lanes equal to the lane before them (lane 0: to `before`), zero elsewhere.
inline Vec8i lanes_same_as_before(Vec8i x, int32_t before) {
  const __m256i shifted = _mm256_blend_epi32(
      _mm256_permutevar8x32_epi32(x.v, _mm256_setr_epi32(0, 0, 1, 2, 3, 4, 5, 6)),
      _mm256_set1_epi32(before), 0x01);
  return {_mm256_cmpeq_epi32(x.v, shifted)};
}
/// Bit mask of the lanes that differ from the lane before them (lane 0: from `before`).
inline int lanes_changed(Vec8i x, int32_t before) {
  return _mm256_movemask_ps(_mm256_castsi256_ps(lanes_same_as_before(x, before).v)) ^ 0xff;
}

/// Transposes four vectors into eight quads: out[4l .. 4l + 3] = (a_l, b_l, c_l, d_l) for
/// lanes l = 0..7 (32 floats, unaligned).
inline void store_quads(Vec8f a, Vec8f b, Vec8f c, Vec8f d, float* out) {
  const __m256 ab_lo = _mm256_unpacklo_ps(a.v, b.v);  // a0 b0 a1 b1 | a4 b4 a5 b5
  const __m256 cd_lo = _mm256_unpacklo_ps(c.v, d.v);
  const __m256 ab_hi = _mm256_unpackhi_ps(a.v, b.v);  // a2 b2 a3 b3 | a6 b6 a7 b7
  const __m256 cd_hi = _mm256_unpackhi_ps(c.v, d.v);
  const __m256 q04 = _mm256_shuffle_ps(ab_lo, cd_lo, 0x44);  // quad 0 | quad 4
  const __m256 q15 = _mm256_shuffle_ps(ab_lo, cd_lo, 0xEE);
  const __m256 q26 = _mm256_shuffle_ps(ab_hi, cd_hi, 0x44);
  const __m256 q37 = _mm256_shuffle_ps(ab_hi, cd_hi, 0xEE);
  _mm256_storeu_ps(out, _mm256_permute2f128_ps(q04, q15, 0x20));
  _mm256_storeu_ps(out + 8, _mm256_permute2f128_ps(q26, q37, 0x20));
  _mm256_storeu_ps(out + 16, _mm256_permute2f128_ps(q04, q15, 0x31));
  _mm256_storeu_ps(out + 24, _mm256_permute2f128_ps(q26, q37, 0x31));
}
/// The quad p[0..3] in both halves.
inline Vec8f broadcast_quad(const float* p) {
  return _mm256_broadcast_ps(reinterpret_cast<const __m128*>(p));
}
/// Lanes 0-3 *lo, lanes 4-7 *hi.
inline Vec8f halves(const float* lo, const float* hi) {
  return _mm256_blend_ps(_mm256_broadcast_ss(lo), _mm256_broadcast_ss(hi), 0xF0);
}
/// Lanes 0-3 lo[0..3], lanes 4-7 hi[0..3] (two unaligned quads).
inline Vec8f quads(const float* lo, const float* hi) {
  return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(lo)), _mm_loadu_ps(hi), 1);
}
/// a·b + c, fused.
inline Vec8f fmadd(Vec8f a, Vec8f b, Vec8f c) {
  return _mm256_fmadd_ps(a.v, b.v, c.v);
}
/// The sums of the even lanes and of the odd lanes (the real and imaginary parts of four
/// interleaved complex values).
inline void sum_even_odd(Vec8f v, float& even, float& odd) {
  __m128 q = _mm_add_ps(_mm256_castps256_ps128(v.v), _mm256_extractf128_ps(v.v, 1));
  q = _mm_add_ps(q, _mm_movehl_ps(q, q));  // (0 + 2, 1 + 3, ...)
  even = _mm_cvtss_f32(q);
  odd = _mm_cvtss_f32(_mm_shuffle_ps(q, q, 1));
}

/// sum_even_odd() of eight vectors at once: lane l of `even` (`odd`) the sum of a[l]'s even (odd)
/// elements, added in the same order (a transposing reduction: 18 operations, not 8 × 6).
inline void sum_even_odd8(const Vec8f* a, Vec8f& even, Vec8f& odd) {
  __m256 c[4];  // (e0 o0 e1 o1) of a[l] | of a[l + 4], each half-sum of the two halves
  for (int l = 0; l < 4; ++l)
    c[l] = _mm256_add_ps(_mm256_permute2f128_ps(a[l].v, a[l + 4].v, 0x20),
                         _mm256_permute2f128_ps(a[l].v, a[l + 4].v, 0x31));
  even = _mm256_hadd_ps(_mm256_shuffle_ps(c[0], c[1], _MM_SHUFFLE(2, 0, 2, 0)),
                        _mm256_shuffle_ps(c[2], c[3], _MM_SHUFFLE(2, 0, 2, 0)));
  odd = _mm256_hadd_ps(_mm256_shuffle_ps(c[0], c[1], _MM_SHUFFLE(3, 1, 3, 1)),
                       _mm256_shuffle_ps(c[2], c[3], _MM_SHUFFLE(3, 1, 3, 1)));
}

/// Stores the lanes' bit patterns as floats (masks that keep_if reads back one at a time).
inline void store_mask(Vec8i mask, float* p) {
  _mm256_storeu_ps(p, _mm256_castsi256_ps(mask.v));
}
/// v where the mask `*bits` (from store_mask) is all ones, +0 where it is zero (every lane alike).
inline Vec8f keep_if(Vec8f v, const float* bits) {
  return _mm256_and_ps(v.v, _mm256_broadcast_ss(bits));
}
/// v where the mask `*bits` is all ones, `other` where it is zero (every lane alike).
inline Vec8f keep_or(Vec8f v, const float* bits, float other) {
  return _mm256_blendv_ps(_mm256_set1_ps(other), v.v, _mm256_broadcast_ss(bits));
}

/// Lanes of x where the float lane k is at least t (all bits), zero elsewhere.
inline Vec8i keep_at_least(Vec8i x, Vec8f k, float t) {
  return {_mm256_and_si256(
      x.v, _mm256_castps_si256(_mm256_cmp_ps(k.v, _mm256_set1_ps(t), _CMP_NLT_UQ)))};
}
/// 1 in the lanes where float lane k is at least t (NaN counts), 0 elsewhere.
inline Vec8i ones_at_least(Vec8f k, float t) {
  return {_mm256_srli_epi32(_mm256_castps_si256(_mm256_cmp_ps(k.v, _mm256_set1_ps(t), _CMP_NLT_UQ)),
                            31)};
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

/// The voxel at each offset of a float volume (nearest sampling).
inline Vec8f gather_float(const float* base, Vec8i i) {
  return _mm256_i32gather_ps(base, i.v, 4);
}

/// The voxel at each offset, as int32 (sign- or zero-extended), for nearest sampling of integer
/// volumes: no float round trip.
template <typename T>
inline Vec8i gather_value(const T* base, Vec8i i) {
  const __m256i p = _mm256_i32gather_epi32(reinterpret_cast<const int*>(base), i.v, int(sizeof(T)));
  constexpr int shift = 32 - 8 * int(sizeof(T));
  if (std::is_signed<T>::value) return {_mm256_srai_epi32(_mm256_slli_epi32(p, shift), shift)};
  return {_mm256_srli_epi32(_mm256_slli_epi32(p, shift), shift)};
}

/// Stores eight int32 lanes as T, saturating (the scalar saturate_cast's rule for integers).
template <typename T>
inline void store_saturated(Vec8i v, T* out);
template <>
inline void store_saturated<float>(Vec8i v, float* out) {
  _mm256_storeu_ps(out, _mm256_cvtepi32_ps(v.v));
}
template <>
inline void store_saturated<int16_t>(Vec8i v, int16_t* out) {
  // packs works per 128-bit half; the permute brings lanes 0..7 together in the low half.
  const __m256i p = _mm256_permute4x64_epi64(_mm256_packs_epi32(v.v, v.v), 0x08);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out), _mm256_castsi256_si128(p));
}
template <>
inline void store_saturated<uint16_t>(Vec8i v, uint16_t* out) {
  const __m256i p = _mm256_permute4x64_epi64(_mm256_packus_epi32(v.v, v.v), 0x08);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out), _mm256_castsi256_si128(p));
}
template <>
inline void store_saturated<uint8_t>(Vec8i v, uint8_t* out) {
  const __m256i p = _mm256_permute4x64_epi64(_mm256_packus_epi32(v.v, v.v), 0x08);
  const __m128i bytes = _mm_packus_epi16(_mm256_castsi256_si128(p), _mm256_castsi256_si128(p));
  _mm_storel_epi64(reinterpret_cast<__m128i*>(out), bytes);
}

/// Stores eight float lanes as T: float as is; integers rounded half up (floor(v + 0.5)),
/// saturated, NaN → 0, like the scalar saturate_cast.
template <typename T>
inline void store_rounded(Vec8f v, T* out) {
  if constexpr (std::is_same<T, float>::value) {
    _mm256_storeu_ps(out, v.v);
  } else {
    __m256 r = _mm256_floor_ps(_mm256_add_ps(v.v, _mm256_set1_ps(0.5f)));
    r = _mm256_max_ps(r, _mm256_set1_ps(float(std::numeric_limits<T>::lowest())));
    r = _mm256_min_ps(r, _mm256_set1_ps(float(std::numeric_limits<T>::max())));
    r = _mm256_and_ps(r, _mm256_cmp_ps(v.v, v.v, _CMP_ORD_Q));  // NaN lanes → 0
    store_saturated<T>({_mm256_cvttps_epi32(r)}, out);
  }
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
