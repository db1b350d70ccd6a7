// Pose samplers: geometry against analytic shapes (a ball "body" with a gas cavity,
// a sphere mesh), tilt ranges, uniform rotations (Kolmogorov–Smirnov), sweeps, rejection,
// determinism, and bad settings.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "../common/TestUtil.h"
#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/sampling/PoseSampler.h"
#include "sonoslice/sampling/SamplerConfig.h"

namespace sonoslice {
namespace {

constexpr double kDeg = kPi / 180;
const Vec3 kCentre{4, -3, 2};
constexpr double kRadius = 55, kCavity = 15;  // the body ball and a gas ball inside it

/// A CT of a soft-tissue ball (0 HU) with an air cavity (−1000 HU) in air, 1.5 mm voxels, each
/// voxel by the spheres the mean of 8³ sub-samples: the −500 HU isosurface lies on the spheres to
/// ~0.1 mm.
const Volume& ball() {
  static const Volume v = [] {
    VolumeGrid g;
    g.dims = {90, 90, 90};
    g.spacing_mm = {1.5, 1.5, 1.5};
    for (int a = 0; a < 3; ++a) g.origin_mm[a] = -0.5 * 89 * 1.5;
    Volume out = Volume::allocate(PixelType::Int16, g);
    int16_t* data = out.data_as<int16_t>();
    for (int64_t z = 0; z < 90; ++z)
      for (int64_t y = 0; y < 90; ++y)
        for (int64_t x = 0; x < 90; ++x) {
          // Only voxels near a sphere need sub-samples.
          const Vec3 c = g.index_to_world(Vec3{double(x), double(y), double(z)});
          const double rc = norm(c - kCentre);
          double tissue = rc < kRadius && rc > kCavity;
          if (std::fabs(rc - kRadius) < 2 || std::fabs(rc - kCavity) < 2) {
            constexpr int n = 8;
            tissue = 0;
            for (int s = 0; s < n * n * n; ++s) {
              const Vec3 p = g.index_to_world(Vec3{x + (s % n + 0.5) / n - 0.5,
                                                   y + ((s / n) % n + 0.5) / n - 0.5,
                                                   z + (s / (n * n) + 0.5) / n - 0.5});
              const double r = norm(p - kCentre);
              tissue += (r < kRadius && r > kCavity) / double(n * n * n);
            }
          }
          data[(z * 90 + y) * 90 + x] = int16_t(std::lround(-1000 + 1000 * tissue));
        }
    return out;
  }();
  return v;
}

SamplerSettings skin(const char* json = "{\"type\": \"skin\"}") {
  return parse_sampler_json(json, "test");
}

std::vector<uint64_t> seeds(size_t n, uint64_t stream = 0) {
  return sample_seeds(7, stream, 0, n);
}

/// The Kolmogorov–Smirnov statistic of `values` against the CDF `F`.
template <typename F>
double ks(std::vector<double> values, const F& cdf) {
  std::sort(values.begin(), values.end());
  double d = 0;
  const double n = double(values.size());
  for (size_t i = 0; i < values.size(); ++i) {
    const double f = cdf(values[i]);
    d = std::max({d, std::fabs(f - i / n), std::fabs(f - (i + 1) / n)});
  }
  return d;
}

TEST(PoseSampler, SkinFaceTouchesTheSurfaceAndLooksAlongTheInwardNormal) {
  const ProbeGeometry p = workload_w1_fan_probe();
  const PoseSampler sampler(skin(), p, &ball());
  // Every surface point is on the outer sphere (the cavity is not skin).
  for (const Vec3& q : sampler.surface_points()) ASSERT_NEAR(norm(q - kCentre), kRadius, 0.5);
  const std::vector<uint64_t> s = seeds(2000);
  const std::vector<Pose> poses = sampler.sample(s.data(), s.size());
  double worst_mm = 0, worst_deg = 0;
  for (const Pose& pose : poses) {
    const Vec3 face = pose.transform_point({0, p.face_y_mm, 0});
    const Vec3 inward = normalized(kCentre - face);
    worst_mm = std::max(worst_mm, std::fabs(norm(face - kCentre) - kRadius));
    worst_deg = std::max(worst_deg, std::acos(std::min(1.0, dot(pose.column3(1), inward))) / kDeg);
  }
  std::printf(
      "[ skin ] %zu poses: face within %.3f mm of the surface, beam within %.3f deg of "
      "the inward normal\n",
      poses.size(), worst_mm, worst_deg);
  EXPECT_LT(worst_mm, 0.5);
  EXPECT_LT(worst_deg, 1.0);
}

TEST(PoseSampler, TiltAndHeelToeStayInTheirRanges) {
  const ProbeGeometry p = workload_w1_fan_probe();
  for (const bool heel_toe : {false, true}) {
    const PoseSampler sampler(
        skin(heel_toe ? R"({"type": "skin", "heel_toe_deg": [-8, -3]})"
                      : R"({"type": "skin", "tilt_deg": [5, 10], "rotation_deg": [0, 90]})"),
        p, &ball());
    const std::vector<uint64_t> s = seeds(2000, heel_toe);
    double lo = 180, hi = 0, off_axis = 0;
    for (const Pose& pose : sampler.sample(s.data(), s.size())) {
      const Vec3 face = pose.transform_point({0, p.face_y_mm, 0});
      const Vec3 inward = normalized(kCentre - face);
      const double angle = std::acos(std::min(1.0, dot(pose.column3(1), inward))) / kDeg;
      lo = std::min(lo, angle);
      hi = std::max(hi, angle);
      // Fanning turns about x̂ (x̂ stays on the surface); heel-toe about ẑ.
      off_axis = std::max(off_axis, std::fabs(dot(pose.column3(heel_toe ? 2 : 0), inward)));
    }
    std::printf("[ tilt ] %s: %.2f..%.2f deg from the normal; axis off the surface %.4f\n",
                heel_toe ? "heel-toe [-8, -3]" : "tilt [5, 10]", lo, hi, off_axis);
    EXPECT_GT(lo, (heel_toe ? 3 : 5) - 1.0);
    EXPECT_LT(hi, (heel_toe ? 8 : 10) + 1.0);
    EXPECT_GT(hi - lo, 4.0);  // the range is used, not one value
    EXPECT_LT(off_axis, std::sin(1 * kDeg));
  }
}

TEST(PoseSampler, DepthShiftPushesTheFaceAlongTheBeam) {
  const ProbeGeometry p = workload_w1_fan_probe();
  const PoseSampler sampler(skin(R"({"type": "skin", "depth_mm": 10})"), p, &ball());
  const std::vector<uint64_t> s = seeds(200);
  for (const Pose& pose : sampler.sample(s.data(), s.size()))
    EXPECT_NEAR(norm(pose.transform_point({0, p.face_y_mm, 0}) - kCentre), kRadius - 10, 0.5);
}

TEST(PoseSampler, UniformRotationsPassKolmogorovSmirnov) {
  // A region sampler in the tissue ball (intensity range), uniform rotations.
  const PoseSampler sampler(
      parse_sampler_json(R"({"type": "region", "intensity": [-100, 100]})", "test"),
      workload_w1_fan_probe(), &ball());
  const size_t n = 20000;
  const std::vector<uint64_t> s = seeds(n);
  std::vector<double> axis[3], angle;
  for (const Pose& pose : sampler.sample(s.data(), n)) {
    for (int a = 0; a < 3; ++a) axis[a].push_back(pose.m[2][a]);  // row z: uniform in [−1, 1]
    const double trace = pose.m[0][0] + pose.m[1][1] + pose.m[2][2];
    angle.push_back(std::acos(std::max(-1.0, std::min(1.0, (trace - 1) / 2))));
    const Vec3 at = pose.transform_point({0, workload_w1_fan_probe().face_y_mm, 0});
    const double r = norm(at - kCentre);
    ASSERT_TRUE(r < kRadius + 2 && r > kCavity - 2) << r;
  }
  const double critical = 1.63 / std::sqrt(double(n));  // α = 0.01
  for (int a = 0; a < 3; ++a) {
    const double d = ks(axis[a], [](double v) { return (v + 1) / 2; });
    std::printf("[ uniform ] R[2][%d] KS D = %.4f (critical %.4f)\n", a, d, critical);
    EXPECT_LT(d, critical);
  }
  // The rotation angle of a uniform rotation has CDF (θ − sin θ)/π.
  const double d = ks(angle, [](double t) { return (t - std::sin(t)) / kPi; });
  std::printf("[ uniform ] angle KS D = %.4f (critical %.4f)\n", d, critical);
  EXPECT_LT(d, critical);
}

TEST(PoseSampler, ConeKeepsTheBeamNearItsDirection) {
  const PoseSampler sampler(
      parse_sampler_json(
          R"({"type": "region", "intensity": [-100, 100], "cone_deg": 20, "direction": [0, 0, 2]})",
          "test"),
      workload_w1_fan_probe(), &ball());
  const std::vector<uint64_t> s = seeds(3000);
  double widest = 0;
  for (const Pose& pose : sampler.sample(s.data(), s.size()))
    widest = std::max(widest, std::acos(pose.m[2][1]) / kDeg);
  EXPECT_LT(widest, 20 + 1e-9);
  EXPECT_GT(widest, 18);
}

TEST(PoseSampler, MeshSamplerUsesOutwardNormalsOfAClosedMesh) {
  // A UV sphere of radius 30 (closed, wound outward), and the same wound inward.
  TriangleMesh mesh;
  const int rings = 60, segments = 120;
  mesh.vertices.push_back({0, 0, 30});
  for (int r = 1; r < rings; ++r)
    for (int k = 0; k < segments; ++k) {
      const double th = kPi * r / rings, ph = 2 * kPi * k / segments;
      mesh.vertices.push_back(
          {30 * std::sin(th) * std::cos(ph), 30 * std::sin(th) * std::sin(ph), 30 * std::cos(th)});
    }
  mesh.vertices.push_back({0, 0, -30});
  const auto at = [&](int r, int k) { return 1 + (r - 1) * segments + (k % segments); };
  const int bottom = int(mesh.vertices.size()) - 1;
  for (int k = 0; k < segments; ++k) {
    mesh.triangles.push_back({0, at(1, k), at(1, k + 1)});
    for (int r = 1; r + 1 < rings; ++r) {
      mesh.triangles.push_back({at(r, k), at(r + 1, k), at(r + 1, k + 1)});
      mesh.triangles.push_back({at(r, k), at(r + 1, k + 1), at(r, k + 1)});
    }
    mesh.triangles.push_back({bottom, at(rings - 1, k + 1), at(rings - 1, k)});
  }
  for (const bool inward_winding : {false, true}) {
    TriangleMesh m = mesh;
    if (inward_winding)
      for (auto& t : m.triangles) std::swap(t[1], t[2]);
    const PoseSampler sampler(parse_sampler_json(R"({"type": "mesh"})", "test"),
                              workload_w1_fan_probe(), nullptr, nullptr, &m);
    const std::vector<uint64_t> s = seeds(2000);
    double worst_deg = 0, worst_mm = 0;
    for (const Pose& pose : sampler.sample(s.data(), s.size())) {
      const Vec3 face = pose.transform_point({0, workload_w1_fan_probe().face_y_mm, 0});
      worst_mm = std::max(worst_mm, std::fabs(norm(face) - 30));
      worst_deg = std::max(
          worst_deg,
          std::acos(std::min(1.0, dot(pose.column3(1), (-1.0 / norm(face)) * face))) / kDeg);
    }
    EXPECT_LT(worst_mm, 0.05);  // on a facet: within the facets' sagitta of the sphere
    // A facet's normal against the sphere's radial direction: up to about 2° on the narrow
    // facets by the poles (3° rings).
    EXPECT_LT(worst_deg, 2.5);
  }
}

TEST(PoseSampler, SweepsStepAsAskedAndJitterIsSeeded) {
  const ProbeGeometry p = workload_w1_fan_probe();
  Pose start = Mat4::from_rotation_translation(Mat3::identity(), {0, -80, 0});
  for (const char* motion : {"linear", "fan", "rotational"}) {
    SamplerSettings s;
    s.type = SamplerType::Sweep;
    s.motion = std::strcmp(motion, "linear") == 0 ? SweepMotion::Linear
               : std::strcmp(motion, "fan") == 0  ? SweepMotion::Fan
                                                  : SweepMotion::Rotational;
    s.step = 2;
    s.frames = 5;
    s.start = start;
    const PoseSampler sampler(s, p);
    ASSERT_EQ(sampler.poses_per_seed(), 5);
    const std::vector<uint64_t> seed = seeds(1);
    const std::vector<Pose> f = sampler.sample(seed.data(), 1);
    ASSERT_EQ(f.size(), 5u);
    for (int k = 0; k + 1 < 5; ++k) {
      const Vec3 a = f[size_t(k)].transform_point({0, p.face_y_mm, 0}),
                 b = f[size_t(k) + 1].transform_point({0, p.face_y_mm, 0});
      const Mat3 ra = f[size_t(k)].linear(), rb = f[size_t(k) + 1].linear();
      double trace = 0;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) trace += ra.m[i][j] * rb.m[i][j];
      const double turned = std::acos(std::max(-1.0, std::min(1.0, (trace - 1) / 2))) / kDeg;
      if (s.motion == SweepMotion::Linear) {
        EXPECT_NEAR(norm(b - a), 2, 1e-9);
        EXPECT_NEAR(dot(b - a, ra.column(2)), 2, 1e-9);  // along the elevation axis
        EXPECT_NEAR(turned, 0, 1e-6);
      } else {
        EXPECT_NEAR(norm(b - a), 0, 1e-9);  // about the face centre
        EXPECT_NEAR(turned, 2, 1e-6);
      }
    }
  }
  // Jitter: the same seed gives the same frames; another seed others.
  SamplerSettings s;
  s.type = SamplerType::Sweep;
  s.start = start;
  s.frames = 4;
  s.jitter_mm = 0.5;
  s.jitter_deg = 0.5;
  const PoseSampler sampler(s, p);
  const std::vector<uint64_t> two = seeds(2);
  const std::vector<Pose> a = sampler.sample(two.data(), 2), b = sampler.sample(two.data(), 2);
  EXPECT_EQ(std::memcmp(a.data(), b.data(), sizeof(Pose) * a.size()), 0);
  EXPECT_NE(std::memcmp(a.data(), a.data() + 4, sizeof(Pose) * 4), 0);
}

TEST(PoseSampler, SweepFromTheSkin) {
  const ProbeGeometry p = workload_w1_fan_probe();
  const SamplerSettings s = parse_sampler_json(
      R"({"type": "sweep", "motion": "fan", "step": 3, "frames": 7, "from": {"type": "skin"}})",
      "test");
  const PoseSampler sampler(s, p, &ball());
  const std::vector<uint64_t> seed = seeds(3);
  const std::vector<Pose> f = sampler.sample(seed.data(), 3);
  ASSERT_EQ(f.size(), 21u);
  for (const Pose& pose : f)  // a fan sweep keeps the face on the skin
    EXPECT_NEAR(norm(pose.transform_point({0, p.face_y_mm, 0}) - kCentre), kRadius, 0.5);
}

TEST(PoseSampler, RejectionRulesHoldAndImpossibleRulesFailInBoundedTries) {
  const ProbeGeometry p = workload_w1_fan_probe();
  const PoseSampler strict(
      skin(
          R"({"type": "skin", "tilt_deg": [-40, 40], "reject": {"min_body": 0.95, "no_gas": true}})"),
      p, &ball());
  const std::vector<uint64_t> s = seeds(300);
  const std::vector<Pose> kept = strict.sample(s.data(), s.size());
  const PoseSampler loose(skin(R"({"type": "skin", "tilt_deg": [-40, 40]})"), p, &ball());
  int rejected = 0;
  for (const Pose& pose : loose.candidates(s.data(), s.size())) rejected += !strict.accepts(pose);
  for (const Pose& pose : kept) EXPECT_TRUE(strict.accepts(pose));
  std::printf("[ reject ] %d of %zu unfiltered candidates fail min_body 0.95\n", rejected,
              s.size());
  EXPECT_GT(rejected, 0);  // the rule does something on this probe and body
  // A probe whose face sits in gas (the cavity or the air around the ball) can never see 100 %
  // body: an error after max_tries candidates, not a hang.
  const PoseSampler impossible(
      parse_sampler_json(R"({"type": "region", "intensity": [-1000, -900], "max_tries": 200,
                             "reject": {"min_body": 1.0}})",
                         "test"),
      p, &ball());
  try {
    impossible.sample(s.data(), 3);
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("200 tries"), std::string::npos) << e.what();
  }
}

