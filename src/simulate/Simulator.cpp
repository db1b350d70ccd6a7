// Simulator: builds the per-volume model (property tables, speckle table, beam layout) once,
// then simulates batches of poses, one image per task (SimulateImpl.h).
#include "sonoslice/simulate/Simulator.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "../core/Random.h"
#include "SimulateBackends.h"
#include "SimulateModel.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/geometry/Math.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace simulate_impl {

constexpr double kSoundSpeedMmPerUs = 1.54;           // 1540 m/s: λ (mm) = 1.54 / f (MHz)
constexpr double kFwhmToSigma = 0.42466090014400953;  // 1 / (2·sqrt(2·ln 2))

namespace {

/// The speckle table: kSpeckleNodes complex nodes, re and im standard normal / sqrt(2)
/// (Box–Muller) from the seed, as int16 at kSpeckleScale per unit, followed by its first
/// kSpecklePad nodes again (SimulateImpl.h).
std::vector<int16_t> speckle_table(uint64_t seed) {
  std::vector<int16_t> t(size_t(kSpeckleNodes + kSpecklePad) * 2);
  SplitMix64 rng(seed);
  constexpr double kTwoPi = 6.283185307179586;
  const auto quantised = [](double v) {
    return int16_t(std::lround(std::fmin(std::fmax(v * kSpeckleScale, -32767.0), 32767.0)));
  };
  for (size_t i = 0; i < size_t(kSpeckleNodes) * 2; i += 2) {
    const double u1 = rng.uniform_nonzero();
    const double u2 = rng.uniform();
    const double radius = std::sqrt(-std::log(u1));  // sqrt(-2 ln u1) / sqrt(2)
    t[i] = quantised(radius * std::cos(kTwoPi * u2));
    t[i + 1] = quantised(radius * std::sin(kTwoPi * u2));
  }
  std::copy(t.begin(), t.begin() + 2 * kSpecklePad, t.begin() + 2 * size_t(kSpeckleNodes));
  return t;
}

Props props_of(const Tissue& t) {
  return {float(t.impedance_mrayl), float(t.attenuation_db_cm_mhz), float(t.scatter_mean)};
}

/// simulate_impl::gaussian_taps() of σ (in samples) as a vector, peak 1 or sum 1.
std::vector<float> gauss_taps(double sigma, bool unit_sum, int max_radius) {
  std::vector<float> taps(size_t(2 * max_radius + 1));
  float sum;
  const int r = simulate_impl::gaussian_taps(float(sigma), max_radius, taps.data(), sum);
  taps.resize(size_t(2 * r + 1));
  if (unit_sum)
    for (float& t : taps) t /= sum;
  return taps;
}

/// The lateral kernels of every depth as a [tap][s × channels] table (taps −kMaxLateralRadius..;
/// each depth's weight repeated for its channels) appended to `table`: `taps(spacing_mm, out)`
/// fills the taps for beams spacing_mm apart and returns the radius; returns the largest radius
/// used.
template <typename Taps>
int lateral_table(const ImageModel& m, int channels, std::vector<float>& table,
                  std::vector<int32_t>& ranges, Taps taps) {
  const int width = 2 * simulate_impl::kMaxLateralRadius + 1;
  const size_t start = table.size(), row = size_t(m.samples) * size_t(channels);
  table.resize(start + size_t(width) * row, 0.f);
  const size_t first_range = ranges.size();
  for (int k = 0; k < width; ++k) {  // empty until a depth uses the tap
    ranges.push_back(m.samples);
    ranges.push_back(0);
  }
  float* t = table.data() + start;
  int radius = 0;
  float w[2 * simulate_impl::kMaxLateralRadius + 1];
  for (int s = 0; s < m.samples; ++s) {
    // Beams are beam_step apart: in mm at this depth for a fan, as given for a linear probe.
    const double spacing_mm =
        m.curvilinear ? (m.start + (s + 0.5) * m.step_mm) * m.beam_step : m.beam_step;
    const int r = taps(spacing_mm, w);
    radius = std::max(radius, r);
    for (int k = -r; k <= r; ++k) {
      const size_t tap = size_t(k + simulate_impl::kMaxLateralRadius);
      for (int c = 0; c < channels; ++c)
        t[tap * row + size_t(s) * size_t(channels) + size_t(c)] = w[k + r];
      int32_t* range = ranges.data() + first_range + 2 * tap;
      range[0] = std::min(range[0], int32_t(s));
      range[1] = std::max(range[1], int32_t(s + 1));
    }
  }
  return radius;
}

/// The lateral speckle filters of every residual level (kResidualLevels tables): the PSF's
/// lateral variance `variance` (mm²) less the level's residual smoothing.
int lateral_speckle_tables(const ImageModel& m, double variance, std::vector<float>& table,
                           std::vector<int32_t>& ranges) {
  table.clear();
  ranges.clear();
  int radius = 0;
  for (int level = 0; level < kResidualLevels; ++level) {
    const float residual = float(residual_of_level(level) * m.layer_variance_mm2);
    radius = std::max(radius, lateral_table(m, 2, table, ranges, [&](double spacing_mm, float* w) {
                        return speckle_taps(float(variance), residual, float(spacing_mm),
                                            kMaxLateralRadius, w);
                      }));
  }
  return radius;
}

}  // namespace

