// Registration: analytic pose gradients against finite differences, recovery of
// perturbed poses from CT fans of the phantom, the rigid-sweep mode and bad input.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "../../src/io/TextParse.h"
#include "../common/TestUtil.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/plus/TransformRepository.h"
#include "sonoslice/register/Differentiable.h"
#include "sonoslice/register/PlusRegistration.h"
#include "sonoslice/register/Registration.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

const Phantom& phantom() {
  static const Phantom p = make_phantom(PhantomSize::Small);
  return p;
}

/// `p` with 1/k of its pixels along each axis, k times as large.
ProbeGeometry coarser(ProbeGeometry p, int k) {
  p.image.width /= k;
  p.image.height /= k;
  p.image.spacing_mm[0] *= k;
  p.image.spacing_mm[1] *= k;
  p.image.set_default_origin();
  return p;
}

/// W1's fan at half its pixels (167 × 136 at 0.494 mm): the small phantom's voxels are coarse.
ProbeGeometry probe() {
  return coarser(workload_w1_fan_probe(), 2);
}

std::vector<float> fans(const std::vector<Pose>& poses) {
  const Slicer slicer(phantom().ct, probe());
  return slicer.slice<float>(poses);
}

/// The poses' true images, with Gaussian noise of `sigma` HU (seeded).
std::vector<float> noisy_fans(const std::vector<Pose>& poses, double sigma) {
  std::vector<float> f = fans(poses);
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.f, float(sigma));
  for (float& v : f) v += noise(rng);
  return f;
}

/// Moves the pose by `mm` and `deg` about its frame centre along fixed, seeded directions.
Pose perturbed(const Pose& pose, const Vec3& centre, double mm, double deg, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0, 1);
  double t[3], a[3], nt = 0, na = 0;
  for (int i = 0; i < 3; ++i) {
    t[i] = n(rng);
    a[i] = n(rng);
    nt += t[i] * t[i];
    na += a[i] * a[i];
  }
  double xi[6];
  for (int i = 0; i < 3; ++i) {
    xi[i] = t[i] / std::sqrt(nt) * mm;
    xi[3 + i] = a[i] / std::sqrt(na) * deg * kPi / 180;
  }
  return apply_increment(pose, xi, centre);
}

/// (mm moved by the frame's centre, degrees turned) between two poses.
std::pair<double, double> pose_error(const Pose& a, const Pose& b, const Vec3& centre_probe) {
  const Vec3 ca = a.transform_point(centre_probe), cb = b.transform_point(centre_probe);
  double d = 0, trace = 0;
  for (int i = 0; i < 3; ++i) {
    d += (ca[i] - cb[i]) * (ca[i] - cb[i]);
    for (int k = 0; k < 3; ++k) trace += a.m[i][k] * b.m[i][k];
  }
  return {std::sqrt(d), std::acos(std::max(-1.0, std::min(1.0, (trace - 1) / 2))) * 180 / kPi};
}

/// `count` poses of `base` moved `step_mm` apart along its elevation axis, centred on it.
/// `count` poses `step_mm` apart along the probe's axis `axis` (2: through the image plane; 0:
/// across, within it), centred on `base`.
std::vector<Pose> straight_sweep(const Pose& base, int count, double step_mm, int axis = 2) {
  std::vector<Pose> sweep;
  for (int k = 0; k < count; ++k) {
    Pose p = base;
    for (int i = 0; i < 3; ++i) p.m[i][3] += step_mm * (k - (count - 1) / 2.0) * base.m[i][axis];
    sweep.push_back(p);
  }
  return sweep;
}

/// Every pose moved by the same world increment ξ about `c`.
std::vector<Pose> moved(const std::vector<Pose>& poses, const double xi[6], const Vec3& c) {
  std::vector<Pose> out;
  for (const Pose& p : poses) out.push_back(apply_increment(p, xi, c));
  return out;
}

Vec3 fan_centre() {
  const ProbeGeometry p = probe();
  return {0, p.face_y_mm + p.depth_mm / 2, 0};
}

TEST(Register, AnalyticGradientsMatchFiniteDifferences) {
  const std::vector<Pose> truth = {phantom_random_poses(3, 5)[1]};
  const std::vector<float> frame = fans(truth);
  const FrameRegistration reg(phantom().ct, probe(), frame.data(), 1);
  const Pose at = perturbed(truth[0], truth[0].transform_point(fan_centre()), 2, 2, 1);
  const Vec3 c = reg.centre(0, at);
  for (RegistrationMetric metric : {RegistrationMetric::SSD, RegistrationMetric::NCC}) {
    double g[6], H[36];
    metric_cost(metric, reg.terms(0, at, 1, c, true), g, H);
    const double steps[6] = {1e-3, 1e-3, 1e-3, 1e-5, 1e-5, 1e-5};  // mm, rad
    for (int k = 0; k < 6; ++k) {
      double xi[6] = {0, 0, 0, 0, 0, 0};
      xi[k] = steps[k];
      const double up = metric_cost(metric, reg.terms(0, apply_increment(at, xi, c), 1, c, false));
      xi[k] = -steps[k];
      const double down =
          metric_cost(metric, reg.terms(0, apply_increment(at, xi, c), 1, c, false));
      const double numeric = (up - down) / (2 * steps[k]);
      std::printf("[ gradient %s ] d/dxi%d analytic %.6g numeric %.6g\n", to_string(metric), k,
                  g[k], numeric);
      EXPECT_NEAR(g[k], numeric, 0.02 * std::fabs(numeric) + 1e-9 * (1 + std::fabs(g[k])));
    }
    for (int k = 0; k < 6; ++k) EXPECT_GT(H[7 * k], 0);  // Gauss–Newton diagonal
  }
}

