#pragma once
/// @file Pose samplers for datasets (docs/datasets.md): probes placed on the skin or on a
/// mesh, looking along the inward normal; sweeps; positions inside a label or intensity range;
/// and rejection on the fan's content. Every pose is a pure function of its seed, so a dataset
/// sample is reproducible from the seed it records, on any machine and thread count.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/surface/Mesh.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

enum class SamplerType {
  Skin,    ///< on the body surface of a CT (threshold, largest component, outward normals)
  Mesh,    ///< on a triangle mesh (an organ surface), area-uniform
  Region,  ///< inside a label (or an intensity range) of the volume
  Sweep    ///< a linear, fan or rotational sweep from a start pose or another sampler's pose
};
enum class SweepMotion {
  Linear,     ///< along the probe's elevation axis ẑ, step in mm
  Fan,        ///< rocking about the probe's lateral axis x̂ through the face centre, step in °
  Rotational  ///< turning about the beam ŷ through the face centre, step in °
};

/// A closed interval [lo, hi], drawn uniformly.
struct Interval {
  double lo = 0, hi = 0;
};

/// Rejection rules, evaluated on a coarse grid of the fan (docs/datasets.md §2): a candidate is
/// kept when every rule given holds.
struct RejectionRules {
  double min_inside = 0;  ///< fraction of the fan's points inside the volume
  double min_body = 0;    ///< fraction inside the body (intensity > the sampler's threshold_hu)
  int label = -1;         ///< with min_label: this label's fraction (needs a label volume)
  double min_label = 0;
  /// No gas right under the face: along the central half of the face, every point from 1 mm to
  /// gas_depth_mm below it must have intensity ≥ gas_hu.
  bool no_gas = false;
  double gas_hu = -400, gas_depth_mm = 5;
  bool any() const { return min_inside > 0 || min_body > 0 || min_label > 0 || no_gas; }
};

struct SamplerSettings {
  SamplerType type = SamplerType::Skin;
  /// Skin: the body is intensity > threshold_hu (its largest 6-connected component); also the
  /// body of the min_body rule for every sampler.
  double threshold_hu = -500;
  /// Skin and mesh: angles drawn uniformly in these ranges (degrees): the probe turned about
  /// the beam, then tilted about its lateral axis x̂ (fanning) and about its elevation axis ẑ
  /// (heel-toe rocking), both through the face centre; then pushed depth_mm along the beam
  /// (a laparoscopic probe pressed into tissue). Region: rotation_deg is the spin about the beam.
  Interval rotation_deg{0, 360}, tilt_deg{0, 0}, heel_toe_deg{0, 0}, depth_mm{0, 0};
  /// Region: voxels whose label is `label` (needs a label volume), else voxels whose intensity
  /// lies in `intensity`; the probe's anchor is placed uniformly inside them.
  int label = -1;
  std::optional<Interval> intensity;
  /// Region orientation: uniform over all rotations (cone_deg ≥ 180), or the beam within
  /// cone_deg of `direction` (uniform over the spherical cap), spin uniform in rotation_deg.
  double cone_deg = 180;
  Vec3 direction{0, 0, 1};
  bool anchor_at_centre = false;  ///< region: the fan's centre (not the face centre) at the point
  /// Sweep: the start (a fixed pose, or a pose of `base`), the motion, `frames` poses spaced by
  /// `step` (mm or °) centred on the start, and Gaussian tracking jitter per frame.
  SweepMotion motion = SweepMotion::Linear;
  double step = 1;
  int frames = 10;
  double jitter_mm = 0, jitter_deg = 0;
  std::optional<Pose> start;
  std::shared_ptr<SamplerSettings> base;
  RejectionRules reject;
  int max_tries = 1000;  ///< candidates per seed before the rules are declared impossible

  /// InputError naming `where` and the setting for a bad value.
  void validate(const std::string& where) const;
};

/// The seeds of samples [first, first + count) of stream `stream` (e.g. a dataset's sampler
/// index) under `base`: a counter-based hash, so any sample's seed is known without the others.
std::vector<uint64_t> sample_seeds(uint64_t base, uint64_t stream, uint64_t first, size_t count);

class PoseSampler {
 public:
  /// `volume`: the CT (skin, region by intensity, and the body and gas rules); `labels`: a label
  /// volume (region by label, the label rule); `mesh`: the mesh sampler's surface. Inputs a
  /// setting needs and lacks, a body without a surface, an empty region or mesh: InputError.
  PoseSampler(const SamplerSettings& settings, const ProbeGeometry& probe,
              const Volume* volume = nullptr, const Volume* labels = nullptr,
              const TriangleMesh* mesh = nullptr);
  ~PoseSampler();
  PoseSampler(PoseSampler&&) noexcept;

  /// Poses per seed: a sweep's frame count, else 1.
  int poses_per_seed() const;
  /// The poses of each seed, seed after seed (probe → world, LPS mm): candidates are drawn from
  /// the seed until one passes the rejection rules; InputError after max_tries. In parallel;
  /// the result does not depend on the thread count.
  std::vector<Pose> sample(const uint64_t* seeds, size_t count) const;
  /// The first candidate of each seed, without rejection (the candidate rate of bench/).
  std::vector<Pose> candidates(const uint64_t* seeds, size_t count) const;
  /// Whether `pose` passes the rejection rules; InputError naming "pose" for a pose that is not
  /// finite and rigid (validate_poses).
  bool accepts(const Pose& pose) const;
  /// Skin and mesh: the surface's points (mm) and outward unit normals, one per candidate site.
  const std::vector<Vec3>& surface_points() const;
  const std::vector<Vec3>& surface_normals() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace sonoslice
