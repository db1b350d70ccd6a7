#pragma once
/// @file The simulation kernel (docs/simulation.md): per image, four stages over independent
/// items, each a SONOSLICE_HOST_DEVICE function of one item:
///   1. trace_beam(b):        properties, interfaces, attenuation and the speckle along beam b;
///   2. filter_axial(b):      the axial point-spread function along beam b;
///      filter_lateral(s):    the lateral point-spread function across the beams at depth s;
///   3. tgc_knot(k):          time-gain compensation: the median loss across the beams at
///      tgc_level(s):         every kTgcStride-th sample, and the level of each sample;
///   4. scan_pixel(i):        scan conversion, envelope and log compression of pixel i.
/// Plain structs and pointers, no allocation. The CPU driver (SimulateDriverCPU.h) runs the
/// stages of one image on one thread, in a fixed order, so the bytes do not depend on the thread
/// count; the CUDA driver (SimulateDriverCUDA.cuh) launches each stage over (image, item).
/// Single precision throughout: the speckle is noise with a fixed seed, and float halves the
/// memory traffic of the tiles and the beam buffers.
#include <cmath>
#include <cstdint>

#include "../geometry/Sampling.h"
#include "sonoslice/backend/HostDevice.h"
#include "sonoslice/geometry/VolumeGrid.h"
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
#include "../backend/Avx2Lanes.h"
#endif

namespace sonoslice {
namespace simulate_impl {

/// Elevation samples across the slice thickness: at most this many.
constexpr int kMaxElevations = 16;
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

/// A complex speckle tile: n³ nodes of (re, im), standard complex Gaussian, periodic. Stored
/// padded to (n+1)³ (node n repeats node 0 along each axis), so a cell's upper corners never
/// wrap. Lattice coordinate k ≥ 0 (floor, shifted by the model's lattice offset) lies on node
/// (k − offset) mod n = r − n·⌊(r + ½)/n⌋ with r = k + shift (shift ≡ −offset mod n): arithmetic
/// rather than a table, so that the loops around it vectorise (a table lookup there is a gather).
struct NoiseTile {
  const float* nodes;
  int32_t stride_y, stride_z;  // floats from a node to the next along y, along z
  int32_t n, shift;
  float inverse_n;
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
  // Probe point p (mm) → speckle lattice coordinate, shifted by the tiles' offset so that the
  // volume and the slice thickness around it have coordinates in [0, lattice_count - 1): Q·p + q.
  // Set per pose from A, a and the lattice per index.
  float Q[9], q[3];
  double lattice_per_index[3];  // lattice coordinate per index step, along each axis
  float lattice_offset = 0;     // the shift above
  int lattice_count = 0;        // lattice coordinates are clamped to [0, lattice_count − 2]
  NoiseTile tiles[2];
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
  // Elevation samples: offsets (mm) and weights; their lattice offsets (Q's third column times
  // the offset) are set per pose.
  int elevations = 1;
  float elevation_mm[kMaxElevations], elevation_weight[kMaxElevations];
  float elevation_q[kMaxElevations][3];
  float frequency_mhz = 5;
  double wavelength_mm = 0.308;           // λ: the lattice step
  double sigma_lateral_speckle_mm = 0.5;  // the lateral speckle filter's σ (calibration)
  // The PSF. Axial: one kernel for every beam, peak 1, taps −radius..radius. Lateral: per depth
  // s, taps −kMaxLateralRadius..kMaxLateralRadius, stored [tap][s], sum 1 (zero beyond 3σ).
  // The speckle gets what the lattice's smoothness leaves to add; interfaces the full PSF.
  const float* axial_speckle = nullptr;
  const float* axial_specular = nullptr;
  int axial_speckle_radius = 0, axial_specular_radius = 0;
  const float* lateral_speckle = nullptr;   // (2·kMaxLateralRadius + 1) × samples
  const float* lateral_specular = nullptr;  // (2·kMaxLateralRadius + 1) × samples
  int lateral_radius = 0;                   // taps used each side (≤ kMaxLateralRadius)
  // Makes a tissue's mean speckle envelope its scatter_mean (Simulator calibrates it).
  float speckle_gain = 1;
  bool tgc_auto = true, bmode = true;
  float dynamic_range_db = 60;
  // Output grid and scan conversion: for pixel i inside the mask, the beam-buffer index of its
  // lower (beam, sample) corner, the steps to the upper ones, and the weights.
  int width = 0, height = 0;
  const uint8_t* mask = nullptr;
  const int32_t* scan_index = nullptr;  // b0·samples + s0, per pixel
  const uint8_t* scan_steps = nullptr;  // bit 0: b1 = b0 + 1; bit 1: s1 = s0 + 1
  const float* scan_weights = nullptr;  // (tb, ts) per pixel
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

/// 1 / sqrt(f² + (1 − f)²) for u = f·(1 − f) ∈ [0, 1/4], i.e. 1 / sqrt(1 − 2u): a cubic
/// (least squares on Chebyshev nodes, error below 1.3e-3, so the field's variance varies by
/// less than 0.3 % across a cell) instead of a division and a square root, which cost a sixth
/// of the tracing time.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float inverse_root_of_weights(float u) {
  return 0.99913569f + u * (1.06436622f + u * (0.47053766f + u * 7.57480051f));
}

/// min(max(v, 0), hi) in the form compilers turn into vector min/max (the operand order of
/// x86's minps/maxps), so that the loops around it vectorise.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE float lane_clamp(float v, float hi) {
  v = v > 0.f ? v : 0.f;
  return v < hi ? v : hi;
}

/// Lattice coordinate k (shifted) → its node along one axis of tile t, by arithmetic.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int32_t wrap_node(const NoiseTile& t, int32_t k) {
  const int32_t r = k + t.shift;
  return r - t.n * int32_t((float(r) + 0.5f) * t.inverse_n);
}

