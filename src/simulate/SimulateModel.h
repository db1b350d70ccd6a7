#pragma once
/// @file What a Simulator holds (Simulator.cpp builds it): the volume and the tables the kernel
/// reads (ImageModel points into them), and, on a GPU, their device copies (SimulatorCUDA.cpp).
#include <memory>
#include <vector>

#include "SimulateImpl.h"
#include "sonoslice/simulate/Simulator.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {
namespace simulate_impl {

struct CudaSimulateState;

struct Model {
  Volume volume;
  SimulationSource source;
  ProbeGeometry probe;
  SimulationSettings settings;
  std::vector<uint8_t> mask;
  std::vector<Props> label_props;  // label source: 65536 entries
  std::vector<Props> hu_table;
  std::vector<int16_t> speckle;  // the speckle table
  std::vector<float> axial_specular, lateral_speckle, lateral_specular;
  std::vector<int32_t> lateral_speckle_range, lateral_specular_range;
  std::vector<int32_t> scan_index, scan_sample;
  std::vector<ScanEntry> scan_order;
  std::vector<uint8_t> scan_steps;
  std::vector<float> scan_weights;
  ImageModel base;                          // everything but the pose
  std::shared_ptr<CudaSimulateState> cuda;  // settings.device is a GPU: the tables there
};

}  // namespace simulate_impl
}  // namespace sonoslice
