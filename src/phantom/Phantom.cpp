#include "sonoslice/phantom/Phantom.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "../backend/ParallelFor.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace {

// ---- deterministic noise: a hash of integer lattice coordinates, never a global RNG, so the
// phantom is identical for any thread count.
inline uint32_t hash3(uint32_t x, uint32_t y, uint32_t z, uint32_t seed) {
  uint32_t h = seed ^ (x * 0x8da6b343u) ^ (y * 0xd8163841u) ^ (z * 0xcb1ab31fu);
  h ^= h >> 16;
  h *= 0x7feb352du;
  h ^= h >> 15;
  h *= 0x846ca68bu;
  h ^= h >> 16;
  return h;
}
inline double unit(uint32_t h) {
  return (h >> 8) * (1.0 / 16777216.0);
}  // [0, 1)

// Roughly Gaussian white noise with unit standard deviation (sum of three uniforms).
inline double white_noise(int64_t i, int64_t j, int64_t k) {
  const double s = unit(hash3(uint32_t(i), uint32_t(j), uint32_t(k), 1)) +
                   unit(hash3(uint32_t(i), uint32_t(j), uint32_t(k), 2)) +
                   unit(hash3(uint32_t(i), uint32_t(j), uint32_t(k), 3));
  return (s - 1.5) * 2.0;  // variance of the sum is 1/4
}

// Smooth value noise in [-1, 1] on an 8 mm lattice in world coordinates: organ texture that
// does not depend on the voxel size.
inline double smooth_noise(double x, double y, double z) {
  const double s = 1.0 / 8.0;
  const double gx = x * s + 1000, gy = y * s + 1000, gz = z * s + 1000;
  const int ix = int(std::floor(gx)), iy = int(std::floor(gy)), iz = int(std::floor(gz));
  const double fx = gx - ix, fy = gy - iy, fz = gz - iz;
  double acc = 0;
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
    const double w = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy) * (dz ? fz : 1 - fz);
    acc += w * unit(hash3(uint32_t(ix + dx), uint32_t(iy + dy), uint32_t(iz + dz), 7));
  }
  return acc * 2 - 1;
}

// ---- anatomy -------------------------------------------------------------------------------
struct BodySection {
  double a, b;  // semi-axes of the body outline (lateral, antero-posterior), mm
};
inline BodySection body_at(double z) {
  const double t = z / 200.0;
  return {165.0 * (1 - 0.05 * t * t), 120.0 * (1 - 0.04 * t * t)};
}
inline double ellipse_level(double x, double y, double a, double b) {
  return (x * x) / (a * a) + (y * y) / (b * b);
}
constexpr double kBackY = 108.0;  // the flattened back (the patient lies on a table)
constexpr double kFatDepth = 16.0, kWallDepth = 27.0;  // mm under the skin

// Diaphragm: the right dome sits higher than the left; z above it is thorax.
inline double sq(double v) {
  return v * v;
}
inline double dome_z(double x, double y) {
  const double r = 125 + 40 * (1 - sq((x + 70) / 100) - sq((y - 10) / 110));
  const double l = 115 + 35 * (1 - sq((x - 70) / 95) - sq((y - 10) / 110));
  return std::max(r, l);
}

enum class Clip { None, BelowDiaphragm, AboveDiaphragm };

// What a voxel is made of: its label, mean HU, noise, and whether it gets smooth texture.
struct Material {
  uint8_t label;
  double hu, noise_sd;
  bool textured;
};

struct Shape {
  enum Kind { Ellipsoid, Capsule, Cylinder } kind;
  double p[3];          // ellipsoid/cylinder centre, capsule start
  double q[3];          // ellipsoid radii; cylinder (rx, ry, unused); capsule end
  double radius;        // capsule radius
  double lo[3], hi[3];  // bounding box
  Material tissue;
  Clip clip;
  double gas_below_y = -1e9;  // content anterior of this y is gas (a supine patient's stomach)

