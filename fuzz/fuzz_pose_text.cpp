// libFuzzer harness: Pose text files (.txt, .csv: 16 or 12 row-major numbers per line) through
// read_poses, read_matrices and read_matrix; written as .csv when the first line holds a comma,
// else .txt.
#include "sonoslice/io/PoseFile.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string head(reinterpret_cast<const char*>(data), std::min<size_t>(size, 256));
  const bool csv = head.substr(0, head.find('\n')).find(',') != std::string::npos;
  const std::string path = fuzz::write_input(data, size, csv ? "poses.csv" : "poses.txt");
  fuzz::expect_sonoslice_errors_only([&] { read_poses(path); });
  fuzz::expect_sonoslice_errors_only([&] { read_poses(path, WorldFrame::RAS); });
  fuzz::expect_sonoslice_errors_only([&] { read_matrices(path); });
  fuzz::expect_sonoslice_errors_only([&] { read_matrix(path, "--image-to-probe"); });
  return 0;
}
