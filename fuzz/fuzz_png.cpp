// libFuzzer harness: PNG images through sonoslice's libpng reader (read_png_file: every layout
// libpng expands, the sCAL spacing), as one frame (read_image_stack) and as a volume (read_volume).
#include "sonoslice/io/VolumeFile.h"

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "image.png");
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_image_stack(path, "--frames")); });
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_volume(path)); });
  return 0;
}
