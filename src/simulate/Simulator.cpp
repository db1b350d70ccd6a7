// Simulator: builds the per-volume model (property tables, speckle tiles, beam layout) once,
// then simulates batches of poses, one image per task (SimulateImpl.h).
#include "sonoslice/simulate/Simulator.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "../backend/ParallelFor.h"
#include "SimulateImpl.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {
namespace simulate_impl {

constexpr double kSoundSpeedMmPerUs = 1.54;           // 1540 m/s: λ (mm) = 1.54 / f (MHz)
constexpr double kFwhmToSigma = 0.42466090014400953;  // 1 / (2·sqrt(2·ln 2))

struct Model {
  Volume volume;
  SimulationSource source;
  ProbeGeometry probe;
  SimulationSettings settings;
  std::vector<uint8_t> mask;
  std::vector<float> hu;           // HU source: the voxels as float
  std::vector<Props> label_props;  // label source: 65536 entries
  std::vector<Props> hu_table;
  std::vector<float> tiles[2];
  std::vector<int32_t> wraps[2];
  ImageModel base;  // everything but the pose
};

namespace {

/// splitmix64: the seed's stream of 64-bit values (public-domain constants, Steele et al.).
uint64_t splitmix(uint64_t& state) {
  uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// n³ complex nodes, each re and im standard normal / sqrt(2) (Box–Muller), from the seed.
std::vector<float> noise_tile(int n, uint64_t seed) {
  std::vector<float> t(size_t(n) * n * n * 2);
  uint64_t state = seed;
  constexpr double kTwoPi = 6.283185307179586;
  for (size_t i = 0; i < t.size(); i += 2) {
    // 53-bit uniforms in (0, 1].
    const double u1 = (double(splitmix(state) >> 11) + 1.0) * (1.0 / 9007199254740992.0);
    const double u2 = double(splitmix(state) >> 11) * (1.0 / 9007199254740992.0);
    const double radius = std::sqrt(-std::log(u1));  // sqrt(-2 ln u1) / sqrt(2)
    t[i] = float(radius * std::cos(kTwoPi * u2));
    t[i + 1] = float(radius * std::sin(kTwoPi * u2));
  }
  return t;
}

Props props_of(const Tissue& t) {
  return {float(t.impedance_mrayl), float(t.attenuation_db_cm_mhz), float(t.scatter_mean)};
}

}  // namespace

/// The gain that makes fully developed speckle's mean envelope 1 (so a tissue's is its
/// scatter_mean): the noise, the slice-thickness sum and the filters of this model on a patch of
/// 96 beams × 384 samples along an oblique line, with a fixed seed. The same for every image
/// of a simulator, so images stay comparable.
double speckle_gain(const ImageModel& model) {
  ImageModel m = model;
  m.A[0] = 0.8;  // probe x → index: a rotation, so the patch is oblique to the lattice
  m.A[1] = -0.36;
  m.A[2] = 0.48;
  m.A[3] = 0.6;
  m.A[4] = 0.48;
  m.A[5] = -0.64;
  m.A[6] = 0;
  m.A[7] = 0.8;
  m.A[8] = 0.6;
  // ... in mm: index = rotation · p / spacing (spacing = lattice_per_index · λ, λ = 4Δ).
  for (int k = 0; k < 3; ++k) {
    const double spacing = m.lattice_per_index[k] * 4 * m.step_mm;
    for (int j = 0; j < 3; ++j) m.A[3 * k + j] /= spacing;
    m.a[k] = 1000.5;
  }
  const int B = 96, S = 384;
  const double lateral_step =
      m.curvilinear ? (m.start + 0.5 * m.samples * m.step_mm) * m.beam_step : m.beam_step;
  std::vector<float> field(size_t(B) * S * 2), tmp(size_t(S) * 2);
  for (int b = 0; b < B; ++b)
    for (int s = 0; s < S; ++s) {
      const double px = b * lateral_step, py = s * m.step_mm;
      double nr = 0, ni = 0;
      for (int e = 0; e < m.elevations; ++e) {
        double c[3], er, ei;
        for (int k = 0; k < 3; ++k)
          c[k] =
              m.A[3 * k] * px + m.A[3 * k + 1] * py + m.A[3 * k + 2] * m.elevation_mm[e] + m.a[k];
        noise_at(m, c[0], c[1], c[2], &er, &ei);
        nr += m.elevation_weight[e] * er;
        ni += m.elevation_weight[e] * ei;
      }
      field[2 * (size_t(b) * S + s)] = float(nr);
      field[2 * (size_t(b) * S + s) + 1] = float(ni);
    }
  for (int b = 0; b < B; ++b)
    gauss_complex(field.data() + 2 * size_t(b) * S, S, 1, m.sigma_axial_samples, Scale::Peak,
                  tmp.data());
  for (int s = 0; s < S; ++s)
    gauss_complex(field.data() + 2 * size_t(s), B, S, m.sigma_lateral_mm / lateral_step, Scale::Sum,
                  tmp.data());
  double sum = 0;
  int n = 0;
  for (int b = 16; b < B - 16; ++b)
    for (int s = 32; s < S - 32; ++s, ++n) {
      const float* v = &field[2 * (size_t(b) * S + s)];
      sum += std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1]);
    }
  return sum > 0 ? n / sum : 1.0;
}

}  // namespace simulate_impl

