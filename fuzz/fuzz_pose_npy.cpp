// libFuzzer harness: Pose .npy files ((N,4,4) or fan-slicer's (4,4N) strip) through read_poses and
// read_matrices.
#include "sonoslice/io/PoseFile.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "poses.npy");
  fuzz::expect_sonoslice_errors_only([&] { read_poses(path, WorldFrame::RAS); });
  fuzz::expect_sonoslice_errors_only([&] { read_matrices(path); });
  return 0;
}
