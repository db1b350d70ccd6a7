// The real tracked sweep of data/plus reconstructed with its PLUS configuration and
// compared with PLUS's own reconstruction (NwirePhantomFreehandReconstructed.mha).
//
// PLUS inserts each pixel into a uint8 volume and rounds the voxel to an integer after every
// update, with a uint16 accumulation buffer (weights in 1/256, saturating at 256). An
// emulation of that arithmetic (below, written from PLUS's documented update rule) reproduces
// the reference almost voxel for voxel, and the same emulation with float arithmetic matches
// sonoslice: the differences between sonoslice and PLUS are PLUS's rounding.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "../common/TestUtil.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"
#include "sonoslice/plus/TransformRepository.h"

namespace sonoslice {
namespace {

std::string plus_file(const std::string& name) {
  return test::data_dir() + "/plus/" + name;
}

struct Sweep {
  PlusSequence sequence;
  PlusReconstructionConfig config;
  std::vector<Mat4> image_to_reference;
  std::vector<int> frames;
};

Sweep load_nwire() {
  Sweep s;
  s.sequence = read_plus_sequence(plus_file("NwirePhantomFreehand.igs.mha"));
  s.config = read_plus_config(
      plus_file("PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"));
  for (int f = 0; f < s.sequence.frame_count; ++f) {
    TransformRepository repo = s.config.coordinate_definitions;
    repo.set_frame(s.sequence, f);
    const auto m = repo.get(s.config.image_frame, s.config.reference_frame);
    if (!m || !s.sequence.image_ok(f)) continue;
    s.image_to_reference.push_back(*m);
    s.frames.push_back(f);
  }
  return s;
}

// PLUS's LINEAR + MEAN insertion of one sweep into `grid` (its unoptimised path: the XML says
// Optimization="NONE"). `integer` = false replaces the uint8 voxels and uint16 weights by doubles.
std::vector<double> plus_linear_mean(const Sweep& s, const VolumeGrid& grid, bool integer) {
  const int64_t nx = grid.dims[0], ny = grid.dims[1];
  std::vector<double> out(size_t(grid.voxel_count()), 0), acc(out.size(), 0);
  // PLUS's Floor/Round carry a tolerance of about 2^-17.
  const auto floor_ = [](double x) { return std::floor(x + 7.62939453125e-06); };
  const auto round_ = [](double x) { return std::floor(x + 0.5 + 7.62939453125e-06); };
  const auto r = s.config.clip.rectangle(s.sequence.width, s.sequence.height);
  for (size_t k = 0; k < s.frames.size(); ++k) {
    const uint8_t* px = static_cast<const uint8_t*>(s.sequence.frame_pixels(s.frames[k]));
    for (int y = r[1]; y < r[3]; ++y)
      for (int x = r[0]; x < r[2]; ++x) {
        const Vec3 p = s.image_to_reference[k].transform_point({{double(x), double(y), 0.0}});
        double f[3];
        int64_t i0[3], i1[3];
        bool inside = true;  // PLUS drops a pixel unless all its corners are in the volume
        for (int a = 0; a < 3; ++a) {
          const double c = (p[a] - grid.origin_mm[a]) / grid.spacing_mm[a];
          i0[a] = int64_t(floor_(c));
          f[a] = c - double(i0[a]);
          i1[a] = i0[a] + (f[a] != 0);
          inside = inside && i0[a] >= 0 && i1[a] <= grid.dims[a] - 1;
        }
        if (!inside) continue;
        const double in = px[size_t(y) * s.sequence.width + x];
        for (int j = 7; j >= 0; --j) {  // PLUS's corner order: bit 2 x, bit 1 y, bit 0 z
          const int bx = (j >> 2) & 1, by = (j >> 1) & 1, bz = j & 1;
          const double w = (bx ? f[0] : 1 - f[0]) * (by ? f[1] : 1 - f[1]) * (bz ? f[2] : 1 - f[2]);
          if (w == 0) continue;
          const size_t i = size_t(((bz ? i1[2] : i0[2]) * ny + (by ? i1[1] : i0[1])) * nx +
                                  (bx ? i1[0] : i0[0]));
          const double old = acc[i] / 256.0, a = w + old;
          const double v = (w * in + old * out[i]) / a;
          out[i] = integer ? round_(v) : v;
          acc[i] = integer ? std::min(round_(a * 256), 65535.0) : a * 256;
        }
      }
  }
  return out;
}

struct Difference {
  double mad = 0, signed_mean = 0, exact = 0;
  int64_t voxels = 0;
};

// Over the voxels where `where(i)` holds; `a` rounded to integers as an output volume would be.
template <typename Where>
Difference compare(const std::vector<double>& a, const uint8_t* b, Where where) {
  Difference d;
  for (size_t i = 0; i < a.size(); ++i) {
    if (!where(i)) continue;
    const double e = std::floor(a[i] + 0.5) - double(b[i]);
    d.mad += std::fabs(e);
    d.signed_mean += e;
    d.exact += e == 0;
    ++d.voxels;
  }
  if (d.voxels) d.mad /= d.voxels, d.signed_mean /= d.voxels, d.exact /= d.voxels;
  return d;
}

// The grid PLUS's rule fits around the sweep's frames.
VolumeGrid frames_grid(const Sweep& s) {
  return Compounder::grid_around(s.image_to_reference, s.sequence.width, s.sequence.height,
                                 s.config.clip, *s.config.output_spacing_mm);
}

// FNV-1a over a uint8 volume's voxels, the hashes the IGSIO checks below keep.
uint64_t fnv1a(const Volume& v) {
  uint64_t h = 0xcbf29ce484222325ull;
  for (int64_t i = 0; i < v.grid().voxel_count(); ++i)
    h = (h ^ v.data_as<uint8_t>()[i]) * 0x100000001b3ull;
  return h;
}

TEST(PlusReconstruction, NwireSweepMatchesPlusReference) {
  SONOSLICE_REQUIRE_DATA();
  const Sweep s = load_nwire();
  ASSERT_EQ(s.frames.size(), 97u);
  const Volume reference = read_volume(plus_file("NwirePhantomFreehandReconstructed.mha"));
  const VolumeGrid& rg = reference.grid();

  // Our grid from the PLUS rule: same origin and spacing; PLUS 2.x's older rounding made the
  // reference one voxel shorter along y (103.90 voxels of extent: floor + 1 = 104, ours 105).
  const VolumeGrid grid = frames_grid(s);
  int longer = 0;
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(grid.origin_mm[a], rg.origin_mm[a], 1e-3) << "axis " << a;
    EXPECT_EQ(grid.spacing_mm[a], rg.spacing_mm[a]);
    EXPECT_GE(grid.dims[a], rg.dims[a]);
    EXPECT_LE(grid.dims[a], rg.dims[a] + 1);
    longer += grid.dims[a] != rg.dims[a];
  }
  EXPECT_LE(longer, 1);