// The AVX2 build samples four pixels at a time by gathers; it must pack the same values as the
// scalar build, so that a registration does not depend on the CPU it runs on: every sum equal
// bit for bit, with and without derivatives, at two levels, on fans inside the volume and on a
// fan that leaves it (whose lanes straddle the border), at widths that leave a scalar tail, in
// the phantom's axis-aligned grid and in an oblique, anisotropic copy of it (where every index
// axis mixes into every world axis, so that a sum taken in another order would show); and LC2's
// and local NCC's patch scores, built on the same samples, equal bit for bit too.
TEST(Register, Avx2AndGenericKernelsGiveTheSameTermsBitForBit) {
  if (!cpu_kernel_isa_available(CpuIsa::Avx2)) GTEST_SKIP() << "no AVX2 + FMA kernels here";
  std::vector<Pose> poses = phantom_random_poses(4, 11);
  Pose out = poses[0];
  for (int i = 0; i < 3; ++i) out.m[i][3] += 70 * out.m[i][0];  // half the fan beyond the side
  poses.push_back(out);
  Volume oblique = phantom().ct.converted(PixelType::Float32);
  const double a = 0.35, b = 0.2;  // radians about z, then about x
  const Mat3 rz{{{std::cos(a), -std::sin(a), 0}, {std::sin(a), std::cos(a), 0}, {0, 0, 1}}};
  const Mat3 rx{{{1, 0, 0}, {0, std::cos(b), -std::sin(b)}, {0, std::sin(b), std::cos(b)}}};
  oblique.grid().direction = rx * rz;
  oblique.grid().spacing_mm[2] *= 1.3;
  for (const Volume* volume : {&phantom().ct, static_cast<const Volume*>(&oblique)})
    for (const ProbeGeometry& p : {workload_w1_fan_probe(), probe()}) {
      const Slicer slicer(*volume, p);
      const std::vector<float> frames = slicer.slice<float>(poses);
      const FrameRegistration reg(*volume, p, frames.data(), poses.size());
      reg.prepare_level(2);
      double compared = 0;
      for (size_t k = 0; k < poses.size(); ++k) {
        const Pose at = perturbed(poses[k], poses[k].transform_point(fan_centre()), 1.5, 1.5, 3);
        for (int level : {1, 2})
          for (bool gradients : {true, false}) {
            set_cpu_kernel_isa(CpuIsa::Generic);
            const PoseTerms a = reg.terms(k, at, level, reg.centre(k, at), gradients);
            set_cpu_kernel_isa(CpuIsa::Avx2);
            const PoseTerms b = reg.terms(k, at, level, reg.centre(k, at), gradients);
            set_cpu_kernel_isa("auto");
            EXPECT_EQ(0, std::memcmp(&a, &b, sizeof a))
                << "width " << p.image.width << ", pose " << k << ", level " << level
                << (gradients ? ", with derivatives" : "") << ": n " << a.n << " / " << b.n
                << ", ΣJ·Jᵀ[20] " << a.sjj[20] << " / " << b.sjj[20];
            compared += a.n;
          }
        // LC2's and local NCC's per-pixel terms (beam gradients: curvilinear and linear beams).
        for (int level : {1, 2})
          for (RegistrationMetric metric : {RegistrationMetric::LC2, RegistrationMetric::LNCC}) {
            set_cpu_kernel_isa(CpuIsa::Generic);
            const std::pair<double, double> a = reg.patch_score(k, at, level, metric);
            set_cpu_kernel_isa(CpuIsa::Avx2);
            const std::pair<double, double> b = reg.patch_score(k, at, level, metric);
            set_cpu_kernel_isa("auto");
            EXPECT_EQ(0, std::memcmp(&a, &b, sizeof a))
                << to_string(metric) << ", width " << p.image.width << ", pose " << k << ", level "
                << level << ": " << a.first << " / " << b.first;
            EXPECT_GT(a.second, 0);
          }
      }
      EXPECT_GT(compared, 1000);
    }
}

// An int16 volume (a CT's own type) is read as it is, not copied to float32: every metric's
// sums must equal, bit for bit, those of its float32 copy (the same values), in both builds, at
// the full-resolution level (int16) and a coarser one (averaged into float32 from the int16).
TEST(Register, Int16VolumesGiveTheSameSumsAsTheirFloatCopies) {
  ASSERT_EQ(phantom().ct.pixel_type(), PixelType::Int16);
  const Volume floats = phantom().ct.converted(PixelType::Float32);
  const std::vector<Pose> poses = phantom_random_poses(3, 12);
  const ProbeGeometry p = workload_w1_fan_probe();
  const std::vector<float> frames = Slicer(phantom().ct, p).slice<float>(poses);
  const FrameRegistration a(phantom().ct, p, frames.data(), poses.size());
  const FrameRegistration b(floats, p, frames.data(), poses.size());
  std::vector<CpuIsa> isas = {CpuIsa::Generic};
  if (cpu_kernel_isa_available(CpuIsa::Avx2)) isas.push_back(CpuIsa::Avx2);
  for (const FrameRegistration* r : {&a, &b}) r->prepare_level(4);
  for (CpuIsa isa : isas) {
    set_cpu_kernel_isa(isa);
    for (size_t k = 0; k < poses.size(); ++k) {
      const Pose at = perturbed(poses[k], poses[k].transform_point(fan_centre()), 1.5, 1.5, 4);
      for (int level : {1, 4}) {
        const PoseTerms ta = a.terms(k, at, level, a.centre(k, at), true);
        const PoseTerms tb = b.terms(k, at, level, b.centre(k, at), true);
        EXPECT_EQ(0, std::memcmp(&ta, &tb, sizeof ta)) << "pose " << k << ", level " << level;
        EXPECT_GT(ta.n, 100);
        for (RegistrationMetric metric :
             {RegistrationMetric::LC2, RegistrationMetric::LNCC, RegistrationMetric::MI}) {
          const double ca = a.cost(k, at, level, metric), cb = b.cost(k, at, level, metric);
          EXPECT_EQ(0, std::memcmp(&ca, &cb, sizeof ca))
              << to_string(metric) << ", pose " << k << ", level " << level << ": " << ca << " / "
              << cb;
        }
      }
    }
  }
  set_cpu_kernel_isa("auto");
}

TEST(Register, RecoversPerturbedPosesFromNoisyCtFans) {
  const std::vector<Pose> truth = phantom_random_poses(8, 11);
  const std::vector<float> frames = noisy_fans(truth, 20);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), truth.size());
  std::vector<Pose> initial;
  for (size_t k = 0; k < truth.size(); ++k)
    initial.push_back(
        perturbed(truth[k], truth[k].transform_point(fan_centre()), 5, 5, unsigned(100 + k)));
  RegistrationSettings settings;  // NCC, LM, pyramid 8-4-2-1
  settings.starts = 4;
  settings.search_rot_deg = settings.search_trans_mm = 5;
  RegistrationReport report;
  const std::vector<Pose> refined = reg.run(initial, settings, &report);
  int within = 0;
  for (size_t k = 0; k < truth.size(); ++k) {
    const auto before = pose_error(initial[k], truth[k], fan_centre());
    const auto after = pose_error(refined[k], truth[k], fan_centre());
    std::printf(
        "[ recovery ] frame %zu: %.2f mm %.2f deg -> %.3f mm %.3f deg (%lld evaluations, "
        "1-NCC %.4f)\n",
        k, before.first, before.second, after.first, after.second,
        static_cast<long long>(report.frames[k].evaluations), report.frames[k].metric);
    within += after.first < 1 && after.second < 1;
  }
  EXPECT_EQ(within, int(truth.size()));
  EXPECT_EQ(report.frames.size(), truth.size());
  for (const FrameReport& r : report.frames) {
    EXPECT_EQ(r.starts, 4);
    EXPECT_TRUE(r.converged) << "frame " << r.index << ": " << r.agreeing_starts << " agreeing";
  }
  EXPECT_GT(report.evaluations, 0);
}

