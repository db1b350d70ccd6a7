#pragma once
/// @file The simulation kernel (docs/simulation.md): per image, four stages over independent
/// items, each a SONOSLICE_HOST_DEVICE function of one item:
///   1. trace_beam(b):        properties, interfaces and attenuation along beam b;
///      add_speckle(b):       the speckle along it (a layered line integral across the slice);
///   2. filter_axial(b):      the axial point-spread function along beam b;
///      filter_lateral(b):    the lateral point-spread function across the beams, into beam b;
///   3. tgc_knot(k):          time-gain compensation: the median loss across the beams at
///      tgc_level(s):         every kTgcStride-th sample, and the level of each sample;
///   4. scan_pixel(i):        scan conversion, envelope and log compression of pixel i.
/// Plain structs and pointers, no allocation. The CPU driver (SimulateDriverCPU.h) runs the
/// stages of one image on one thread, in a fixed order, so the bytes do not depend on the thread
/// count; the CUDA driver (SimulateDriverCUDA.cuh) launches each stage over (image, item).
/// Single precision throughout: the speckle is noise with a fixed seed, and float halves the
/// memory traffic of the beam buffers.
#include <cmath>
#include <cstdint>
#include <cstring>

#include "../geometry/Sampling.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/geometry/VolumeGrid.h"
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
#include "../backend/Avx2Lanes.h"
#endif