  // sonoslice with the XML's settings, on the reference's grid for a voxel-by-voxel comparison.
  EXPECT_EQ(s.config.settings.interpolation, Interpolation::Linear);
  EXPECT_EQ(s.config.settings.mode, CompoundingMode::Mean);
  Compounder c(rg, s.config.settings);
  for (size_t k = 0; k < s.frames.size(); ++k)
    c.add_image(s.sequence.frame_pixels(s.frames[k]), s.sequence.pixel_type, s.sequence.width,
                s.sequence.height, s.image_to_reference[k], s.config.clip);
  const Volume ours = c.volume(PixelType::Float32), weights = c.weights();
  const float* v = ours.data_as<float>();
  const float* w = weights.data_as<float>();
  const uint8_t* ref = reference.data_as<uint8_t>();
  const std::vector<double> mine(v, v + rg.voxel_count());

  // Voxels both fill: every voxel a sample reached (PLUS reached the same ones, less a rim
  // where it drops pixels whose cell crosses the grid's edge).
  const Difference filled = compare(mine, ref, [&](size_t i) { return w[i] > 0; });
  const Difference bright = compare(mine, ref, [&](size_t i) { return w[i] > 0 && ref[i] > 0; });
  std::printf(
      "[ sonoslice vs PLUS ] filled voxels: %lld, MAD %.3f, identical %.1f%%; where PLUS "
      "is non-zero: %lld, MAD %.3f, mean signed %.3f\n",
      (long long)filled.voxels, filled.mad, 100 * filled.exact, (long long)bright.voxels,
      bright.mad, bright.signed_mean);
  EXPECT_GT(filled.voxels, 350000);
  EXPECT_LT(filled.mad, 0.3);  // the bound is 2; an empty volume would score about 1
  EXPECT_GT(filled.exact, 0.9);
  // On the wires PLUS is brighter: its per-update rounding (explained below), not a shift.
  EXPECT_GT(bright.voxels, 10000);
  EXPECT_LT(bright.mad, 7.0);
  EXPECT_LT(bright.signed_mean, 0.0);

