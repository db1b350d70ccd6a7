// Ultrasound simulation: the analytic checks of the model, docs/simulation.md §5.
// Phantoms are label volumes built here; the probe is a linear probe looking down +y of the
// phantom's frame. Each physics check runs at three orientations of the probe to the volume's
// axes (Aligned, Oblique30, CubeDiagonal; SimulateTestUtil.h): the phantom is voxelised in the
// probe-relative frame, label(world) = f(Rᵀ(world − c) + c), and every pose is rotated by the same
// R about c, so the anatomy in the image, its rows and columns and the thresholds are the same
// while the speckle lattice (along the volume's axes) is crossed obliquely.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <numeric>
#include <optional>
#include <string>
#include <vector>

#include "../common/TestUtil.h"
#include "SimulateTestUtil.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/simulate/Simulator.h"

namespace sonoslice {
namespace {

// The shared phantoms, probes, poses and statistics (SimulateTestUtil.h).
using namespace simtest;

/// The physics checks, once per orientation: phantom() and pose_at() give today's phantom and
/// poses rotated together by the orientation's R about simtest::kCentre.
class Oriented : public ::testing::TestWithParam<simtest::Orientation> {
 protected:
  const char* name() const { return GetParam().name.c_str(); }
  Volume phantom(const simtest::LabelFn& label) const {
    return simtest::oriented_phantom(label, GetParam());
  }
  Pose pose_at(double z, double y0 = 2.0) const {
    return simtest::rotated_about(simtest::pose_at(z, y0), GetParam().rotation);
  }
  /// Fails the test when an image (grown by 2 mm: the slice thickness, the gradient's reach)
  /// would leave the volume: the rotated phantoms are sized for these images.
  void expect_inside(const Volume& v, const ProbeGeometry& probe,
                     const std::vector<Pose>& poses) const {
    for (const Pose& p : poses)
      EXPECT_TRUE(simtest::image_inside(v, probe, p, 2.0)) << "an image leaves the phantom";
  }
};

INSTANTIATE_TEST_SUITE_P(Simulate, Oriented, ::testing::ValuesIn(simtest::orientations()),
                         simtest::OrientationName());

// The orientations are what their names say.
TEST(Simulate, OrientationsCrossTheVolumeAxes) {
  for (const auto& o : simtest::orientations()) {
    const Vec3 x = o.rotation.column(0), y = o.rotation.column(1), z = o.rotation.column(2);
    std::printf(
        "[ orientation %s ] from the nearest volume axis: lateral %.1f deg, beam %.1f deg, "
        "elevation %.1f deg; elevation to the cube diagonal %.1f deg\n",
        o.name.c_str(), simtest::angle_to_nearest_axis(x), simtest::angle_to_nearest_axis(y),
        simtest::angle_to_nearest_axis(z), simtest::angle_deg(z, {1, 1, 1}));
    EXPECT_NEAR(o.rotation.determinant(), 1.0, 1e-12);
    EXPECT_NEAR(dot(x, y), 0.0, 1e-12);
  }
  EXPECT_NEAR(simtest::angle_to_nearest_axis(simtest::oblique30().rotation.column(2)), 30.0, 1e-9);
  for (int k = 0; k < 3; ++k)
    EXPECT_GT(simtest::angle_to_nearest_axis(simtest::oblique30().rotation.column(k)), 25.0);
  EXPECT_NEAR(simtest::angle_deg(simtest::cube_diagonal().rotation.column(2), {1, 1, 1}), 0.0,
              1e-6);
}

// 1. Fully developed speckle, homogeneous scatterer, no attenuation: Rayleigh statistics.
TEST_P(Oriented, FullyDevelopedSpeckleIsRayleigh) {
  const Volume v = phantom([](double, double, double) { return 1; });
  const Simulator sim(v, SimulationSource::Labels, linear_probe(), {tissue(1, 1.6, 0.0, 0.02)},
                      envelope_settings());
  std::vector<Pose> poses;
  for (int k = 0; k < 6; ++k) poses.push_back(pose_at(10 + 5 * k));
  expect_inside(v, sim.probe(), poses);
  const auto img = envelope(sim, poses);
  std::vector<double> env, logs;
  for (int k = 0; k < 6; ++k)
    for (double e : region(img, sim.width(), sim.height(), k, 10, 120, 10, 90)) {
      env.push_back(e);
      logs.push_back(20 * std::log10(e));
    }
  const double snr = mean(env) / stdev(env), log_sd = stdev(logs);
  std::printf("[ speckle %s ] SNR %.3f (Rayleigh 1.913), log-envelope sd %.3f dB (5.57)\n", name(),
              snr, log_sd);
  // Calibration: a tissue's mean speckle envelope is its scatter_mean.
  std::printf("[ speckle %s ] mean envelope %.4f (scatter_mean 0.02)\n", name(), mean(env));
  EXPECT_NEAR(mean(env), 0.02, 0.1 * 0.02);
  EXPECT_NEAR(snr, 1.913, 0.05 * 1.913);
  EXPECT_NEAR(log_sd, 5.57, 0.05 * 5.57);
}

// 2. Speckle size: the envelope intensity's autocorrelation has the PSF's widths (for a Gaussian
// PSF of amplitude FWHM F, fully developed speckle's intensity autocorrelation has FWHM F).
TEST_P(Oriented, SpeckleSizeIsThePsf) {
  const ProbeGeometry probe = linear_probe(300, 300, 0.03);
  SimulationSettings st = envelope_settings();
  st.axial_fwhm_mm = 0.4;
  st.lateral_fwhm_mm = 0.8;
  const Volume v = phantom([](double, double, double) { return 1; });
  const Simulator sim(v, SimulationSource::Labels, probe, {tissue(1, 1.6, 0.0, 0.02)}, st);
  double axial = 0, lateral = 0;
  for (int k = 0; k < 4; ++k) {
    const Pose pose = pose_at(15 + 5 * k, 10);
    expect_inside(v, probe, {pose});
    const auto env = envelope(sim, {pose});
    std::vector<float> intensity(env.size());
    for (size_t i = 0; i < env.size(); ++i) intensity[i] = env[i] * env[i];
    axial += 0.25 * 0.03 * simtest::acf_fwhm(intensity, 300, 300, 0, 1);
    lateral += 0.25 * 0.03 * simtest::acf_fwhm(intensity, 300, 300, 1, 0);
  }
  std::printf(
      "[ speckle size %s ] intensity autocorrelation FWHM: axial %.3f mm (PSF 0.4), lateral "
      "%.3f mm (PSF 0.8)\n",
      name(), axial, lateral);
  EXPECT_NEAR(axial, 0.4, 0.15 * 0.4);
  EXPECT_NEAR(lateral, 0.8, 0.15 * 0.8);
}

// 3. Attenuation: with TGC off the mean log envelope falls 2·α·f dB per cm; with auto TGC the
// B-mode image is flat.
TEST_P(Oriented, AttenuationSlopeAndAutoTgc) {
  const double alpha = 0.5, f = 3.5;
  const Volume v = phantom([](double, double, double) { return 1; });
  const std::vector<Tissue> t = {tissue(1, 1.6, alpha, 0.02)};
  const Simulator sim(v, SimulationSource::Labels, linear_probe(), t, envelope_settings(f));
  std::vector<Pose> poses;
  for (int k = 0; k < 6; ++k) poses.push_back(pose_at(10 + 5 * k));
  expect_inside(v, sim.probe(), poses);
  const auto img = envelope(sim, poses);
  // Mean log envelope per row, rows 10..120 (3 mm .. 36 mm), least-squares slope.
  std::vector<double> depth, level;
  for (int r = 10; r < 120; ++r) {
    double s = 0;
    int n = 0;
    for (int k = 0; k < 6; ++k)
      for (double e : region(img, sim.width(), sim.height(), k, r, r + 1, 10, 90)) {
        s += 20 * std::log10(e);
        ++n;
      }
    depth.push_back(r * 0.03);  // cm
    level.push_back(s / n);
  }
  const double md = mean(depth), ml = mean(level);
  double sxy = 0, sxx = 0;
  for (size_t i = 0; i < depth.size(); ++i) {
    sxy += (depth[i] - md) * (level[i] - ml);
    sxx += (depth[i] - md) * (depth[i] - md);
  }
  const double slope = sxy / sxx;
  std::printf("[ attenuation %s ] %.3f dB/cm (expected %.3f)\n", name(), slope, -2 * alpha * f);
  EXPECT_NEAR(slope, -2 * alpha * f, 0.1 * 2 * alpha * f);

  SimulationSettings st = envelope_settings(f);
  st.output = SimulationOutput::BMode;
  st.tgc_auto = true;
  const Simulator bmode(v, SimulationSource::Labels, linear_probe(), t, st);
  const auto b = simtest::bmode(bmode, poses);
  // Mean pixel value in 5 mm bands: within 1 dB (255/60 levels per dB) of each other.
  std::vector<double> bands;
  for (int r0 = 10; r0 + 16 <= 122; r0 += 16) {
    double s = 0;
    int n = 0;
    for (int k = 0; k < 6; ++k)
      for (int r = r0; r < r0 + 16; ++r)
        for (int c = 10; c < 90; ++c) {
          s += b[(size_t(k) * bmode.height() + r) * bmode.width() + c];
          ++n;
        }
    bands.push_back(s / n);
  }
  const double spread =
      *std::max_element(bands.begin(), bands.end()) - *std::min_element(bands.begin(), bands.end());
  std::printf("[ auto TGC %s ] band means spread %.2f grey levels (1 dB = %.2f)\n", name(), spread,
              255.0 / 60);
  EXPECT_LT(spread, 255.0 / 60);
}

// 4. A bone plate: bright echo, then at least 40 dB less behind it; gas: nothing behind it;
// tilting the plate lowers the echo.
TEST_P(Oriented, BoneAndGasShadow) {
  for (int shadow : {2, 3}) {  // 2 bone, 3 gas
    const std::vector<Tissue> t = {tissue(1, 1.63, 0.54, 0.02), tissue(2, 7.8, 20.0, 0.05),
                                   tissue(3, 0.0004, 12.0, 0.0)};
    const Volume v =
        phantom([&](double, double y, double) { return y >= 17 && y < 21 ? shadow : 1; });
    const Simulator sim(v, SimulationSource::Labels, linear_probe(), t, envelope_settings());
    expect_inside(v, sim.probe(), {pose_at(25)});
    const auto img = envelope(sim, {pose_at(25)});
    const int w = sim.width(), h = sim.height();
    // Rows: 0.3 mm from y = 2: the plate's top at y = 17 is row 50.
    const double above = mean(region(img, w, h, 0, 20, 45, 10, 90));
    double peak = 0;
    for (double e : region(img, w, h, 0, 45, 56, 10, 90)) peak = std::max(peak, e);
    const double behind = mean(region(img, w, h, 0, 75, 125, 10, 90));
    const double drop_db = 20 * std::log10(above / std::max(behind, 1e-30));
    std::printf(
        "[ %s plate %s ] peak %.4f, peak/above %.1f dB, behind: %.1f dB below the tissue above\n",
        shadow == 2 ? "bone" : "gas", name(), peak, 20 * std::log10(peak / above), drop_db);
    EXPECT_GT(peak, 5 * above);
    EXPECT_GT(drop_db, shadow == 2 ? 40.0 : 100.0);
  }
  // Tilted 30° about the elevation axis: the returned echo falls.
  const std::vector<Tissue> t = {tissue(1, 1.63, 0.0, 0.0), tissue(2, 7.8, 20.0, 0.0)};
  double peaks[2];
  for (int tilted = 0; tilted < 2; ++tilted) {
    const double slope = tilted ? std::tan(30 * 3.141592653589793 / 180) : 0;
    const Simulator sim(
        phantom([&](double x, double y, double) { return y >= 17 + slope * (x - 25) ? 2 : 1; }),
        SimulationSource::Labels, linear_probe(), t, envelope_settings());
    const auto img = envelope(sim, {pose_at(25)});
    // The beam at the probe's centre (column 50).
    double peak = 0;
    for (double e : region(img, sim.width(), sim.height(), 0, 30, 70, 45, 55))
      peak = std::max(peak, e);
    peaks[tilted] = peak;
  }
  std::printf("[ tilt %s ] flat %.4f, 30 deg %.4f: %.1f dB\n", name(), peaks[0], peaks[1],
              20 * std::log10(peaks[1] / peaks[0]));
  EXPECT_LT(peaks[1], 0.5 * peaks[0]);
}

// 5. Interface strengths follow R = ((Z2 − Z1)/(Z2 + Z1))² (the echo amplitude is √R).
TEST_P(Oriented, InterfaceEchoesFollowTheReflectionCoefficient) {
  const Volume v = phantom([](double, double y, double) { return y >= 17 ? 2 : 1; });
  const auto echo = [&](double z1, double z2) {
    const std::vector<Tissue> t = {tissue(1, z1, 0.0, 0.0), tissue(2, z2, 0.0, 0.0)};
    const Simulator sim(v, SimulationSource::Labels, linear_probe(), t, envelope_settings());
    const auto img = envelope(sim, {pose_at(25)});
    double peak = 0;
    for (double e : region(img, sim.width(), sim.height(), 0, 40, 60, 30, 70))
      peak = std::max(peak, e);
    return peak;
  };
  const auto r = [](double z1, double z2) { return (z2 - z1) / (z2 + z1); };
  const double fat_liver = echo(1.38, 1.65), liver_blood = echo(1.65, 1.61),
               soft_bone = echo(1.63, 7.8);
  std::printf(
      "[ interfaces %s ] fat/liver %.4g, liver/blood %.4g, soft tissue/bone %.4g (|r|: %.4g, "
      "%.4g, %.4g)\n",
      name(), fat_liver, liver_blood, soft_bone, std::fabs(r(1.38, 1.65)), std::fabs(r(1.65, 1.61)),
      std::fabs(r(1.63, 7.8)));
  std::printf(
      "[ interfaces %s ] ratios fat-liver/soft-bone %.4f (expected %.4f), liver-blood/fat-liver "
      "%.4f (expected %.4f)\n",
      name(), fat_liver / soft_bone, std::fabs(r(1.38, 1.65) / r(1.63, 7.8)),
      liver_blood / fat_liver, std::fabs(r(1.65, 1.61) / r(1.38, 1.65)));
  EXPECT_NEAR(fat_liver / soft_bone, std::fabs(r(1.38, 1.65) / r(1.63, 7.8)),
              0.05 * fat_liver / soft_bone);
  EXPECT_NEAR(liver_blood / fat_liver, std::fabs(r(1.65, 1.61) / r(1.38, 1.65)),
              0.05 * liver_blood / fat_liver);
}

// 6. A water cyst: anechoic inside, brighter behind it than beside it.
TEST_P(Oriented, CystIsAnechoicWithPosteriorEnhancement) {
  const std::vector<Tissue> t = {tissue(1, 1.63, 0.7, 0.02), tissue(2, 1.48, 0.0022, 0.0)};
  const Simulator sim(
      phantom([](double x, double y, double z) {
        return (x - 25) * (x - 25) + (y - 15) * (y - 15) + (z - 25) * (z - 25) < 36 ? 2 : 1;
      }),
      SimulationSource::Labels, linear_probe(), t, envelope_settings());
  const auto img = envelope(sim, {pose_at(25)});
  const int w = sim.width(), h = sim.height();
  // Centre (25, 15) mm: column 50, row 43. Behind: rows 70..110 under the cyst (columns 45..55)
  // against the same rows 20 columns aside.
  const double inside = mean(region(img, w, h, 0, 38, 48, 45, 55));
  const double around = mean(region(img, w, h, 0, 38, 48, 5, 20));
  const double behind = mean(region(img, w, h, 0, 70, 110, 45, 55));
  const double beside = mean(region(img, w, h, 0, 70, 110, 5, 20));
  std::printf("[ cyst %s ] inside/around %.1f dB, behind/beside %+.1f dB\n", name(),
              20 * std::log10(inside / around), 20 * std::log10(behind / beside));
  EXPECT_LT(inside, 0.1 * around);
  EXPECT_GT(behind, 1.2 * beside);
}

// 7. Determinism and a speckle field fixed in the volume.
TEST_P(Oriented, SameSeedSameBytesOnAnyThreadCount) {
  const test::ScopedCpuSettings restore;
  const Volume v = phantom([](double, double y, double z) { return y > 20 && z > 20 ? 2 : 1; });
  const std::vector<Tissue> t = {tissue(1, 1.63, 0.54, 0.02), tissue(2, 1.65, 0.5, 0.03)};
  SimulationSettings st;
  st.seed = 11;
  std::vector<Pose> poses = {pose_at(20), pose_at(24), pose_at(28)};
  std::vector<std::vector<uint8_t>> runs;
  for (int threads : {1, 2, 5}) {
    set_cpu_threads(threads);
    const Simulator sim(v, SimulationSource::Labels, linear_probe(), t, st);
    runs.push_back(simtest::bmode(sim, poses));
  }
  EXPECT_EQ(runs[0], runs[1]);
  EXPECT_EQ(runs[0], runs[2]);
  st.seed = 12;
  const Simulator other(v, SimulationSource::Labels, linear_probe(), t, st);
  EXPECT_NE(runs[0], simtest::bmode(other, poses));
}

TEST_P(Oriented, SpeckleDecorrelatesWithElevationalShift) {
  const Simulator sim(phantom([](double, double, double) { return 1; }), SimulationSource::Labels,
                      linear_probe(), {tissue(1, 1.6, 0.0, 0.02)}, envelope_settings());
  const auto img = envelope(sim, {pose_at(25), pose_at(25.1), pose_at(30)});
  const int w = sim.width(), h = sim.height();
  const auto a = region(img, w, h, 0, 10, 120, 10, 90);
  const double near = correlation(a, region(img, w, h, 1, 10, 120, 10, 90));
  const double far = correlation(a, region(img, w, h, 2, 10, 120, 10, 90));
  std::printf("[ elevation %s ] correlation at 0.1 mm %.3f, at 5 mm %.3f\n", name(), near, far);
  EXPECT_GT(near, 0.8);
  EXPECT_LT(far, 0.2);
}

// 8. CT mode and label mode agree where the CT holds the table's HU.
TEST_P(Oriented, CtAndLabelsAgree) {
  // Water (0 HU, label 1) above liver (60 HU, label 4): the knots give the default table's
  // water and liver there.
  const Volume labels = phantom([](double, double y, double) { return y >= 15 ? 4 : 1; });
  Volume ct = Volume::allocate(PixelType::Int16, labels.grid());
  for (int64_t i = 0; i < labels.grid().voxel_count(); ++i)
    ct.data_as<int16_t>()[i] = labels.data_as<uint8_t>()[i] == 4 ? 60 : 0;
  const auto st = envelope_settings();
  const Simulator a(labels, SimulationSource::Labels, linear_probe(), default_tissues(), st);
  const Simulator b(ct, SimulationSource::HounsfieldUnits, linear_probe(), {}, st);
  const auto ia = envelope(a, {pose_at(25)}), ib = envelope(b, {pose_at(25)});
  const int w = a.width(), h = a.height();
  // Deep in the liver (rows 60..120): the same speckle, the same attenuation.
  const auto ra = region(ia, w, h, 0, 60, 120, 10, 90), rb = region(ib, w, h, 0, 60, 120, 10, 90);
  std::printf("[ CT vs labels %s ] liver mean %.4g vs %.4g, correlation %.3f\n", name(), mean(ra),
              mean(rb), correlation(ra, rb));
  EXPECT_NEAR(mean(rb), mean(ra), 0.02 * mean(ra));
  EXPECT_GT(correlation(ra, rb), 0.99);
}

// A float CT with NaN and infinite voxels (missing data) simulates without a crash; NaN reads as
// outside the volume.
TEST(Simulate, NonFiniteHuIsNoData) {
  const Volume labels = phantom([](double, double, double) { return 1; });
  Volume ct = Volume::allocate(PixelType::Float32, labels.grid());
  float* v = ct.data_as<float>();
  for (int64_t i = 0; i < labels.grid().voxel_count(); ++i)
    v[i] = i % 7 == 0 ? std::nanf("") : (i % 11 == 0 ? INFINITY : 50.f);
  const Simulator sim(ct, SimulationSource::HounsfieldUnits, linear_probe(), {},
                      envelope_settings());
  const auto img = envelope(sim, {pose_at(25)});
  for (float e : img) ASSERT_TRUE(std::isfinite(e));
}

TEST(Simulate, BadInputIsNamed) {
  const Volume v = phantom([](double, double, double) { return 7; });
  EXPECT_THROW(Simulator(v, SimulationSource::Labels, linear_probe(), {tissue(1, 1.6, 0, 0)}),
               InputError);  // label 7 missing
  EXPECT_THROW(Simulator(v, SimulationSource::Labels, linear_probe(),
                         {tissue(7, 1.6, 0, 0), tissue(7, 1.5, 0, 0)}),
               InputError);  // label twice
  EXPECT_THROW(Simulator(v, SimulationSource::Labels, linear_probe(), {tissue(7, -1, 0, 0)}),
               InputError);
  SimulationSettings st;
  st.frequency_mhz = std::nan("");
  EXPECT_THROW(Simulator(v, SimulationSource::Labels, linear_probe(), {tissue(7, 1.6, 0, 0)}, st),
               InputError);
  const Simulator sim(v, SimulationSource::Labels, linear_probe(), {tissue(7, 1.6, 0, 0.02)});
  Pose bad = pose_at(25);
  bad.m[0][0] = std::nan("");
  std::vector<uint8_t> out(sim.image_bytes(), 42);
  EXPECT_THROW(sim.simulate(&bad, 1, out.data()), InputError);
  EXPECT_EQ(out[0], 42);  // nothing written
}

TEST(Simulate, SettingsChooseTheFrequencyAndTheProbeAndNameTheSetting) {
  SimulationSettings s;
  EXPECT_FALSE(s.frequency_mhz.has_value());
  EXPECT_EQ(*s.resolved().frequency_mhz, SimulationSettings::kDefaultFrequencyMhz);
  s.preset = "lus";
  EXPECT_EQ(*s.resolved().frequency_mhz, simulation_preset("lus").frequency_mhz);
  s.frequency_mhz = 3.0;
  EXPECT_EQ(*s.resolved().frequency_mhz, 3.0);
  // Without a probe, the preset's; without either, an error naming the probe.
  const Volume v = phantom([](double, double, double) { return 7; });
  const Simulator sim(v, SimulationSource::Labels, std::nullopt, {tissue(7, 1.6, 0, 0.02)}, s);
  EXPECT_EQ(sim.width(), simulation_preset("lus").probe.image.width);
  EXPECT_EQ(*sim.settings().frequency_mhz, 3.0);
  EXPECT_THROW(Simulator(v, SimulationSource::Labels, std::nullopt, {tissue(7, 1.6, 0, 0.02)}),
               InputError);
  // Errors name the setting as the caller spells it: the library's name, or a CLI's flag.
  const auto message = [](const SimulationSettings& bad, const ParameterNames& names) {
    try {
      bad.resolved(names);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  SimulationSettings bad;
  bad.preset = "nope";
  EXPECT_EQ(message(bad, {}).rfind("preset nope: unknown (presets: abdominal", 0), 0u);
  const ParameterNames flags = [](const std::string& p) { return "--" + p; };
  EXPECT_EQ(message(bad, flags).rfind("--preset nope: unknown", 0), 0u);
  for (SimulationOutput o : {SimulationOutput::BMode, SimulationOutput::Envelope})
    EXPECT_EQ(parse_simulation_output(to_string(o)), o);
  for (SimulationSource k : {SimulationSource::HounsfieldUnits, SimulationSource::Labels})
    EXPECT_EQ(parse_simulation_source(to_string(k)), k);
  EXPECT_THROW(parse_simulation_output("rf"), InputError);
}

}  // namespace
}  // namespace sonoslice