namespace sonoslice {
namespace simulate_impl {

/// Lateral filter taps each side: at most this many (σ is at most kMaxLateralRadius / 3 beams).
constexpr int kMaxLateralRadius = 24;

/// Intensity reflections at or below this (−50 dB) over a step of λ/4 are not interfaces: the
/// small impedance steps of CT noise and texture neither echo nor dim the beam. A ramp's
/// reflection per step grows as the step squared, so the threshold is scaled by (Δ / (λ/4))²
/// (ImageModel::min_reflection): the same ramps are interfaces at any step.
constexpr float kMinReflection = 1e-5f;

/// Acoustic properties at a point (the kernel's float copy of a Tissue).
struct Props {
  float z, alpha, scatter;
};

/// The speckle table: kSpeckleNodes complex nodes, standard complex Gaussian, stored as int16
/// (re, im) pairs at kSpeckleScale per unit (a quantisation step of 1.7e-4 σ: 256 KB, so it stays
/// in a core's L2 cache), followed by its first kSpecklePad nodes again, so that the four nodes of
/// a cell, r, r + 1, r + W and r + W + 1, never wrap. docs/simulation.md §3.
constexpr int kSpeckleBits = 16;
constexpr int32_t kSpeckleNodes = int32_t(1) << kSpeckleBits;
constexpr int32_t kSpeckleMask = kSpeckleNodes - 1;
/// A layer's nodes are the table read as rows of W nodes (node (i, j) at i + W·j + offset, modulo
/// the table), W one of eight odd widths 255, 257, ..., 269 picked per layer. Each width's rows
/// wrap into a 2-D lattice whose shortest period is at least 252 nodes (a spectral test over the
/// table size), so no layer repeats within an image along any axis; layers of different widths
/// repeat along different vectors, so their sum does not repeat at all.
constexpr int32_t kRowWidthBase = 255, kRowWidthStep = 2;
constexpr int32_t kSpecklePad = kRowWidthBase + 7 * kRowWidthStep + 2;
constexpr float kSpeckleScale = 8192.f;
/// Layer families blended at one pose (one per lattice axis), and crossings of the slice
/// thickness summed per family (a thicker slice takes every stride-th layer).
constexpr int kMaxFields = 3;
constexpr int kMaxLayers = 12;
/// Residual-smoothing levels the lateral speckle filter is tabulated for (set per pose).
constexpr int kResidualLevels = 16;

/// One family of speckle layers at one pose: the planes of constant lattice coordinate `axis`,
/// crossed by the elevation line of every sample. docs/simulation.md §3.
struct LayerField {
  int axis = 2;
  int layers = 0;    // crossings evaluated per sample
  int stride = 1;    // only layers k ≡ 0 (mod stride)
  float weight = 0;  // the family's amplitude in the blend (Σ weight² = 1)
  float e[3];        // the elevation direction, lattice units per mm
  float inverse_e;   // 1 / e[axis]
  float reach;       // T·|e[axis]|: the slice thickness's half-width in layers
  uint32_t seed;     // the layers' hash seed
};

/// One pixel's place in the (beam, sample) grid: the beam-buffer index of its lower corner,
/// its sample, the steps to the upper corners (bit 0: next beam, bit 1: next sample) and the
/// weights, and the pixel. The CPU driver reads them in beam order from one array.
struct ScanEntry {
  int32_t pixel, index, sample;
  float tb, ts;
  uint8_t steps;
};

/// Everything one image needs, in the probe frame (mm) and the volume's continuous index.
struct ImageModel {
  // Volume: HU (float, trilinear) or labels (uint16, nearest) → Props.
  const float* hu = nullptr;           // HU source: voxel values as float, or ...
  const int16_t* hu16 = nullptr;       // ... as int16 (a CT's usual type, read in place)
  const uint16_t* labels = nullptr;    // label source
  const Props* label_props = nullptr;  // label → props (65536 entries)
  const Props* hu_table = nullptr;     // HU source: props at integer HU from hu_min
  int hu_min = -1024, hu_count = 0;
  geometry::VolumeView grid;
  Props outside{1.48f, 0.0022f, 0.f};  // outside the volume: water (no echo, no loss)
  // Probe point p (mm) → continuous index: A·p + a (row-major A). Set per pose.
  float A[9], a[3];
  // Probe point p (mm) → speckle lattice coordinate, shifted by lattice_offset so that the
  // volume and the slice thickness around it have coordinates in [0, lattice_count - 1): Q·p + q.
  // Set per pose from A, a and the lattice per index.
  float Q[9], q[3];
  double lattice_per_index[3];       // lattice coordinate per index step, along each axis
  float lattice_offset = 0;          // the shift above
  int lattice_count = 0;             // lattice coordinates are clamped to [0, lattice_count − 2]
  const int16_t* speckle = nullptr;  // the speckle table (kSpeckleNodes + kSpecklePad nodes)
  uint32_t layer_seed[3] = {0, 0, 0};  // per lattice axis: its layers' hash seed
  // The slice thickness: the elevation profile's half-width T = 1.5σ (mm); per pose, the layer
  // families blended (set_pose).
  float elevation_reach_mm = 0;
  int fields = 0;
  LayerField field[kMaxFields];
  float turn_cos[8], turn_sin[8];  // kLayerCos, kLayerSin (a copy the GPU can read)
  // Beams: curvilinear (angles about the apex) or linear (parallel, along +y).
  bool curvilinear = false;
  int beams = 0, samples = 0;
  float step_mm = 0;                      // axial sample step Δ
  float gradient_mm = 1;                  // half-width of the impedance gradient's differences
  int gradient_reuse = 0;                 // samples along an interface that reuse its normal
  float min_reflection = kMinReflection;  // kMinReflection at this step
  double beam0 = 0, beam_step = 0;        // first beam's angle (rad) or x (mm), and the step
  double start = 0;                       // first sample: radius R (curvilinear) or face y (linear)
  double apex_y = 0;                      // curvilinear
  float frequency_mhz = 5;
  double wavelength_mm = 0.308;  // λ: the lattice step
  // The PSF (docs/simulation.md §3). Specular echoes get it whole: axial taps (peak 1) and, per
  // depth s, lateral taps −kMaxLateralRadius..kMaxLateralRadius stored [tap][s] (sum 1). The
  // speckle gets what the layers' own in-plane smoothing leaves to add, and that depends on the
  // pose: its axial taps are made per beam (filter_axial_speckle), its lateral taps are
  // tabulated for kResidualLevels levels of that smoothing ([level][tap][s]) and picked per pose.
  float axial_variance_mm2 = 0;  // the PSF's axial σ²
  float layer_variance_mm2 = 0;  // a layer's bilinear smoothing along a lattice axis: λ²/6
  const float* axial_specular = nullptr;
  int axial_specular_radius = 0;
  const float* lateral_speckle =
      nullptr;  // kResidualLevels × (2·kMaxLateralRadius + 1) × 2·samples
  const float* lateral_specular = nullptr;  // (2·kMaxLateralRadius + 1) × samples
  // Per table and tap: the samples [first, last) where its weight is not zero.
  const int32_t* lateral_speckle_range = nullptr;   // kResidualLevels × taps × 2
  const int32_t* lateral_specular_range = nullptr;  // taps × 2
  int lateral_radius = 0;                           // taps used each side (≤ kMaxLateralRadius)
  // Makes a tissue's mean speckle envelope its scatter_mean (Simulator calibrates it).
  float speckle_gain = 1;
  bool tgc_auto = true, bmode = true;
  float grey_per_db = 255.0f / 60;  // log compression: 255 / the dynamic range (dB)
  // Output grid and scan conversion: for pixel i inside the mask, the beam-buffer index of its
  // lower (beam, sample) corner, the steps to the upper ones, and the weights.
  int width = 0, height = 0;
  const uint8_t* mask = nullptr;
  const int32_t* scan_index = nullptr;   // b0·samples + s0, per pixel
  const int32_t* scan_sample = nullptr;  // s0, per pixel (a division less per pixel)
  const uint8_t* scan_steps = nullptr;   // bit 0: b1 = b0 + 1; bit 1: s1 = s0 + 1
  const float* scan_weights = nullptr;   // (tb, ts) per pixel
  // The pixels inside the mask in the order of their beam-buffer index, with their scan
  // conversion (the CPU driver converts them in that order: the echo is read along the beams,
  // not a beam per pixel, and the entries from one array).
  const ScanEntry* scan_order = nullptr;
  int64_t scan_count = 0;
};

// The functions below are compiled once per instruction set (generic, AVX2 + FMA, CUDA).
inline namespace SONOSLICE_KERNEL_ISA {

SONOSLICE_HOST_DEVICE inline float clampf(float v, float lo, float hi) {
  return v < lo ? lo : (v > hi ? hi : v);
}

/// The properties at continuous index c: docs/conventions.md §5's inside test, then labels by
/// `nearest` or HU by `linear` and the knots' table.
SONOSLICE_HOST_DEVICE inline Props props_at(const ImageModel& m, float cx, float cy, float cz) {
  if (!geometry::inside(m.grid, cx, cy, cz)) return m.outside;
  if (m.labels) return m.label_props[geometry::sample_nearest(m.labels, m.grid, cx, cy, cz)];
  const float hu = m.hu16 ? geometry::sample_linear<float>(m.hu16, m.grid, cx, cy, cz)
                          : geometry::sample_linear<float>(m.hu, m.grid, cx, cy, cz);
  if (!(hu == hu)) return m.outside;  // a NaN voxel nearby: no data, as outside the volume
  const float k = clampf(hu - float(m.hu_min), 0, float(m.hu_count) - 1.0001f);
  const int i = int(k);
  const float w = k - float(i);
  const Props& p = m.hu_table[i];
  const Props& q = m.hu_table[i + 1];
  return {p.z + w * (q.z - p.z), p.alpha + w * (q.alpha - p.alpha),
          p.scatter + w * (q.scatter - p.scatter)};
}

/// 1 / √x (scalar; AVX2 lanes: the estimate refined by one Newton step, Avx2Lanes.h).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float inverse_sqrt(float x) {
  return 1.0f / std::sqrt(x);
}

/// A layer's nodes are rotated in its plane by one of eight angles (i + ½)·11.25°, i from its
/// hash: the interpolation's faint periodic texture (a mean-intensity ripple of 1e-6 of the
/// variance, at the node spacing) is then spread over eight directions with random phases, never
/// along the image's or the volume's axes, instead of one spectral peak at 1/λ.
constexpr float kLayerCos[8] = {0.995184727f, 0.956940336f, 0.881921264f, 0.773010453f,
                                0.634393284f, 0.471396737f, 0.290284677f, 0.098017140f};
constexpr float kLayerSin[8] = {0.098017140f, 0.290284677f, 0.471396737f, 0.634393284f,
                                0.773010453f, 0.881921264f, 0.956940336f, 0.995184727f};

/// Scalar forms of the lane operations layer_crossing() uses (AVX2 lanes: Avx2Lanes.h).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float abs(float a) {
  return std::fabs(a);
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float min(float a, float b) {
  return std::fmin(a, b);
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float max(float a, float b) {
  return std::fmax(a, b);
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int32_t floor_to_int(float a) {
  return int32_t(std::floor(a));
}
// Integer lanes are uint32_t in scalar code (wrapping, as the AVX2 lanes), read as int32 where
// they become floats.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE uint32_t truncate_to_int(float a) {
  return uint32_t(int32_t(a));
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float to_float(uint32_t a) {
  return float(int32_t(a));
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE uint32_t shift_right(uint32_t a, int n) {
  return a >> n;
}
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float lookup8(const float* table, uint32_t i) {
  return table[i];
}

/// Layer k of a family (seed): a hash of k (an integer mixer: fixed in the volume, no table,
/// the same on every backend) whose low bits are the layer's offset into the speckle table and
/// bits 16–18 its row width. On int32 lanes (wrapping arithmetic, logical shifts).
template <typename I>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE I layer_hash(I k, uint32_t seed) {
  I h = k * 0x9E3779B1u + seed;
  h = h ^ shift_right(h, 16);
  h = h * 0x85EBCA6Bu;
  return h ^ shift_right(h, 13);
}
template <typename I>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE I layer_width(I h) {
  return (shift_right(h, 16) & 7) * kRowWidthStep + kRowWidthBase;
}

/// The elevation profile at u = |t| / T (t: mm from the image plane): a Gaussian of σ = T / 1.5
/// (exp(−1.125·u²), a quartic in u² within 1.8e-5), tapered by a smoothstep over u ∈ [0.75, 1]
/// to zero at the slice's edge, so that a layer enters and leaves the sum without a jump.
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F elevation_profile(F u) {
  const F v = u * u;
  const F g =
      F(0.99998242f) +
      v * (F(-1.12409487f) + v * (F(0.625325396f) + v * (F(-0.215178982f) + v * F(0.0386345179f))));
  const F s = min(max((F(1.0f) - u) * F(4.0f), F(0.0f)), F(1.0f));
  return g * (s * s * (F(3.0f) - F(2.0f) * s));
}

SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float exp2_of_int(int32_t n) {
  const uint32_t bits = uint32_t(n + 127) << 23;
  float f;
  std::memcpy(&f, &bits, sizeof f);
  return f;
}

/// 2^x for x ≤ 0 (the round-trip attenuation): 2^⌊x⌋ by the exponent field times a degree-5
/// polynomial of the fraction (relative error below 2.3e-7), on float or AVX2 lanes alike, so that
/// the generic and the AVX2 builds agree; 0 below 2^−126.
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F attenuation_exp2(F x) {
  x = max(x, F(-126.0f));
  const auto n = floor_to_int(x);
  const F f = x - to_float(n);
  const F p = F(0.999999771f) +
              f * (F(0.693156756f) +
                   f * (F(0.240131774f) +
                        f * (F(0.0558764407f) + f * (F(0.00894062992f) + f * F(0.00189438727f)))));
  return p * exp2_of_int(n);
}

/// Coupling: along a beam, samples below this impedance (MRayl) before the first one above it are
/// gel. Air is 0.0004 and fat 1.38; a CT's skin voxels, part air and part tissue, lie between,
/// and would otherwise dim each beam by a different amount (streaks down the image).
constexpr float kCouplingImpedance = 1.0f;

/// The specular echo's amplitude falls as cos^8 of the angle between the interface normal and
/// the beam (−10 dB at 30°): most of a tilted interface's echo misses the aperture.
SONOSLICE_HOST_DEVICE inline float directivity(float cosine) {
  const float c2 = cosine * cosine, c4 = c2 * c2;
  return c4 * c4;
}

/// log2(10) / 20: round-trip dB of amplitude → exponent of 2.
constexpr float kDbToLog2 = 0.16609640474436813f;

/// Beam b's origin and direction in the probe plane.
SONOSLICE_HOST_DEVICE inline void beam_line(const ImageModel& m, int b, float* o, float* d) {
  const double t = m.beam0 + b * m.beam_step;
  if (m.curvilinear) {
    d[0] = float(std::sin(t));
    d[1] = float(std::cos(t));
    o[0] = float(m.start) * d[0];
    o[1] = float(m.apex_y + m.start * double(d[1]));
  } else {
    d[0] = 0;
    d[1] = 1;
    o[0] = float(t);
    o[1] = float(m.start);
  }
}

/// The in-plane variance (mm²) that the layers' bilinear interpolation adds along the in-plane
/// direction (dx, dy) of the probe: a layer's nodes are λ apart (variance 1/6 in lattice units²
/// along any in-layer direction), and an in-plane step moves the elevation line's crossing with
/// the layer by v = Q·u − (Q·u)ₐ/eₐ · e (lattice units per mm), at least |Q·u| and at most √3
/// times it (cube diagonal). Blended families add their variances by weight².
SONOSLICE_HOST_DEVICE inline float residual_variance(const ImageModel& m, float dx, float dy) {
  float r = 0;
  for (int f = 0; f < m.fields; ++f) {
    const LayerField& L = m.field[f];
    float qu[3];
    for (int k = 0; k < 3; ++k) qu[k] = m.Q[3 * k] * dx + m.Q[3 * k + 1] * dy;
    const float along = qu[L.axis] * L.inverse_e;
    float v2 = 0;
    for (int k = 0; k < 3; ++k) {
      const float v = qu[k] - along * L.e[k];
      v2 += v * v;
    }
    r += L.weight * L.weight / (6.0f * v2);
  }
  return r;
}

/// Which of the kResidualLevels levels (residual / layer variance from 1/3 to 1) is nearest.
SONOSLICE_HOST_DEVICE inline int residual_level(const ImageModel& m, float residual) {
  const float g = residual / m.layer_variance_mm2;
  const int level = int((g - 1.0f / 3.0f) * 1.5f * float(kResidualLevels - 1) + 0.5f);
  return level < 0 ? 0 : (level >= kResidualLevels ? kResidualLevels - 1 : level);
}
inline double residual_of_level(int level) {
  return 1.0 / 3.0 + (2.0 / 3.0) * level / double(kResidualLevels - 1);
}

/// Sets the pose-dependent part of an image model: probe mm → index (A, a), → shifted lattice
/// coordinate (Q, q), the layer families of the slice thickness and the lateral speckle filter's
/// level. docs/simulation.md §3: the layers are the lattice planes normal to the axis most
/// aligned with the elevation direction; where a second (or third) axis is nearly as aligned
/// (|eₓ| > 0.9·max), its family is blended in, its weight rising smoothly from 0 to equal at the
/// switch, so that the image changes continuously with the pose.
inline void set_pose(ImageModel& im, const IndexMap& map) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      im.A[3 * r + c] = float(map.A[r][c]);
      im.Q[3 * r + c] = float(map.A[r][c] * im.lattice_per_index[r]);
    }
    im.a[r] = float(map.a[r]);
    im.q[r] = float(map.a[r] * im.lattice_per_index[r] + im.lattice_offset);
  }
  double e[3], top = 0;
  for (int r = 0; r < 3; ++r) {
    e[r] = map.A[r][2] * im.lattice_per_index[r];
    top = std::fmax(top, std::fabs(e[r]));
  }
  constexpr double kBlendFrom = 0.9;
  double w[3], sum = 0;
  for (int r = 0; r < 3; ++r) {
    const double x =
        std::fmin(std::fmax((std::fabs(e[r]) / top - kBlendFrom) / (1 - kBlendFrom), 0.0), 1.0);
    w[r] = x * x * (3 - 2 * x);
    sum += w[r] * w[r];
  }
  im.fields = 0;
  for (int r = 0; r < 3; ++r) {
    if (w[r] <= 0) continue;
    LayerField& L = im.field[im.fields++];
    L.axis = r;
    L.weight = float(w[r] / std::sqrt(sum));
    for (int k = 0; k < 3; ++k) L.e[k] = float(e[k]);
    L.inverse_e = float(1 / e[r]);
    const double reach = im.elevation_reach_mm * std::fabs(e[r]);
    L.stride = int(std::floor(2 * reach / kMaxLayers)) + 1;
    L.layers = int(std::floor(2 * reach / L.stride)) + 1;
    L.reach = float(reach);
    L.seed = im.layer_seed[r];
  }
}

/// A label volume's voxels read as their impedance (for the interface normals below).
struct LabelImpedance {
  const uint16_t* labels;
  const Props* props;
  SONOSLICE_HOST_DEVICE float operator()(int64_t i) const { return props[labels[i]].z; }
};

/// The impedance at continuous index c, trilinear for labels as for a CT: the interface normal
/// comes from differences of it, and a label volume's nearest voxels would give a staircase
/// whose differences jump from beam to beam on an oblique surface (the cos⁸ directivity would
/// turn that into a speckle of bright and dark beams along it).
SONOSLICE_HOST_DEVICE inline float smooth_impedance(const ImageModel& m, float cx, float cy,
                                                    float cz) {
  if (!m.labels || !geometry::inside(m.grid, cx, cy, cz)) return props_at(m, cx, cy, cz).z;
  return geometry::sample_linear<float>(LabelImpedance{m.labels, m.label_props}, m.grid, cx, cy,
                                        cz);
}

/// |cos θ| between beam direction d and the impedance gradient at probe point (px, py, 0), from
/// central differences over ±gradient_mm along the probe's three axes; 1 where it vanishes.
SONOSLICE_HOST_DEVICE inline float interface_cosine(const ImageModel& m, float px, float py,
                                                    const float* d) {
  const auto index_of = [&](float x, float y, float z, float* c) {
    for (int k = 0; k < 3; ++k)
      c[k] = m.A[3 * k] * x + m.A[3 * k + 1] * y + m.A[3 * k + 2] * z + m.a[k];
  };
  const float h = m.gradient_mm;
  float cp[3], cm[3], g[3];
  index_of(px + h, py, 0, cp);
  index_of(px - h, py, 0, cm);
  g[0] = smooth_impedance(m, cp[0], cp[1], cp[2]) - smooth_impedance(m, cm[0], cm[1], cm[2]);
  index_of(px, py + h, 0, cp);
  index_of(px, py - h, 0, cm);
  g[1] = smooth_impedance(m, cp[0], cp[1], cp[2]) - smooth_impedance(m, cm[0], cm[1], cm[2]);
  index_of(px, py, h, cp);
  index_of(px, py, -h, cm);
  g[2] = smooth_impedance(m, cp[0], cp[1], cp[2]) - smooth_impedance(m, cm[0], cm[1], cm[2]);
  const float gn = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
  return gn > 0 ? std::fabs(g[0] * d[0] + g[1] * d[1]) / gn : 1.0f;
}

/// A traced sample s (even) of one beam's buffers: its diffuse weight and loss, and the sample
/// before it (between two traced ones) their mean; its specular echo spread ½ on it and ¼ on
/// each neighbour. The sample after it takes its values until the next traced one replaces them
/// (the beam's last sample keeps them).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void store_traced(float* echo, float* specular_echo,
                                                         float* loss_db, int s, int S, float weight,
                                                         float loss, float specular) {
  echo[2 * s] = weight;
  echo[2 * s + 1] = 0;
  loss_db[s] = loss;
  specular_echo[s] += 0.5f * specular;
  if (s > 0) {
    echo[2 * s - 2] = 0.5f * (echo[2 * s - 4] + weight);
    loss_db[s - 1] = 0.5f * (loss_db[s - 2] + loss);
    specular_echo[s - 1] += 0.25f * specular;
  }
  if (s + 1 < S) {
    specular_echo[s + 1] += 0.25f * specular;
    echo[2 * s + 2] = weight;
    echo[2 * s + 3] = 0;
    loss_db[s + 1] = loss;
  }
}

/// Stage 1a, beam b: the weight of the diffuse echo (amplitude × scatter × gain, in echo's real
/// part; add_speckle() then makes it the complex diffuse echo) and the (real) specular echo of
/// every sample, kept apart because they get different filters (§3), and the round-trip
/// attenuation in dB met down to it (for TGC). Buffers are beam-major: sample s of beam b at
/// b·samples + s. docs/simulation.md §2.
/// The tissue is traced at every other sample (twice the speckle's step: properties,
/// interfaces and losses change over millimetres, the speckle over λ): the weights and losses
/// of the samples between are the mean of their neighbours', and each traced echo is spread
/// over its sample (½) and the two beside it (¼ each), which keeps the coherent sum of a ramp's
/// echoes.
SONOSLICE_HOST_DEVICE inline void trace_beam(const ImageModel& m, int b, float* echo,
                                             float* specular_echo, float* loss_db) {
  float o[2], d[2];
  beam_line(m, b, o, d);
  const int S = m.samples;
  echo += 2 * int64_t(b) * S;
  specular_echo += int64_t(b) * S;
  loss_db += int64_t(b) * S;
  for (int s = 0; s < S; ++s) specular_echo[s] = 0;
  float transmitted = 1;  // intensity transmission down to here (interfaces)
  float att_db = 0;       // one-way attenuation down to here
  float z_before = -1;
  bool in_tissue = false;
  float cosine = 1;       // the last interface sample's normal against the beam ...
  int normal_at = -1;     // ... taken at this (traced) sample
  int interface_at = -2;  // the last traced sample that was an interface
  const float step = 2 * m.step_mm;
  const float att_per_alpha = m.frequency_mhz * step / 10;  // dB per (dB/cm/MHz), one step
  for (int j = 0, s = 0; s < S; ++j, s += 2) {
    const float depth = (float(s) + 0.5f) * m.step_mm;
    const float px = o[0] + depth * d[0], py = o[1] + depth * d[1];
    float c[3];
    for (int k = 0; k < 3; ++k) c[k] = m.A[3 * k] * px + m.A[3 * k + 1] * py + m.a[k];
    Props p = props_at(m, c[0], c[1], c[2]);
    // Coupling: gas (and the skin's part-air voxels) between the face and the first tissue
    // along the beam is gel (the probe is pressed on; a face that only partly touches a curved
    // skin is not left in air).
    if (!in_tissue) {
      if (p.z < kCouplingImpedance)
        p = m.outside;
      else
        in_tissue = true;
    }
    if (z_before < 0) z_before = p.z;
    // Attenuation of the step that led here, at this sample's tissue.
    att_db += p.alpha * att_per_alpha;
    float specular = 0;
    const float ratio = (p.z - z_before) / (p.z + z_before);
    const float r = ratio * ratio;
    // Round trip: the intensity transmission both ways is transmitted², an amplitude factor of
    // transmitted; the attenuation both ways is 2·att_db.
    const float amplitude = transmitted * attenuation_exp2(-2 * kDbToLog2 * att_db);
    if (r > m.min_reflection) {
      // The interface's normal from the impedance gradient (central differences over
      // ±gradient_mm around the sample); the echo that returns falls as cos^8 of the angle
      // between the normal and the beam (docs/simulation.md §2). Differences over ±h change
      // little within h/2: the samples of one interface ramp reuse its normal that far.
      if (interface_at != j - 1 || j - normal_at > m.gradient_reuse) {
        cosine = interface_cosine(m, px, py, d);
        normal_at = j;
      }
      interface_at = j;
      specular = std::sqrt(r) * directivity(cosine);
      transmitted *= 1 - r;  // for the samples below; CT noise (r ≤ min_reflection) neither
                             // echoes nor dims
    }
    // Diffuse scattering: its weight here; add_speckle() multiplies in the speckle field.
    store_traced(echo, specular_echo, loss_db, s, S, amplitude * p.scatter * m.speckle_gain,
                 2 * att_db, amplitude * specular);
    z_before = p.z;
  }
}

#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
/// props_at() for eight points whose cells lie wholly inside the volume (0 ≤ c < n − 1 on each
/// axis, checked by the caller; voxel offsets fit in int32): the same sampling rule, with
/// gathers. CT: trilinear HU (a NaN voxel: outside), then the knots' table; labels: nearest.
inline void props_lanes(const ImageModel& m, backend::Vec8f cx, backend::Vec8f cy,
                        backend::Vec8f cz, backend::Vec8f& z, backend::Vec8f& alpha,
                        backend::Vec8f& scatter) {
  using backend::Vec8f;
  using backend::Vec8i;
  const int32_t sy = int32_t(m.grid.stride_y), sz = int32_t(m.grid.stride_z);
  const float* table;
  Vec8i entry;
  Vec8f w(0.f);
  if (m.labels) {
    const Vec8i nx = backend::floor_to_int(cx + Vec8f(0.5f)),
                ny = backend::floor_to_int(cy + Vec8f(0.5f)),
                nz = backend::floor_to_int(cz + Vec8f(0.5f));
    entry = backend::gather_value(m.labels, backend::offsets(nx, ny, nz, sy, sz)) * 3;
    table = &m.label_props[0].z;
  } else {
    const Vec8i ix = backend::floor_to_int(cx), iy = backend::floor_to_int(cy),
                iz = backend::floor_to_int(cz);
    const Vec8f fx = cx - backend::to_float(ix), fy = cy - backend::to_float(iy),
                fz = cz - backend::to_float(iz);
    const Vec8i r00 = backend::offsets(ix, iy, iz, sy, sz);
    Vec8f v[8];
    const auto pairs = [&](const auto* voxels) {
      backend::gather_pair(voxels, r00, v[0], v[1]);
      backend::gather_pair(voxels, r00 + sy, v[2], v[3]);
      backend::gather_pair(voxels, r00 + sz, v[4], v[5]);
      backend::gather_pair(voxels, r00 + (sy + sz), v[6], v[7]);
    };
    if (m.hu16)
      pairs(m.hu16);
    else
      pairs(m.hu);
    Vec8f hu = geometry::trilinear(fx, fy, fz, v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]);
    const Vec8f nan = _mm256_cmp_ps(hu.v, hu.v, _CMP_UNORD_Q);
    hu = backend::select(nan, Vec8f(float(m.hu_min)), hu);  // replaced by `outside` below
    const Vec8f k = backend::min(backend::max(hu - Vec8f(float(m.hu_min)), Vec8f(0.f)),
                                 Vec8f(float(m.hu_count) - 1.0001f));
    const Vec8i i = backend::truncate_to_int(k);
    w = k - backend::to_float(i);
    entry = i * 3;
    table = &m.hu_table[0].z;
    const auto at = [&](int field, int next) {
      const Vec8f lo = backend::gather_float(table + field, entry);
      const Vec8f hi = backend::gather_float(table + field + 3 * next, entry);
      return backend::select(nan, Vec8f((&m.outside.z)[field]), lo + w * (hi - lo));
    };
    z = at(0, 1);
    alpha = at(1, 1);
    scatter = at(2, 1);
    return;
  }
  z = backend::gather_float(table, entry);
  alpha = backend::gather_float(table + 1, entry);
  scatter = backend::gather_float(table + 2, entry);
}