/// The gain that makes fully developed speckle's mean envelope 1 (so a tissue's is its
/// scatter_mean): the noise, the slice-thickness sum and the filters of this model on a patch of
/// 96 beams × 384 samples along an oblique line (the image's own add_speckle and filters), with a
/// fixed seed, interpolated as scan conversion does. The same for every image
/// of a simulator, so images stay comparable.
double speckle_gain(const ImageModel& model, double lateral_variance_mm2) {
  ImageModel m = model;
  const int B = 96, S = 384;
  // A rotation, so the patch is oblique to the lattice; probe mm → lattice: rotation / λ.
  const double R[9] = {0.8, -0.36, 0.48, 0.6, 0.48, -0.64, 0, 0.8, 0.6};
  const double lateral_step =
      m.curvilinear ? (m.start + 0.5 * m.samples * m.step_mm) * m.beam_step : m.beam_step;
  // The patch's reach in lattice steps (one per wavelength), with the slice thickness.
  const double reach = 4 + m.elevation_reach_mm / m.wavelength_mm;
  const double extent = (B * lateral_step + S * double(m.step_mm)) / m.wavelength_mm;
  const int offset = int(std::ceil(reach)) + 2, count = int(std::ceil(2 * extent)) + 2 * offset + 4;
  m.lattice_count = count;
  // Probe mm → lattice coordinates directly (index = lattice here).
  IndexMap map;
  for (int k = 0; k < 9; ++k) map.A[k / 3][k % 3] = R[k] / m.wavelength_mm;
  // The rotated patch spans at most [-extent, extent] on each axis: start it mid-table.
  for (int k = 0; k < 3; ++k) {
    m.lattice_per_index[k] = 1;
    map.a[k] = extent;
  }
  m.lattice_offset = float(offset);
  set_pose(m, map);
  // The patch as B parallel beams of S samples, lateral_step apart, through the image's own
  // stages: speckle (weight 1 everywhere), then the speckle's axial and lateral filters.
  m.curvilinear = false;
  m.beams = B;
  m.samples = S;
  m.beam0 = 0;
  m.beam_step = lateral_step;
  m.start = 0;
  std::vector<float> lateral;
  std::vector<int32_t> ranges;
  const int radius = lateral_speckle_tables(m, lateral_variance_mm2, lateral, ranges);
  m.lateral_speckle = lateral.data();
  m.lateral_speckle_range = ranges.data();
  std::vector<float> field(size_t(B) * S * 2, 0.f), out(size_t(B) * S * 2), tmp(size_t(S) * 2);
  for (size_t i = 0; i < field.size(); i += 2) field[i] = 1;
  for (int b = 0; b < B; ++b) {
    simulate_impl::add_speckle(m, b, field.data());
    simulate_impl::filter_axial_speckle(m, b, field.data() + 2 * size_t(b) * S, tmp.data());
  }
  for (int b = 0; b < B; ++b) {
    const int level = lateral_level(m, b);
    simulate_impl::filter_lateral(field.data(), out.data() + 2 * size_t(b) * S, B, S, 2,
                                  lateral_speckle_taps(m, level), lateral_speckle_ranges(m, level),
                                  radius, b);
  }
  // The mean envelope where the image's pixels fall: anywhere between samples and beams, where
  // scan conversion interpolates the complex echo (a little below the samples' own mean).
  double sum = 0;
  int n = 0;
  for (int b = 16; b < B - 16; ++b)
    for (int s = 32; s < S - 32; ++s)
      for (int fb = 0; fb < 4; ++fb)
        for (int fs = 0; fs < 4; ++fs, ++n) {
          const double tb = 0.125 + 0.25 * fb, ts = 0.125 + 0.25 * fs;
          double c[2];
          for (int k = 0; k < 2; ++k) {
            const auto at = [&](int bb, int ss) {
              return double(out[2 * (size_t(bb) * S + ss) + k]);
            };
            const double lo = at(b, s) + ts * (at(b, s + 1) - at(b, s));
            const double hi = at(b + 1, s) + ts * (at(b + 1, s + 1) - at(b + 1, s));
            c[k] = lo + tb * (hi - lo);
          }
          sum += std::sqrt(c[0] * c[0] + c[1] * c[1]);
        }
  return sum > 0 ? n / sum : 1.0;
}