  bool contains(double x, double y, double z) const {
    if (x < lo[0] || x > hi[0] || y < lo[1] || y > hi[1] || z < lo[2] || z > hi[2]) return false;
    switch (kind) {
      case Ellipsoid: {
        const double dx = (x - p[0]) / q[0], dy = (y - p[1]) / q[1], dz = (z - p[2]) / q[2];
        if (dx * dx + dy * dy + dz * dz > 1) return false;
        break;
      }
      case Cylinder: {
        const double dx = (x - p[0]) / q[0], dy = (y - p[1]) / q[1];
        if (dx * dx + dy * dy > 1) return false;
        break;
      }
      case Capsule: {
        const Vec3 a{p[0], p[1], p[2]}, b{q[0], q[1], q[2]}, v{x, y, z};
        const Vec3 ab = b - a;
        double t = dot(v - a, ab) / dot(ab, ab);
        t = t < 0 ? 0 : (t > 1 ? 1 : t);
        const Vec3 d = v - (a + t * ab);
        if (dot(d, d) > radius * radius) return false;
        break;
      }
    }
    if (clip == Clip::BelowDiaphragm && z > dome_z(x, y)) return false;
    if (clip == Clip::AboveDiaphragm && z < dome_z(x, y) + 4) return false;
    return true;
  }
};

Shape ellipsoid(Vec3 c, Vec3 r, uint8_t label, double hu, double sd, bool textured,
                Clip clip = Clip::None) {
  Shape s{};
  s.kind = Shape::Ellipsoid;
  for (int k = 0; k < 3; ++k) {
    s.p[k] = c[k];
    s.q[k] = r[k];
    s.lo[k] = c[k] - r[k];
    s.hi[k] = c[k] + r[k];
  }
  s.tissue = {label, hu, sd, textured};
  s.clip = clip;
  return s;
}

Shape cylinder(double cx, double cy, double rx, double ry, double zlo, double zhi, uint8_t label,
               double hu, double sd, Clip clip = Clip::None) {
  Shape s = ellipsoid({cx, cy, 0.5 * (zlo + zhi)}, {rx, ry, 0.5 * (zhi - zlo)}, label, hu, sd,
                      false, clip);
  s.kind = Shape::Cylinder;
  return s;
}

Shape capsule(Vec3 a, Vec3 b, double radius, uint8_t label, double hu, double sd) {
  Shape s{};
  s.kind = Shape::Capsule;
  for (int k = 0; k < 3; ++k) {
    s.p[k] = a[k];
    s.q[k] = b[k];
    s.lo[k] = std::min(a[k], b[k]) - radius;
    s.hi[k] = std::max(a[k], b[k]) + radius;
  }
  s.radius = radius;
  s.tissue = {label, hu, sd, false};
  s.clip = Clip::None;
  return s;
}

bool inside_liver(const Vec3& p) {
  auto in = [&](Vec3 c, Vec3 r) {
    const Vec3 d{(p[0] - c[0]) / r[0], (p[1] - c[1]) / r[1], (p[2] - c[2]) / r[2]};
    return dot(d, d) < 0.8;  // well inside, so branches do not poke out
  };
  return (in({-62, 0, 92}, {78, 88, 82}) || in({5, -45, 118}, {68, 38, 42})) &&
         p[2] < dome_z(p[0], p[1]) - 8;
}

// Two generations of side branches off every hepatic vessel segment already in `s`: each child
// leaves its parent's far end at a hashed angle, 0.6x as long and 0.65x as thick, and is
// shortened until it ends inside the liver.
void add_branches(std::vector<Shape>& s) {
  std::vector<Shape> parents;
  for (const Shape& x : s)
    if (x.kind == Shape::Capsule && x.tissue.label == kHepaticVessel) parents.push_back(x);
  uint32_t seed = 11;
  for (int generation = 0; generation < 2; ++generation) {
    std::vector<Shape> children;
    for (const Shape& parent : parents) {
      const Vec3 a{parent.p[0], parent.p[1], parent.p[2]}, b{parent.q[0], parent.q[1], parent.q[2]};
      const Vec3 axis = b - a;
      const double length = norm(axis);
      for (int k = 0; k < 2; ++k) {
        const Vec3 random{unit(hash3(seed, 1, 0, 5)) - 0.5, unit(hash3(seed, 2, 0, 5)) - 0.5,
                          unit(hash3(seed, 3, 0, 5)) - 0.5};
        ++seed;
        const Vec3 side = normalized(cross(axis, random));
        // 35° off the parent's direction, to either side.
        Vec3 dir = normalized(normalized(axis) + (k ? 0.7 : -0.7) * side);
        const Vec3 start = a + 0.75 * axis;
        double l = 0.6 * length;
        while (l > 4 && !inside_liver(start + l * dir)) l *= 0.8;
        if (l <= 4 || !inside_liver(start)) continue;
        children.push_back(capsule(start, start + l * dir, std::max(1.2, 0.65 * parent.radius),
                                   kHepaticVessel, parent.tissue.hu, 8));
      }
    }
    s.insert(s.end(), children.begin(), children.end());
    parents = children;
  }
}