TEST(PoseSampler, SamePosesOnAnyThreadCount) {
  const PoseSampler sampler(
      skin(R"({"type": "skin", "tilt_deg": [-10, 10], "reject": {"min_body": 0.5}})"),
      workload_w1_fan_probe(), &ball());
  const std::vector<uint64_t> s = seeds(5000);
  const test::ScopedCpuSettings restore;
  set_cpu_threads(1);
  const std::vector<Pose> one = sampler.sample(s.data(), s.size());
  set_cpu_threads(2);
  const std::vector<Pose> all = sampler.sample(s.data(), s.size());
  EXPECT_EQ(std::memcmp(one.data(), all.data(), sizeof(Pose) * one.size()), 0);
  // A seed's pose does not depend on the other seeds asked for with it.
  const std::vector<Pose> alone = sampler.sample(s.data() + 4321, 1);
  EXPECT_EQ(std::memcmp(&alone[0], &all[4321], sizeof(Pose)), 0);
  // Seeds are counter-based: any range is the same as its part of a longer one.
  const std::vector<uint64_t> part = sample_seeds(7, 0, 100, 10);
  EXPECT_TRUE(std::equal(part.begin(), part.end(), s.begin() + 100));
}

TEST(PoseSampler, BadSettingsAreNamed) {
  const auto message = [](const char* json) {
    try {
      parse_sampler_json(json, "samplers[2]");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message(R"({"type": "skin", "tilt": [0, 1]})").find("unknown key 'tilt'"),
            std::string::npos);
  EXPECT_NE(message(R"({"type": "skin", "cone_deg": 5})").find("does not apply to a skin"),
            std::string::npos);
  EXPECT_NE(message(R"({"type": "ring"})").find("type 'ring'"), std::string::npos);
  EXPECT_NE(message(R"({"type": "skin", "tilt_deg": [10, 0]})").find("samplers[2].tilt_deg"),
            std::string::npos);
  EXPECT_NE(message(R"({"type": "skin", "reject": {"min_bdy": 1}})").find("min_bdy"),
            std::string::npos);
  EXPECT_NE(
      message(R"({"type": "sweep"})").find("give its \"start\" pose or a base sampler as \"from\""),
      std::string::npos);
  EXPECT_NE(message(R"({"type": "region"})").find("give its \"label\" or \"intensity\" range"),
            std::string::npos);
  EXPECT_NE(message("{not json").find("invalid JSON"), std::string::npos);
  EXPECT_EQ(message(R"({"type": "skin", "reject": {"min_body": 1.5}})"),
            "samplers[2]: reject.min_body 1.5: must be a fraction in [0, 1]");
  // A label alone would reject nothing: it names the label that min_label counts.
  EXPECT_EQ(message(R"({"type": "skin", "reject": {"label": 3}})"),
            "samplers[2]: reject.label 3: needs min_label, the fraction of the fan that must lie "
            "in that label");
  EXPECT_EQ(message(R"({"type": "skin", "reject": {"label": 3, "min_label": 0.2}})"), "no error");
  // Inputs a sampler needs.
  EXPECT_THROW(PoseSampler(skin(), workload_w1_fan_probe()), InputError);  // skin without a CT
  EXPECT_THROW(PoseSampler(parse_sampler_json(R"({"type": "region", "label": 3})", "t"),
                           workload_w1_fan_probe(), &ball()),
               InputError);  // a label without a label volume
}

}  // namespace
}  // namespace sonoslice