namespace {

/// The point-spread function's widths (FWHM, mm) at wavelength λ: the settings' where given,
/// else from the frequency (docs/simulation.md §3).
struct Psf {
  double lambda, axial, lateral, elevation;
  Psf(const SimulationSettings& settings, double wavelength_mm)
      : lambda(wavelength_mm),
        axial(settings.axial_fwhm_mm > 0 ? settings.axial_fwhm_mm : lambda),
        lateral(settings.lateral_fwhm_mm > 0 ? settings.lateral_fwhm_mm : 2 * lambda),
        elevation(std::max(settings.elevation_fwhm_mm > 0 ? settings.elevation_fwhm_mm : 5 * lambda,
                           kMinElevationFwhm * lambda)) {}
  /// The thinnest slice: its profile (±1.5σ) spans 2√3 layers λ apart, so that every sample's
  /// elevation line crosses at least two at any orientation (one, at the cube diagonal, would
  /// leave the speckle jumping from layer to layer as the probe moves).
  static constexpr double kMinElevationFwhm = 2 * 1.7320508075688772 / (3 * kFwhmToSigma);
  static double variance(double fwhm) { return fwhm * kFwhmToSigma * fwhm * kFwhmToSigma; }
  double sigma_elevation() const { return elevation * kFwhmToSigma; }
};

/// A label volume: every label it holds must be in the tissue table; the kernel reads uint16
/// labels (a uint8 volume is widened once) and their properties from a 65536-entry table.
void set_label_source(Model& m, Volume& volume, const std::vector<Tissue>& tissues) {
  ImageModel& b = m.base;
  const VolumeGrid grid = volume.grid();
  const int64_t voxels = grid.voxel_count();
  check_label_volume(volume, "labels");
  validate_tissues(tissues, "tissues");
  // Which labels the volume holds: each must be in the table.
  std::vector<uint8_t> present(65536, 0);
  const bool wide = volume.pixel_type() == PixelType::UInt16;
  for (int64_t i = 0; i < voxels; ++i)
    present[wide ? volume.data_as<uint16_t>()[i] : volume.data_as<uint8_t>()[i]] = 1;
  m.label_props.assign(65536, b.outside);
  std::vector<uint8_t> known(65536, 0);
  for (const Tissue& t : tissues) {
    m.label_props[size_t(t.label)] = simulate_impl::props_of(t);
    known[size_t(t.label)] = 1;
  }
  for (int l = 0; l < 65536; ++l)
    if (present[size_t(l)] && !known[size_t(l)]) throw UnlistedLabelError(l);
  if (!wide) {  // the kernel reads uint16 labels
    Volume widened = Volume::allocate(PixelType::UInt16, grid);
    std::copy(volume.data_as<uint8_t>(), volume.data_as<uint8_t>() + voxels,
              widened.data_as<uint16_t>());
    volume = std::move(widened);
  }
  b.labels = volume.data_as<uint16_t>();
  b.label_props = m.label_props.data();
}

/// A CT in HU: read in place when float32 or int16, else converted to float once; properties
/// from the HU knots' table at every integer HU.
void set_ct_source(Model& m, Volume& volume) {
  ImageModel& b = m.base;
  // The kernel reads a float32 or int16 volume as it is (shared); others are converted to
  // float once.
  if (volume.pixel_type() == PixelType::Float32) {
    b.hu = volume.data_as<float>();
  } else if (volume.pixel_type() == PixelType::Int16) {
    b.hu16 = volume.data_as<int16_t>();
  } else {
    volume = volume.converted(PixelType::Float32);  // kept in m.volume below
    b.hu = volume.data_as<float>();
  }
  b.hu_min = -1024;
  b.hu_count = 4096 + 1024;  // -1024 .. 4095 HU
  for (int k = 0; k < b.hu_count; ++k)
    m.hu_table.push_back(simulate_impl::props_of(tissue_from_hu(b.hu_min + k)));
  b.hu_table = m.hu_table.data();
}

/// Sampling along the beams and interfaces: the axial step, the impedance-gradient reach and
/// the reflection threshold at that step.
void set_sampling(ImageModel& b, const VolumeGrid& grid, const ImageGrid& img, double lambda) {
  // The axial step: two samples per image row, between λ/4 and λ/2. The complex echo's
  // spectrum (the PSF's, axial FWHM λ) is sampled at λ/2 or finer; a finer step only matters
  // when the image's rows are finer.
  b.step_mm = float(std::min(lambda / 2, std::max(lambda / 4, img.spacing_mm[1] / 2)));
  // Interface normals from impedance differences over a millimetre-scale neighbourhood: at
  // least three voxels, so that a voxelised oblique surface shows its slope, not its stairs (two
  // left a 30° tilt 4 dB below flat at an oblique orientation; cos⁸ says 10 dB).
  b.gradient_mm =
      float(std::max(double(b.step_mm),
                     3 * std::max({grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2]})));
  // trace_beam() traces every other sample: its step is 2Δ.
  b.gradient_reuse = int(b.gradient_mm / (4 * b.step_mm));
  const double quarter_steps = b.step_mm / (lambda / 4);
  b.min_reflection = float(kMinReflection * quarter_steps * quarter_steps);
}