/// The float offset of the lower corner node of cell (ix, iy, iz) in tile t.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE int32_t node_offset(const NoiseTile& t, int32_t ix,
                                                           int32_t iy, int32_t iz) {
  return 2 * wrap_node(t, ix) + t.stride_y * wrap_node(t, iy) + t.stride_z * wrap_node(t, iz);
}

/// The complex field from speckle_of_lane()'s partial sums (generic path): per tile, (re, im)
/// of the x0 and of the x1 corners.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void speckle_sum(const float* acc, float& re, float& im) {
  re = (acc[0] + acc[2]) + (acc[4] + acc[6]);
  im = (acc[1] + acc[3]) + (acc[5] + acc[7]);
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

/// Sets the pose-dependent part of an image model: probe mm → index (A, a), → shifted lattice
/// coordinate (Q, q), and the elevation points' lattice offsets.
inline void set_pose(ImageModel& im, const IndexMap& map) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      im.A[3 * r + c] = float(map.A[r][c]);
      im.Q[3 * r + c] = float(map.A[r][c] * im.lattice_per_index[r]);
    }
    im.a[r] = float(map.a[r]);
    im.q[r] = float(map.a[r] * im.lattice_per_index[r] + im.lattice_offset);
  }
  for (int e = 0; e < im.elevations; ++e)
    for (int r = 0; r < 3; ++r)
      im.elevation_q[e][r] = float(map.A[r][2] * im.lattice_per_index[r]) * im.elevation_mm[e];
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
  g[0] = props_at(m, cp[0], cp[1], cp[2]).z - props_at(m, cm[0], cm[1], cm[2]).z;
  index_of(px, py + h, 0, cp);
  index_of(px, py - h, 0, cm);
  g[1] = props_at(m, cp[0], cp[1], cp[2]).z - props_at(m, cm[0], cm[1], cm[2]).z;
  index_of(px, py, h, cp);
  index_of(px, py, -h, cm);
  g[2] = props_at(m, cp[0], cp[1], cp[2]).z - props_at(m, cm[0], cm[1], cm[2]).z;
  const float gn = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
  return gn > 0 ? std::fabs(g[0] * d[0] + g[1] * d[1]) / gn : 1.0f;
}

