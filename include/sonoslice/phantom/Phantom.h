#pragma once
/// @file A deterministic CT-like abdominal phantom: the built-in default data for the demo,
/// the benchmarks and the tests. World frame LPS (x: patient left, y: posterior, z: superior),
/// millimetres, identity direction, centred on the world origin.
#include <cstdint>
#include <string>
#include <vector>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/simulate/Simulator.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

enum class PhantomSize {
  Small,  ///< 128 × 128 × 100 voxels at 3.2 × 3.2 × 4 mm (tests, quick looks)
  Full,   ///< 512 × 512 × 400 voxels at 0.8 × 0.8 × 1 mm (benchmarks; a typical abdominal CT)
};
PhantomSize parse_phantom_size(const std::string& name);  ///< "small" / "full"
const char* to_string(PhantomSize size);                  ///< "small" / "full"

/// Label values of Phantom::labels.
enum PhantomLabel : uint8_t {
  kAir = 0,         ///< outside the body
  kFat = 1,         ///< subcutaneous and visceral fat
  kSoftTissue = 2,  ///< body-wall muscle, paraspinal muscle, diaphragm, discs, heart, bowel wall
  kLiver = 3,
  kHepaticVessel = 4,  ///< hepatic and portal veins
  kGreatVessel = 5,    ///< aorta and inferior vena cava
  kBone = 6,           ///< vertebrae and ribs
  kLung = 7,           ///< lung bases
  kKidney = 8,
  kSpleen = 9,
  kBowel = 10,        ///< stomach and bowel content (fluid and gas)
  kLesion = 11,       ///< liver lesions (two hypodense, one hyperdense)
  kGallbladder = 12,  ///< bile
};
constexpr int kPhantomLabelCount = 13;
const char* phantom_label_name(int label);

/// The tissue table of the phantom's labels for simulation (docs/simulation.md §1): air and
/// lung as gas, fat, soft tissue, liver, both vessel labels as blood, bone, kidney, spleen,
/// bowel (soft tissue, brighter), lesions (liver, darker) and gallbladder (bile, as water).
std::vector<Tissue> phantom_tissues();

struct Phantom {
  Volume ct;      ///< int16, Hounsfield units
  Volume labels;  ///< uint8, PhantomLabel values
};

/// Generates the phantom (deterministic: the same voxels on every machine and thread count).
Phantom make_phantom(PhantomSize size);

/// The grid of a phantom of that size (without generating voxels).
VolumeGrid phantom_grid(PhantomSize size);

/// `count` random poses (seeded, reproducible) with their origin inside the abdominal cavity and
/// a uniformly random orientation: the benchmark workloads' poses.
std::vector<Pose> phantom_random_poses(size_t count, uint64_t seed = 2024);

/// Poses with the probe face on the skin looking inward (ŷ aimed at the liver's right lobe),
/// spread over the anterior and right-lateral abdomen; alternating transverse (x̂ in the axial
/// plane) and longitudinal (x̂ along the body axis) orientations. `face_y_mm` is the probe's
/// axial face offset so the face, not the probe origin, touches the skin.
std::vector<Pose> phantom_surface_poses(size_t count, double face_y_mm);

}  // namespace sonoslice