  // The explanation: PLUS's integer arithmetic, emulated, gives the reference...
  const std::vector<double> plus_int = plus_linear_mean(s, rg, true);
  const Difference emulated = compare(plus_int, ref, [&](size_t i) { return ref[i] > 0; });
  std::printf("[ PLUS emulation vs PLUS ] where PLUS is non-zero: MAD %.3f, identical %.1f%%\n",
              emulated.mad, 100 * emulated.exact);
  EXPECT_LT(emulated.mad, 0.2);
  EXPECT_GT(emulated.exact, 0.9);
  // ...and the same insertion in floating point gives sonoslice's volume.
  const std::vector<double> plus_float = plus_linear_mean(s, rg, false);
  double max_diff = 0;
  int64_t compared = 0;
  const auto border = [&](size_t i) {  // PLUS drops the samples whose cell crosses the edge
    const int64_t x = int64_t(i) % rg.dims[0], y = int64_t(i) / rg.dims[0] % rg.dims[1],
                  z = int64_t(i) / (rg.dims[0] * rg.dims[1]);
    return x == 0 || y == 0 || z == 0 || x == rg.dims[0] - 1 || y == rg.dims[1] - 1 ||
           z == rg.dims[2] - 1;
  };
  for (size_t i = 0; i < mine.size(); ++i) {
    if (!(w[i] > 0) || border(i)) continue;
    max_diff = std::max(max_diff, std::fabs(plus_float[i] - mine[i]));
    ++compared;
  }
  std::printf("[ float emulation vs sonoslice ] max |difference| %.4f over %lld voxels\n", max_diff,
              (long long)compared);
  EXPECT_LT(max_diff, 0.05);
}

// --plus-exact: PLUS's arithmetic reproduced gives PLUS's reference byte for byte,
// over the grid both share (PLUS 2.x made this reference one voxel shorter along y), for any
// thread count.
// The sweep compounded on `grid` with `settings` on `threads` CPU threads.
Volume compound_sweep(const Sweep& s, const VolumeGrid& grid, const CompoundSettings& settings,
                      int threads) {
  set_cpu_threads(threads);
  Compounder c(grid, settings);
  for (size_t k = 0; k < s.frames.size(); ++k)
    c.add_image(s.sequence.frame_pixels(s.frames[k]), s.sequence.pixel_type, s.sequence.width,
                s.sequence.height, s.image_to_reference[k], s.config.clip);
  return c.volume(PixelType::UInt8);
}

TEST(PlusReconstruction, PlusExactGivesPlusReferenceByteForByte) {
  SONOSLICE_REQUIRE_DATA();
  const Sweep s = load_nwire();
  const Volume reference = read_volume(plus_file("NwirePhantomFreehandReconstructed.mha"));
  const VolumeGrid& rg = reference.grid();
  CompoundSettings settings = s.config.settings;
  settings.plus_exact = true;
  // PLUS's grid at full precision: the reference's header rounds the origin to 6 digits, which
  // moves every sample by up to 1e-4 voxel and changes roundings. Ours is one voxel longer in y.
  const VolumeGrid grid = frames_grid(s);
  ASSERT_EQ(grid.dims[0], rg.dims[0]);
  ASSERT_EQ(grid.dims[1], rg.dims[1] + 1);
  ASSERT_EQ(grid.dims[2], rg.dims[2]);
  std::vector<uint8_t> first;
  for (int threads : {1, 2, 5}) {
    const Volume full = compound_sweep(s, grid, settings, threads);
    std::vector<uint8_t> shared;  // our volume on the reference's 101 x 104 x 74
    for (int64_t z = 0; z < rg.dims[2]; ++z)
      for (int64_t y = 0; y < rg.dims[1]; ++y)
        for (int64_t x = 0; x < rg.dims[0]; ++x)
          shared.push_back(full.data_as<uint8_t>()[(z * grid.dims[1] + y) * grid.dims[0] + x]);
    const uint8_t* o = shared.data();
    const uint8_t* ref = reference.data_as<uint8_t>();
    int64_t differ = 0, nonzero = 0, first_diff = -1;
    for (int64_t i = 0; i < rg.voxel_count(); ++i) {
      nonzero += ref[i] != 0;
      if (o[i] != ref[i]) {
        if (first_diff < 0) first_diff = i;
        ++differ;
      }
    }
    std::printf("[ --plus-exact vs PLUS, %d threads ] %lld of %lld voxels differ (%lld non-zero)\n",
                threads, (long long)differ, (long long)rg.voxel_count(), (long long)nonzero);
    if (first_diff >= 0)
      std::printf("  first at %lld: ours %d, PLUS %d\n", (long long)first_diff, o[first_diff],
                  ref[first_diff]);
    EXPECT_GT(nonzero, 10000);  // the wires
    EXPECT_EQ(differ, 0);
    if (first.empty())
      first.assign(o, o + rg.voxel_count());
    else
      EXPECT_TRUE(std::equal(first.begin(), first.end(), o)) << threads << " threads";
  }
  reset_cpu_threads();
}

// PLUS's optimised paths (Optimization PARTIAL, FULL) on the NWire sweep: the FNV-1a hashes of
// the whole 101 x 105 x 74 volume that IGSIO's own vtkOptimizedInsertSlice<fixed|double, uint8>
// gives for these matrices (compiled from IGSIO's source with VTK 9.1 and run on one thread;
// docs/compounding.md §4b says how). Same bytes for 1, 2 and 5 threads.
TEST(PlusReconstruction, PlusExactOptimizedPathsGiveIgsioBytes) {
  SONOSLICE_REQUIRE_DATA();
  const Sweep s = load_nwire();
  const VolumeGrid grid = frames_grid(s);
  struct Case {
    PlusOptimization path;
    Interpolation interp;
    CompoundingMode mode;
    uint64_t hash;
  };
  const Case cases[] = {
      {PlusOptimization::Full, Interpolation::Linear, CompoundingMode::Mean, 0x1f1ce6ca62829fbaull},
      {PlusOptimization::Full, Interpolation::Nearest, CompoundingMode::Mean,
       0x080b465ccac44011ull},
      {PlusOptimization::Full, Interpolation::Linear, CompoundingMode::Max, 0x995af95ffb29a22bull},
      {PlusOptimization::Partial, Interpolation::Nearest, CompoundingMode::Max,
       0x8fa326e0c443f3deull},
  };
  for (const Case& k : cases) {
    CompoundSettings settings = s.config.settings;
    settings.plus_exact = true;
    settings.plus_optimization = k.path;
    settings.interpolation = k.interp;
    settings.mode = k.mode;
    // Every thread count for the first case; 2 threads for the others (each run takes ~2 s).
    for (int threads : k.hash == cases[0].hash ? std::vector<int>{1, 2, 5} : std::vector<int>{2}) {
      const Volume v = compound_sweep(s, grid, settings, threads);
      EXPECT_EQ(fnv1a(v), k.hash) << "path " << int(k.path) << ", mode " << int(k.mode) << ", "
                                  << threads << " threads";
    }
  }
  reset_cpu_threads();
}

// --plus-exact with hole filling: IGSIO's vtkIGSIOFillHolesInVolume elements (compiled from
// IGSIO's source, run on IGSIO's own pasted NWire volume and accumulation buffer, Optimization
// FULL, nearest, mean) give these FNV-1a hashes of the filled 101 x 105 x 74 volume.
TEST(PlusReconstruction, PlusExactHoleFillingGivesIgsioBytes) {
  SONOSLICE_REQUIRE_DATA();
  const Sweep s = load_nwire();
  const VolumeGrid grid = frames_grid(s);
  const auto element = [](HoleFillingKernel::Type type, int size, double stdev, double ratio) {
    HoleFillingKernel k;
    k.type = type;
    k.size = size;
    k.stdev = stdev;
    k.minimum_known_ratio = ratio;
    return k;
  };
  const auto stick = [](int limit, int count) {
    HoleFillingKernel k;
    k.type = HoleFillingKernel::Stick;
    k.stick_length_limit = limit;
    k.sticks_to_use = count;
    return k;
  };
  struct Case {
    std::vector<HoleFillingKernel> elements;
    uint64_t hash;
  };
  const Case cases[] = {
      {{element(HoleFillingKernel::GaussianAccumulation, 5, 1.0, 0.25)}, 0x06367594e5c16f6full},
      {{element(HoleFillingKernel::Gaussian, 5, 0.6667, 0.5), stick(9, 1)}, 0x3442066e557c7123ull},
      {{element(HoleFillingKernel::NearestNeighbor, 5, 0, 0.02), stick(11, 3)},
       0x22de5f74b000e4b6ull},
      {{element(HoleFillingKernel::DistanceWeightInverse, 5, 0, 0.125)}, 0x8a692e192c08797dull},
  };
  for (const Case& k : cases) {
    CompoundSettings settings = s.config.settings;
    settings.plus_exact = true;
    settings.plus_optimization = PlusOptimization::Full;
    settings.interpolation = Interpolation::Nearest;
    settings.mode = CompoundingMode::Mean;
    settings.fill_holes = true;
    settings.hole_filling = k.elements;
    const Volume v = compound_sweep(s, grid, settings, 2);
    EXPECT_EQ(fnv1a(v), k.hash) << "element " << int(k.elements[0].type);
  }
  reset_cpu_threads();
}

}  // namespace
}  // namespace sonoslice