/// Stage 1a, beam b: the weight of the diffuse echo (amplitude × scatter × gain, in echo's real
/// part; add_speckle() then makes it the complex diffuse echo) and the (real) specular echo of
/// every sample, kept apart because they get different filters (§3), and the round-trip
/// attenuation in dB met down to it (for TGC). Buffers are beam-major: sample s of beam b at
/// b·samples + s. docs/simulation.md §2.
SONOSLICE_HOST_DEVICE inline void trace_beam(const ImageModel& m, int b, float* echo,
                                             float* specular_echo, float* loss_db) {
  float o[2], d[2];
  beam_line(m, b, o, d);
  echo += 2 * int64_t(b) * m.samples;
  specular_echo += int64_t(b) * m.samples;
  loss_db += int64_t(b) * m.samples;
  const auto index_of = [&](float px, float py, float pz, float* c) {
    for (int k = 0; k < 3; ++k)
      c[k] = m.A[3 * k] * px + m.A[3 * k + 1] * py + m.A[3 * k + 2] * pz + m.a[k];
  };
  float transmitted = 1;  // intensity transmission down to here (interfaces)
  float att_db = 0;       // one-way attenuation down to here
  float z_before = -1;
  bool in_tissue = false;
  float cosine = 1;       // the last interface sample's normal against the beam ...
  int normal_at = -1;     // ... taken at this sample
  int interface_at = -2;  // the last sample that was an interface
  const float att_per_alpha = m.frequency_mhz * m.step_mm / 10;  // dB per (dB/cm/MHz), one step
  for (int s = 0; s < m.samples; ++s) {
    const float depth = (float(s) + 0.5f) * m.step_mm;
    const float px = o[0] + depth * d[0], py = o[1] + depth * d[1];
    float c[3];
    index_of(px, py, 0, c);
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
    const float amplitude = transmitted * std::exp2(-2 * kDbToLog2 * att_db);
    if (r > m.min_reflection) {
      // The interface's normal from the impedance gradient (central differences over
      // ±gradient_mm around the sample); the echo that returns falls as cos^8 of the angle
      // between the normal and the beam (docs/simulation.md §2). Differences over ±h change
      // little within h/2: the samples of one interface ramp reuse its normal that far.
      if (interface_at != s - 1 || s - normal_at > m.gradient_reuse) {
        cosine = interface_cosine(m, px, py, d);
        normal_at = s;
      }
      interface_at = s;
      specular = std::sqrt(r) * directivity(cosine);
      transmitted *= 1 - r;  // for the samples below; CT noise (r ≤ min_reflection) neither
                             // echoes nor dims
    }
    // Diffuse scattering: its weight here; add_speckle() multiplies in the speckle field.
    echo[2 * s] = amplitude * p.scatter * m.speckle_gain;
    echo[2 * s + 1] = 0;
    specular_echo[s] = amplitude * specular;
    loss_db[s] = 2 * att_db;
    z_before = p.z;
  }
}

/// Samples of a beam whose speckle add_speckle() computes together: the cell and weight
/// arithmetic of every elevation point runs over them as one loop (SIMD lanes on the CPU).
constexpr int kSpeckleLanes = 8;

/// add_speckle()'s cells and weights for kSpeckleLanes samples at every elevation point
/// ([elevation][lane]): the x weights (norm and elevation weight folded in), the four (y, z)
/// weights and each tile's lower-corner node offset.
struct SpeckleCells {
  float xw0[kMaxElevations][kSpeckleLanes], xw1[kMaxElevations][kSpeckleLanes];
  float w00[kMaxElevations][kSpeckleLanes], w10[kMaxElevations][kSpeckleLanes];
  float w01[kMaxElevations][kSpeckleLanes], w11[kMaxElevations][kSpeckleLanes];
  int32_t off0[kMaxElevations][kSpeckleLanes], off1[kMaxElevations][kSpeckleLanes];
};