TEST(Register, RigidSweepRecoversOneSharedCorrection) {
  // A sweep of 6 frames 3 mm apart; the initial poses all carry the same world error X.
  const Pose base = phantom_random_poses(4, 3)[2];
  const std::vector<Pose> truth = straight_sweep(base, 6, 3.0);
  const std::vector<float> frames = noisy_fans(truth, 20);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), truth.size());
  const Vec3 c = truth[0].transform_point(fan_centre());
  const double xi[6] = {2.0, -1.5, 2.5, 0.03, -0.04, 0.02};  // mm, rad (about 3 degrees)
  const std::vector<Pose> initial = moved(truth, xi, c);
  // Every frame within 0.5 mm and 0.5° of the truth after registering in `mode`.
  RegistrationReport report;
  const auto expect_recovered = [&](RegistrationMode mode) {
    RegistrationSettings settings;
    settings.mode = mode;
    const std::vector<Pose> refined = reg.run(initial, settings, &report);
    for (size_t k = 0; k < truth.size(); ++k) {
      const auto e = pose_error(refined[k], truth[k], fan_centre());
      std::printf("[ %s ] frame %zu: %.3f mm %.3f deg\n", to_string(mode), k, e.first, e.second);
      EXPECT_LT(e.first, 0.5);
      EXPECT_LT(e.second, 0.5);
    }
  };
  expect_recovered(RegistrationMode::RigidSweep);
  // One correction: every frame's change is the same rotation.
  for (size_t k = 1; k < truth.size(); ++k)
    EXPECT_NEAR(report.frames[k].rotation_change_deg, report.frames[0].rotation_change_deg, 1e-6);
  // smooth-sweep from the same start ends near the truth too. (The comparison of the modes,
  // SmoothSweepTiesNeighbouringFramesTogether, is too slow for CI's sanitizer build; this is
  // where that build runs smooth-sweep's solver.)
  expect_recovered(RegistrationMode::SmoothSweep);
}

/// A linear probe at a quarter of W2's pixels (100 × 125 at 0.494 mm).
ProbeGeometry linear_probe() {
  return coarser(workload_w2_linear_probe(), 4);
}

// As a new user tries it: a straight 30-frame sweep of a linear probe, 1 mm apart, every frame
// off by one shared 5 mm / 5° error (the turn about the sweep line). At the defaults (automatic
// starts) the sweep is recovered and says it converged; a single start is never called converged.
TEST(Register, RigidSweepAtTheDefaultsConvergesAndSaysSo) {
  const Pose base = phantom_random_poses(4, 3)[2];
  const ProbeGeometry probe = linear_probe();
  const std::vector<Pose> truth = straight_sweep(base, 30, 1.0);
  const std::vector<float> frames = Slicer(phantom().ct, probe).slice<float>(truth);
  const FrameRegistration reg(phantom().ct, probe, frames.data(), truth.size());
  const Vec3 centre_probe = {0, probe.face_y_mm + probe.depth_mm / 2, 0};
  const Vec3 c = base.transform_point(centre_probe);
  const double deg = 5 * kPi / 180;
  const double xi[6] = {3, -4, 0, deg * base.m[0][2], deg * base.m[1][2], deg * base.m[2][2]};
  const std::vector<Pose> initial = moved(truth, xi, c);
  RegistrationSettings settings;
  settings.mode = RegistrationMode::RigidSweep;
  RegistrationReport report;
  const std::vector<Pose> refined = reg.run(initial, settings, &report);
  double worst_mm = 0, worst_deg = 0;
  for (size_t k = 0; k < truth.size(); ++k) {
    const auto e = pose_error(refined[k], truth[k], centre_probe);
    worst_mm = std::max(worst_mm, e.first);
    worst_deg = std::max(worst_deg, e.second);
  }
  std::printf(
      "[ rigid sweep, defaults ] worst frame %.3f mm %.3f deg; %d starts, %d agreeing, "
      "%.1f s\n",
      worst_mm, worst_deg, report.frames[0].starts, report.frames[0].agreeing_starts,
      report.seconds);
  EXPECT_LT(worst_mm, 0.5);
  EXPECT_LT(worst_deg, 0.5);
  for (const FrameReport& r : report.frames) EXPECT_TRUE(r.converged);
  EXPECT_GE(report.frames[0].agreeing_starts, kAgreeingStarts);
  // The halves check: a right answer fits both halves of the sweep.
  ASSERT_TRUE(report.halves_mm.has_value());
  std::printf("[ rigid sweep, defaults ] halves %.4f mm apart\n", *report.halves_mm);
  EXPECT_LT(*report.halves_mm, 0.1);
  // Through the image plane, the frames' halves see other tissue: the sides are not compared.
  EXPECT_FALSE(report.sides_mm.has_value());

  // One start: whatever it finds, it cannot confirm it.
  settings.starts = 1;
  const test::CapturedWarnings warnings;
  reg.run(initial, settings, &report);
  for (const FrameReport& r : report.frames) {
    EXPECT_FALSE(r.converged);
    EXPECT_EQ(r.starts, 1);
  }
  ASSERT_EQ(warnings.messages().size(), 1u);
  EXPECT_EQ(warnings.messages()[0].rfind("registration: 30 of 30 frames not converged", 0), 0u)
      << warnings.messages()[0];
}

