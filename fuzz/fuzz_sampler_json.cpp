// libFuzzer harness: pose sampler settings (poses --sampler, a dataset SPEC's samplers), parsed
// from memory by parse_sampler_json, alone and as the overrides laid over a skin sampler.
#include "sonoslice/sampling/SamplerConfig.h"

#include "FuzzCommon.h"

using namespace sonoslice;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::remember_input(data, size);
  const std::string text(reinterpret_cast<const char*>(data), size);
  fuzz::expect_sonoslice_errors_only([&] { parse_sampler_json(text, "fuzz"); });
  fuzz::expect_sonoslice_errors_only([&] {
    parse_sampler_json(R"({"type": "skin", "reject": {"min_body": 0.5}})", "fuzz", text);
  });
  return 0;
}
