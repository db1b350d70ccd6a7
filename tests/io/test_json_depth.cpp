// Every reader of JSON settings refuses a document nested deeper than kMaxJsonDepth with one
// error naming the input (code that walks a document recursively would otherwise exhaust the
// stack), and reads one nested exactly that deep.
#include <gtest/gtest.h>

#include <fstream>
#include <functional>
#include <string>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/JsonDepth.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/sampling/SamplerConfig.h"
#include "sonoslice/simulate/TissueFile.h"

namespace sonoslice {
namespace {

// `levels` nested arrays: depth levels - 1 at the innermost.
std::string nested(int levels) {
  return std::string(size_t(levels), '[') + std::string(size_t(levels), ']');
}

std::string error_of(const std::function<void()>& read) {
  try {
    read();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

const char* const kTooDeep = "invalid JSON (nested deeper than 64 levels)";

TEST(JsonDepth, TooDeepIsRefusedByEveryReaderNamingTheInput) {
  static_assert(kMaxJsonDepth == 64, "the messages below say 64");
  // A million levels: the depth at which the recursive code used to crash.
  const std::string deep = nested(1000000);
  const std::string probe = R"({"type": "linear", "notes": )" + deep + "}";
  EXPECT_EQ(error_of([&] { parse_probe_json(probe, "p.json"); }),
            std::string("probe 'p.json': ") + kTooDeep);
  const std::string tissues = R"({"tissues": [], "notes": )" + deep + "}";
  EXPECT_EQ(error_of([&] { parse_tissue_table(tissues, "tissues 't.json'"); }),
            std::string("tissues 't.json': ") + kTooDeep);
  std::string chain;  // a sweep's base sampler, nested without end
  for (int i = 0; i < 100000; ++i) chain += R"({"type": "sweep", "from": )";
  chain += R"({"type": "skin"})" + std::string(100000, '}');
  EXPECT_EQ(error_of([&] { parse_sampler_json(chain, "--sampler"); }),
            std::string("--sampler: ") + kTooDeep);
  EXPECT_EQ(error_of([&] { parse_sampler_json(R"({"type": "skin"})", "--sampler", chain); }),
            std::string("sampler overrides: ") + kTooDeep);
  test::TempDir dir;
  std::ofstream(dir.file("poses.json")) << R"({"poses": )" << deep << "}";
  EXPECT_EQ(error_of([&] { read_poses(dir.file("poses.json")); }),
            "poses '" + dir.file("poses.json") + "': " + kTooDeep);
}

TEST(JsonDepth, AsDeepAsTheLimitIsRead) {
  // The table's object is level 0, its notes' arrays levels 1 to 64.
  const std::string table =
      R"({"tissues": [{"name": "liver", "label": 1, "impedance_mrayl": 1.65,
          "attenuation_db_cm_mhz": 0.5, "scatter_mean": 0.025}], "notes": )";
  EXPECT_EQ(parse_tissue_table(table + nested(kMaxJsonDepth) + "}", "t").size(), 1u);
  EXPECT_EQ(error_of([&] { parse_tissue_table(table + nested(kMaxJsonDepth + 1) + "}", "t"); }),
            std::string("t: ") + kTooDeep);
}

// The flags of `sonoslice poses` laid over a sampler file: keys replaced, rules merged one by one.
TEST(JsonDepth, SamplerOverridesReplaceKeysAndMergeRules) {
  const SamplerSettings s = parse_sampler_json(
      R"({"type": "skin", "tilt_deg": [-5, 5], "depth_mm": [0, 2], "reject": {"min_body": 0.5}})",
      "--sampler", R"({"tilt_deg": [-10, 10], "reject": {"min_inside": 0.9}})");
  EXPECT_EQ(s.tilt_deg.lo, -10);
  EXPECT_EQ(s.tilt_deg.hi, 10);
  EXPECT_EQ(s.depth_mm.hi, 2);
  EXPECT_EQ(s.reject.min_body, 0.5);
  EXPECT_EQ(s.reject.min_inside, 0.9);
  EXPECT_NE(error_of([&] {
              parse_sampler_json(R"({"type": "region", "label": 3})", "--sampler",
                                 R"({"tilt_deg": [0, 1]})");
            }).find("key 'tilt_deg' does not apply to a region sampler"),
            std::string::npos);
  EXPECT_EQ(error_of([&] {
              parse_sampler_json(R"({"type": "skin", "reject": 5})", "--sampler",
                                 R"({"reject": {"min_inside": 0.9}})");
            }),
            "--sampler.reject: expected an object");
}

}  // namespace
}  // namespace sonoslice