// A tracking jump: the second half of a sweep was recorded 3 mm to the side of where it was
// taken. No one correction fits the whole sweep, whatever the starts agree on; refined alone,
// its halves end about 3 mm apart, so the sweep is not converged and the warning says why.
TEST(Register, RigidSweepWhoseHalvesDisagreeIsNotConverged) {
  const Pose base = phantom_random_poses(4, 3)[2];
  const ProbeGeometry probe = linear_probe();
  const std::vector<Pose> truth = straight_sweep(base, 20, 1.0);
  const std::vector<float> frames = Slicer(phantom().ct, probe).slice<float>(truth);
  const FrameRegistration reg(phantom().ct, probe, frames.data(), truth.size());
  std::vector<Pose> recorded = truth;
  for (size_t k = 10; k < recorded.size(); ++k)
    for (int i = 0; i < 3; ++i) recorded[k].m[i][3] += 3 * base.m[i][0];  // the probe's lateral
  RegistrationSettings settings;
  settings.mode = RegistrationMode::RigidSweep;
  RegistrationReport report;
  const test::CapturedWarnings warnings;
  reg.run(recorded, settings, &report);
  ASSERT_TRUE(report.halves_mm.has_value());
  std::printf("[ rigid sweep, tracking jump ] halves %.3f mm apart; %d of %d starts agree\n",
              *report.halves_mm, report.frames[0].agreeing_starts, report.frames[0].starts);
  EXPECT_GT(*report.halves_mm, 2.0);
  EXPECT_LT(*report.halves_mm, 4.0);
  for (const FrameReport& r : report.frames) EXPECT_FALSE(r.converged);
  bool said = false;
  for (const std::string& m : warnings.messages())
    said = said || m.rfind(
                       "registration: the sweep is not converged: refined alone from its "
                       "result, its first and second halves end 3.00 mm apart",
                       0) == 0;
  EXPECT_TRUE(said) << (warnings.messages().empty() ? "" : warnings.messages()[0]);

  // Per frame, no halves: each frame finds its own pose.
  settings.mode = RegistrationMode::PerFrame;
  settings.starts = 1;
  reg.run(recorded, settings, &report);
  EXPECT_FALSE(report.halves_mm.has_value());
}

// A sweep across the probe (within its image plane), whose frames' right halves were taken 3 mm
// through the plane from their left halves: no one correction fits both sides, but each half of
// the sweep sees much the same tissue with the same mismatch. Refined alone, the sides end about
// 3 mm apart, the frames' halves less.
TEST(Register, RigidSweepAcrossWhoseSidesDisagreeIsNotConverged) {
  const Pose base = phantom_random_poses(4, 3)[2];
  const ProbeGeometry probe = linear_probe();
  const std::vector<Pose> truth = straight_sweep(base, 20, 1.0, 0);
  std::vector<Pose> moved_through = truth;
  for (Pose& p : moved_through)
    for (int i = 0; i < 3; ++i) p.m[i][3] += 3 * base.m[i][2];  // along the probe's normal
  const Slicer slicer(phantom().ct, probe);
  std::vector<float> frames = slicer.slice<float>(truth);
  const std::vector<float> right = slicer.slice<float>(moved_through);
  const int W = probe.image.width;
  for (size_t i = 0; i < frames.size(); ++i)
    if (int(i % size_t(W)) >= W / 2) frames[i] = right[i];
  const FrameRegistration reg(phantom().ct, probe, frames.data(), truth.size());
  RegistrationSettings settings;
  settings.mode = RegistrationMode::RigidSweep;
  RegistrationReport report;
  const test::CapturedWarnings warnings;
  reg.run(truth, settings, &report);
  ASSERT_TRUE(report.halves_mm.has_value() && report.sides_mm.has_value());
  std::printf("[ rigid sweep across, sides 3 mm apart ] halves %.3f mm, sides %.3f mm\n",
              *report.halves_mm, *report.sides_mm);
  EXPECT_LT(*report.halves_mm, *report.sides_mm);
  EXPECT_GT(*report.sides_mm, 2.0);
  EXPECT_LT(*report.sides_mm, 4.0);
  for (const FrameReport& r : report.frames) EXPECT_FALSE(r.converged);
  ASSERT_EQ(warnings.messages().size(), 1u);
  const std::string& said = warnings.messages()[0];
  EXPECT_EQ(
      said.rfind("registration: the sweep is not converged: refined alone from its result, ", 0),
      0u)
      << said;
  EXPECT_NE(said.find("the left and right halves of its frames end 3.00 mm apart (the report's "
                      "sides_mm)"),
            std::string::npos)
      << said;

  // The same sweep without the mismatch: the sides agree.
  const std::vector<float> clean = slicer.slice<float>(truth);
  const FrameRegistration clean_reg(phantom().ct, probe, clean.data(), truth.size());
  clean_reg.run(truth, settings, &report);
  ASSERT_TRUE(report.sides_mm.has_value());
  std::printf("[ rigid sweep across ] halves %.4f mm, sides %.4f mm\n", *report.halves_mm,
              *report.sides_mm);
  EXPECT_LT(*report.sides_mm, 0.1);
  for (const FrameReport& r : report.frames) EXPECT_TRUE(r.converged);
}

// A probe calibration error: every frame's pose is off by the same probe-side X0 (T_i·X0⁻¹ given
// for T_i), frames at unrelated orientations, so no world-side correction explains it.
// Calibration mode (Levenberg–Marquardt on the derivatives turned into the probe frame) finds X0.
TEST(Register, CalibrationModeFindsOneProbeSideError) {
  const std::vector<Pose> truth = phantom_random_poses(8, 13);
  const std::vector<float> frames = noisy_fans(truth, 20);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), truth.size());
  double xi[6] = {1.5, -1.0, 1.2, 0.02, -0.025, 0.015};  // mm, rad (about 2 degrees)
  const Pose X0 = apply_increment(Pose::identity(), xi, fan_centre());
  const Pose X0_inverse = *invert(X0);
  std::vector<Pose> initial;
  for (const Pose& t : truth) initial.push_back(t * X0_inverse);
  RegistrationSettings settings;
  settings.mode = RegistrationMode::Calibration;
  RegistrationReport report;
  const std::vector<Pose> refined = reg.run(initial, settings, &report);
  for (size_t k = 0; k < truth.size(); ++k) {
    const auto before = pose_error(initial[k], truth[k], fan_centre());
    const auto e = pose_error(refined[k], truth[k], fan_centre());
    std::printf("[ calibration ] frame %zu: %.2f mm %.2f deg -> %.3f mm %.3f deg\n", k,
                before.first, before.second, e.first, e.second);
    EXPECT_LT(e.first, 0.3);
    EXPECT_LT(e.second, 0.3);
    EXPECT_TRUE(report.frames[k].converged);
  }
  ASSERT_TRUE(report.correction.has_value());
  const auto x_error = pose_error(*report.correction, X0, fan_centre());
  std::printf("[ calibration ] X against X0: %.3f mm %.3f deg\n", x_error.first, x_error.second);
  EXPECT_LT(x_error.first, 0.3);
  EXPECT_LT(x_error.second, 0.3);
}

