// libFuzzer harness: PLUS configuration XML (VolumeReconstruction, CoordinateDefinitions) through
// read_plus_config, its output grid and its Image-to-Reference chain.
#include "sonoslice/plus/PlusConfig.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "config.xml");
  fuzz::expect_sonoslice_errors_only([&] {
    const PlusReconstructionConfig c = read_plus_config(path);
    c.output_grid();
    c.coordinate_definitions.get(c.image_frame, c.reference_frame);
  });
  return 0;
}