// Painter's order: later shapes overwrite earlier ones.
std::vector<Shape> anatomy() {
  std::vector<Shape> s;
  const double kInf = 1e9;
  // Bowel loops in the lower anterior abdomen: wall, then fluid content (gas added per voxel).
  const double loops[][3] = {{-60, -45, -60},  {-20, -60, -90}, {25, -55, -50},  {65, -40, -95},
                             {-75, -30, -130}, {0, -40, -140},  {50, -25, -150}, {-35, -35, -20},
                             {40, -45, -10},   {-5, -70, -15}};
  for (const auto& c : loops) {
    s.push_back(ellipsoid({c[0], c[1], c[2]}, {24, 18, 22}, kSoftTissue, 40, 10, false));
    s.push_back(ellipsoid({c[0], c[1], c[2]}, {20.5, 14.5, 18.5}, kBowel, 15, 10, false));
  }
  // Kidneys: enhancing cortex around a fluid-density pelvis; the right one sits lower.
  for (double side : {-1.0, 1.0}) {
    const Vec3 c{side * 72, 55, side < 0 ? -15.0 : 5.0};
    s.push_back(ellipsoid(c, {28, 24, 55}, kKidney, 150, 12, true));
    s.push_back(ellipsoid(c + Vec3{-side * 6, -4, 0}, {13, 11, 32}, kKidney, 25, 10, false));
  }
  s.push_back(ellipsoid({82, 45, 95}, {28, 45, 55}, kSpleen, 50, 10, true, Clip::BelowDiaphragm));
  // Stomach under the left dome (wall, then content), and the pancreas across the midline.
  s.push_back(
      ellipsoid({48, -38, 92}, {46, 38, 42}, kSoftTissue, 45, 10, false, Clip::BelowDiaphragm));
  s.push_back(ellipsoid({48, -38, 92}, {42, 34, 38}, kBowel, 15, 10, false, Clip::BelowDiaphragm));
  s.back().gas_below_y = -58;
  s.push_back(capsule({-12, 12, 32}, {62, 22, 48}, 11, kSoftTissue, 45, 10));
  // Liver: right lobe plus a left lobe reaching across the midline, under the right dome.
  s.push_back(ellipsoid({-62, 0, 92}, {78, 88, 82}, kLiver, 60, 10, true, Clip::BelowDiaphragm));
  s.push_back(ellipsoid({5, -45, 118}, {68, 38, 42}, kLiver, 60, 10, true, Clip::BelowDiaphragm));
  // Heart above the diaphragm.
  s.push_back(
      ellipsoid({15, -25, 205}, {70, 58, 65}, kSoftTissue, 40, 10, false, Clip::AboveDiaphragm));
  // Portal vein and its branches (contrast-enhanced).
  const double pv = 170;
  s.push_back(capsule({5, 20, 15}, {-30, 5, 70}, 7.0, kHepaticVessel, pv, 8));
  s.push_back(capsule({-30, 5, 70}, {-100, 0, 78}, 5.5, kHepaticVessel, pv, 8));
  s.push_back(capsule({-30, 5, 70}, {20, -40, 108}, 4.5, kHepaticVessel, pv, 8));
  s.push_back(capsule({-65, 2, 73}, {-92, -45, 52}, 3.2, kHepaticVessel, pv, 8));
  s.push_back(capsule({-65, 2, 73}, {-85, 45, 110}, 3.2, kHepaticVessel, pv, 8));
  s.push_back(capsule({-5, -18, 89}, {-10, -70, 105}, 3.0, kHepaticVessel, pv, 8));
  // Hepatic veins draining into the IVC just under the dome.
  const Vec3 confluence{-24, 28, 140};
  s.push_back(capsule(confluence, {-115, 10, 82}, 5.5, kHepaticVessel, 150, 8));
  s.push_back(capsule(confluence, {-50, -58, 66}, 5.0, kHepaticVessel, 150, 8));
  s.push_back(capsule(confluence, {12, -52, 112}, 4.5, kHepaticVessel, 150, 8));
  s.push_back(capsule({-75, 18, 108}, {-105, 55, 75}, 3.2, kHepaticVessel, 150, 8));
  s.push_back(capsule({-38, -20, 100}, {-80, -65, 110}, 3.0, kHepaticVessel, 150, 8));
  // Smaller branches, grown deterministically from the main veins above.
  add_branches(s);
  // The gallbladder under the liver's anterior edge, and three lesions in the right lobe.
  s.push_back(ellipsoid({-42, -66, 52}, {15, 14, 28}, kGallbladder, 8, 8, false));
  s.push_back(ellipsoid({-72, -42, 82}, {15, 15, 15}, kLesion, 30, 10, false));
  s.push_back(ellipsoid({-100, 8, 100}, {11, 11, 11}, kLesion, 25, 10, false));
  s.push_back(ellipsoid({-28, -52, 112}, {8, 8, 8}, kLesion, 130, 10, false));
  // Great vessels: IVC (right), aorta (left), and the iliacs below the bifurcation.
  s.push_back(cylinder(-24, 30, 11, 11, -125, 185, kGreatVessel, 150, 8));
  s.push_back(cylinder(18, 38, 12, 12, -125, kInf, kGreatVessel, 220, 8));
  for (double side : {-1.0, 1.0}) {
    s.push_back(capsule({18, 38, -125}, {side * 62 + 10, 30, -210}, 7.5, kGreatVessel, 220, 8));
    s.push_back(capsule({-24, 30, -125}, {side * 55 - 14, 40, -210}, 8.5, kGreatVessel, 150, 8));
  }
  // Paraspinal muscles and psoas.
  for (double side : {-1.0, 1.0}) {
    s.push_back(cylinder(side * 40, 90, 26, 17, -kInf, kInf, kSoftTissue, 50, 10));
    s.push_back(cylinder(side * 40, 58, 15, 15, -kInf, 20, kSoftTissue, 50, 10));
  }
  // Spine: vertebral bodies (cortex + cancellous bone) with discs, canal, arch and process.
  for (double z0 = -200; z0 < 200; z0 += 32) {
    s.push_back(cylinder(0, 62, 21, 21, z0, z0 + 26, kBone, 700, 25));
    s.push_back(cylinder(0, 62, 18.5, 18.5, z0 + 2, z0 + 24, kBone, 220, 25));
    s.push_back(cylinder(0, 62, 20, 20, z0 + 26, z0 + 32, kSoftTissue, 85, 10));
    s.push_back(cylinder(0, 93, 15, 14, z0 + 3, z0 + 23, kBone, 600, 25));
    s.push_back(capsule({0, 100, z0 + 13}, {0, 116, z0 + 6}, 5, kBone, 600, 25));
  }
  s.push_back(cylinder(0, 93, 8.5, 8.0, -kInf, kInf, kSoftTissue, 15, 8));  // spinal canal (CSF)
  return s;
}