/// The speckle field of lane l from its cells: the weighted node sums over both tiles and every
/// elevation point.
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void speckle_of_lane(const ImageModel& m,
                                                            const SpeckleCells& c, int l, float& re,
                                                            float& im) {
  const NoiseTile& t0 = m.tiles[0];
  const NoiseTile& t1 = m.tiles[1];
#if !defined(__CUDACC__) && defined(__AVX2__) && defined(__FMA__)
  // Eight floats at once: the x0 and x1 corners' (re, im) of two (y, z) rows per load pair.
  using backend::Vec8f;
  Vec8f acc0(0.f), acc1(0.f);
  for (int e = 0; e < m.elevations; ++e) {
    const Vec8f xw = backend::blend<0xCC>(Vec8f(c.xw0[e][l]), Vec8f(c.xw1[e][l]));
    const Vec8f wy0 = xw * backend::halves(&c.w00[e][l], &c.w10[e][l]);
    const Vec8f wy1 = xw * backend::halves(&c.w01[e][l], &c.w11[e][l]);
    const float* a0 = t0.nodes + c.off0[e][l];
    const float* a1 = t1.nodes + c.off1[e][l];
    acc0 = backend::fmadd(backend::quads(a0, a0 + t0.stride_y), wy0, acc0);
    acc0 =
        backend::fmadd(backend::quads(a0 + t0.stride_z, a0 + t0.stride_z + t0.stride_y), wy1, acc0);
    acc1 = backend::fmadd(backend::quads(a1, a1 + t1.stride_y), wy0, acc1);
    acc1 =
        backend::fmadd(backend::quads(a1 + t1.stride_z, a1 + t1.stride_z + t1.stride_y), wy1, acc1);
  }
  backend::sum_even_odd(acc0 + acc1, re, im);
#else
  float acc[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  for (int e = 0; e < m.elevations; ++e) {
    const float xw[4] = {c.xw0[e][l], c.xw0[e][l], c.xw1[e][l], c.xw1[e][l]};
    const float* a0 = t0.nodes + c.off0[e][l];
    const float* a1 = t1.nodes + c.off1[e][l];
    for (int k = 0; k < 4; ++k) {
      acc[k] +=
          xw[k] *
          ((c.w00[e][l] * a0[k] + c.w10[e][l] * a0[t0.stride_y + k]) +
           (c.w01[e][l] * a0[t0.stride_z + k] + c.w11[e][l] * a0[t0.stride_z + t0.stride_y + k]));
      acc[4 + k] +=
          xw[k] *
          ((c.w00[e][l] * a1[k] + c.w10[e][l] * a1[t1.stride_y + k]) +
           (c.w01[e][l] * a1[t1.stride_z + k] + c.w11[e][l] * a1[t1.stride_z + t1.stride_y + k]));
    }
  }
  speckle_sum(acc, re, im);
#endif
}

/// Stage 1b, beam b: the diffuse echo weights trace_beam() left in echo's real parts times the
/// speckle field summed across the slice thickness. The field at a lattice coordinate is the sum
/// of two tiles of co-prime size (so the pattern repeats only after n1·n2 lattice steps), each
/// trilinear between its nodes and divided by the weights' root sum of squares: interpolated
/// white noise is 8 times weaker mid-cell than at a node, which a beam running along a lattice
/// axis would show as streaks; normalised, its variance is the same everywhere. Both tiles share
/// the cell and its weights (the same lattice), only the nodes differ. The cells, weights and
/// node offsets of kSpeckleLanes samples are computed together, then the node loads follow
/// sample by sample (speckle_of_lane).
/// Beam b's line in lattice coordinates: the sample at depth t lies at q0 + t·dq (before the
/// elevation offsets).
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
  const float hi = float(m.lattice_count - 2);
  constexpr int L = kSpeckleLanes;
  const int n = m.samples - first < L ? m.samples - first : L;
  bool any = false;
  for (int l = 0; l < n; ++l) any = any || echo[2 * (first + l)] != 0;
  if (!any) return;  // water, gas, outside the volume: no speckle
  SpeckleCells c;
  for (int e = 0; e < m.elevations; ++e)
    for (int l = 0; l < L; ++l) {
      const float depth = (float(first + l) + 0.5f) * m.step_mm;
      const float x = lane_clamp(q0[0] + depth * dq[0] + m.elevation_q[e][0], hi);
      const float y = lane_clamp(q0[1] + depth * dq[1] + m.elevation_q[e][1], hi);
      const float z = lane_clamp(q0[2] + depth * dq[2] + m.elevation_q[e][2], hi);
      const int ix = int(x), iy = int(y), iz = int(z);
      const float fx = x - float(ix), fy = y - float(iy), fz = z - float(iz);
      const float gx = 1 - fx, gy = 1 - fy, gz = 1 - fz;
      const float norm = m.elevation_weight[e] * inverse_root_of_weights(fx * gx) *
                         inverse_root_of_weights(fy * gy) * inverse_root_of_weights(fz * gz);
      c.xw0[e][l] = gx * norm;
      c.xw1[e][l] = fx * norm;
      c.w00[e][l] = gy * gz;
      c.w10[e][l] = fy * gz;
      c.w01[e][l] = gy * fz;
      c.w11[e][l] = fy * fz;
      c.off0[e][l] = node_offset(m.tiles[0], ix, iy, iz);
      c.off1[e][l] = node_offset(m.tiles[1], ix, iy, iz);
    }
  for (int l = 0; l < n; ++l) {
    const float weight = echo[2 * (first + l)];
    if (weight == 0) {
      echo[2 * (first + l) + 1] = 0;
      continue;
    }
    float re, im;
    speckle_of_lane(m, c, l, re, im);
    echo[2 * (first + l)] = weight * re;
    echo[2 * (first + l) + 1] = weight * im;
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
  for (int i = 0; i < n * channels; ++i) tmp[i] = data[i];
  for (int i = 0; i < n; ++i) {
    float acc[2] = {0, 0};
    for (int k = -radius; k <= radius; ++k) {
      int j = i + k;
      j = j < 0 ? 0 : (j >= n ? n - 1 : j);
      for (int c = 0; c < channels; ++c) acc[c] += kernel[k + radius] * tmp[j * channels + c];
    }
    for (int c = 0; c < channels; ++c) data[i * channels + c] = acc[c];
  }
}

/// Stage 2, across the beams: output beam b of `out` from beams b ± r of `in` (both B × S ×
/// channels, beam-major), with the per-depth kernel `kernel` ([tap][s], taps −kMax..kMax of
/// which −radius..radius are used), edges clamped. Vectorises along s.
SONOSLICE_HOST_DEVICE inline void filter_lateral(const float* in, float* out, int beams,
                                                 int samples, int channels, const float* kernel,
                                                 int radius, int b) {
  const int64_t row = int64_t(samples) * channels;
  float* o = out + b * row;
  for (int64_t i = 0; i < row; ++i) o[i] = 0;
  for (int k = -radius; k <= radius; ++k) {
    int j = b + k;
    j = j < 0 ? 0 : (j >= beams ? beams - 1 : j);
    const float* src = in + j * row;
    const float* w = kernel + int64_t(k + kMaxLateralRadius) * samples;
    if (channels == 2)
      for (int s = 0; s < samples; ++s) {
        o[2 * s] += w[s] * src[2 * s];
        o[2 * s + 1] += w[s] * src[2 * s + 1];
      }
    else
      for (int s = 0; s < samples; ++s) o[s] += w[s] * src[s];
  }
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

/// Stage 4, pixel i: the complex echo (speckle + specular, summed into `echo`) bilinear in
/// (beam, sample) — interpolating the complex signal keeps the speckle's statistics; an envelope
/// would be smoothed — then the envelope and, for B-mode, TGC (`level`: dB per sample) and log
/// compression.
SONOSLICE_HOST_DEVICE inline void scan_pixel(const ImageModel& m, const float* echo,
                                             const float* level, int64_t i, void* out) {
  if (m.mask[i]) {
    const int64_t j = m.scan_index[i];
    const int64_t step_b = m.scan_steps[i] & 1 ? m.samples : 0, ds = m.scan_steps[i] & 2 ? 1 : 0;
    const float tb = m.scan_weights[2 * i], ts = m.scan_weights[2 * i + 1];
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
    const int s0 = int(j % m.samples);
    const float gain_db = level[s0] + ts * (level[s0 + ds] - level[s0]);
    // 20·log10(env) = 10·log10(power) = (10 / log2(10))·log2(power).
    const float db = power > 0 ? 3.0102999566398120f * std::log2(power) + gain_db : -1e9f;
    const float grey = clampf(255.0f * (1.0f + db / m.dynamic_range_db), 0.0f, 255.0f);
    static_cast<uint8_t*>(out)[i] = uint8_t(std::floor(grey + 0.5f));
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
