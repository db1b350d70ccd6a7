// libFuzzer harness: The JSON configurations read from files: read_probe, fan-slicer surface
// configs (read_fanslicer_models), beam geometry (read_beam_geometry), the .npy volume sidecar and
// fan-slicer's npy_config (read_volume).
#include "sonoslice/compound/BeamGeometryFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/surface/SurfaceConfig.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::string volume = [] {
    const std::string p = (fuzz::work_dir() / "vol.npy").string();
    const float voxels[2 * 3 * 4] = {};
    write_npy(p, PixelType::Float32, {2, 3, 4}, voxels);
    return p;
  }();
  const std::string path = fuzz::write_input(data, size, "config.json");
  fuzz::expect_sonoslice_errors_only([&] { read_probe(path, 2); });
  fuzz::expect_sonoslice_errors_only(
      [&] { read_fanslicer_models(path, fuzz::work_dir().string()); });
  fuzz::expect_sonoslice_errors_only([&] { read_beam_geometry(path); });
  fuzz::expect_sonoslice_errors_only([&] {
    VolumeReadOptions options;
    options.fanslicer_npy_config = path;
    read_volume(volume, options);
  });
  // The same text as vol.npy's sidecar, vol.json.
  const std::string sidecar = fuzz::write_input(data, size, "vol.json");
  fuzz::expect_sonoslice_errors_only([&] { read_volume(volume); });
  std::remove(sidecar.c_str());
  return 0;
}