/// The slice thickness (docs/simulation.md §3): the elevation profile's half-width T = 1.5σ, σ
/// from its FWHM.
void set_slice_thickness(ImageModel& b, const Psf& psf) {
  b.elevation_reach_mm = float(1.5 * psf.sigma_elevation());
}

/// The speckle lattice: one node per wavelength in the volume frame, the table and the layer
/// seeds drawn from the seed, lattice coordinates covering the volume and the slice thickness
/// around it.
void set_speckle_lattice(Model& m, const VolumeGrid& grid, const Psf& psf, uint64_t seed) {
  ImageModel& b = m.base;
  const double lambda = psf.lambda;
  for (int k = 0; k < 3; ++k) b.lattice_per_index[k] = grid.spacing_mm[k] / lambda;
  const double reach = b.elevation_reach_mm / lambda + 4;
  int extent = 0;
  for (int k = 0; k < 3; ++k)
    extent = std::max(extent, int(std::ceil(double(grid.dims[k]) * b.lattice_per_index[k])));
  const int offset = int(std::ceil(reach)), count = extent + 2 * offset + 2;
  b.lattice_offset = float(offset);
  b.lattice_count = count;
  m.speckle = speckle_table(seed * 2 + 1);
  b.speckle = m.speckle.data();
  SplitMix64 rng(seed * 2 + 2);
  for (uint32_t& s : b.layer_seed) s = uint32_t(rng.next() >> 32);
  std::copy(kLayerCos, kLayerCos + 8, b.turn_cos);
  std::copy(kLayerSin, kLayerSin + 8, b.turn_sin);
}

/// Beams: one per image column, over the probe's shape (angles about the apex for a fan,
/// parallel lines for a linear probe), each long enough for the image's deepest row.
void set_beams(ImageModel& b, const ProbeGeometry& probe) {
  const ImageGrid& img = probe.image;
  b.width = img.width;
  b.height = img.height;
  b.beams = img.width;
  const double last_row_y = img.origin_mm[1] + (img.height - 1) * img.spacing_mm[1];
  if (probe.type == ProbeType::Curvilinear) {
    b.curvilinear = true;
    const double sector = probe.sector_deg * kPi / 180;
    b.beam_step = sector / b.beams;
    b.beam0 = -sector / 2 + b.beam_step / 2;
    b.start = probe.radius_mm;
    b.apex_y = probe.face_y_mm - probe.radius_mm;
    b.samples = int(std::ceil(probe.depth_mm / b.step_mm)) + 1;
  } else {
    b.beam_step = img.spacing_mm[0];
    b.beam0 = img.origin_mm[0];
    b.start = std::min(probe.face_y_mm, img.origin_mm[1]);
    b.samples = int(std::ceil((last_row_y - b.start) / b.step_mm)) + 1;
  }
  if (b.samples < 1 || int64_t(b.samples) * b.beams > (int64_t(1) << 28))
    throw InputError("probe: " + std::to_string(b.beams) + " beams of " +
                     std::to_string(b.samples) + " samples at " + std::to_string(b.step_mm) +
                     " mm is too many for one image");
}