// One frame has the threads to itself: its candidate starts are ranked and its starts optimised
// side by side, the ends taken in start order. Poses and reports must not depend on the thread
// count, also when the stopping rule falls while another start runs (automatic starts stop at
// the third agreeing one, so two threads optimise a fourth that is dropped).
// Also for a frame of noise, whose automatic starts (up to default_max_starts) end apart, so that
// most of them stop at the coarse levels (docs/registration.md §3): which ones does not depend on
// the thread count either.
TEST(Register, OneFrameGivesTheSameResultOnAnyThreadCount) {
  const std::vector<Pose> truth = phantom_random_poses(1, 31);
  // Every start of the noise frame runs: a frame of a quarter of the pixels keeps that quick.
  const ProbeGeometry small = coarser(probe(), 2);
  std::vector<float> noise(size_t(small.image.pixel_count()));
  std::mt19937 rng(3);
  std::normal_distribution<float> normal(0.f, 100.f);
  for (float& v : noise) v = normal(rng);
  const std::vector<std::pair<std::vector<float>, ProbeGeometry>> cases = {
      {noisy_fans(truth, 20), probe()}, {noise, small}};
  for (const auto& [frames, frame_probe] : cases) {
    const FrameRegistration reg(phantom().ct, frame_probe, frames.data(), 1);
    const std::vector<Pose> initial = {
        perturbed(truth[0], truth[0].transform_point(fan_centre()), 5, 5, 7)};
    RegistrationSettings settings;  // NCC, automatic starts
    settings.search_rot_deg = settings.search_trans_mm = 5;
    std::vector<std::vector<Pose>> refined;
    std::vector<RegistrationReport> reports(3);
    for (int threads : {1, 2, 3}) {
      set_cpu_threads(threads);
      refined.push_back(reg.run(initial, settings, &reports[refined.size()]));
    }
    reset_cpu_threads();
    const FrameReport& one = reports[0].frames[0];
    std::printf("[ threads ] %d starts, %d agreeing, %lld evaluations\n", one.starts,
                one.agreeing_starts, static_cast<long long>(one.evaluations));
    EXPECT_GE(one.starts, kAgreeingStarts);
    for (size_t t = 1; t < refined.size(); ++t) {
      EXPECT_EQ(0, std::memcmp(&refined[t][0], &refined[0][0], sizeof(Pose)))
          << t + 1 << " threads";
      const FrameReport& r = reports[t].frames[0];
      EXPECT_EQ(r.starts, one.starts);
      EXPECT_EQ(r.agreeing_starts, one.agreeing_starts);
      EXPECT_EQ(r.evaluations, one.evaluations);
      EXPECT_EQ(r.iterations, one.iterations);
      EXPECT_EQ(r.metric, one.metric);
    }
  }
}

// Frames that match nothing in the volume (noise): the starts end in different places, and the
// frames are reported not converged, with one warning.
TEST(Register, NoiseFramesAreNotConverged) {
  const std::vector<Pose> truth = phantom_random_poses(2, 21);
  std::vector<float> frames(truth.size() * size_t(probe().image.pixel_count()));
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.f, 100.f);
  for (float& v : frames) v = noise(rng);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), truth.size());
  const test::CapturedWarnings warnings;
  RegistrationReport report;
  reg.run(truth, {}, &report);
  for (const FrameReport& r : report.frames) {
    std::printf("[ noise ] frame %zu: %d starts, %d agreeing\n", r.index, r.starts,
                r.agreeing_starts);
    EXPECT_FALSE(r.converged);
    EXPECT_EQ(r.starts, default_max_starts(RegistrationSettings().metric));
  }
  EXPECT_EQ(warnings.messages().size(), 1u);
}

TEST(Register, SmoothSweepTiesNeighbouringFramesTogether) {
  // A sweep of 12 frames 2 mm apart. The initial poses carry a shared error (3 mm, 3°), a slow
  // drift along the sweep, and independent jitter; the frames are very noisy, and frames 5 and 6
  // have almost nothing to register on (their pixels replaced by noise alone).
  const Pose base = phantom_random_poses(4, 3)[2];
  const size_t n = 12;
  std::vector<Pose> truth;
  for (size_t k = 0; k < n; ++k) {
    Pose p = base;
    for (int i = 0; i < 3; ++i) p.m[i][3] += 2.0 * (double(k) - 5.5) * base.m[i][2];
    truth.push_back(p);
  }
  std::vector<float> frames = noisy_fans(truth, 150);
  const size_t plane = size_t(probe().image.pixel_count());
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.f, 150.f);
  for (size_t k : {size_t(5), size_t(6)})
    for (size_t i = 0; i < plane; ++i) frames[k * plane + i] = noise(rng);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), n);
  const Vec3 c = truth[0].transform_point(fan_centre());
  std::vector<Pose> initial;
  for (size_t k = 0; k < n; ++k) {
    const double drift = 0.15 * double(k);
    double xi[6] = {3.0 * 0.6 + drift, -3.0 * 0.6, 3.0 * 0.5, 0.03, -0.03, 0.02};
    const Pose shared = apply_increment(truth[k], xi, c);
    initial.push_back(
        perturbed(shared, shared.transform_point(fan_centre()), 0.7, 0.7, unsigned(200 + k)));
  }
  const auto mean_error = [&](RegistrationMode mode, const char* name) {
    RegistrationSettings settings;
    settings.mode = mode;
    RegistrationReport report;
    const std::vector<Pose> refined = reg.run(initial, settings, &report);
    double mm = 0, deg = 0, worst = 0;
    for (size_t k = 0; k < n; ++k) {
      const auto e = pose_error(refined[k], truth[k], fan_centre());
      std::printf("[ %s ] frame %zu: %.3f mm %.3f deg (%lld evaluations)\n", name, k, e.first,
                  e.second, static_cast<long long>(report.frames[k].evaluations));
      mm += e.first / double(n);
      deg += e.second / double(n);
      worst = std::max({worst, e.first, e.second});
    }
    std::printf("[ %s ] mean %.3f mm %.3f deg, worst %.3f\n", name, mm, deg, worst);
    EXPECT_EQ(report.frames.size(), n);
    return std::array<double, 3>{mm, deg, worst};
  };
  const auto per_frame = mean_error(RegistrationMode::PerFrame, "per frame");
  const auto rigid = mean_error(RegistrationMode::RigidSweep, "rigid sweep");
  const auto smooth = mean_error(RegistrationMode::SmoothSweep, "smooth sweep");
  // Per frame, the two empty frames wander off; one rigid correction cannot follow the drift
  // and jitter; the prior keeps the empty frames with their neighbours and lets the others move.
  EXPECT_GT(per_frame[2], 5);
  EXPECT_LT(smooth[0], rigid[0]);
  EXPECT_LT(smooth[1], rigid[1]);
  EXPECT_LT(smooth[2], 1.5);
}

