// Probe files: native JSON (docs/conventions.md §3) and fan-slicer configurations unchanged
// (docs/conventions.md §4).
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/phantom/Workloads.h"

namespace sonoslice {
namespace {

std::string error_of(const std::string& json, int ds = 1) {
  try {
    parse_probe_json(json, "p.json", ds);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(ProbeFile, NativeCurvilinear) {
  const ProbeGeometry p = parse_probe_json(R"({"type": "curvilinear", "radius_mm": 46.93,
      "depth_mm": 64.96, "sector_deg": 36, "face_y_mm": 2.1,
      "image": {"width": 334, "height": 272, "spacing_mm": [0.247, 0.247],
                "origin_mm": [-41.25, 0.0]}})",
                                           "p.json");
  EXPECT_EQ(p.type, ProbeType::Curvilinear);
  EXPECT_DOUBLE_EQ(p.radius_mm, 46.93);
  EXPECT_DOUBLE_EQ(p.depth_mm, 64.96);
  EXPECT_DOUBLE_EQ(p.sector_deg, 36);
  EXPECT_DOUBLE_EQ(p.face_y_mm, 2.1);
  EXPECT_EQ(p.image.width, 334);
  EXPECT_EQ(p.image.height, 272);
  EXPECT_DOUBLE_EQ(p.image.origin_mm[0], -41.25);
}

TEST(ProbeFile, NativeLinearDefaultsAndRoundTrip) {
  const ProbeGeometry p = parse_probe_json(
      R"({"type": "linear", "width_mm": 38, "image": {"width": 100, "height": 50, "spacing_mm": [0.4, 0.2]}})",
      "p.json");
  EXPECT_EQ(p.type, ProbeType::Linear);
  EXPECT_TRUE(p.has_width);
  EXPECT_FALSE(p.has_depth);
  EXPECT_DOUBLE_EQ(p.image.origin_mm[0],
                   -(100 - 1) * 0.4 / 2);  // default origin, docs/conventions.md §3
  EXPECT_DOUBLE_EQ(p.image.origin_mm[1], 0.0);
  const ProbeGeometry q = parse_probe_json(probe_to_json(p), "round trip");
  EXPECT_EQ(q.mask(), p.mask());
  EXPECT_DOUBLE_EQ(q.image.origin_mm[0], p.image.origin_mm[0]);
}

TEST(ProbeFile, ErrorsNameTheKey) {
  const std::string base = R"("image": {"width": 10, "height": 10, "spacing_mm": [1, 1]})";
  EXPECT_NE(
      error_of(
          R"({"type": "curvilinear", "radius_mm": 5, "depth_mm": 5, "sector_deg": 30, "radius": 3, )" +
          base + "}")
          .find("unknown key 'radius'"),
      std::string::npos);
  EXPECT_NE(error_of(R"({"type": "curvilinear", "depth_mm": 5, "sector_deg": 30, )" + base + "}")
                .find("missing key 'radius_mm'"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"type": "phased", )" + base + "}").find("type 'phased'"),
            std::string::npos);
  EXPECT_NE(
      error_of(R"({"type": "linear", "image": {"width": 10, "height": -2, "spacing_mm": [1, 1]}})")
          .find("width and height"),
      std::string::npos);
  EXPECT_NE(
      error_of(R"({"type": "linear", "image": {"width": 10, "height": 2, "spacing_mm": [1]}})")
          .find("'spacing_mm' must be a list of 2"),
      std::string::npos);
  EXPECT_NE(
      error_of(R"({"type": "linear", "image": {"width": 10, "height": 2, "spacing_mm": [1, 0]}})")
          .find("spacing"),
      std::string::npos);
  EXPECT_NE(
      error_of(
          R"({"type": "linear", "image": {"width": 10, "height": 2, "spacing_mm": [1, 1], "colour": 1}})")
          .find("unknown key 'colour'"),
      std::string::npos);
  EXPECT_NE(error_of(R"({"type": "linear", )").find("invalid JSON"), std::string::npos);
  EXPECT_NE(
      error_of(R"({"type": "linear", )" + base + "}", 0).find("downsampling 0: must be in 1..64"),
      std::string::npos);
  EXPECT_NE(error_of("[1, 2]").find("expected a JSON object"), std::string::npos);
  // Every message names the file.
  EXPECT_NE(error_of(R"({"type": "curvilinear", )" + base + "}").find("p.json"), std::string::npos);
}

// A parse error quotes the bytes it read; from a broken file they need not be UTF-8, and the
// message must stay one line of printable text naming the file.
TEST(ProbeFile, InvalidJsonMessageIsPrintable) {
  const std::string e = error_of("{\"type\": \"linear\xff\xfe\", \n}");
  EXPECT_NE(e.find("invalid JSON"), std::string::npos) << e;
  EXPECT_NE(e.find("p.json"), std::string::npos) << e;
  for (char c : e) EXPECT_TRUE(c >= 0x20 && c <= 0x7e) << int(static_cast<unsigned char>(c));
}

TEST(ProbeFile, MissingFileIsFileError) {
  EXPECT_THROW(read_probe("/nonexistent/probe.json"), FileError);
}

// docs/conventions.md §4 with the real fan-slicer files.
TEST(FanSlicerConfig, CurvilinearMappingWithDownsampling) {
  SONOSLICE_REQUIRE_DATA();
  const std::string path = test::data_dir() + "/fanslicer/models_intensity_LUS_config.json";
  // fan_geometry [0.05, 0.1235, 36, 526, 380, 17], 668 x 544 px of 0.1235 mm.
  const ProbeGeometry p = read_probe(path, 2);
  EXPECT_EQ(p.type, ProbeType::Curvilinear);
  EXPECT_EQ(p.image.width, 334);
  EXPECT_EQ(p.image.height, 272);
  EXPECT_DOUBLE_EQ(p.image.spacing_mm[0], 0.247);
  EXPECT_DOUBLE_EQ(p.radius_mm, 380 * 0.1235);
  EXPECT_DOUBLE_EQ(p.depth_mm, 526 * 0.1235);
  EXPECT_DOUBLE_EQ(p.face_y_mm, 17 * 0.1235);
  EXPECT_DOUBLE_EQ(p.sector_deg, 36);
  EXPECT_DOUBLE_EQ(p.image.origin_mm[0], -334 * 0.247 / 2);  // −W'·sx/2
  EXPECT_DOUBLE_EQ(p.image.origin_mm[1], 0);
  // Odd sizes floor: 668/3 = 222, 544/3 = 181.
  const ProbeGeometry q = read_probe(path, 3);
  EXPECT_EQ(q.image.width, 222);
  EXPECT_EQ(q.image.height, 181);
  EXPECT_DOUBLE_EQ(q.image.spacing_mm[0], 3 * 0.1235);
  // The built-in W1 probe (benchmarks, demo) is exactly this file.
  const ProbeGeometry w1 = workload_w1_fan_probe();
  EXPECT_EQ(w1.mask(), p.mask());
  EXPECT_DOUBLE_EQ(w1.image.origin_mm[0], p.image.origin_mm[0]);
  EXPECT_DOUBLE_EQ(w1.face_y_mm, p.face_y_mm);
  // The surface config of the same probe gives the same probe.
  const ProbeGeometry s =
      read_probe(test::data_dir() + "/fanslicer/models_binary_LUS_config.json", 2);
  EXPECT_EQ(s.mask(), p.mask());
  // And the 70° fan.
  const ProbeGeometry w = read_probe(test::data_dir() + "/fanslicer/intensity_config_2.json");
  EXPECT_EQ(w.image.width, 600);
  EXPECT_DOUBLE_EQ(w.sector_deg, 70);
  EXPECT_DOUBLE_EQ(w.image.origin_mm[0], -600 * 0.1235 / 2);
}

TEST(FanSlicerConfig, LinearMapping) {
  SONOSLICE_REQUIRE_DATA();
  const std::string path = test::data_dir() + "/fanslicer/linear_config.json";
  const ProbeGeometry p = read_probe(path);
  EXPECT_EQ(p.type, ProbeType::Linear);
  EXPECT_FALSE(p.has_width);
  EXPECT_FALSE(p.has_depth);
  EXPECT_EQ(p.image.width, 400);
  EXPECT_EQ(p.image.height, 500);
  EXPECT_DOUBLE_EQ(p.image.origin_mm[0], -200 * 0.1235);  // −floor(W'/2)·sx
  EXPECT_EQ(p.mask(), std::vector<uint8_t>(400 * 500, 1));
  EXPECT_EQ(workload_w2_linear_probe().image.origin_mm[0], p.image.origin_mm[0]);  // built-in W2
  const ProbeGeometry q = read_probe(path, 3);  // W' = 133: origin −floor(133/2)·sx = −66·sx
  EXPECT_EQ(q.image.width, 133);
  EXPECT_DOUBLE_EQ(q.image.origin_mm[0], -66 * 3 * 0.1235);
}

TEST(FanSlicerConfig, UnknownKeysAreErrors) {
  EXPECT_NE(error_of(R"({"simulation": {"transducer": "linear", "image_dimensions": [10, 10],
      "pixel_size": [1, 1], "pixelsize": 3}})")
                .find("unknown key 'pixelsize'"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"simulation": {"transducer": "linear", "image_dimensions": [10, 10]}})")
                .find("missing key 'pixel_size'"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"simulation": {"transducer": "curvilinear", "image_dimensions": [10, 10],
      "pixel_size": [1, 1], "fan_geometry": [1, 2, 3]}})")
                .find("fan_geometry"),
            std::string::npos);
  // fan-slicer's early configs have no transducer: a fan.
  const ProbeGeometry p =
      parse_probe_json(R"({"simulation": {"fan_geometry": [0.1, 0.1235, 110, 394, 46, 19],
      "image_dimensions": [722, 402], "pixel_size": [0.1235, 0.1235]}})",
                       "eus.json");
  EXPECT_EQ(p.type, ProbeType::Curvilinear);
  EXPECT_DOUBLE_EQ(p.sector_deg, 110);
}

}  // namespace
}  // namespace sonoslice
