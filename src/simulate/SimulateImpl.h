#pragma once
/// @file The simulation kernel (docs/simulation.md): one image per call, beam by beam, then the
/// point-spread function, envelope, time-gain compensation, log compression and scan conversion.
/// Plain structs and pointers, no allocation inside; the CPU driver (Simulator.cpp) gives each
/// thread its scratch buffers. Every image is computed by one thread in a fixed order, so the
/// bytes do not depend on the number of threads.
#include <cmath>
#include <cstdint>

namespace sonoslice {
namespace simulate_impl {

/// Elevation samples across the slice thickness: at most this many.
constexpr int kMaxElevations = 16;

/// Acoustic properties at a point (the kernel's float copy of a Tissue).
struct Props {
  float z, alpha, scatter;
};

/// A complex speckle tile: n³ nodes of (re, im), standard complex Gaussian, periodic.
struct NoiseTile {
  const float* nodes;  // n³ × 2
  int n;
  // Lattice coordinate k (floor) → node k mod n, for k in [-wrap_offset, wrap_count -
  // wrap_offset - 1] (the volume and the slice thickness around it): a table, not a division.
  const int32_t* wrap;
  int wrap_offset, wrap_count;
};

/// Everything one image needs, in the probe frame (mm) and the volume's continuous index.
struct ImageModel {
  // Volume: HU (float, trilinear) or labels (uint16, nearest) → Props.
  const float* hu = nullptr;           // HU source: voxel values as float
  const uint16_t* labels = nullptr;    // label source
  const Props* label_props = nullptr;  // label → props (65536 entries)
  const Props* hu_table = nullptr;     // HU source: props at integer HU from hu_min
  int hu_min = -1024, hu_count = 0;
  int nx = 0, ny = 0, nz = 0;
  Props outside{1.48f, 0.0022f, 0.f};  // outside the volume: water (no echo, no loss)
  // Probe point p (mm) → continuous index: A·p + a (row-major A).
  double A[9], a[3];
  // Continuous index → speckle lattice coordinate: S·c (diagonal: spacing / lattice step).
  double lattice_per_index[3];
  NoiseTile tiles[2];
  // Beams: curvilinear (angles about the apex) or linear (parallel, along +y).
  bool curvilinear = false;
  int beams = 0, samples = 0;
  double step_mm = 0;               // axial sample step Δ
  double gradient_mm = 1;           // half-width of the impedance gradient's differences
  double beam0 = 0, beam_step = 0;  // first beam's angle (rad) or x (mm), and the step
  double start = 0;                 // first sample: radius R (curvilinear) or face y (linear)
  double apex_y = 0;                // curvilinear
  // Elevation samples: offsets (mm) and weights.
  int elevations = 1;
  double elevation_mm[kMaxElevations], elevation_weight[kMaxElevations];
  double frequency_mhz = 5;
  // The PSF: for the speckle, what the lattice's smoothness leaves to add; for interfaces, all.
  double sigma_axial_samples = 1, sigma_lateral_mm = 0.5;
  double specular_sigma_axial_samples = 1, specular_sigma_lateral_mm = 0.5;
  // Makes a tissue's mean speckle envelope its scatter_mean (Simulator calibrates it).
  double speckle_gain = 1;
  bool tgc_auto = true, bmode = true;
  double dynamic_range_db = 60;
  // Output grid.
  int width = 0, height = 0;
  double x0 = 0, y0 = 0, sx = 1, sy = 1;
  const uint8_t* mask = nullptr;
};

inline double clampd(double v, double lo, double hi) {
  return v < lo ? lo : (v > hi ? hi : v);
}

inline Props props_at(const ImageModel& m, double cx, double cy, double cz) {
  if (!(cx >= -0.5 && cy >= -0.5 && cz >= -0.5 && cx < m.nx - 0.5 && cy < m.ny - 0.5 &&
        cz < m.nz - 0.5))
    return m.outside;
  const int64_t sy = m.nx, sz = int64_t(m.nx) * m.ny;
  if (m.labels) {
    const int ix = int(cx + 0.5), iy = int(cy + 0.5), iz = int(cz + 0.5);
    return m.label_props[m.labels[iz * sz + iy * sy + ix]];
  }
  // Trilinear HU, clamped at the faces (as slicing's `linear`), then the knots' table.
  const double fx = clampd(cx, 0, m.nx - 1), fy = clampd(cy, 0, m.ny - 1),
               fz = clampd(cz, 0, m.nz - 1);
  const int x0 = int(fx), y0 = int(fy), z0 = int(fz);
  const int x1 = x0 + 1 < m.nx ? x0 + 1 : x0, y1 = y0 + 1 < m.ny ? y0 + 1 : y0,
            z1 = z0 + 1 < m.nz ? z0 + 1 : z0;
  const double tx = fx - x0, ty = fy - y0, tz = fz - z0;
  const float* v = m.hu;
  const auto at = [&](int x, int y, int z) { return double(v[z * sz + y * sy + x]); };
  const double c00 = at(x0, y0, z0) + tx * (at(x1, y0, z0) - at(x0, y0, z0));
  const double c10 = at(x0, y1, z0) + tx * (at(x1, y1, z0) - at(x0, y1, z0));
  const double c01 = at(x0, y0, z1) + tx * (at(x1, y0, z1) - at(x0, y0, z1));
  const double c11 = at(x0, y1, z1) + tx * (at(x1, y1, z1) - at(x0, y1, z1));
  const double c0 = c00 + ty * (c10 - c00), c1 = c01 + ty * (c11 - c01);
  const double hu = c0 + tz * (c1 - c0);
  if (!(hu == hu)) return m.outside;  // a NaN voxel nearby: no data, as outside the volume
  const double k = clampd(hu - m.hu_min, 0, m.hu_count - 1.000001);
  const int i = int(k);
  const double w = k - i;
  const Props& p = m.hu_table[i];
  const Props& q = m.hu_table[i + 1];
  return {float(p.z + w * (q.z - p.z)), float(p.alpha + w * (q.alpha - p.alpha)),
          float(p.scatter + w * (q.scatter - p.scatter))};
}

/// The speckle field at continuous index c: the sum of two tiles of co-prime size (so the
/// pattern repeats only after n1·n2 lattice steps), each trilinear between its nodes.
inline void noise_at(const ImageModel& m, double cx, double cy, double cz, double* re, double* im) {
  const double q[3] = {cx * m.lattice_per_index[0], cy * m.lattice_per_index[1],
                       cz * m.lattice_per_index[2]};
  double r = 0, i = 0;
  for (const NoiseTile& t : m.tiles) {
    int n0[3], n1[3];
    double f[3];
    for (int k = 0; k < 3; ++k) {
      const double shifted = q[k] + t.wrap_offset;
      const double fl = std::floor(shifted);
      f[k] = shifted - fl;
      if (fl >= 0 && fl <= t.wrap_count - 2) {  // the volume and its margin: a table
        n0[k] = t.wrap[int(fl)];
        n1[k] = t.wrap[int(fl) + 1];
      } else {  // anywhere else (calibration patches): the division
        int64_t w = (int64_t(fl) - t.wrap_offset) % t.n;
        w = w < 0 ? w + t.n : w;
        n0[k] = int(w);
        n1[k] = n0[k] + 1 == t.n ? 0 : n0[k] + 1;
      }
    }
    // Divided by the weights' root sum of squares: interpolated white noise is 8 times weaker
    // mid-cell than at a node, which a beam running along a lattice axis would show as streaks;
    // normalised, its variance is the same everywhere.
    const double norm = 1 / std::sqrt((f[0] * f[0] + (1 - f[0]) * (1 - f[0])) *
                                      (f[1] * f[1] + (1 - f[1]) * (1 - f[1])) *
                                      (f[2] * f[2] + (1 - f[2]) * (1 - f[2])));
    for (int c = 0; c < 8; ++c) {
      const int x = c & 1 ? n1[0] : n0[0], y = c & 2 ? n1[1] : n0[1], z = c & 4 ? n1[2] : n0[2];
      const double w =
          norm * (c & 1 ? f[0] : 1 - f[0]) * (c & 2 ? f[1] : 1 - f[1]) * (c & 4 ? f[2] : 1 - f[2]);
      const float* node = t.nodes + 2 * ((int64_t(z) * t.n + y) * t.n + x);
      r += w * node[0];
      i += w * node[1];
    }
  }
  *re = r;
  *im = i;
}

/// Coupling: along a beam, samples below this impedance (MRayl) before the first one above it are
/// gel. Air is 0.0004 and fat 1.38; a CT's skin voxels, part air and part tissue, lie between,
/// and would otherwise dim each beam by a different amount (streaks down the image).
constexpr float kCouplingImpedance = 1.0f;

/// Intensity reflections at or below this (−50 dB) are not interfaces: the small impedance steps
/// of CT noise and texture neither echo nor dim the beam.
constexpr double kMinReflection = 1e-5;

/// The specular echo's amplitude falls as cos^8 of the angle between the interface normal and
/// the beam (−10 dB at 30°): most of a tilted interface's echo misses the aperture.
constexpr double kSpecularExponent = 8;

/// Beam b's origin and direction in the probe plane.
inline void beam_line(const ImageModel& m, int b, double* o, double* d) {
  const double t = m.beam0 + b * m.beam_step;
  if (m.curvilinear) {
    d[0] = std::sin(t);
    d[1] = std::cos(t);
    o[0] = m.start * d[0];
    o[1] = m.apex_y + m.start * d[1];
  } else {
    d[0] = 0;
    d[1] = 1;
    o[0] = t;
    o[1] = m.start;
  }
}

/// Pass 1, one beam: the complex diffuse echo (re, im) and the specular echo of every sample
/// (kept apart: they get different filters, §3), and the round-trip attenuation in dB met down
/// to it (for TGC). docs/simulation.md §2.
inline void trace_beam(const ImageModel& m, int b, float* echo, float* specular_echo,
                       float* loss_db) {
  double o[2], d[2];
  beam_line(m, b, o, d);
  const auto index_of = [&](double px, double py, double pz, double* c) {
    for (int k = 0; k < 3; ++k)
      c[k] = m.A[3 * k] * px + m.A[3 * k + 1] * py + m.A[3 * k + 2] * pz + m.a[k];
  };
  double transmitted = 1;  // intensity transmission down to here (interfaces)
  double att_db = 0;       // one-way attenuation down to here
  float z_before = -1;
  bool in_tissue = false;
  const double step_cm = m.step_mm / 10;
  for (int s = 0; s < m.samples; ++s) {
    const double depth = (s + 0.5) * m.step_mm;
    const double px = o[0] + depth * d[0], py = o[1] + depth * d[1];
    double c[3];
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
    att_db += double(p.alpha) * m.frequency_mhz * step_cm;
    double specular = 0;
    const double dz = double(p.z) - z_before;
    const double r = (dz / (double(p.z) + z_before)) * (dz / (double(p.z) + z_before));
    if (r > kMinReflection) {
      // The interface's normal from the impedance gradient (central differences over
      // ±gradient_mm around the sample); the echo that returns falls as cos^8 of the angle
      // between the normal and the beam (docs/simulation.md §2).
      double g[2];
      const double h = m.gradient_mm;
      double cp[3], cm[3];
      index_of(px + h, py, 0, cp);
      index_of(px - h, py, 0, cm);
      g[0] = props_at(m, cp[0], cp[1], cp[2]).z - props_at(m, cm[0], cm[1], cm[2]).z;
      index_of(px, py + h, 0, cp);
      index_of(px, py - h, 0, cm);
      g[1] = props_at(m, cp[0], cp[1], cp[2]).z - props_at(m, cm[0], cm[1], cm[2]).z;
      double ge;
      index_of(px, py, h, cp);
      index_of(px, py, -h, cm);
      ge = props_at(m, cp[0], cp[1], cp[2]).z - props_at(m, cm[0], cm[1], cm[2]).z;
      const double gn = std::sqrt(g[0] * g[0] + g[1] * g[1] + ge * ge);
      const double cosine = gn > 0 ? std::fabs(g[0] * d[0] + g[1] * d[1]) / gn : 1.0;
      specular = std::sqrt(r) * std::pow(cosine, kSpecularExponent);
    }
    // Diffuse scattering: the speckle field across the slice thickness.
    double nr = 0, ni = 0;
    if (p.scatter > 0) {
      for (int e = 0; e < m.elevations; ++e) {
        double ce[3], er, ei;
        index_of(px, py, m.elevation_mm[e], ce);
        noise_at(m, ce[0], ce[1], ce[2], &er, &ei);
        nr += m.elevation_weight[e] * er;
        ni += m.elevation_weight[e] * ei;
      }
    }
    // Round trip: the intensity transmission both ways is transmitted², an amplitude factor of
    // transmitted; the attenuation both ways is 2·att_db.
    const double amplitude = transmitted * std::pow(10.0, -2 * att_db / 20);
    echo[2 * s] = float(amplitude * p.scatter * m.speckle_gain * nr);
    echo[2 * s + 1] = float(amplitude * p.scatter * m.speckle_gain * ni);
    specular_echo[2 * s] = float(amplitude * specular);
    specular_echo[2 * s + 1] = 0.f;
    loss_db[s] = float(2 * att_db);
    if (r > kMinReflection) transmitted *= 1 - r;  // CT noise neither echoes nor dims
    z_before = p.z;
  }
}

/// How a filter is scaled: its peak 1 (axially: an echo keeps the pulse's amplitude) or its sum
/// 1 (laterally: a plane reflector across the beams keeps its amplitude).
enum class Scale { Peak, Sum };

/// 1D Gaussian convolution of n complex samples spaced `stride` complex values apart, σ in
/// samples (truncated at 3σ, at most 48 taps each side; edges clamped). `tmp`: n complex values.
inline void gauss_complex(float* data, int n, int stride, double sigma, Scale scale, float* tmp) {
  if (!(sigma > 0.3)) return;
  int r = int(std::ceil(3 * sigma));
  r = r > 48 ? 48 : r;
  double w[97], wsum = 0;
  for (int k = -r; k <= r; ++k) wsum += w[k + r] = std::exp(-0.5 * k * k / (sigma * sigma));
  if (scale == Scale::Sum)
    for (int k = 0; k <= 2 * r; ++k) w[k] /= wsum;
  for (int i = 0; i < n; ++i) {
    tmp[2 * i] = data[2 * int64_t(i) * stride];
    tmp[2 * i + 1] = data[2 * int64_t(i) * stride + 1];
  }
  for (int i = 0; i < n; ++i) {
    double re = 0, im = 0;
    for (int k = -r; k <= r; ++k) {
      int j = i + k;
      j = j < 0 ? 0 : (j >= n ? n - 1 : j);
      re += w[k + r] * tmp[2 * j];
      im += w[k + r] * tmp[2 * j + 1];
    }
    data[2 * int64_t(i) * stride] = float(re);
    data[2 * int64_t(i) * stride + 1] = float(im);
  }
}

}  // namespace simulate_impl
}  // namespace sonoslice