/// trace_beam() for beams b0 .. b0 + 7 at once (AVX2 lanes, one beam each): the same steps and
/// formulas, with the volume read by props_lanes() where all eight cells lie inside the volume
/// (props_at() lane by lane elsewhere) and interfaces, which are rare, handled lane by lane.
inline void trace_beams8(const ImageModel& m, int b0, float* echo, float* specular_echo,
                         float* loss_db) {
  using backend::Vec8f;
  constexpr int N = 8;
  const int S = m.samples;
  float ox[N], oy[N], dx[N], dy[N];
  for (int l = 0; l < N; ++l) {
    float o[2], d[2];
    beam_line(m, b0 + l, o, d);
    ox[l] = o[0];
    oy[l] = o[1];
    dx[l] = d[0];
    dy[l] = d[1];
    for (int s = 0; s < S; ++s) specular_echo[int64_t(b0 + l) * S + s] = 0;
  }
  const Vec8f Ox = backend::load_as_float(ox), Oy = backend::load_as_float(oy),
              Dx = backend::load_as_float(dx), Dy = backend::load_as_float(dy);
  const bool fits_int32 = m.grid.stride_z * m.grid.nz < (int64_t(1) << 31) - 4;
  Vec8f transmitted(1.f), att_db(0.f), z_before(0.f), in_tissue(0.f);
  float cosine[N], transmitted_lane[N];
  int normal_at[N], interface_at[N];
  for (int l = 0; l < N; ++l) {
    cosine[l] = 1;
    normal_at[l] = -1;
    interface_at[l] = -2;
  }
  const float step = 2 * m.step_mm;
  const float att_per_alpha = m.frequency_mhz * step / 10;
  // Cells wholly inside, and a voxel to spare (a 32-bit gather of a uint16 label reads two bytes
  // past it).
  const float hi[3] = {float(m.grid.nx - 2), float(m.grid.ny - 2), float(m.grid.nz - 2)};
  const float end[3] = {float(m.grid.nx) - 0.5f, float(m.grid.ny) - 0.5f, float(m.grid.nz) - 0.5f};
  for (int j = 0, s = 0; s < S; ++j, s += 2) {
    const float depth = (float(s) + 0.5f) * m.step_mm;
    const Vec8f px = Ox + Vec8f(depth) * Dx, py = Oy + Vec8f(depth) * Dy;
    Vec8f c[3];
    for (int k = 0; k < 3; ++k)
      c[k] = Vec8f(m.A[3 * k]) * px + Vec8f(m.A[3 * k + 1]) * py + Vec8f(m.a[k]);
    Vec8f z, alpha, scatter;
    // Lanes whose cells lie inside, and lanes outside the volume (its inside test): where every
    // lane is one or the other (a beam leaving the volume), the first read with gathers, the
    // others water; lane by lane only near the volume's faces.
    int interior = 0xff, inside = 0xff;
    for (int k = 0; k < 3; ++k) {
      interior &= backend::lanes_in_range(c[k], 0.f, hi[k]);
      inside &= backend::lanes_in_range(c[k], -0.5f, end[k]);
    }
    if ((interior | (~inside & 0xff)) == 0xff && fits_int32) {
      z = Vec8f(m.outside.z);
      alpha = Vec8f(m.outside.alpha);
      scatter = Vec8f(m.outside.scatter);
      if (interior) {
        // Lanes outside read a cell inside (clamped; the others are left as they are), then
        // keep the water above.
        for (int k = 0; k < 3; ++k)
          c[k] = backend::min(backend::max(c[k], Vec8f(0.f)), Vec8f(hi[k]));
        Vec8f zi, ai, si;
        props_lanes(m, c[0], c[1], c[2], zi, ai, si);
        const Vec8f in = backend::lane_mask(interior);
        z = backend::select(in, zi, z);
        alpha = backend::select(in, ai, alpha);
        scatter = backend::select(in, si, scatter);
      }
    } else {
      float cl[3][N], zl[N], al[N], sl[N];
      for (int k = 0; k < 3; ++k) c[k].store(cl[k]);
      for (int l = 0; l < N; ++l) {
        const Props p = props_at(m, cl[0][l], cl[1][l], cl[2][l]);
        zl[l] = p.z;
        al[l] = p.alpha;
        sl[l] = p.scatter;
      }
      z = backend::load_as_float(zl);
      alpha = backend::load_as_float(al);
      scatter = backend::load_as_float(sl);
    }
    // Coupling (trace_beam): gas before the first tissue along the beam is gel.
    const Vec8f below = z < Vec8f(kCouplingImpedance);
    const Vec8f gel = backend::and_not(in_tissue, below);
    z = backend::select(gel, Vec8f(m.outside.z), z);
    alpha = backend::select(gel, Vec8f(m.outside.alpha), alpha);
    scatter = backend::select(gel, Vec8f(m.outside.scatter), scatter);
    in_tissue =
        in_tissue | backend::and_not(below, Vec8f(_mm256_castsi256_ps(_mm256_set1_epi32(-1))));
    if (j == 0) z_before = z;
    att_db = att_db + alpha * Vec8f(att_per_alpha);
    const Vec8f ratio = (z - z_before) / (z + z_before);
    const Vec8f r = ratio * ratio;
    const Vec8f amplitude = transmitted * attenuation_exp2(Vec8f(-2 * kDbToLog2) * att_db);
    float specular[N] = {0, 0, 0, 0, 0, 0, 0, 0};
    const int interfaces = backend::lanes_of(r > Vec8f(m.min_reflection));
    if (interfaces) {
      float rl[N];
      r.store(rl);
      transmitted.store(transmitted_lane);
      float pxl[N], pyl[N];
      px.store(pxl);
      py.store(pyl);
      for (int l = 0; l < N; ++l) {
        if (!(interfaces >> l & 1)) continue;
        if (interface_at[l] != j - 1 || j - normal_at[l] > m.gradient_reuse) {
          const float d[2] = {dx[l], dy[l]};
          cosine[l] = interface_cosine(m, pxl[l], pyl[l], d);
          normal_at[l] = j;
        }
        interface_at[l] = j;
        specular[l] = std::sqrt(rl[l]) * directivity(cosine[l]);
        transmitted_lane[l] *= 1 - rl[l];
      }
      transmitted = backend::load_as_float(transmitted_lane);
    }
    float weight[N], loss[N], amp[N];
    (amplitude * scatter * Vec8f(m.speckle_gain)).store(weight);
    (Vec8f(2.f) * att_db).store(loss);
    amplitude.store(amp);
    for (int l = 0; l < N; ++l) {
      const int64_t row = int64_t(b0 + l) * S;
      store_traced(echo + 2 * row, specular_echo + row, loss_db + row, s, S, weight[l], loss[l],
                   amp[l] * specular[l]);
    }
    z_before = z;
  }
}
#endif