// Inside the muscle wall: where the organs are.
inline bool inside_cavity(double x, double y, const BodySection& s) {
  return ellipse_level(x, y, s.a - kWallDepth, s.b - kWallDepth * 0.85) <= 1;
}

// Layers every voxel starts from: air, skin, fat, muscle wall, then the cavity (visceral fat
// below the diaphragm, lungs above it). `s` is the body's section at z.
inline Material base_tissue(double x, double y, double z, const BodySection& s) {
  if (y > kBackY || ellipse_level(x, y, s.a, s.b) > 1) return {kAir, -1000, 4, false};
  if (ellipse_level(x, y, s.a - 2.5, s.b - 2.5) > 1) return {kSoftTissue, 30, 10, false};  // skin
  if (ellipse_level(x, y, s.a - kFatDepth, s.b - kFatDepth * 0.8) > 1)
    return {kFat, -100, 10, false};
  if (!inside_cavity(x, y, s)) {
    // Ribs: 9 mm slabs every 28 mm above z = 20, in the wall, except the anterior third.
    const double angle = std::atan2(y, x) * 180 / kPi;  // -90 = anterior
    if (z > 20 && std::fmod(z + 1000, 28.0) < 9 && std::fabs(angle + 90) > 50)
      return {kBone, 550, 25, false};
    return {kSoftTissue, 50, 10, false};
  }
  const double dome = dome_z(x, y);
  if (z > dome + 4) return {kLung, -850, 30, true};
  if (z > dome) return {kSoftTissue, 45, 10, false};  // diaphragm
  return {kFat, -90, 12, false};
}

}  // namespace