/// The point-spread function as filters: axial in samples (peak 1: an echo keeps the pulse's
/// amplitude), lateral per depth in beams (sum 1: a plane reflector across the beams keeps its
/// amplitude); the speckle's filters add only what the layers' smoothing lacks (per beam axially,
/// per residual level laterally).
void set_filters(Model& m, const Psf& psf) {
  ImageModel& b = m.base;
  b.axial_variance_mm2 = float(Psf::variance(psf.axial));
  b.layer_variance_mm2 = float(psf.lambda * psf.lambda / 6);
  m.axial_specular = gauss_taps(psf.axial * kFwhmToSigma / b.step_mm, false, kMaxAxialRadius);
  b.axial_specular = m.axial_specular.data();
  b.axial_specular_radius = int(m.axial_specular.size() / 2);
  const int speckle_radius = lateral_speckle_tables(b, Psf::variance(psf.lateral),
                                                    m.lateral_speckle, m.lateral_speckle_range);
  m.lateral_specular.clear();
  m.lateral_specular_range.clear();
  const int specular_radius = lateral_table(
      b, 1, m.lateral_specular, m.lateral_specular_range, [&](double spacing_mm, float* w) {
        const std::vector<float> taps =
            gauss_taps(psf.lateral * kFwhmToSigma / spacing_mm, true, kMaxLateralRadius);
        std::copy(taps.begin(), taps.end(), w);
        return int(taps.size() / 2);
      });
  b.lateral_radius = std::max(speckle_radius, specular_radius);
  b.lateral_speckle = m.lateral_speckle.data();
  b.lateral_specular = m.lateral_specular.data();
  b.lateral_speckle_range = m.lateral_speckle_range.data();
  b.lateral_specular_range = m.lateral_specular_range.data();
}

/// Scan conversion: each pixel's place in the (beam, sample) grid, once.
void set_scan_conversion(Model& m, const ImageGrid& img) {
  ImageModel& b = m.base;
  const int64_t pixels = int64_t(img.width) * img.height;
  m.scan_index.assign(size_t(pixels), 0);
  m.scan_sample.assign(size_t(pixels), 0);
  m.scan_steps.assign(size_t(pixels), 0);
  m.scan_weights.assign(size_t(pixels) * 2, 0.f);
  for (int v = 0; v < img.height; ++v)
    for (int u = 0; u < img.width; ++u) {
      const size_t i = size_t(v) * size_t(img.width) + size_t(u);
      if (!m.mask[i]) continue;
      const double x = img.origin_mm[0] + u * img.spacing_mm[0],
                   y = img.origin_mm[1] + v * img.spacing_mm[1];
      double fb, fs;
      if (b.curvilinear) {
        const double dy = y - b.apex_y;
        fb = (std::atan2(x, dy) - b.beam0) / b.beam_step;
        fs = (std::sqrt(x * x + dy * dy) - b.start) / b.step_mm - 0.5;
      } else {
        fb = (x - b.beam0) / b.beam_step;
        fs = (y - b.start) / b.step_mm - 0.5;
      }
      fb = std::min(std::max(fb, 0.0), double(b.beams - 1));
      fs = std::min(std::max(fs, 0.0), double(b.samples - 1));
      const int b0 = int(fb), s0 = int(fs);
      m.scan_index[i] = b0 * b.samples + s0;
      m.scan_sample[i] = s0;
      m.scan_steps[i] = uint8_t((b0 + 1 < b.beams ? 1 : 0) | (s0 + 1 < b.samples ? 2 : 0));
      m.scan_weights[2 * i] = float(fb - b0);
      m.scan_weights[2 * i + 1] = float(fs - s0);
    }
  b.mask = m.mask.data();
  b.scan_index = m.scan_index.data();
  b.scan_sample = m.scan_sample.data();
  b.scan_steps = m.scan_steps.data();
  b.scan_weights = m.scan_weights.data();
  m.scan_order.clear();
  for (int64_t i = 0; i < pixels; ++i)
    if (m.mask[size_t(i)])
      m.scan_order.push_back({int32_t(i), m.scan_index[size_t(i)], m.scan_sample[size_t(i)],
                              m.scan_weights[2 * size_t(i)], m.scan_weights[2 * size_t(i) + 1],
                              m.scan_steps[size_t(i)]});
  std::stable_sort(m.scan_order.begin(), m.scan_order.end(),
                   [](const ScanEntry& x, const ScanEntry& y) { return x.index < y.index; });
  b.scan_order = m.scan_order.data();
  b.scan_count = int64_t(m.scan_order.size());
}

}  // namespace

}  // namespace simulate_impl