TEST(Register, DerivativeFreeOptimisersRecoverPoses) {
  if (!built_with_nlopt()) GTEST_SKIP() << "built without NLopt";
  const std::vector<Pose> truth = phantom_random_poses(8, 11);
  const std::vector<Pose> two = {truth[1], truth[5]};
  const std::vector<float> frames = noisy_fans(two, 20);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), two.size());
  std::vector<Pose> initial;
  for (size_t k = 0; k < two.size(); ++k)
    initial.push_back(
        perturbed(two[k], two[k].transform_point(fan_centre()), 3, 3, unsigned(200 + k)));
  for (RegistrationOptimizer optimizer :
       {RegistrationOptimizer::Bobyqa, RegistrationOptimizer::NelderMead}) {
    RegistrationSettings settings;
    settings.optimizer = optimizer;
    RegistrationReport report;
    const std::vector<Pose> refined = reg.run(initial, settings, &report);
    for (size_t k = 0; k < two.size(); ++k) {
      const auto e = pose_error(refined[k], two[k], fan_centre());
      std::printf("[ %s ] frame %zu: 3 mm 3 deg -> %.3f mm %.3f deg (%lld evaluations)\n",
                  optimizer == RegistrationOptimizer::Bobyqa ? "bobyqa" : "nelder-mead", k, e.first,
                  e.second, static_cast<long long>(report.frames[k].evaluations));
      EXPECT_LT(e.first, 1);
      EXPECT_LT(e.second, 1);
    }
  }
}

TEST(Register, PatchAndHistogramMetricsPreferTheTruePoseAndRecoverFromCtLikeFrames) {
  if (!built_with_nlopt()) GTEST_SKIP() << "built without NLopt";
  // Frames that are a linear function of the CT plus noise: LC2's fit, the local NCCs and the
  // joint histogram all explain them best at the true pose, and BOBYQA finds it.
  const std::vector<Pose> truth = phantom_random_poses(8, 11);
  const std::vector<Pose> two = {truth[1], truth[5]};
  std::vector<float> frames = noisy_fans(two, 20);
  for (float& v : frames) v = 0.25f * v + 40;
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), two.size());
  std::vector<Pose> initial;
  for (size_t k = 0; k < two.size(); ++k)
    initial.push_back(
        perturbed(two[k], two[k].transform_point(fan_centre()), 3, 3, unsigned(300 + k)));
  for (RegistrationMetric metric :
       {RegistrationMetric::LC2, RegistrationMetric::LNCC, RegistrationMetric::MI}) {
    for (size_t k = 0; k < two.size(); ++k) {
      const double at_truth = reg.cost(k, two[k], 1, metric);
      const double off = reg.cost(k, initial[k], 1, metric);
      std::printf("[ %s ] frame %zu: cost %.4f at the truth, %.4f 3 mm and 3 deg off\n",
                  to_string(metric), k, at_truth, off);
      EXPECT_LT(at_truth, off);
    }
    RegistrationSettings settings;
    settings.metric = metric;
    settings.optimizer = RegistrationOptimizer::Bobyqa;
    const std::vector<Pose> refined = reg.run(initial, settings, nullptr);
    for (size_t k = 0; k < two.size(); ++k) {
      const auto e = pose_error(refined[k], two[k], fan_centre());
      std::printf("[ %s ] frame %zu: 3 mm 3 deg -> %.3f mm %.3f deg\n", to_string(metric), k,
                  e.first, e.second);
      EXPECT_LT(e.first, 1);
      EXPECT_LT(e.second, 1);
    }
    settings.optimizer = RegistrationOptimizer::LevenbergMarquardt;
    EXPECT_THROW(reg.run(initial, settings, nullptr), InputError);  // no derivatives
  }
}

TEST(Register, Lc2FitsAPatchAroundEveryPixel) {
  // A volume linear in world (trilinear sampling reproduces it: p = 2x + 3y + z/2 + 1 and the
  // gradient along the linear probe's beams g = 3 everywhere, so each patch's fit is U on p
  // alone) and a frame correlated with it plus noise, with a user mask: LC2 must be Wein's
  // Σ σ_U·R² / Σ σ_U over the (2·5 + 1)² patch centred on every compared pixel that has at least
  // half its patch compared, computed here by brute force.
  VolumeGrid grid;
  grid.dims = {40, 40, 5};
  grid.spacing_mm = {1, 1, 1};
  grid.origin_mm = {-20, -5, -2};
  Volume volume = Volume::allocate(PixelType::Float32, grid);
  for (int64_t z = 0; z < 5; ++z)
    for (int64_t y = 0; y < 40; ++y)
      for (int64_t x = 0; x < 40; ++x)
        volume.data_as<float>()[(z * 40 + y) * 40 + x] =
            float(2 * (x - 20) + 3 * (y - 5) + 0.5 * (z - 2) + 1);
  ProbeGeometry probe = ProbeGeometry::linear(ImageGrid::centred(30, 24, 0.5, 0.5));
  const int W = probe.image.width, H = probe.image.height;
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0, 1);
  std::vector<float> frame(size_t(W) * H), p(frame.size());
  std::vector<uint8_t> mask(frame.size(), 1);
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) {
      const double x = probe.image.origin_mm[0] + u * 0.5, y = probe.image.origin_mm[1] + v * 0.5;
      p[size_t(v) * W + u] = float(2 * x + 3 * y + 1);
      // Correlation that changes across the frame, and a mask whose rows start and end inside
      // the frame (the kernels skip each row's columns outside its mask), with a gap inside
      // rows and a row without any pixel.
      frame[size_t(v) * W + u] = float(p[size_t(v) * W + u] * (u / double(W)) + 4 * noise(rng));
      if ((u > 20 && v > 15) || 3 * u < v || (u == 12 && v < 10) || v == 3)
        mask[size_t(v) * W + u] = 0;
    }
  const FrameRegistration reg(volume, probe, frame.data(), 1, mask.data());
  const auto [weighted, weight] = reg.patch_score(0, Pose::identity(), 1, RegistrationMetric::LC2);
  double want_weighted = 0, want_weight = 0;
  const std::vector<uint8_t> fan = probe.mask();
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) {
      if (!mask[size_t(v) * W + u] || !fan[size_t(v) * W + u]) continue;
      double n = 0, su = 0, sp = 0, suu = 0, spp = 0, sup = 0;
      for (int b = v - 5; b <= v + 5; ++b)
        for (int a = u - 5; a <= u + 5; ++a) {
          if (a < 0 || b < 0 || a >= W || b >= H) continue;
          const size_t i = size_t(b) * W + a;
          if (!mask[i] || !fan[i]) continue;
          n += 1;
          su += frame[i];
          sp += p[i];
          suu += double(frame[i]) * frame[i];
          spp += double(p[i]) * p[i];
          sup += double(frame[i]) * p[i];
        }
      if (n < 60.5) continue;
      const double vu = suu / n - su * su / n / n, vp = spp / n - sp * sp / n / n;
      const double c = sup / n - su * sp / n / n;
      want_weighted += std::sqrt(vu) * c * c / (vp * vu);
      want_weight += std::sqrt(vu);
    }
  ASSERT_GT(want_weight, 0);
  EXPECT_NEAR(weight, want_weight, 1e-9 * want_weight);
  EXPECT_NEAR(weighted / weight, want_weighted / want_weight, 1e-6);
  std::printf("[ LC2 ] %.6f (brute force %.6f)\n", weighted / weight, want_weighted / want_weight);

  // A flat volume explains nothing: every patch's fit is 0, not the round-off of its sums.
  for (int64_t i = 0; i < grid.voxel_count(); ++i) volume.data_as<float>()[i] = 1000.3f;
  const FrameRegistration flat(volume, probe, frame.data(), 1, mask.data());
  const auto [flat_weighted, flat_weight] =
      flat.patch_score(0, Pose::identity(), 1, RegistrationMetric::LC2);
  EXPECT_EQ(flat_weighted, 0.0);
  EXPECT_NEAR(flat_weight, want_weight, 1e-9 * want_weight);
}

