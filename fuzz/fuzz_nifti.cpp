// libFuzzer harness: NIfTI volumes (header, extensions, voxels; gzip-compressed when the input
// starts with gzip's magic) through read_volume: ITK reads the header, sonoslice the voxels.
#include "sonoslice/io/VolumeFile.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const bool gz = size >= 2 && data[0] == 0x1f && data[1] == 0x8b;
  const std::string path = fuzz::write_input(data, size, gz ? "volume.nii.gz" : "volume.nii");
  fuzz::expect_sonoslice_errors_only([&] { fuzz::touch(read_volume(path)); });
  return 0;
}