using simulate_impl::ImageModel;
using simulate_impl::Model;
using simulate_impl::Props;

Simulator::Simulator(Volume volume, SimulationSource source,
                     std::optional<ProbeGeometry> given_probe, std::vector<Tissue> tissues,
                     SimulationSettings requested)
    : model_(std::make_unique<Model>()) {
  using namespace simulate_impl;
  const SimulationSettings settings = requested.resolved();
  if (!given_probe && !settings.preset) throw InputError("probe: give a probe or a preset");
  const ProbeGeometry probe =
      given_probe ? *given_probe : simulation_preset(*settings.preset).probe;
  probe.validate("probe");
  Model& m = *model_;
  m.source = source;
  m.probe = probe;
  m.settings = settings;
  m.mask = probe.mask();
  const VolumeGrid grid = volume.grid();
  ImageModel& b = m.base;
  b.grid = geometry::VolumeView::of(grid.dims[0], grid.dims[1], grid.dims[2]);
  if (source == SimulationSource::Labels)
    set_label_source(m, volume, tissues);
  else
    set_ct_source(m, volume);
  m.volume = std::move(volume);

  const double frequency_mhz = *settings.frequency_mhz;  // resolved() chose it
  const Psf psf(settings, kSoundSpeedMmPerUs / frequency_mhz);
  b.frequency_mhz = float(frequency_mhz);
  b.wavelength_mm = psf.lambda;
  set_sampling(b, grid, probe.image, psf.lambda);
  set_slice_thickness(b, psf);
  set_speckle_lattice(m, grid, psf, settings.seed);
  set_beams(b, probe);
  set_filters(m, psf);
  set_scan_conversion(m, probe.image);
  b.speckle_gain = float(speckle_gain(b, Psf::variance(psf.lateral)));
  b.tgc_auto = settings.tgc_auto;
  b.bmode = settings.output == SimulationOutput::BMode;
  b.grey_per_db = float(255.0 / settings.dynamic_range_db);
  if (settings.device.type == DeviceType::CUDA) {
    require_device(settings.device);  // names the device, or says the build has no CUDA
#ifdef SONOSLICE_HAVE_CUDA
    m.cuda = cuda_prepare(m, settings.device.index);
#endif
  }
}

Simulator::~Simulator() = default;
Simulator::Simulator(Simulator&&) noexcept = default;

int Simulator::width() const {
  return model_->probe.image.width;
}
int Simulator::height() const {
  return model_->probe.image.height;
}
const SimulationSettings& Simulator::settings() const {
  return model_->settings;
}
const ProbeGeometry& Simulator::probe() const {
  return model_->probe;
}
SimulationSource Simulator::source() const {
  return model_->source;
}
const std::vector<uint8_t>& Simulator::mask() const {
  return model_->mask;
}
int Simulator::beams() const {
  return model_->base.beams;
}
int Simulator::samples_per_beam() const {
  return model_->base.samples;
}
size_t Simulator::image_bytes() const {
  return size_t(width()) * size_t(height()) *
         (model_->settings.output == SimulationOutput::BMode ? 1 : 4);
}

void Simulator::simulate(const Pose* poses, size_t count, void* out, size_t first_index) const {
  if (count == 0) return;
  validate_poses(poses, count, "poses", first_index, /*warn_non_orthonormal=*/false);
  const Model& m = *model_;
  std::vector<IndexMap> maps(count);
  for (size_t n = 0; n < count; ++n) maps[n] = m.volume.grid().index_map(poses[n]);
#ifdef SONOSLICE_HAVE_CUDA
  if (m.cuda)
    return simulate_impl::cuda_simulate(*m.cuda, maps.data(), count, static_cast<uint8_t*>(out),
                                        image_bytes());
#endif
  simulate_impl::simulate_cpu(cpu_kernel_isa(), m.base, maps.data(), count,
                              static_cast<uint8_t*>(out), image_bytes());
}

}  // namespace sonoslice