TEST(Register, DifferentiableSliceGradientsMatchFiniteDifferences) {
  // A 9×8×7 float64 volume of smooth random values, a 5×4 linear probe at an oblique pose.
  VolumeGrid grid;
  grid.dims = {9, 8, 7};
  grid.spacing_mm = {0.9, 1.1, 1.0};
  Volume volume = Volume::allocate(PixelType::Float64, grid);
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0, 1);
  for (int64_t i = 0; i < grid.voxel_count(); ++i) volume.data_as<double>()[i] = n(rng);
  ProbeGeometry probe;
  probe.type = ProbeType::Linear;
  probe.image.width = 5;
  probe.image.height = 4;
  probe.image.spacing_mm[0] = probe.image.spacing_mm[1] = 0.7;
  probe.image.set_default_origin();
  Pose T = apply_increment(
      Pose::identity(), std::array<double, 6>{3.1, 2.3, 2.7, 0.2, 0.3, 0.1}.data(), Vec3{0, 0, 0});
  const size_t pixels = 20;
  std::vector<double> weights(pixels);
  for (double& w : weights) w = n(rng);
  const auto loss = [&](const Pose& pose) {
    std::vector<double> img(pixels);
    slice_linear_f64(volume, probe, &pose, 1, 0.0, img.data());
    double l = 0;
    for (size_t i = 0; i < pixels; ++i) l += weights[i] * img[i];
    return l;
  };
  double grad[16];
  std::vector<double> grad_volume(size_t(grid.voxel_count()), 0.0);
  slice_linear_backward(volume, probe, &T, 1, weights.data(), grad, grad_volume.data());
  std::vector<double> img(pixels);
  slice_linear_f64(volume, probe, &T, 1, std::nan(""), img.data());
  for (double v : img) ASSERT_TRUE(std::isfinite(v));  // every pixel inside the volume
  for (int e = 0; e < 12; ++e) {
    Pose up = T, down = T;
    up.m[e / 4][e % 4] += 1e-6;
    down.m[e / 4][e % 4] -= 1e-6;
    EXPECT_NEAR(grad[e], (loss(up) - loss(down)) / 2e-6, 1e-5 * (1 + std::fabs(grad[e]))) << e;
  }
  // The volume gradient: the loss is linear in the voxels, so dL/dV_j is exactly the change.
  int touched = 0;
  for (double g : grad_volume) touched += g != 0;
  EXPECT_GT(touched, 20);
  for (int64_t j = 0; j < grid.voxel_count(); j += 37) {
    const double before = loss(T);
    volume.data_as<double>()[j] += 1;
    EXPECT_NEAR(loss(T) - before, grad_volume[size_t(j)], 1e-9) << j;
    volume.data_as<double>()[j] -= 1;
  }
}

TEST(Register, BadInputIsNamed) {
  const std::vector<Pose> truth = phantom_random_poses(2, 5);
  const std::vector<float> frames = fans(truth);
  const FrameRegistration reg(phantom().ct, probe(), frames.data(), truth.size());
  EXPECT_THROW(reg.run({truth[0]}, {}, nullptr), InputError);  // 1 pose for 2 frames
  std::vector<Pose> bad = truth;
  bad[1].m[0][3] = std::nan("");
  try {
    reg.run(bad, {}, nullptr);
    FAIL() << "a NaN pose was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("pose 1"), std::string::npos) << e.what();
  }
  RegistrationSettings s;
  s.starts = 0;
  EXPECT_THROW(reg.run(truth, s, nullptr), InputError);
  EXPECT_THROW(parse_registration_metric("mutual"), InputError);
  EXPECT_FALSE(metric_has_derivatives(parse_registration_metric("mi")));
  EXPECT_THROW(parse_registration_optimizer("adam"), InputError);
  EXPECT_THROW(parse_registration_mode("sweep"), InputError);
}

