// libFuzzer harness: tissue tables (simulate --tissues), parsed from memory by
// parse_tissue_table; what parses round-trips through tissue_table_json.
#include "sonoslice/simulate/TissueFile.h"

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::remember_input(data, size);
  const std::string text(reinterpret_cast<const char*>(data), size);
  fuzz::expect_sonoslice_errors_only([&] {
    const std::vector<Tissue> tissues = parse_tissue_table(text, "fuzz.json");
    if (parse_tissue_table(tissue_table_json(tissues), "round trip").size() != tissues.size())
      std::abort();
  });
  return 0;
}