/// Whether any of v[0], v[stride], ..., v[(n − 1)·stride] is not zero: without an early exit, so
/// that it vectorises (the beams it scans are mostly all echo or all zero).
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool any_nonzero(const float* v, int n, int stride = 1) {
  int found = 0;
  for (int i = 0; i < n; ++i) found |= v[i * stride] != 0;
  return found != 0;
}

/// Samples of a beam whose speckle add_speckle() computes together: the crossing, cell and
/// weight arithmetic runs over them as one loop (SIMD lanes on the CPU).
constexpr int kSpeckleLanes = 8;

/// add_speckle()'s cells for kSpeckleLanes samples at each crossing ([crossing][lane]): the four
/// node weights (x0·y0, x1·y0, x0·y1, x1·y1; profile weight and norm folded in) and the table
/// index of the cell's lower row and of its upper row.
struct SpeckleCells {
  float w[kMaxLayers][kSpeckleLanes][4];
  uint32_t row0[kMaxLayers][kSpeckleLanes], row1[kMaxLayers][kSpeckleLanes];
  float scale[kSpeckleLanes];  // the family's weight / the root sum of squared profile weights
};

/// Crossing j of family L by the elevation lines of samples at lattice coordinates (pa, pb, pc)
/// (the family's axis first), on lanes F (float, or eight AVX2 floats) and I (int32 likewise):
/// layer k = (first + j)·stride lies at t = (k − pₐ)/eₐ mm from the sample; its weight is the
/// elevation profile there, times the bilinear norm (interpolated white noise is up to 4 times
/// weaker mid-cell than at a node: divided by the weights' root sum of squares, exactly, its
/// variance is the same everywhere, and no trace of the lattice's period is left in the
/// intensity's spectrum). Writes the cell's weights and rows; returns the profile weight.
template <typename F, typename I>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F layer_crossing(const ImageModel& m, const LayerField& L,
                                                        F pa, F pb, F pc, I first, int j, float hi,
                                                        float inverse_reach, F& x0, F& x1, F& y0,
                                                        F& y1, I& row0, I& row1) {
  const int a = L.axis, ab = a == 2 ? 0 : a + 1, ac = a == 0 ? 2 : a - 1;
  const I k = (first + j) * L.stride;
  const F t = (to_float(k) - pa) * F(L.inverse_e);
  const F w = elevation_profile(abs(t) * F(inverse_reach));
  const F yb = min(max(pb + t * F(L.e[ab]), F(0.f)), F(hi));
  const F yc = min(max(pc + t * F(L.e[ac]), F(0.f)), F(hi));
  const I h = layer_hash(k, L.seed);
  const I width = layer_width(h);
  // The layer's own node axes (rotated, shifted by hi so that the coordinates stay positive).
  const I turn = shift_right(h, 19) & 7;
  const F cs = lookup8(m.turn_cos, turn), sn = lookup8(m.turn_sin, turn);
  const F xb = cs * yb - sn * yc + F(hi), xc = sn * yb + cs * yc;
  const I ib = truncate_to_int(xb), ic = truncate_to_int(xc);
  const F fb = xb - to_float(ib), fc = xc - to_float(ic);
  const F gb = F(1.f) - fb, gc = F(1.f) - fc;
  const F norm = w * inverse_sqrt((fb * fb + gb * gb) * (fc * fc + gc * gc));
  row0 = (ib + width * ic + h) & kSpeckleMask;
  row1 = row0 + width;
  x0 = gb * norm;
  x1 = fb * norm;
  y0 = gc;
  y1 = fc;
  return w;
}

