// libFuzzer harness: .npy arrays (header and data, format versions 1-3): read_npy_header, read_npy
// (every byte the header claims is touched), and read_volume (which maps a native C-order file).
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/VolumeFile.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "array.npy");
  fuzz::expect_sonoslice_errors_only([&] { read_npy_header(path); });
  fuzz::expect_sonoslice_errors_only([&] {
    const NpyArray a = read_npy(path);
    fuzz::touch(a.data.get(), size_t(a.element_count()) * pixel_size(a.type));
  });
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_volume(path)); });
  return 0;
}