PhantomSize parse_phantom_size(const std::string& name) {
  if (name == "small") return PhantomSize::Small;
  if (name == "full") return PhantomSize::Full;
  throw InputError("phantom size '" + name + "': expected small or full");
}

const char* to_string(PhantomSize size) {
  switch (size) {
    case PhantomSize::Small:
      return "small";
    case PhantomSize::Full:
      return "full";
  }
  return "?";
}

std::vector<sonoslice::Tissue> phantom_tissues() {
  // By name from the default table, so the two never disagree; the phantom's own variants
  // (bowel, lesion, spleen) are derived from them.
  const std::vector<sonoslice::Tissue> base = default_tissues();
  const auto get = [&](const char* name) {
    for (const sonoslice::Tissue& t : base)
      if (t.name == name) return t;
    throw Error(std::string("phantom_tissues: no default tissue '") + name + "'");
  };
  const auto as = [](sonoslice::Tissue t, int label, const char* name) {
    t.label = label;
    t.name = name;
    return t;
  };
  sonoslice::Tissue bowel = as(get("soft tissue"), kBowel, "bowel");
  bowel.scatter_mean = 0.035;  // mixed content: brighter than the wall
  sonoslice::Tissue lesion = as(get("liver"), kLesion, "lesion");
  lesion.scatter_mean = 0.012;  // hypoechoic
  sonoslice::Tissue spleen = as(get("liver"), kSpleen, "spleen");
  spleen.scatter_mean = 0.022;
  return {as(get("gas"), kAir, "air"),
          as(get("fat"), kFat, "fat"),
          as(get("soft tissue"), kSoftTissue, "soft tissue"),
          as(get("liver"), kLiver, "liver"),
          as(get("blood"), kHepaticVessel, "hepatic vessel"),
          as(get("blood"), kGreatVessel, "great vessel"),
          as(get("bone"), kBone, "bone"),
          as(get("gas"), kLung, "lung"),
          as(get("kidney"), kKidney, "kidney"),
          spleen,
          bowel,
          lesion,
          as(get("water"), kGallbladder, "gallbladder")};
}

const char* phantom_label_name(int label) {
  static const char* names[kPhantomLabelCount] = {
      "air",  "fat",    "soft tissue", "liver", "hepatic vessel", "great vessel", "bone",
      "lung", "kidney", "spleen",      "bowel", "lesion",         "gallbladder"};
  return label >= 0 && label < kPhantomLabelCount ? names[label] : "unknown";
}

VolumeGrid phantom_grid(PhantomSize size) {
  VolumeGrid g;
  if (size == PhantomSize::Full) {
    g.dims = {512, 512, 400};
    g.spacing_mm = {0.8, 0.8, 1.0};
  } else {
    g.dims = {128, 128, 100};
    g.spacing_mm = {3.2, 3.2, 4.0};
  }
  for (int a = 0; a < 3; ++a) g.origin_mm[a] = -0.5 * double(g.dims[a] - 1) * g.spacing_mm[a];
  return g;
}