/// add_speckle()'s cells of family L for kSpeckleLanes samples at lattice coordinates p[axis]
/// [lane]: every crossing's cell (layer_crossing), and the scale that divides the sum by the root
/// sum of the squared profile weights, so that every sample has unit variance.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void layer_cells(const ImageModel& m, const LayerField& L,
                                                        const float* const* p, SpeckleCells& c) {
  const float hi = float(m.lattice_count - 2);
  const float inverse_reach = 1.0f / m.elevation_reach_mm;
  const int a = L.axis, ab = a == 2 ? 0 : a + 1, ac = a == 0 ? 2 : a - 1;
  const float inverse_stride = 1.0f / float(L.stride);
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
  using backend::Vec8f;
  using backend::Vec8i;
  const Vec8f pa = backend::load_as_float(p[a]), pb = backend::load_as_float(p[ab]),
              pc = backend::load_as_float(p[ac]);
  const Vec8i first = backend::floor_to_int((pa - Vec8f(L.reach)) * Vec8f(inverse_stride)) + 1;
  Vec8f sum(0.f);
  for (int j = 0; j < L.layers; ++j) {
    Vec8f x0, x1, y0, y1;
    Vec8i row0, row1;
    const Vec8f w =
        layer_crossing(m, L, pa, pb, pc, first, j, hi, inverse_reach, x0, x1, y0, y1, row0, row1);
    backend::store_quads(x0 * y0, x1 * y0, x0 * y1, x1 * y1, &c.w[j][0][0]);
    row0.store(reinterpret_cast<int32_t*>(c.row0[j]));
    row1.store(reinterpret_cast<int32_t*>(c.row1[j]));
    sum = backend::fmadd(w, w, sum);
  }
  const Vec8f scale =
      Vec8f(L.weight / kSpeckleScale) / backend::sqrt(backend::max(sum, Vec8f(1e-30f)));
  scale.store(c.scale);
#else
  for (int l = 0; l < kSpeckleLanes; ++l) {
    const float pa = p[a][l], pb = p[ab][l], pc = p[ac][l];
    const uint32_t first = uint32_t(floor_to_int((pa - L.reach) * inverse_stride) + 1);
    float sum = 0;
    for (int j = 0; j < L.layers; ++j) {
      float x0, x1, y0, y1;
      const float w = layer_crossing(m, L, pa, pb, pc, first, j, hi, inverse_reach, x0, x1, y0, y1,
                                     c.row0[j][l], c.row1[j][l]);
      c.w[j][l][0] = x0 * y0;
      c.w[j][l][1] = x1 * y0;
      c.w[j][l][2] = x0 * y1;
      c.w[j][l][3] = x1 * y1;
      sum += w * w;
    }
    c.scale[l] = L.weight / (kSpeckleScale * std::sqrt(std::fmax(sum, 1e-30f)));
  }
#endif
}

