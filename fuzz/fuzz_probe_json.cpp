// libFuzzer harness: Probe JSON: native probe files and fan-slicer configurations (a "simulation"
// key), parsed from memory by parse_probe_json, with and without downsampling; what parses
// round-trips.
#include "sonoslice/io/ProbeFile.h"

#include <algorithm>

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::remember_input(data, size);
  const std::string text(reinterpret_cast<const char*>(data), size);
  for (int downsampling : {1, 3}) {
    fuzz::expect_sonoslice_errors_only([&] {
      const ProbeGeometry probe = parse_probe_json(text, "fuzz.json", downsampling);
      parse_probe_json(probe_to_json(probe), "round trip");
    });
  }
  return 0;
}