Phantom make_phantom(PhantomSize size) {
  const VolumeGrid grid = phantom_grid(size);
  Phantom ph{Volume::allocate(PixelType::Int16, grid), Volume::allocate(PixelType::UInt8, grid)};
  const std::vector<Shape> shapes = anatomy();
  int16_t* ct = ph.ct.data_as<int16_t>();
  uint8_t* labels = ph.labels.data_as<uint8_t>();
  const int64_t nx = grid.dims[0], ny = grid.dims[1];

  backend::parallel_for(grid.dims[2], [&](int64_t k) {
    const double z = grid.origin_mm[2] + k * grid.spacing_mm[2];
    const BodySection body = body_at(z);
    std::vector<const Shape*> active;  // shapes that reach this slice
    for (const Shape& s : shapes)
      if (z >= s.lo[2] && z <= s.hi[2]) active.push_back(&s);
    for (int64_t j = 0; j < ny; ++j) {
      const double y = grid.origin_mm[1] + j * grid.spacing_mm[1];
      for (int64_t i = 0; i < nx; ++i) {
        const double x = grid.origin_mm[0] + i * grid.spacing_mm[0];
        Material t = base_tissue(x, y, z, body);
        if (t.label != kAir) {
          const bool in_cavity = inside_cavity(x, y, body);
          const Shape* hit = nullptr;
          for (const Shape* s : active) {
            // Organs stay inside the cavity; the spine and paraspinal muscles may cross the wall.
            const uint8_t label = s->tissue.label;
            if (label != kBone && label != kSoftTissue && !in_cavity) continue;
            if (s->contains(x, y, z)) hit = s;
          }
          if (hit) t = hit->tissue;
          // Gas rises anteriorly (towards -y) in a supine patient: a cap in the stomach, pockets
          // in the bowel.
          if (hit && hit->tissue.label == kBowel &&
              (y < hit->gas_below_y ||
               (hit->gas_below_y < -1e8 && smooth_noise(x * 2, y * 2, z * 2) > 0.3)))
            t.hu = -950;
        }
        double hu = t.hu + t.noise_sd * white_noise(i, j, k);
        if (t.textured) hu += 10 * smooth_noise(x, y, z);
        const int64_t idx = (k * ny + j) * nx + i;
        ct[idx] = int16_t(std::lround(std::max(-1024.0, std::min(3071.0, hu))));
        labels[idx] = t.label;
      }
    }
  });
  return ph;
}

std::vector<Pose> phantom_random_poses(size_t count, uint64_t seed) {
  std::mt19937_64 rng(seed);
  // Own uniform mapping (not std::uniform_real_distribution) so every standard library gives
  // the same poses.
  auto uniform = [&](double lo, double hi) {
    return lo + (hi - lo) * double(rng() >> 11) * 0x1p-53;
  };
  std::vector<Pose> poses;
  poses.reserve(count);
  while (poses.size() < count) {
    const double z = uniform(-150, 150);
    const BodySection s = body_at(z);
    const double x = uniform(-s.a, s.a), y = uniform(-s.b, s.b);
    if (!inside_cavity(x, y, s)) continue;
    // A uniform random rotation (the three draws in this order, as before).
    const double u1 = uniform(0, 1), u2 = uniform(0, 1), u3 = uniform(0, 1);
    const Mat3 r = uniform_rotation(u1, u2, u3);
    poses.push_back(Mat4::from_rotation_translation(r, {x, y, z}));
  }
  return poses;
}

std::vector<Pose> phantom_surface_poses(size_t count, double face_y_mm) {
  std::vector<Pose> poses;
  for (size_t n = 0; n < count; ++n) {
    // Walk from the anterior midline (-90°) round the patient's right side (180°), at heights
    // over the liver.
    const double f = count > 1 ? double(n) / double(count - 1) : 0.5;
    const double t = (-100.0 - 75.0 * f) * kPi / 180.0;
    const double z = 95.0 + 25.0 * std::sin(6.0 * f);
    const BodySection s = body_at(z);
    const Vec3 skin{s.a * std::cos(t), s.b * std::sin(t), z};
    // Aimed, as a sonographer would, at the right lobe's portal branches and lesions.
    const Vec3 target{-62, -12, z - 5};
    const Vec3 inward = normalized(target - skin);
    const Vec3 tangent = normalized(cross(Vec3{0, 0, 1}, inward));  // in the axial plane
    const Vec3 up{0, 0, 1};
    const Vec3 along = normalized(up - dot(up, inward) * inward);  // body axis, made ⟂ to ŷ
    // Even poses: transverse (x̂ in the axial plane); odd: longitudinal (x̂ along the body).
    const Vec3 x_hat = n % 2 == 0 ? tangent : along;
    const Vec3 y_hat = inward;
    poses.push_back(
        Mat4::from_columns(x_hat, y_hat, cross(x_hat, y_hat), skin - face_y_mm * y_hat));
  }
  return poses;
}

}  // namespace sonoslice