#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
/// Lane l's weighted nodes of one family from its cells, on AVX2: one crossing's four nodes are
/// two rows of two (re, im) int16 pairs, one 16-byte vector widened to eight floats, times the
/// four weights each repeated for (re, im), summed over the crossings. Its even elements sum to
/// the field's real part, its odd ones to the imaginary (before the scale).
inline backend::Vec8f layer_nodes(const ImageModel& m, const LayerField& L, const SpeckleCells& c,
                                  int l) {
  const int16_t* nodes = m.speckle;
  const __m256i pairs = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
  __m256 acc = _mm256_setzero_ps();
  for (int j = 0; j < L.layers; ++j) {
    const __m128i lo = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(nodes + 2 * c.row0[j][l]));
    const __m128i both = _mm_castpd_si128(_mm_loadh_pd(
        _mm_castsi128_pd(lo), reinterpret_cast<const double*>(nodes + 2 * c.row1[j][l])));
    const __m256 v = _mm256_cvtepi32_ps(_mm256_cvtepi16_epi32(both));
    const __m256 w =
        _mm256_permutevar8x32_ps(_mm256_castps128_ps256(_mm_loadu_ps(c.w[j][l])), pairs);
    acc = _mm256_fmadd_ps(v, w, acc);
  }
  return acc;
}
#else
/// Lane l's field of one family from its cells: the weighted sum of each crossing's four nodes.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void layer_sum(const ImageModel& m, const LayerField& L,
                                                      const SpeckleCells& c, int l, float& re,
                                                      float& im) {
  const int16_t* nodes = m.speckle;
  float acc[4] = {0, 0, 0, 0};
  for (int j = 0; j < L.layers; ++j) {
    const int16_t* n0 = nodes + 2 * c.row0[j][l];
    const int16_t* n1 = nodes + 2 * c.row1[j][l];
    for (int k = 0; k < 4; ++k)
      acc[k] += c.w[j][l][k / 2] * float(n0[k]) + c.w[j][l][2 + k / 2] * float(n1[k]);
  }
  re = (acc[0] + acc[2]) * c.scale[l];
  im = (acc[1] + acc[3]) * c.scale[l];
}
#endif

/// Stage 1b, beam b: the diffuse echo weights trace_beam() left in echo's real parts times the
/// speckle field: per sample, the elevation profile's weighted sum of the speckle layers its
/// elevation line crosses (docs/simulation.md §3), over the families of this pose.
/// Beam b's line in lattice coordinates: the sample at depth t lies at q0 + t·dq.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void speckle_line(const ImageModel& m, int b, float* q0,
                                                         float* dq) {
  float o[2], d[2];
  beam_line(m, b, o, d);
  for (int k = 0; k < 3; ++k) {
    q0[k] = m.Q[3 * k] * o[0] + m.Q[3 * k + 1] * o[1] + m.q[k];
    dq[k] = m.Q[3 * k] * d[0] + m.Q[3 * k + 1] * d[1];
  }
}

