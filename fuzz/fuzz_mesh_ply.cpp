// libFuzzer harness: Surface meshes as Stanford .ply (ASCII and binary) through read_mesh.
#include "sonoslice/io/MeshFile.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = fuzz::write_input(data, size, "mesh.ply");
  fuzz::expect_sonoslice_errors_only([&] { read_mesh(path, WorldFrame::RAS); });
  return 0;
}