using simulate_impl::ImageModel;
using simulate_impl::Model;
using simulate_impl::Props;
using simulate_impl::Scale;

Simulator::Simulator(Volume volume, SimulationSource source, ProbeGeometry probe,
                     std::vector<Tissue> tissues, SimulationSettings settings)
    : model_(std::make_unique<Model>()) {
  settings.validate();
  probe.validate("probe");
  Model& m = *model_;
  m.source = source;
  m.probe = probe;
  m.settings = settings;
  m.mask = probe.mask();
  const VolumeGrid grid = volume.grid();
  ImageModel& b = m.base;
  b.nx = int(grid.dims[0]);
  b.ny = int(grid.dims[1]);
  b.nz = int(grid.dims[2]);
  const int64_t voxels = grid.voxel_count();

  if (source == SimulationSource::Labels) {
    if (volume.pixel_type() != PixelType::UInt8 && volume.pixel_type() != PixelType::UInt16)
      throw InputError("labels: a label volume is uint8 or uint16, this one is " +
                       to_string(volume.pixel_type()));
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
      if (present[size_t(l)] && !known[size_t(l)])
        throw InputError("tissues: the label volume holds label " + std::to_string(l) +
                         ", which the tissue table does not list");
    if (!wide) {  // the kernel reads uint16 labels
      Volume widened = Volume::allocate(PixelType::UInt16, grid);
      std::copy(volume.data_as<uint8_t>(), volume.data_as<uint8_t>() + voxels,
                widened.data_as<uint16_t>());
      volume = std::move(widened);
    }
    b.labels = volume.data_as<uint16_t>();
    b.label_props = m.label_props.data();
  } else {
    // The kernel reads HU as float: a float32 volume as it is (shared), others converted once.
    if (volume.pixel_type() == PixelType::Float32) {
      b.hu = volume.data_as<float>();
    } else {
      m.hu.resize(size_t(voxels));
      visit_pixel_type(volume.pixel_type(), [&](auto zero) {
        using T = decltype(zero);
        const T* v = volume.data_as<T>();
        for (int64_t i = 0; i < voxels; ++i) m.hu[size_t(i)] = float(v[i]);
      });
      b.hu = m.hu.data();
    }
    b.hu_min = -1024;
    b.hu_count = 4096 + 1024;  // -1024 .. 4095 HU
    for (int k = 0; k < b.hu_count; ++k)
      m.hu_table.push_back(simulate_impl::props_of(tissue_from_hu(b.hu_min + k)));
    b.hu_table = m.hu_table.data();
  }
  m.volume = std::move(volume);

  // Wavelength, sampling and the point-spread function (docs/simulation.md §3).
  const double lambda = simulate_impl::kSoundSpeedMmPerUs / settings.frequency_mhz;
  b.frequency_mhz = settings.frequency_mhz;
  b.step_mm = lambda / 4;
  const double axial = settings.axial_fwhm_mm > 0 ? settings.axial_fwhm_mm : lambda;
  const double lateral = settings.lateral_fwhm_mm > 0 ? settings.lateral_fwhm_mm : 2 * lambda;
  const double elevation = settings.elevation_fwhm_mm > 0 ? settings.elevation_fwhm_mm : 5 * lambda;
  // The speckle field is already smooth at the lattice's scale: trilinear interpolation between
  // nodes λ apart is a triangle kernel of variance λ²/6 along any direction. The filters add
  // what is missing, so that the speckle's size is the PSF's (validation 2).
  const double lattice_var = lambda * lambda / 6;
  const auto filter_sigma = [&](double fwhm) {
    const double s = fwhm * simulate_impl::kFwhmToSigma;
    return std::sqrt(std::max(s * s - lattice_var, 0.0));
  };
  b.sigma_axial_samples = filter_sigma(axial) / b.step_mm;
  b.sigma_lateral_mm = filter_sigma(lateral);
  b.specular_sigma_axial_samples = axial * simulate_impl::kFwhmToSigma / b.step_mm;
  b.specular_sigma_lateral_mm = lateral * simulate_impl::kFwhmToSigma;
  // Interface normals from impedance differences over a millimetre-scale neighbourhood: at
  // least two voxels, so that a voxelised oblique surface shows its slope, not its stairs.
  b.gradient_mm = std::max(
      b.step_mm, 2 * std::max({grid.spacing_mm[0], grid.spacing_mm[1], grid.spacing_mm[2]}));
  const double sigma_el = elevation * simulate_impl::kFwhmToSigma;
  // The slice thickness: elevation samples about a lattice step apart over ±1.5σ, Gaussian
  // weights (a quadrature of the beam's elevation profile, so that a small elevational move
  // changes the sum smoothly), normalised to unit variance for independent samples.
  const int half =
      std::min(simulate_impl::kMaxElevations / 2 - 1, int(std::ceil(1.5 * sigma_el / lambda)));
  b.elevations = 2 * half + 1;
  double wsum = 0;
  for (int e = 0; e < b.elevations; ++e) {
    const double offset = (e - half) * (1.5 * sigma_el / std::max(half, 1));
    b.elevation_mm[e] = offset;
    b.elevation_weight[e] = std::exp(-0.5 * offset * offset / (sigma_el * sigma_el));
    wsum += b.elevation_weight[e] * b.elevation_weight[e];
  }
  for (int e = 0; e < b.elevations; ++e) b.elevation_weight[e] /= std::sqrt(wsum);

  // The speckle lattice: one node per wavelength in the volume frame, two co-prime tiles.
  const int sizes[2] = {37, 41};
  for (int k = 0; k < 3; ++k) b.lattice_per_index[k] = grid.spacing_mm[k] / lambda;
  // Lattice coordinates met: the volume (noise is drawn only inside it) and the slice thickness
  // around it, plus a margin.
  const double reach = 1.5 * sigma_el / lambda + 4;
  int extent = 0;
  for (int k = 0; k < 3; ++k)
    extent = std::max(extent, int(std::ceil(double(grid.dims[k]) * b.lattice_per_index[k])));
  const int offset = int(std::ceil(reach)), count = extent + 2 * offset + 2;
  for (int t = 0; t < 2; ++t) {
    m.tiles[t] = simulate_impl::noise_tile(sizes[t], settings.seed * 2 + uint64_t(t) + 1);
    m.wraps[t].resize(size_t(count));
    for (int i = 0; i < count; ++i)
      m.wraps[t][size_t(i)] = ((i - offset) % sizes[t] + sizes[t]) % sizes[t];
    b.tiles[t] = {m.tiles[t].data(), sizes[t], m.wraps[t].data(), offset, count};
  }

  // Beams: one per image column, over the probe's shape.
  const ImageGrid& img = probe.image;
  b.width = img.width;
  b.height = img.height;
  b.x0 = img.origin_mm[0];
  b.y0 = img.origin_mm[1];
  b.sx = img.spacing_mm[0];
  b.sy = img.spacing_mm[1];
  b.beams = img.width;
  const double last_row_y = img.origin_mm[1] + (img.height - 1) * img.spacing_mm[1];
  if (probe.type == ProbeType::Curvilinear) {
    b.curvilinear = true;
    const double sector = probe.sector_deg * 3.141592653589793 / 180;
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
  b.speckle_gain = simulate_impl::speckle_gain(b);
  b.tgc_auto = settings.tgc_auto;
  b.bmode = settings.output == SimulationOutput::BMode;
  b.dynamic_range_db = settings.dynamic_range_db;
  b.mask = m.mask.data();
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

namespace simulate_impl {
namespace {

/// One image: trace every beam, the PSF (axial, then lateral at each depth), the envelope, TGC
/// and log compression, then scan conversion onto the probe's grid.
void simulate_image(const ImageModel& m, void* out, std::vector<float>& echo,
                    std::vector<float>& specular, std::vector<float>& loss,
                    std::vector<float>& tmp) {
  const int B = m.beams, S = m.samples;
  echo.resize(size_t(B) * S * 2);
  specular.resize(size_t(B) * S * 2);
  loss.resize(size_t(B) * S);
  tmp.resize(size_t(std::max(B, S)) * 2);
  for (int b = 0; b < B; ++b)
    trace_beam(m, b, echo.data() + 2 * size_t(b) * S, specular.data() + 2 * size_t(b) * S,
               loss.data() + size_t(b) * S);
  for (int b = 0; b < B; ++b) {
    gauss_complex(echo.data() + 2 * size_t(b) * S, S, 1, m.sigma_axial_samples, Scale::Peak,
                  tmp.data());
    gauss_complex(specular.data() + 2 * size_t(b) * S, S, 1, m.specular_sigma_axial_samples,
                  Scale::Peak, tmp.data());
  }
  for (int s = 0; s < S; ++s) {
    // Beams are beam_step apart: in mm at this depth for a fan, as given for a linear probe.
    const double spacing_mm =
        m.curvilinear ? (m.start + (s + 0.5) * m.step_mm) * m.beam_step : m.beam_step;
    gauss_complex(echo.data() + 2 * size_t(s), B, S, m.sigma_lateral_mm / spacing_mm, Scale::Sum,
                  tmp.data());
    gauss_complex(specular.data() + 2 * size_t(s), B, S, m.specular_sigma_lateral_mm / spacing_mm,
                  Scale::Sum, tmp.data());
  }
  for (size_t i = 0; i < echo.size(); i += 2) echo[i] += specular[i];
  // TGC: the median round-trip attenuation across the beams at each depth (auto), or none. The
  // median, not the mean: a few beams through gas or bone lose far more, and compensating them
  // would flood the others.
  std::vector<float>& level = tmp;
  level.assign(size_t(S), 0.f);
  if (m.tgc_auto) {
    std::vector<float> across(static_cast<size_t>(B));
    for (int s = 0; s < S; ++s) {
      for (int b = 0; b < B; ++b) across[size_t(b)] = loss[size_t(b) * S + s];
      std::nth_element(across.begin(), across.begin() + B / 2, across.end());
      level[size_t(s)] = across[size_t(B / 2)];
    }
  }
  // Scan conversion: the complex echo bilinear in (beam, sample) at each pixel inside the mask
  // (interpolating the complex signal keeps the speckle's statistics; an envelope would be
  // smoothed), then the envelope, TGC and log compression.
  for (int v = 0; v < m.height; ++v)
    for (int u = 0; u < m.width; ++u) {
      const int64_t i = int64_t(v) * m.width + u;
      double env = 0, gain_db = 0;
      if (m.mask[i]) {
        const double x = m.x0 + u * m.sx, y = m.y0 + v * m.sy;
        double fb, fs;
        if (m.curvilinear) {
          const double dy = y - m.apex_y;
          fb = (std::atan2(x, dy) - m.beam0) / m.beam_step;
          fs = (std::sqrt(x * x + dy * dy) - m.start) / m.step_mm - 0.5;
        } else {
          fb = (x - m.beam0) / m.beam_step;
          fs = (y - m.start) / m.step_mm - 0.5;
        }
        fb = clampd(fb, 0, B - 1);
        fs = clampd(fs, 0, S - 1);
        const int b0 = int(fb), s0 = int(fs);
        const int b1 = b0 + 1 < B ? b0 + 1 : b0, s1 = s0 + 1 < S ? s0 + 1 : s0;
        const double tb = fb - b0, ts = fs - s0;
        double c[2];
        for (int k = 0; k < 2; ++k) {
          const auto at = [&](int b, int s) { return double(echo[2 * (size_t(b) * S + s) + k]); };
          const double lo = at(b0, s0) + ts * (at(b0, s1) - at(b0, s0));
          const double hi = at(b1, s0) + ts * (at(b1, s1) - at(b1, s0));
          c[k] = lo + tb * (hi - lo);
        }
        env = std::sqrt(c[0] * c[0] + c[1] * c[1]);
        gain_db = level[size_t(s0)] + ts * (level[size_t(s1)] - level[size_t(s0)]);
      }
      if (!m.bmode) {
        static_cast<float*>(out)[i] = float(env);
        continue;
      }
      const double db = env > 0 ? 20 * std::log10(env) + gain_db : -1e9;
      const double grey = clampd(255.0 * (1.0 + db / m.dynamic_range_db), 0.0, 255.0);
      static_cast<uint8_t*>(out)[i] = uint8_t(std::floor(grey + 0.5));
    }
}

}  // namespace
}  // namespace simulate_impl

void Simulator::simulate(const Pose* poses, size_t count, void* out, size_t first_index) const {
  if (count == 0) return;
  validate_poses(poses, count, "poses", first_index, /*warn_non_orthonormal=*/false);
  const Model& m = *model_;
  const VolumeGrid& grid = m.volume.grid();
  const Mat3 L = grid.world_to_index_linear();
  const Vec3 o = grid.world_to_index_offset();
  const size_t bytes = image_bytes();
  backend::parallel_for(int64_t(count), [&](int64_t n) {
    ImageModel im = m.base;
    const Pose& p = poses[n];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        double s = 0;
        for (int k = 0; k < 3; ++k) s += L.m[r][k] * p.m[k][c];
        im.A[3 * r + c] = s;
      }
      double t = o[r];
      for (int k = 0; k < 3; ++k) t += L.m[r][k] * p.m[k][3];
      im.a[r] = t;
    }
    thread_local std::vector<float> echo, specular, loss, tmp;
    simulate_impl::simulate_image(im, static_cast<uint8_t*>(out) + size_t(n) * bytes, echo,
                                  specular, loss, tmp);
  });
}

}  // namespace sonoslice