/// add_speckle() for the kSpeckleLanes samples from `first` of one beam (its line q0, dq from
/// speckle_line; `echo`: that beam's buffer): the unit of work of the CUDA driver.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void add_speckle_group(const ImageModel& m, const float* q0,
                                                              const float* dq, int first,
                                                              float* echo) {
  constexpr int N = kSpeckleLanes;
  const int n = m.samples - first < N ? m.samples - first : N;
  if (!any_nonzero(echo + 2 * first, n, 2)) return;  // water, gas, outside the volume: no speckle
  float px[N], py[N], pz[N];
  for (int l = 0; l < N; ++l) {
    const float depth = (float(first + l) + 0.5f) * m.step_mm;
    px[l] = q0[0] + depth * dq[0];
    py[l] = q0[1] + depth * dq[1];
    pz[l] = q0[2] + depth * dq[2];
  }
  const float* p[3] = {px, py, pz};
  float re[N], im[N];
  SpeckleCells c;
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
  // Every lane (a group is all tissue or all not but at a few edges), summed across lanes at once.
  using backend::Vec8f;
  Vec8f re8(0.f), im8(0.f);
  for (int f = 0; f < m.fields; ++f) {
    layer_cells(m, m.field[f], p, c);
    Vec8f nodes[N], r, i;
    for (int l = 0; l < N; ++l) nodes[l] = layer_nodes(m, m.field[f], c, l);
    backend::sum_even_odd8(nodes, r, i);
    const Vec8f scale = backend::load_as_float(c.scale);
    re8 = re8 + r * scale;
    im8 = im8 + i * scale;
  }
  re8.store(re);
  im8.store(im);
#else
  for (int l = 0; l < N; ++l) re[l] = im[l] = 0;
  for (int f = 0; f < m.fields; ++f) {
    layer_cells(m, m.field[f], p, c);
    for (int l = 0; l < n; ++l) {
      if (echo[2 * (first + l)] == 0) continue;
      float r, i;
      layer_sum(m, m.field[f], c, l, r, i);
      re[l] += r;
      im[l] += i;
    }
  }
#endif
  for (int l = 0; l < n; ++l) {
    const float weight = echo[2 * (first + l)];
    echo[2 * (first + l)] = weight * re[l];
    echo[2 * (first + l) + 1] = weight * im[l];
  }
}

/// Stage 1b, beam b: add_speckle_group() over the beam's samples.
SONOSLICE_HOST_DEVICE inline void add_speckle(const ImageModel& m, int b, float* echo) {
  float q0[3], dq[3];
  speckle_line(m, b, q0, dq);
  echo += 2 * int64_t(b) * m.samples;
  for (int first = 0; first < m.samples; first += kSpeckleLanes)
    add_speckle_group(m, q0, dq, first, echo);
}

/// Stage 2, along one beam: `data` (n values, `channels` interleaved: 2 for the complex echo, 1
/// for the specular) convolved with `kernel` (taps −radius..radius), edges clamped. `tmp`: n ×
/// channels floats.
SONOSLICE_HOST_DEVICE inline void filter_axial(float* data, int n, int channels,
                                               const float* kernel, int radius, float* tmp) {
  if (radius == 0) return;
  const int q = n * channels;
  if (!any_nonzero(data, q)) return;  // a beam without echoes (most beams' specular echo)
  for (int i = 0; i < q; ++i) tmp[i] = data[i];
  // The first and last `radius` samples, whose taps reach past the ends (clamped) ...
  for (int i = 0; i < n; ++i) {
    if (i == radius && n > 2 * radius) i = n - radius;
    float acc[2] = {0, 0};
    for (int k = -radius; k <= radius; ++k) {
      int j = i + k;
      j = j < 0 ? 0 : (j >= n ? n - 1 : j);
      for (int c = 0; c < channels; ++c) acc[c] += kernel[k + radius] * tmp[j * channels + c];
    }
    for (int c = 0; c < channels; ++c) data[i * channels + c] = acc[c];
  }
  // ... and the others, tap by tap over contiguous values (vectorises).
  if (n <= 2 * radius) return;
  float* d = data + radius * channels;
  const int inner = (n - 2 * radius) * channels;
  for (int i = 0; i < inner; ++i) d[i] = 0;
  for (int k = -radius; k <= radius; ++k) {
    const float w = kernel[k + radius];
    const float* src = tmp + (radius + k) * channels;
    for (int i = 0; i < inner; ++i) d[i] += w * src[i];
  }
}
/// Axial taps each side: at most this many.
constexpr int kMaxAxialRadius = 48;

/// Gaussian taps −r..r of σ (in steps) with peak 1, r = ⌈3σ⌉ (at most max_radius), into `taps`;
/// their sum in `sum`. No filter (the single tap 1, r = 0) when σ ≤ 0.3. Returns r. Every filter
/// of the PSF is made here.
SONOSLICE_HOST_DEVICE inline int gaussian_taps(float sigma, int max_radius, float* taps,
                                               float& sum) {
  sum = 1;
  taps[0] = 1;
  if (!(sigma > 0.3f)) return 0;
  int r = int(std::ceil(3 * sigma));
  r = r < max_radius ? r : max_radius;
  sum = 0;
  for (int k = -r; k <= r; ++k)
    sum += taps[k + r] = std::exp(-0.5f * float(k * k) / (sigma * sigma));
  return r;
}

/// The speckle filter that brings a field already smoothed with variance `residual` (mm², the
/// layers' own interpolation along this direction) to the PSF's variance `variance`: a Gaussian
/// of σ² = variance − residual in steps of `step` mm (none below 0.3 steps), sum 1, times the
/// amplitude that keeps the field's variance: smoothing white noise to a total variance V leaves
/// it √(residual / V) as strong as the unfiltered field (Gaussian kernels), so the taps are scaled
/// by (V / residual)^¼. Returns the radius; `taps` holds 2·kMaxAxialRadius + 1 at most.
SONOSLICE_HOST_DEVICE inline int speckle_taps(float variance, float residual, float step,
                                              int max_radius, float* taps) {
  const float extra = variance - residual;
  float sum;
  const int r = gaussian_taps(extra > 0 ? std::sqrt(extra) / step : 0.f, max_radius, taps, sum);
  if (r == 0) return 0;
  const float gain = std::sqrt(std::sqrt(variance / residual)) / sum;
  for (int k = 0; k <= 2 * r; ++k) taps[k] *= gain;
  return r;
}

/// Stage 2, along beam b: the complex echo's speckle filter for this beam's direction (the
/// layers' residual smoothing depends on it, residual_variance). `data`: that beam's buffer;
/// `tmp`: 2 × samples floats.
SONOSLICE_HOST_DEVICE inline void filter_axial_speckle(const ImageModel& m, int b, float* data,
                                                       float* tmp) {
  float o[2], d[2];
  beam_line(m, b, o, d);
  float taps[2 * kMaxAxialRadius + 1];
  const int radius = speckle_taps(m.axial_variance_mm2, residual_variance(m, d[0], d[1]), m.step_mm,
                                  kMaxAxialRadius, taps);
  if (radius == 0 && taps[0] == 1) return;
  filter_axial(data, m.samples, 2, taps, radius, tmp);
}

/// Stage 2, across the beams: output beam b (`o`: its S × channels values) from beams b ± r of
/// `in` (B × S × channels, beam-major), with the per-depth kernel `kernel` ([tap][s × channels]:
/// each depth's weight repeated for its channels; taps −kMax..kMax of which −radius..radius are
/// used), edges clamped; `nonzero` (optional, per beam): beams known to be all zero are skipped.
/// Vectorises along s.
SONOSLICE_HOST_DEVICE inline void filter_lateral(const float* in, float* o, int beams, int samples,
                                                 int channels, const float* kernel,
                                                 const int32_t* ranges, int radius, int b,
                                                 const uint8_t* nonzero = nullptr) {
  const int64_t row = int64_t(samples) * channels;
  for (int64_t i = 0; i < row; ++i) o[i] = 0;
  for (int k = -radius; k <= radius; ++k) {
    int j = b + k;
    j = j < 0 ? 0 : (j >= beams ? beams - 1 : j);
    if (nonzero && !nonzero[j]) continue;  // a beam without echoes adds nothing
    const float* src = in + j * row;
    const int64_t tap = k + kMaxLateralRadius;
    const float* w = kernel + tap * row;
    // Only the samples where this tap's weight is not zero (a fan's beams spread with depth,
    // and its outer taps end there).
    const int64_t first = int64_t(ranges[2 * tap]) * channels,
                  last = int64_t(ranges[2 * tap + 1]) * channels;
    for (int64_t i = first; i < last; ++i) o[i] += w[i] * src[i];
  }
}