TEST(Register, SettingsChooseTheOptimiserAndNameTheSetting) {
  RegistrationSettings s;
  EXPECT_FALSE(s.optimizer.has_value());
  EXPECT_EQ(*s.resolved().optimizer, RegistrationOptimizer::LevenbergMarquardt);
  s.metric = RegistrationMetric::SSD;
  EXPECT_EQ(*s.resolved().optimizer, RegistrationOptimizer::LevenbergMarquardt);
  for (RegistrationMetric m :
       {RegistrationMetric::LNCC, RegistrationMetric::MI, RegistrationMetric::LC2}) {
    s.metric = m;
    EXPECT_EQ(*s.resolved().optimizer, RegistrationOptimizer::Bobyqa);
  }
  s.optimizer = RegistrationOptimizer::GaussNewton;  // given: kept
  EXPECT_EQ(*s.resolved().optimizer, RegistrationOptimizer::GaussNewton);
  // Errors name the setting as the caller spells it: the library's name, or a CLI's flag.
  const auto message = [](const RegistrationSettings& bad, const ParameterNames& names) {
    try {
      bad.validate(names);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const ParameterNames flags = [](const std::string& p) { return "--" + p; };
  EXPECT_EQ(message(s, {}), std::string("metric lc2 has no analytic derivatives: use optimizer "
                                        "bobyqa or nelder-mead"));
  EXPECT_EQ(message(s, flags), std::string("--metric lc2 has no analytic derivatives: use "
                                           "--optimizer bobyqa or nelder-mead"));
  RegistrationSettings t;
  t.starts = 0;
  EXPECT_EQ(message(t, {}), "starts 0: must be at least 1");
  t = RegistrationSettings();
  t.pyramid = std::vector<int>{4, 0};
  EXPECT_EQ(message(t, flags).rfind("--pyramid 4,0: expected block sizes from 1 to 64", 0), 0u);
  for (std::vector<int> levels : {std::vector<int>{1, 2}, std::vector<int>{4, 4, 1}}) {
    t.pyramid = levels;  // fine to coarse, or a level twice: the result would not be the finest
    EXPECT_NE(message(t, {}).find(": the block sizes must decrease, coarse to fine"),
              std::string::npos);
  }
  t.pyramid = std::vector<int>{4, 2};  // stopping above full resolution is allowed
  EXPECT_EQ(message(t, {}), "no error");
  // smooth-sweep's prior weight: chosen for that mode, refused in another (it changes nothing).
  t = RegistrationSettings();
  EXPECT_FALSE(t.resolved().smoothness);
  t.mode = RegistrationMode::SmoothSweep;
  EXPECT_EQ(*t.resolved().smoothness, RegistrationSettings::kDefaultSmoothness);
  t.smoothness = 2.0;
  EXPECT_EQ(*t.resolved().smoothness, 2.0);
  t.mode = RegistrationMode::RigidSweep;
  EXPECT_EQ(message(t, flags),
            "--smoothness: applies to --mode smooth-sweep (the prior between "
            "neighbouring frames' corrections), not rigid-sweep");
  // One spelling table per choice.
  for (RegistrationMetric m :
       {RegistrationMetric::SSD, RegistrationMetric::NCC, RegistrationMetric::LNCC,
        RegistrationMetric::MI, RegistrationMetric::LC2})
    EXPECT_EQ(parse_registration_metric(to_string(m)), m);
  for (RegistrationOptimizer o :
       {RegistrationOptimizer::GaussNewton, RegistrationOptimizer::LevenbergMarquardt,
        RegistrationOptimizer::Bobyqa, RegistrationOptimizer::NelderMead})
    EXPECT_EQ(parse_registration_optimizer(to_string(o)), o);
  for (RegistrationMode m :
       {RegistrationMode::PerFrame, RegistrationMode::RigidSweep, RegistrationMode::SmoothSweep})
    EXPECT_EQ(parse_registration_mode(to_string(m)), m);
  try {
    parse_registration_metric("mutual", "--metric");
    FAIL() << "parsed";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), "--metric mutual: expected ssd, ncc, lncc, mi or lc2");
  }
}

// A corrected PLUS sequence: whichever way the frame's own transform is stored (ProbeToTracker
// walked forwards, or TrackerToProbe walked backwards), the configuration's chain of the
// corrected frame is the correction times the original, and the rest is kept.
TEST(RegisterPlus, CorrectedSequenceChainsToTheRefinedMatrices) {
  PlusReconstructionConfig config;
  const Mat4 image_to_probe =
      Mat4::from_columns({0.2, 0, 0}, {0, 0.2, 0.01}, {0, -0.01, 1}, {-30, 5, 2});
  config.coordinate_definitions.set("Image", "Probe", image_to_probe);
  const Mat4 reference_to_tracker =
      Mat4::from_rotation_translation(test::rotation({0, 0, 1}, 30), {100, -20, 5});
  const Mat4 probe_to_tracker[2] = {
      Mat4::from_rotation_translation(test::rotation(normalized({1, 1, 0}), 20), {5, 6, 7}),
      Mat4::from_rotation_translation(test::rotation(normalized({0, 1, 1}), -40), {-8, 2, 30})};
  PlusRegistration registration;
  registration.frames = {1};  // frame 0 is not used: kept as it is
  registration.corrections = {
      Mat4::from_rotation_translation(test::rotation(normalized({1, -2, 0.5}), 3), {1.5, -2, 0.7})};
  for (const bool stored_backwards : {false, true}) {
    PlusSequence s;
    s.path = "sweep.igs.mha";
    s.width = s.height = 2;
    s.frame_count = 2;
    s.pixels.assign(8, 7);
    for (int k = 0; k < 2; ++k) {
      const Mat4 tracked = stored_backwards ? *invert(probe_to_tracker[k]) : probe_to_tracker[k];
      s.frame_fields.push_back(
          {{stored_backwards ? "TrackerToProbeTransform" : "ProbeToTrackerTransform",
            text::format_matrix16(tracked)},
           {"ReferenceToTrackerTransform", text::format_matrix16(reference_to_tracker)},
           {"ImageStatus", "OK"}});
    }
    const PlusSequence corrected = corrected_plus_sequence(s, config, registration);
    const auto image_to_reference = [&](const PlusSequence& seq, int frame) {
      TransformRepository r = config.coordinate_definitions;
      r.set_frame(seq, frame);
      return *r.get("Image", "Reference");
    };
    const Mat4 want = registration.corrections[0] * image_to_reference(s, 1);
    const Mat4 got = image_to_reference(corrected, 1);
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) EXPECT_NEAR(got.m[r][c], want.m[r][c], 1e-9) << r << c;
    EXPECT_EQ(corrected.frame_fields[0], s.frame_fields[0]);
    EXPECT_EQ(corrected.frame_fields[1].at("ReferenceToTrackerTransform"),
              s.frame_fields[1].at("ReferenceToTrackerTransform"));
    EXPECT_EQ(corrected.pixels, s.pixels);
  }
  // A chain of the configuration's transforms alone has nothing of the frame's to correct.
  PlusReconstructionConfig fixed;
  fixed.coordinate_definitions.set("Image", "Reference", image_to_probe);
  PlusSequence s;
  s.path = "still.igs.mha";
  s.width = s.height = s.frame_count = 1;
  s.pixels.assign(1, 0);
  s.frame_fields.push_back({{"ImageStatus", "OK"}});
  registration.frames = {0};
  try {
    corrected_plus_sequence(s, fixed, registration);
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(),
                 "still.igs.mha: frame 0: its ImageToReference holds none of the frame's own "
                 "transforms to correct");
  }
}

}  // namespace
}  // namespace sonoslice