/// Beam b's level of the lateral speckle filter: the layers' residual smoothing along the beam's
/// lateral direction (in the image plane, across the beam: a fan's beams turn, and so does it).
SONOSLICE_HOST_DEVICE inline int lateral_level(const ImageModel& m, int b) {
  float o[2], d[2];
  beam_line(m, b, o, d);
  return residual_level(m, residual_variance(m, d[1], -d[0]));
}

/// The lateral speckle filter of a level ([tap][s]) and its taps' sample ranges.
SONOSLICE_HOST_DEVICE inline const float* lateral_speckle_taps(const ImageModel& m, int level) {
  return m.lateral_speckle + int64_t(level) * (2 * kMaxLateralRadius + 1) * 2 * int64_t(m.samples);
}
SONOSLICE_HOST_DEVICE inline const int32_t* lateral_speckle_ranges(const ImageModel& m, int level) {
  return m.lateral_speckle_range + int64_t(level) * (2 * kMaxLateralRadius + 1) * 2;
}

/// Stage 2 → 4: sample i's specular echo added to its complex echo's real part (both
/// filtered), so that scan conversion interpolates one signal.
SONOSLICE_HOST_DEVICE inline void add_specular(float* echo, const float* specular, int64_t i) {
  echo[2 * i] += specular[i];
}

/// Stage 3: time-gain compensation. The median round-trip attenuation across the beams at each
/// depth (auto), or none. The median, not the mean: a few beams through gas or bone lose far
/// more, and compensating them would flood the others. Taken every kTgcStride samples (the
/// knots: samples 0, kTgcStride, 2·kTgcStride, ... and the last) and linear between: the
/// attenuation met grows by hundredths of a dB per sample, and each median reads a sample of
/// every beam.
constexpr int kTgcStride = 8;

/// Knots of `samples` samples: 0, kTgcStride, ... and samples − 1.
SONOSLICE_HOST_DEVICE inline int tgc_knot_count(int samples) {
  return samples <= 1 ? 1 : (samples - 2) / kTgcStride + 2;
}
SONOSLICE_HOST_DEVICE inline int tgc_knot_sample(int samples, int k) {
  return k * kTgcStride < samples - 1 ? k * kTgcStride : samples - 1;
}

/// The k-th smallest of v[0..n) (v is reordered): Hoare's selection with the middle element as
/// pivot, deterministic and without recursion, so that CPU and GPU pick the same value.
SONOSLICE_HOST_DEVICE inline float kth_smallest(float* v, int n, int k) {
  int lo = 0, hi = n - 1;
  while (lo < hi) {
    const float pivot = v[lo + (hi - lo) / 2];
    int i = lo, j = hi;
    while (i <= j) {
      while (v[i] < pivot) ++i;
      while (pivot < v[j]) --j;
      if (i <= j) {
        const float t = v[i];
        v[i] = v[j];
        v[j] = t;
        ++i;
        --j;
      }
    }
    if (k <= j)
      hi = j;
    else if (k >= i)
      lo = i;
    else
      return v[k];
  }
  return v[k];
}

/// Knot k's level: the median across the beams of the round-trip loss (`loss`, beam-major) at
/// its sample. `scratch`: `beams` floats.
SONOSLICE_HOST_DEVICE inline float tgc_knot(const ImageModel& m, const float* loss, int k,
                                            float* scratch) {
  const int s = tgc_knot_sample(m.samples, k);
  for (int b = 0; b < m.beams; ++b) scratch[b] = loss[int64_t(b) * m.samples + s];
  return kth_smallest(scratch, m.beams, m.beams / 2);
}

/// Sample s's TGC level (dB), linear between the knots (`knots`: tgc_knot_count of them); 0
/// without auto TGC.
SONOSLICE_HOST_DEVICE inline float tgc_level(const ImageModel& m, const float* knots, int s) {
  if (!m.tgc_auto) return 0;
  if (s == 0) return knots[0];
  const int k = (s - 1) / kTgcStride;
  const int s0 = k * kTgcStride, s1 = tgc_knot_sample(m.samples, k + 1);
  const float before = knots[k], after = knots[k + 1];
  return before + (after - before) * float(s - s0) / float(s1 - s0);
}

/// log2(x) for a normal x > 0: the exponent plus a degree-6 polynomial in the mantissa (error
/// below 2.1e-6, a thousandth of a grey level at 60 dB), not the math library's call, which cost
/// a fifth of scan conversion. The GPU's own log2 is as fast.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float fast_log2(float x) {
#if defined(__CUDACC__)
  return log2f(x);
#else
  uint32_t bits;
  std::memcpy(&bits, &x, sizeof bits);
  const float exponent = float(int32_t(bits >> 23) - 127);
  bits = (bits & 0x007FFFFFu) | 0x3F800000u;
  float m;
  std::memcpy(&m, &bits, sizeof m);
  const float f = m - 1.0f;
  return exponent +
         (2.09796667e-06f +
          f * (1.44247595f +
               f * (-0.717562253f +
                    f * (0.455539722f +
                         f * (-0.274640336f + f * (0.119308718f + f * -0.0251254486f))))));
#endif
}

/// Stage 4 for one pixel from its ScanEntry fields: the complex echo (speckle + specular, summed
/// into `echo`) bilinear in (beam, sample) — interpolating the complex signal keeps the
/// speckle's statistics; an envelope would be smoothed — then the envelope and, for B-mode, TGC
/// (`level`: dB per sample) and log compression.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void scan_value(const ImageModel& m, const float* echo,
                                                       const float* level, int64_t j, int s0,
                                                       uint8_t steps, float tb, float ts, int64_t i,
                                                       void* out) {
  const int64_t step_b = steps & 1 ? m.samples : 0, ds = steps & 2 ? 1 : 0;
  float c[2];
  for (int k = 0; k < 2; ++k) {
    const float* e = echo + k;
    const float lo = e[2 * j] + ts * (e[2 * (j + ds)] - e[2 * j]);
    const float hi = e[2 * (j + step_b)] + ts * (e[2 * (j + step_b + ds)] - e[2 * (j + step_b)]);
    c[k] = lo + tb * (hi - lo);
  }
  const float power = c[0] * c[0] + c[1] * c[1];
  if (!m.bmode) {
    static_cast<float*>(out)[i] = std::sqrt(power);
    return;
  }
  const float gain_db = level[s0] + ts * (level[s0 + ds] - level[s0]);
  // 20·log10(env) = 10·log10(power) = (10 / log2(10))·log2(power).
  const float db = power > 0 ? 3.0102999566398120f * fast_log2(power) + gain_db : -1e9f;
  const float grey = clampf(255.0f + db * m.grey_per_db, 0.0f, 255.0f);
  static_cast<uint8_t*>(out)[i] = uint8_t(std::floor(grey + 0.5f));
}

/// Stage 4, pixel i (scan_value), or 0 outside the mask.
SONOSLICE_HOST_DEVICE inline void scan_pixel(const ImageModel& m, const float* echo,
                                             const float* level, int64_t i, void* out) {
  if (m.mask[i]) {
    scan_value(m, echo, level, m.scan_index[i], m.scan_sample[i], m.scan_steps[i],
               m.scan_weights[2 * i], m.scan_weights[2 * i + 1], i, out);
    return;
  }
  if (!m.bmode)
    static_cast<float*>(out)[i] = 0;
  else
    static_cast<uint8_t*>(out)[i] = 0;
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace simulate_impl
}  // namespace sonoslice
