// The sonoslice command line end to end: outputs on disk, and one clear line plus a non-zero
// exit (and no partial or overwritten output) for every kind of bad input.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <sstream>
#include <stdexcept>

#include <nlohmann/json.hpp>

#include "../common/TestUtil.h"
#include "sonoslice/compound/Compounder.h"
#include "sonoslice/compound/Reconstruction.h"
#include "sonoslice/io/MeshFile.h"
#include "sonoslice/io/Npy.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/plus/PlusConfig.h"
#include "sonoslice/plus/PlusSequence.h"

namespace sonoslice {
namespace {

namespace fs = std::filesystem;

struct CliRun {
  int code;
  std::string out, err;
};

std::string quote(const std::string& s) {
  return "'" + s + "'";
}

CliRun run(const std::string& args, const fs::path& dir) {
  const std::string out_file = (dir / ".stdout").string(), err_file = (dir / ".stderr").string();
  const std::string cmd =
      std::string(SONOSLICE_CLI) + " " + args + " >" + quote(out_file) + " 2>" + quote(err_file);
  const int status = std::system(cmd.c_str());
  auto slurp = [](const std::string& p) {
    std::ifstream in(p);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  };
  CliRun r{WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(out_file), slurp(err_file)};
  fs::remove(out_file);
  fs::remove(err_file);
  return r;
}

CliRun run(const std::string& args, const test::TempDir& dir) {
  return run(args, dir.path());
}

// "size:mtime" of a file, to tell a rebuilt program from the one that made a cached input.
std::string file_stamp(const fs::path& path) {
  struct stat s {};
  if (::stat(path.c_str(), &s) != 0) return "missing";
  return std::to_string(s.st_size) + ":" + std::to_string(s.st_mtim.tv_sec) + "." +
         std::to_string(s.st_mtim.tv_nsec);
}

// The inputs the tests read and never write (the small phantom, a fan, twelve poses), in `dir`.
// ctest runs every test case in its own process, and each would make the same phantom again
// (0.7 s; 1.8 s under the sanitizers), so they are made once per build under a lock, and made
// again when the CLI or this program has been rebuilt since.
void make_shared_inputs(const fs::path& dir) {
  fs::create_directories(dir);
  const int lock = ::open((dir / ".lock").c_str(), O_CREAT | O_RDWR, 0644);
  if (lock < 0 || ::flock(lock, LOCK_EX) != 0)
    throw std::runtime_error("cannot lock " + dir.string());
  const std::string stamp =
      file_stamp(SONOSLICE_CLI) + " " + file_stamp(fs::read_symlink("/proc/self/exe"));
  if (test::read_file_bytes((dir / "stamp").string()) != stamp) {
    fs::remove(dir / "stamp");
    fs::remove_all(dir / "ph");
    const CliRun made = run("phantom " + quote((dir / "ph").string()) + " --size small -q", dir);
    if (made.code != 0) throw std::runtime_error("sonoslice phantom: " + made.err);
    const ProbeGeometry probe = test::curvilinear_probe(20, 60, 60, 120, 100, 0.7);
    std::ofstream((dir / "fan.json").string()) << probe_to_json(probe);
    write_poses_text((dir / "poses.txt").string(), phantom_random_poses(12, 5));
    std::ofstream((dir / "stamp").string()) << stamp;  // last: the inputs are complete
  }
  ::close(lock);  // releases the lock
}

// Directory entries other than the ones named (to spot partial or temporary outputs).
std::vector<std::string> entries(const test::TempDir& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir.path()))
    names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

class Cli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    data_ = SONOSLICE_CLI_TEST_DATA;
    make_shared_inputs(data_);
  }
  static std::string data_file(const std::string& name) { return (data_ / name).string(); }
  static std::string ct() { return quote(data_file("ph/ct.nii.gz")); }
  static std::string fan() { return quote(data_file("fan.json")); }
  static std::string poses() { return quote(data_file("poses.txt")); }
  static fs::path data_;
};
fs::path Cli::data_;

TEST_F(Cli, SliceToNpyMatchesLibraryAndWritesMask) {
  test::TempDir out;
  const CliRun r =
      run("slice --volume " + ct() + " --probe " + fan() + " --poses " + poses() + " --out " +
              quote(out.file("s.npy")) + " --mask " + quote(out.file("mask.png")) + " --verbose",
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("load"), std::string::npos);  // --verbose timings
  EXPECT_NE(r.err.find("slice"), std::string::npos);
  const NpyArray a = read_npy(out.file("s.npy"));
  EXPECT_EQ(a.type, PixelType::Float32);
  EXPECT_EQ(a.shape, (std::vector<int64_t>{12, 100, 120}));
  // Same numbers as the library on the same inputs.
  const Slicer slicer(read_volume(data_file("ph/ct.nii.gz")), read_probe(data_file("fan.json")));
  const auto expected = slicer.slice<float>(read_poses(data_file("poses.txt")));
  EXPECT_EQ(0, std::memcmp(expected.data(), a.data.get(), expected.size() * sizeof(float)));
  const Volume mask = read_volume(out.file("mask.png"));
  EXPECT_EQ(mask.grid().dims, (std::array<int64_t, 3>{120, 100, 1}));
  int64_t inside = 0;
  for (int64_t i = 0; i < 12000; ++i) inside += mask.data_as<uint8_t>()[i] == 255;
  int64_t expected_inside = 0;
  for (uint8_t m : slicer.mask()) expected_inside += m;
  EXPECT_EQ(inside, expected_inside);
  EXPECT_EQ(entries(out), (std::vector<std::string>{"mask.png", "s.npy"}));
}

TEST_F(Cli, SliceToNiftiStackAndPngDirectory) {
  test::TempDir out;
  CliRun r =
      run("slice --volume " + ct() + " --probe " + fan() + " --poses " + poses() + " --out " +
              quote(out.file("s.nii.gz")) + " --dtype int16 --interp nearest --fill -1000 -q",
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  const Volume stack = read_volume(out.file("s.nii.gz"));
  EXPECT_EQ(stack.pixel_type(), PixelType::Int16);
  EXPECT_EQ(stack.grid().dims, (std::array<int64_t, 3>{120, 100, 12}));
  EXPECT_NEAR(stack.grid().spacing_mm[0], 0.7, 1e-6);
  EXPECT_NEAR(stack.grid().spacing_mm[2], 1.0, 1e-6);
  EXPECT_EQ(stack.data_as<int16_t>()[0], -1000);  // top-left corner: outside the fan
  r = run("slice --volume " + ct() + " --probe " + fan() + " --poses " + poses() + " --out " +
              quote(out.file("pngs")) + " --window 40,400",
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out.file("pngs/img_00000.png")));
  EXPECT_TRUE(fs::exists(out.file("pngs/img_00011.png")));
  EXPECT_EQ(read_poses(out.file("pngs/poses.txt")).size(), 12u);
  EXPECT_EQ(read_volume(out.file("pngs/img_00003.png")).pixel_type(), PixelType::UInt8);
}

TEST_F(Cli, InfoPrintsGeometryAndJson) {
  test::TempDir out;
  CliRun r = run("info " + ct(), out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("128 x 128 x 100"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("int16"), std::string::npos);
  r = run("info --json " + ct(), out);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["dims"], nlohmann::json({128, 128, 100}));
  EXPECT_EQ(j["pixel_type"], "int16");
  EXPECT_NEAR(j["spacing"][2].get<double>(), 4.0, 1e-6);
  EXPECT_LT(j["value_range"][0].get<double>(), -900);
  r = run("info --devices", out);
  ASSERT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("cuda: "), std::string::npos);
}

TEST_F(Cli, DemoAndBenchRun) {
  test::TempDir out;
  CliRun r = run("demo " + quote(out.file("demo")) + " --size small --poses 4 -q", out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out.file("demo/contact_sheet.png")));
  EXPECT_TRUE(fs::exists(out.file("demo/fan/img_00003.png")));
  const Volume sheet = read_volume(out.file("demo/contact_sheet.png"));
  EXPECT_GT(sheet.grid().dims[0], 1000);
  r = run("bench --size small --count 20 --repeat 1 --json", out);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j.size(), 4u);  // W1, W2 × float32, int16
  for (const auto& row : j) EXPECT_GT(row["images_per_second"].get<double>(), 0);
}

TEST_F(Cli, VoxelizeAndSliceMeshesInBothModesWithColours) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir out;
  const std::string d = test::data_dir() + "/fanslicer";
  const std::string veins = quote(d + "/hepatic veins.vtk"), portal = quote(d + "/portal vein.vtk");
  // voxelize: two meshes (names with spaces) into one label volume, fan-slicer's grid.
  CliRun r = run("voxelize " + veins + " " + portal + " --spacing 0.5 --margin 20 --out " +
                     quote(out.file("labels.nii.gz")),
                 out);
  ASSERT_EQ(r.code, 0) << r.err;
  const Volume labels = read_volume(out.file("labels.nii.gz"));
  EXPECT_EQ(labels.pixel_type(), PixelType::UInt8);
  EXPECT_EQ(labels.value_range().second, 2);
  // Poses through the vessels' region, probe = fan-slicer's surface config.
  std::vector<Pose> poses = phantom_random_poses(20, 3);
  for (Pose& p : poses) {
    p.m[0][3] = -30 + 0.15 * p.m[0][3];
    p.m[1][3] = 0 + 0.15 * p.m[1][3];
    p.m[2][3] = -310 + 0.15 * p.m[2][3];
  }
  write_poses_npy(out.file("in_poses.npy"), poses);
  const std::string cfg = quote(d + "/models_binary_LUS_config.json");
  const std::string common =
      " --probe " + cfg + " --downsampling 2 --poses " + quote(out.file("in_poses.npy"));
  r = run("slice --labels " + quote(out.file("labels.nii.gz")) + common + " --out " +
              quote(out.file("from_labels.npy")) + " --colors " + quote(out.file("colors.npy")),
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  r = run("slice --mesh-dir " + quote(d) + common + " --surface-mode exact --out " +
              quote(out.file("exact.npy")) + " --colors " + quote(out.file("colors_png")),
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  r = run("slice --mesh-dir " + quote(d) + common + " --voxel-size 0.5 --out " +
              quote(out.file("voxel.nii.gz")),
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  const NpyArray a = read_npy(out.file("from_labels.npy")), e = read_npy(out.file("exact.npy"));
  EXPECT_EQ(a.type, PixelType::UInt8);
  EXPECT_EQ(a.shape, (std::vector<int64_t>{20, 272, 334}));
  const NpyArray c = read_npy(out.file("colors.npy"));
  EXPECT_EQ(c.shape, (std::vector<int64_t>{20, 272, 334, 3}));
  // Colours: grey 210 outside the fan (top-left corner), black background, label 1 in the
  // default palette's first colour (150, 0, 0).
  const auto* rgb = static_cast<const uint8_t*>(c.data.get());
  EXPECT_EQ(rgb[0], 210);
  const auto* lab = static_cast<const uint8_t*>(a.data.get());
  int64_t ones = 0, agree = 0, exact_ones = 0;
  const auto* ex = static_cast<const uint8_t*>(e.data.get());
  for (int64_t i = 0; i < a.element_count(); ++i) {
    if (lab[i] == 1) {
      ++ones;
      EXPECT_EQ(rgb[3 * i], 150);
    }
    exact_ones += ex[i] == 1;
    agree += lab[i] == 1 && ex[i] == 1;
  }
  ASSERT_GT(ones, 500);
  EXPECT_GT(2.0 * double(agree) / double(ones + exact_ones), 0.9);  // 0.5 mm voxels vs exact
  EXPECT_TRUE(fs::exists(out.file("colors_png/img_00019.png")));
  EXPECT_EQ(read_volume(out.file("voxel.nii.gz")).grid().dims[2], 20);
}

TEST_F(Cli, CompoundPlusSequencesBothFormatsAgree) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir out;
  const std::string plus = test::data_dir() + "/plus/";
  const std::string xml =
      quote(plus + "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml");
  const CliRun a = run("compound --sequence " + quote(plus + "NwirePhantomFreehand.igs.mha") +
                           " --config " + xml + " --out " + quote(out.file("a.nii.gz")) +
                           " --weights " + quote(out.file("w.nrrd")) + " -q",
                       out);
  ASSERT_EQ(a.code, 0) << a.err;
  const CliRun b = run("compound --sequence " + quote(plus + "NwirePhantomFreehand.igs.nrrd") +
                           " --config " + xml + " --out " + quote(out.file("b.mha")) + " -q",
                       out);
  ASSERT_EQ(b.code, 0) << b.err;
  const Volume va = read_volume(out.file("a.nii.gz")), vb = read_volume(out.file("b.mha"));
  EXPECT_EQ(va.pixel_type(), PixelType::UInt8);
  EXPECT_EQ(va.grid().dims, (std::array<int64_t, 3>{101, 105, 74}));
  EXPECT_NEAR(va.grid().origin_mm[0], -22.2573, 1e-3);  // PLUS's reference origin
  ASSERT_EQ(va.byte_size(), vb.byte_size());
  EXPECT_EQ(std::memcmp(va.data(), vb.data(), va.byte_size()), 0);
  const Volume w = read_volume(out.file("w.nrrd"));
  EXPECT_EQ(w.pixel_type(), PixelType::Float32);
  // Flags override the XML: nearest, max, hole filling, a clip rectangle.
  const CliRun c = run("compound --sequence " + quote(plus + "NwirePhantomFreehand.igs.mha") +
                           " --config " + xml +
                           " --interp nearest --compounding max --fill-holes on"
                           " --clip-rect 200,100,300,300 --spacing 1 --out " +
                           quote(out.file("c.nii")) + " -v",
                       out);
  ASSERT_EQ(c.code, 0) << c.err;
  EXPECT_NE(c.err.find("nearest splats, max compounding, hole filling on"), std::string::npos)
      << c.err;
  EXPECT_NE(c.err.find("97 of 97 frames"), std::string::npos) << c.err;
  EXPECT_LT(read_volume(out.file("c.nii")).grid().dims[0], 60);  // 1 mm, smaller clip
}

// The CLI is a thin caller of the reconstruction recipe: the same volume, byte for byte, as the
// library gives for the same inputs; --dtype is honoured for every type (float64 included:
// before the recipe, the CLI silently wrote float32).
TEST_F(Cli, CompoundIsTheLibraryRecipeAndHonoursDtype) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir out;
  const std::string plus = test::data_dir() + "/plus/";
  const std::string seq = plus + "NwirePhantomFreehand.igs.mha";
  const std::string xml =
      plus + "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml";
  const CliRun a = run("compound --sequence " + quote(seq) + " --config " + quote(xml) +
                           " --skip 2 --dtype float64 --out " + quote(out.file("a.npy")) + " -q",
                       out);
  ASSERT_EQ(a.code, 0) << a.err;
  const NpyArray cli = read_npy(out.file("a.npy"));
  EXPECT_EQ(cli.type, PixelType::Float64);

  const PlusSequence s = read_plus_sequence(seq);
  const PlusReconstructionConfig config = read_plus_config(xml);
  ReconstructionOptions o;
  o.skip = 2;
  o.output_type = PixelType::Float64;
  Reconstruction recon(FrameSource::plus(s), &config, o);
  EXPECT_EQ(recon.report().frames_considered, 49);
  EXPECT_EQ(recon.report().frames_used, 49);
  const Volume lib = recon.run().volume;
  ASSERT_EQ(size_t(cli.element_count()) * 8, lib.byte_size());
  EXPECT_EQ(std::memcmp(cli.data.get(), lib.data(), lib.byte_size()), 0);
  // Not all zeros, and a float64 volume keeps the fractions a uint8 one would round away.
  const double* v = static_cast<const double*>(lib.data());
  size_t fractional = 0;
  for (int64_t i = 0; i < lib.grid().voxel_count(); ++i) fractional += v[i] != std::floor(v[i]);
  EXPECT_GT(fractional, 1000u);
}

TEST_F(Cli, CompoundSlicedFramesAndBeamFrames) {
  test::TempDir out;
  // A sweep of the phantom sliced by `slice`, compounded back with the same probe and poses.
  std::vector<Pose> sweep;
  for (int k = 0; k < 40; ++k)
    sweep.push_back(Mat4::from_rotation_translation(test::rotation({{1, 0, 0}}, 90),
                                                    {{0.0, -20.0 + 1.0 * k, -40.0}}));
  write_poses_text(out.file("sweep.txt"), sweep);
  ASSERT_EQ(
      run("slice --volume " + ct() + " --probe " + fan() + " --poses " +
              quote(out.file("sweep.txt")) + " --out " + quote(out.file("frames.nii")) + " -q",
          out)
          .code,
      0);
  const CliRun r =
      run("compound --frames " + quote(out.file("frames.nii")) + " --poses " +
              quote(out.file("sweep.txt")) + " --probe " + fan() + " --spacing 1.5 --out " +
              quote(out.file("v.nii.gz")) + " --weights " + quote(out.file("w.nii.gz")) + " -q",
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  const Volume v = read_volume(out.file("v.nii.gz")), w = read_volume(out.file("w.nii.gz"));
  const Volume ct_volume = read_volume(data_file("ph/ct.nii.gz"));
  EXPECT_EQ(v.pixel_type(), PixelType::Float32);  // the frames' type
  // Covered voxels hold the CT values at their centres (within the blur of two resamplings).
  std::vector<double> errors;
  for (int64_t i = 0; i < v.grid().voxel_count(); i += 7) {
    if (w.data_as<float>()[i] < 1) continue;
    const int64_t x = i % v.grid().dims[0], y = i / v.grid().dims[0] % v.grid().dims[1],
                  z = i / (v.grid().dims[0] * v.grid().dims[1]);
    double expected = 0, margin = 0;
    if (!test::reference_sample(ct_volume,
                                v.grid().index_to_world({{double(x), double(y), double(z)}}),
                                Interpolation::Linear, 0, &expected, &margin))
      continue;
    errors.push_back(std::fabs(v.data_as<float>()[i] - expected));
  }
  ASSERT_GT(errors.size(), 1000u);
  std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
  EXPECT_LT(errors[errors.size() / 2], 2.0);  // HU (measured 0.46); contrasts are hundreds of HU

  // Beam-space frames with their geometry file: values that change along each beam and from
  // one elevation to the next, so that an axis mix-up shows.
  std::vector<uint8_t> beams(3 * 4 * 6 * 30);
  for (size_t i = 0; i < beams.size(); ++i)
    beams[i] = uint8_t(10 + 8 * (i % 30) + (i / (6 * 30)) % 4);
  write_npy(out.file("beams.npy"), PixelType::UInt8, {3, 4, 6, 30}, beams.data());
  std::ofstream(out.file("geom.json"))
      << R"({"r0_mm": 2, "dr_mm": 0.5, "azimuth0_deg": -10, "dazimuth_deg": 4,
            "elevation0_deg": -6, "delevation_deg": 4, "apex_offset_mm": 1})";
  write_poses_text(out.file("bp.txt"), {Pose{}, Pose{}, Pose{}});
  const CliRun b =
      run("compound --beam-frames " + quote(out.file("beams.npy")) + " --beam-geometry " +
              quote(out.file("geom.json")) + " --poses " + quote(out.file("bp.txt")) +
              " --spacing 0.5 --out " + quote(out.file("b.nii")) + " -q",
          out);
  ASSERT_EQ(b.code, 0) << b.err;
  const Volume bv = read_volume(out.file("b.nii"));
  EXPECT_EQ(bv.pixel_type(), PixelType::UInt8);
  // The library, given the same frames in docs/conventions.md §7's (elevation, azimuth, sample)
  // order, makes the same volume (its own placement is checked against docs/conventions.md in
  // test_core).
  BeamGeometry g;
  g.n_elevation = 4;
  g.n_azimuth = 6;
  g.n_samples = 30;
  g.r0_mm = 2;
  g.dr_mm = 0.5;
  g.azimuth0_deg = -10;
  g.dazimuth_deg = 4;
  g.elevation0_deg = -6;
  g.delevation_deg = 4;
  g.apex_offset_mm = 1;
  const std::vector<Mat4> identity(3);
  Compounder c(Compounder::grid_around_beams(identity, g, 0.5), CompoundSettings{});
  c.add_beams(beams.data(), PixelType::UInt8, g, 3, identity.data());
  const Volume expected = c.volume(PixelType::UInt8);
  ASSERT_EQ(bv.grid().dims, expected.grid().dims);
  for (int a = 0; a < 3; ++a)
    EXPECT_NEAR(bv.grid().origin_mm[a], expected.grid().origin_mm[a], 1e-4);
  EXPECT_EQ(std::memcmp(bv.data(), expected.data(), expected.byte_size()), 0);
  int64_t reached = 0;
  for (int64_t i = 0; i < bv.grid().voxel_count(); ++i) reached += bv.data_as<uint8_t>()[i] != 0;
  EXPECT_GT(reached, 500);
}

// One frame with an all-zero ProbeToTracker (a tracker that lost the probe) turned the
// Nwire grid of 101x105x74 voxels into 519x689x4084 without a word; one frame without its
// ProbeToTracker failed the sweep without naming the frame. Both frames are now left out, named.
TEST_F(Cli, CompoundSkipsAndNamesFramesItsTransformsCannotPlace) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir out;
  const std::string plus = test::data_dir() + "/plus/";
  std::string bytes;
  {
    std::ifstream in(plus + "NwirePhantomFreehand.igs.mha", std::ios::binary);
    bytes.assign((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  }
  const std::string zero = "Seq_Frame0005_ProbeToTrackerTransform = ";
  const size_t at = bytes.find(zero) + zero.size();
  bytes.replace(at, bytes.find('\n', at) - at, "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1");
  const size_t gone = bytes.find("Seq_Frame0007_ProbeToTrackerTransform =");
  bytes.erase(gone, bytes.find('\n', gone) + 1 - gone);
  std::ofstream(out.file("sweep.igs.mha"), std::ios::binary) << bytes;
  const CliRun r =
      run("compound --sequence " + quote(out.file("sweep.igs.mha")) + " --config " +
              quote(plus + "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml") +
              " --out " + quote(out.file("v.nii")),
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("skipped 2 of 97 frames: 2 whose transforms cannot place them (frame 5: "
                       "its ImageToReference maps the image's x axis to a point"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("frame 7: no chain of transforms"), std::string::npos) << r.err;
  EXPECT_EQ(read_volume(out.file("v.nii")).grid().dims, (std::array<int64_t, 3>{101, 105, 74}));
}

// --- bad input: one line on stderr naming the input, exit 1, nothing written -----------------

struct BadCase {
  std::string name, args, needle;
};
void PrintTo(const BadCase& c, std::ostream* os) {
  *os << c.name;
}

class CliBadInput : public Cli, public ::testing::WithParamInterface<BadCase> {};

void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

// Broken inputs for the readers: meshes, volume headers, JSON, PLUS transforms.
void write_broken_reader_inputs(const test::TempDir& dir) {
  const std::string liver = test::data_dir() + "/fanslicer/liver.vtk";
  if (fs::exists(liver))  // `head -c 308216 liver.vtk`: crashed VTK's reader
    write_text(dir.file("in_cut.vtk"), test::read_file_bytes(liver).substr(0, 308216));
  write_text(dir.file("in_idx.vtk"),
             "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n"
             "0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 99999\n");
  std::string stl = test::read_file_bytes(dir.file("in_tet.stl"));
  const uint32_t claimed = 4294967295u;
  std::memcpy(&stl[80], &claimed, 4);
  write_text(dir.file("in_big.stl"), stl);
  write_text(dir.file("in_junk.obj"), "hello world\nthis is not an obj\n");
  VolumeGrid grid;
  grid.dims = {4, 4, 4};
  std::vector<int16_t> voxels(64, 7);
  write_volume(dir.file("in_good.nii"), Volume::wrap(voxels.data(), PixelType::Int16, grid, {}));
  auto patched = [&](const std::string& name, std::streamoff at, const void* bytes, size_t n) {
    fs::copy_file(dir.file("in_good.nii"), dir.file(name));
    std::fstream f(dir.file(name), std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(at);
    f.write(static_cast<const char*>(bytes), std::streamsize(n));
  };
  const float zero = 0.0f, nan_inter[2] = {std::nanf(""), 5.0f};
  const int16_t no_size = 0;
  patched("in_pix0.nii", 80, &zero, 4);
  patched("in_sclnan.nii", 112, nan_inter, 8);
  patched("in_dim.nii", 42, &no_size, 2);
  write_text(dir.file("in_spnan.mha"),
             "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\nElementSpacing = nan 1 1\n"
             "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" +
                 std::string(64, '\1'));
  write_text(dir.file("in_detached.mhd"),
             "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\nElementType = MET_UCHAR\n"
             "ElementDataFile = in_gone.raw\n");
  std::string dict =
      "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296, 1), }";
  dict.append(size_t(63 - (10 + dict.size()) % 64), ' ');
  dict += '\n';
  write_text(dir.file("in_over.npy"), std::string("\x93NUMPY\x01\x00", 8) +
                                          char(dict.size() & 0xff) + char(dict.size() >> 8) + dict +
                                          std::string(102, '\0'));
  const std::string models = test::data_dir() + "/fanslicer/models_binary_LUS_config.json";
  if (fs::exists(models)) {
    std::string cfg = test::read_file_bytes(models);
    cfg.replace(cfg.find("[0, 200, 0]"), 11, "[\"green\", 200, 0]");
    write_text(dir.file("in_colour.json"), cfg);
  }
  const std::string xml =
      test::data_dir() + "/plus/PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml";
  if (fs::exists(xml)) {
    std::string x = test::read_file_bytes(xml);
    const size_t from = x.find("Matrix=\"", x.find("From=\"Image\" To=\"Probe\"")) + 8;
    x.replace(from, x.find('"', from) - from, "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0");
    write_text(dir.file("in_zero_cal.xml"), x);
  }
  // The Nwire sweep without any ProbeToTracker: no frame can be placed.
  const std::string seq = test::data_dir() + "/plus/NwirePhantomFreehand.igs.mha";
  if (fs::exists(seq)) {
    const std::string bytes = test::read_file_bytes(seq);
    const size_t data = bytes.find("ElementDataFile");
    std::istringstream header(bytes.substr(0, data));
    std::string kept, line;
    while (std::getline(header, line))
      if (line.find("_ProbeToTrackerTransform =") == std::string::npos) kept += line + "\n";
    write_text(dir.file("in_notrack.igs.mha"), kept + bytes.substr(data));
  }
}

// The broken inputs the cases read (all named in_*).
void write_bad_inputs(const test::TempDir& dir, const std::string& good_ct) {
  write_text(dir.file("in_junk.nii.gz"), "not a volume at all");
  fs::copy_file(good_ct, dir.file("in_trunc.nii.gz"));
  fs::resize_file(dir.file("in_trunc.nii.gz"), fs::file_size(good_ct) / 3);
  // A MetaImage with RGB voxels, written by hand.
  write_text(dir.file("in_rgb.mha"),
             "ObjectType = Image\nNDims = 3\nDimSize = 4 4 4\nElementNumberOfChannels = 3\n"
             "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n" +
                 std::string(4 * 4 * 4 * 3, '\x7f'));
  const std::string eye = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n";
  write_text(dir.file("in_nan.txt"), eye + eye + "1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1\n");
  write_text(dir.file("in_flat.txt"), "1 1 0 0 0 0 0 0 0 0 1 0 0 0 0 1\n");
  std::vector<double> wrong(15, 0.0);
  write_npy(dir.file("in_shape.npy"), PixelType::Float64, {3, 5}, wrong.data());
  const std::string image = R"("image": {"width": 64, "height": 64, "spacing_mm": [0.5, 0.5]})";
  write_text(
      dir.file("in_typo.json"),
      R"({"type": "curvilinear", "radius_mm": 20, "depth_mm": 40, "sector": 60, )" + image + "}");
  write_text(dir.file("in_missing.json"),
             R"({"type": "curvilinear", "radius_mm": 20, "sector_deg": 60, )" + image + "}");
  write_text(
      dir.file("in_negative.json"),
      R"({"type": "linear", "image": {"width": -5, "height": 64, "spacing_mm": [0.5, 0.5]}})");
  write_text(
      dir.file("in_huge.json"),
      R"({"type": "linear", "image": {"width": 30000, "height": 30000, "spacing_mm": [0.01, 0.01]}})");
  std::vector<float> vol(4 * 4 * 4, 1.0f);
  write_npy(dir.file("in_vol.npy"), PixelType::Float32, {4, 4, 4}, vol.data());
  fs::create_directory(dir.file("in_dir.npy"));
  write_text(dir.file("in_junk.vtk"),
             "# vtk DataFile Version 3.0\nbroken\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n1 2\n");
  TriangleMesh tet;
  tet.vertices = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
  tet.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  write_mesh(dir.file("in_tet.stl"), tet);
  // Compounding inputs: a truncated PLUS sequence, a bad PLUS XML, beam frames with a typo.
  const std::string seq = test::data_dir() + "/plus/NwirePhantomFreehand.igs.mha";
  if (fs::exists(seq)) {
    fs::copy_file(seq, dir.file("in_seq.igs.mha"));
    fs::resize_file(dir.file("in_seq.igs.mha"), fs::file_size(seq) / 2);
  }
  write_text(dir.file("in_plus.xml"),
             "<PlusConfiguration><VolumeReconstruction OutputSpacing=\"0.5 x 0.5\"/>"
             "</PlusConfiguration>");
  std::vector<float> beams(2 * 3 * 4 * 5, 10.0f);
  write_npy(dir.file("in_beams.npy"), PixelType::Float32, {2, 3, 4, 5}, beams.data());
  write_text(dir.file("in_geom.json"),
             R"({"r0_mm": 1, "dr_mm": 0.5, "azimuth0_deg": -5, "dazimuth_deg": 2.5,
                 "elevation0_deg": -4, "delevation_deg": 4, "apex": 0})");
  write_text(dir.file("in_geom_ok.json"),
             R"({"r0_mm": 1, "dr_mm": 0.5, "azimuth0_deg": -5, "dazimuth_deg": 2.5,
                 "elevation0_deg": -4, "delevation_deg": 4})");
  write_text(dir.file("in_two.txt"), eye + eye);
  write_broken_reader_inputs(dir);
}

TEST_P(CliBadInput, OneLineNonZeroExitNoOutput) {
  test::TempDir out;
  const BadCase& c = GetParam();
  write_bad_inputs(out, data_file("ph/ct.nii.gz"));
  // A good output from an earlier run must survive the failed one untouched.
  std::ofstream(out.file("out.npy")) << "previous good data";
  std::string args = c.args;
  auto replace = [&](const std::string& key, const std::string& value) {
    for (size_t at; (at = args.find(key)) != std::string::npos;)
      args.replace(at, key.size(), value);
  };
  replace("{CT}", ct());
  replace("{FAN}", fan());
  replace("{POSES}", poses());
  replace("{OUT}", quote(out.file("out.npy")));
  replace("{DIR}", out.path().string());
  replace("{SHARED}", test::data_dir());
  const CliRun r = run(args, out);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_EQ(r.err.rfind("sonoslice: error: ", 0), 0u) << r.err;
  EXPECT_NE(r.err.find(c.needle), std::string::npos)
      << "expected '" << c.needle << "' in: " << r.err;
  std::ifstream previous(out.file("out.npy"));
  std::string content((std::istreambuf_iterator<char>(previous)), std::istreambuf_iterator<char>());
  EXPECT_EQ(content, "previous good data");
  // Only the inputs the case made itself and the untouched output: no partial or temp files.
  for (const std::string& name : entries(out))
    EXPECT_TRUE(name == "out.npy" || name.rfind("in", 0) == 0) << "left behind: " << name;
}

const char* kSlice = "slice --volume {CT} --probe {FAN} --poses {POSES} --out {OUT} ";
const char* kNwire = "{SHARED}/plus/NwirePhantomFreehand.igs.mha";
const char* kNwireXml =
    "{SHARED}/plus/PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml";
const char* kCompound =
    "compound --sequence {SHARED}/plus/NwirePhantomFreehand.igs.mha --config "
    "{SHARED}/plus/PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml --out {OUT} ";

std::vector<BadCase> bad_cases() {
  std::vector<BadCase> cases = {
      {"MissingVolume",
       "slice --volume {DIR}/nope.nii.gz --probe {FAN} --poses {POSES} --out {OUT}",
       "nope.nii.gz': no such file"},
      {"CorruptVolume",
       "slice --volume {DIR}/in_junk.nii.gz --probe {FAN} --poses {POSES} --out {OUT}",
       "in_junk.nii.gz"},
      {"TruncatedVolume",
       "slice --volume {DIR}/in_trunc.nii.gz --probe {FAN} --poses {POSES} --out {OUT}",
       "in_trunc.nii.gz"},
      {"UnsupportedPixelType",
       "slice --volume {DIR}/in_rgb.mha --probe {FAN} --poses {POSES} --out {OUT}",
       "unsupported pixel type"},
      {"NanPose", "slice --volume {CT} --probe {FAN} --poses {DIR}/in_nan.txt --out {OUT}",
       "in_nan.txt': pose 2: has a non-finite"},
      {"DegeneratePose", "slice --volume {CT} --probe {FAN} --poses {DIR}/in_flat.txt --out {OUT}",
       "in_flat.txt': pose 0: lateral and axial axes"},
      {"WrongPoseShape", "slice --volume {CT} --probe {FAN} --poses {DIR}/in_shape.npy --out {OUT}",
       "shape (3, 5)"},
      {"UnknownProbeKey",
       "slice --volume {CT} --probe {DIR}/in_typo.json --poses {POSES} --out {OUT}",
       "unknown key 'sector'"},
      {"MissingProbeKey",
       "slice --volume {CT} --probe {DIR}/in_missing.json --poses {POSES} --out {OUT}",
       "missing key 'depth_mm'"},
      {"NegativeImageSize",
       "slice --volume {CT} --probe {DIR}/in_negative.json --poses {POSES} --out {OUT}",
       "width and height must be > 0"},
      {"ZeroSpacing",
       "slice --volume {DIR}/in_vol.npy --spacing 1,0,1 --probe {FAN} --poses {POSES} --out {OUT}",
       "spacing along axis 1"},
      {"OutputExceedsMemory",
       "slice --volume {CT} --probe {DIR}/in_huge.json --poses {POSES} --out {DIR}/big.nii",
       "GiB in memory"},
      {"UnwritableOutput",
       "slice --volume {CT} --probe {FAN} --poses {POSES} --out {DIR}/no/such/dir/x.npy",
       "does not exist"},
      {"OutputIsADirectory",
       "slice --volume {CT} --probe {FAN} --poses {POSES} --out {DIR}/in_dir.npy",
       "is an existing directory"},
      {"UnknownDtype", std::string(kSlice) + "--dtype float16", "--dtype float16"},
      // Readers: refused before a library crashes, prints or guesses.
      {"VoxelizeTruncatedBinaryVtk", "voxelize {DIR}/in_cut.vtk --spacing 1 --out {OUT}",
       "in_cut.vtk': truncated or corrupt file: POLYGONS announces 88000 values"},
      {"SliceTruncatedBinaryVtk",
       "slice --meshes {DIR}/in_cut.vtk --probe {FAN} --poses {POSES} --out {OUT}",
       "in_cut.vtk': truncated"},
      {"VtkIndexOutOfRange", "voxelize {DIR}/in_idx.vtk --spacing 1 --out {OUT}",
       "in_idx.vtk': POLYGONS: cell 0 uses point 99999, but the file has 3 points"},
      {"StlTriangleCountBeyondFile", "voxelize {DIR}/in_big.stl --spacing 1 --out {OUT}",
       "in_big.stl': truncated or corrupt binary STL: its header announces 4294967295 triangles"},
      {"ObjGarbage", "voxelize {DIR}/in_junk.obj --spacing 1 --out {OUT}",
       "in_junk.obj': not an OBJ mesh"},
      {"NiftiZeroPixdim",
       "slice --volume {DIR}/in_pix0.nii --probe {FAN} --poses {POSES} --out {OUT}",
       "in_pix0.nii': pixdim[1] is 0"},
      {"NiftiNanSlopeWithIntercept", "info {DIR}/in_sclnan.nii",
       "in_sclnan.nii': scl_slope is nan with scl_inter 5"},
      {"NiftiBadDimensionNoLibraryLine", "info {DIR}/in_dim.nii", "in_dim.nii': corrupt header"},
      {"MetaImageNanSpacingNoMetaIoNoise", "info {DIR}/in_spnan.mha",
       "in_spnan.mha': ElementSpacing 'nan 1 1'"},
      {"MetaImageMissingDataFile", "info {DIR}/in_detached.mhd", "in_gone.raw' (ElementDataFile)"},
      {"NpyShapeOverflow",
       "slice --volume {DIR}/in_over.npy --probe {FAN} --poses {POSES} --out {OUT}",
       "in_over.npy': the shape (4294967296, 4294967296, 1)"},
      {"FanSlicerColourNotANumber",
       "slice --mesh-dir {SHARED}/fanslicer --probe {DIR}/in_colour.json --poses {POSES} "
       "--out {OUT}",
       "in_colour.json': colour of 'hepatic veins' must be [r, g, b]"},
      {"ImageToProbeSevenNumbers",
       "compound --sequence " + std::string(kNwire) +
           " --image-to-probe 1,0,0,0,0,1,0 --spacing 1 --out {OUT}",
       "--image-to-probe '1,0,0,0,0,1,0': 7 numbers"},
      {"ImageToProbeAllZero",
       "compound --sequence " + std::string(kNwire) +
           " --image-to-probe 0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0 --spacing 1 --out {OUT}",
       "--image-to-probe: the pixel-to-probe matrix is all zero"},
      {"CompoundZeroCalibrationInXml",
       "compound --sequence " + std::string(kNwire) + " --config {DIR}/in_zero_cal.xml --out {OUT}",
       "in_zero_cal.xml: CoordinateDefinitions/Transform[2] (ImageToProbe)/@Matrix is all zero"},
      {"CompoundNoFrameHasItsTransforms",
       "compound --sequence {DIR}/in_notrack.igs.mha --config " + std::string(kNwireXml) +
           " --out {OUT}",
       "in_notrack.igs.mha: frame 0: no chain of transforms from 'Image' to 'Reference'"},
      {"UnknownInterp", std::string(kSlice) + "--interp cubic", "interpolation 'cubic'"},
      {"UnknownWorld", std::string(kSlice) + "--world XYZ", "world frame 'XYZ'"},
      {"BadWindow", std::string(kSlice) + "--window 40", "--window '40'"},
      {"WindowTrailingComma", std::string(kSlice) + "--window 40,400,",
       "--window '40,400,': '' is not a finite number"},
      {"BadDownsampling", std::string(kSlice) + "--downsampling 0", "--downsampling 0"},
      // cuda:99 fails on every machine: "not available" without a GPU, "no such GPU" with one.
      {"CudaUnavailable", std::string(kSlice) + "--device cuda:99", "cuda:99"},
      {"UnknownOutputFormat",
       "slice --volume {CT} --probe {FAN} --poses {POSES} --out {DIR}/x.tiff",
       "unknown format '.tiff'"},
      {"TwoSources", std::string(kSlice) + "--labels {CT}", "exactly one of"},
      {"LabelsNotInteger", "slice --labels {CT} --probe {FAN} --poses {POSES} --out {OUT}",
       "a label volume is uint8 or uint16"},
      {"LinearOnLabels",
       "slice --meshes {DIR}/in_tet.stl --probe {FAN} --poses {POSES} --out {OUT} --interp linear",
       "label images are nearest"},
      {"MissingMesh", "slice --meshes {DIR}/nope.vtk --probe {FAN} --poses {POSES} --out {OUT}",
       "nope.vtk': no such file"},
      {"CorruptMesh", "slice --meshes {DIR}/in_junk.vtk --probe {FAN} --poses {POSES} --out {OUT}",
       "in_junk.vtk"},
      {"ColorsWithoutLabels", std::string(kSlice) + "--colors {DIR}/c.npy", "--colors"},
      {"MeshDirNeedsSurfaceConfig",
       "slice --mesh-dir {DIR} --probe {FAN} --poses {POSES} --out {OUT}", "no \"models\""},
      {"ExactOnCuda",
       "slice --meshes {DIR}/in_tet.stl --surface-mode exact --probe {FAN} --poses {POSES} "
       "--out {OUT} --device cuda",
       "--surface-mode exact runs on the CPU"},
      {"VoxelizeZeroSpacing", "voxelize {DIR}/in_tet.stl --spacing 0 --out {OUT}",
       "--spacing 0: must be > 0 mm"},
      {"VoxelizeNoMesh", "voxelize {DIR}/nope.stl --spacing 1 --out {OUT}",
       "nope.stl': no such file"},
      {"CompoundMissingSequence", "compound --sequence {DIR}/nope.igs.mha --spacing 1 --out {OUT}",
       "nope.igs.mha"},
      {"CompoundTruncatedSequence",
       "compound --sequence {DIR}/in_seq.igs.mha --config " + std::string(kNwireXml) +
           " --out {OUT}",
       "in_seq.igs.mha"},
      {"CompoundNoCalibration",
       "compound --sequence " + std::string(kNwire) + " --spacing 1 --out {OUT}", "Image"},
      {"CompoundPlusOptimizationWithoutPlusExact",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --plus-optimization none --out {OUT}",
       "--plus-optimization needs --plus-exact"},
      {"CompoundPlusOptimizationUnknown",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --plus-exact --plus-optimization fast --out {OUT}",
       "\"fast\": not one of NONE, PARTIAL, FULL"},
      {"CompoundPlusGridWithoutPlusExact",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --plus-grid lattice --out {OUT}",
       "--plus-grid needs --plus-exact"},
      {"CompoundPlusGridUnknown",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --plus-exact --plus-grid round --out {OUT}",
       "\"round\": not legacy or lattice"},
      {"CompoundPlusOptimizationGpu",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --plus-exact --plus-optimization gpu --out {OUT}",
       "GPU (OpenCL) path is not reproduced"},
      {"CompoundBadXml",
       "compound --sequence " + std::string(kNwire) + " --config {DIR}/in_plus.xml --out {OUT}",
       "OutputSpacing"},
      {"CompoundMissingXml",
       "compound --sequence " + std::string(kNwire) + " --config {DIR}/nope.xml --out {OUT}",
       "nope.xml"},
      {"CompoundUnknownInterp", std::string(kCompound) + "--interp cubic", "--interp 'cubic'"},
      {"CompoundUnknownMode", std::string(kCompound) + "--compounding median", "'median'"},
      {"CompoundBadFillHoles", std::string(kCompound) + "--fill-holes maybe", "--fill-holes maybe"},
      {"CompoundBadClipRect", std::string(kCompound) + "--clip-rect 1,2,3", "--clip-rect"},
      {"CompoundTooBig", std::string(kCompound) + "--spacing 0.01 --max-memory 1G", "a spacing of"},
      {"CompoundBadMaxMemory", std::string(kCompound) + "--max-memory lots", "--max-memory lots"},
      {"CompoundCudaUnavailable", std::string(kCompound) + "--device cuda:99", "cuda:99"},
      {"CompoundOutputFormat",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --out {DIR}/v.png",
       "v.png': PNG holds 2-D images"},
      {"CompoundUnknownOutputFormat",
       "compound --sequence " + std::string(kNwire) + " --config " + std::string(kNwireXml) +
           " --out {DIR}/v.xyz",
       "v.xyz': unknown format '.xyz'"},
      {"DownsamplingOutOfRange", std::string(kSlice) + "--downsampling 0",
       "error: --downsampling 0: must be in 1..64"},
      {"VoxelSizeZero",
       "slice --meshes {DIR}/in_tet.stl --voxel-size 0 --probe {FAN} --poses {POSES} --out {OUT}",
       "error: --voxel-size must be > 0 mm"},
      {"EnvelopeWithDynamicRange",
       "simulate --volume {CT} --preset lus --poses {POSES} --out {OUT} --output envelope "
       "--dynamic-range 40",
       "error: --dynamic-range: applies to --output bmode"},
      {"EnvelopeWithTgc",
       "simulate --volume {CT} --preset lus --poses {POSES} --out {OUT} --output envelope --tgc "
       "auto",
       "error: --tgc auto: applies to --output bmode"},
      {"VoxelSizeWithoutMeshes", std::string(kSlice) + "--voxel-size 0.2",
       "error: --voxel-size: applies only to meshes that are voxelised"},
      {"VoxelSizeWithExactSurfaces",
       "slice --meshes {DIR}/in_tet.stl --surface-mode exact --voxel-size 0.2 --probe {FAN} "
       "--poses {POSES} --out {OUT}",
       "error: --voxel-size: applies only to meshes that are voxelised"},
      {"CompoundSkipZero", std::string(kCompound) + "--skip 0", "--skip 0: must be >= 1"},
      {"CompoundClipAndProbeOnSequence", std::string(kCompound) + "--poses {DIR}/p.npy",
       "a PLUS sequence carries its own transforms"},
      {"CompoundTwoInputs", std::string(kCompound) + "--frames {CT}", "exactly one of"},
      {"CompoundFramesPoseCount",
       "compound --frames {CT} --poses {POSES} --probe {FAN} --spacing 1 --out {OUT}",
       "has 12 poses"},
      {"CompoundBeamGeometryTypo",
       "compound --beam-frames {DIR}/in_beams.npy --beam-geometry {DIR}/in_geom.json "
       "--poses {DIR}/in_two.txt --spacing 1 --out {OUT}",
       "unknown key 'apex'"},
      {"CompoundNanPose",
       "compound --beam-frames {DIR}/in_beams.npy --beam-geometry {DIR}/in_geom_ok.json "
       "--poses {DIR}/in_nan.txt --spacing 1 --out {OUT}",
       "in_nan.txt"},
      // Outputs that cannot lie: two outputs never share a file, an output is never an
      // input, a PNG folder never holds anything but sonoslice's images.
      {"MaskOnTheOutput", std::string(kSlice) + "--mask {OUT}", "would write the same file"},
      {"OutputIsTheInput",
       "slice --volume {DIR}/in_vol.npy --spacing 1,1,1 --probe {FAN} --poses {POSES} "
       "--out {DIR}/in_vol.npy",
       "is the input --volume"},
      {"CompoundWeightsOnTheOutput", std::string(kCompound) + "--weights {OUT}",
       "would write the same file"},
      {"CompoundWeightsSidecarOnTheOutputs", std::string(kCompound) + "--weights {DIR}/out.NPY",
       "would write the same file"},
      {"CompoundOutputIsTheFrames",
       "compound --frames {DIR}/in_vol.npy --poses {POSES} --probe {FAN} --spacing 1 "
       "--out {DIR}/in_vol.npy",
       "is the input --frames"},
      {"PngFolderHoldingOtherFiles",
       "slice --volume {CT} --probe {FAN} --poses {POSES} --out {DIR}",
       "which sonoslice did not write"},
      {"MaskInsideThePngFolder",
       "slice --volume {CT} --probe {FAN} --poses {POSES} --out {DIR}/pngs --mask "
       "{DIR}/pngs/m.png",
       "is inside the folder --out"},
  };
  return cases;
}

INSTANTIATE_TEST_SUITE_P(Cases, CliBadInput, ::testing::ValuesIn(bad_cases()),
                         [](const auto& info) { return info.param.name; });

// --- outputs that cannot lie ---------------------------------------------------------

// Runs the CLI like run(), in a child process: with a file-size limit and SIGXFSZ ignored (a write
// past the limit then fails with EFBIG, as under `ulimit -f`), after `prepare` (which runs in the
// child, whose pid the CLI keeps: exec).
CliRun run_in_child(const std::string& args, const test::TempDir& dir,
                    rlim_t limit_bytes = RLIM_INFINITY,
                    const std::function<void()>& prepare = nullptr) {
  const std::string out_file = dir.file(".stdout"), err_file = dir.file(".stderr");
  const std::string cmd = "exec " + std::string(SONOSLICE_CLI) + " " + args + " >" +
                          quote(out_file) + " 2>" + quote(err_file);
  const pid_t pid = ::fork();
  if (pid == 0) {
    if (prepare) prepare();
    ::signal(SIGXFSZ, SIG_IGN);
    const rlimit limit{limit_bytes, limit_bytes};
    ::setrlimit(RLIMIT_FSIZE, &limit);
    ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  auto slurp = [](const std::string& p) {
    std::ifstream in(p);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  };
  CliRun r{WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(out_file), slurp(err_file)};
  fs::remove(out_file);
  fs::remove(err_file);
  return r;
}

// Every file under `dir` with its bytes (folders as "<folder>").
std::map<std::string, std::string> snapshot(const fs::path& dir) {
  std::map<std::string, std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    std::ifstream in(e.path(), std::ios::binary);
    std::stringstream s;
    s << in.rdbuf();
    out[fs::relative(e.path(), dir).string()] = e.is_regular_file() ? s.str() : "<folder>";
  }
  return out;
}

// A failed write: one line naming the output, exit 1, everything on disk as it was.
void expect_failed_write_changed_nothing(const CliRun& r, const std::string& path,
                                         const std::string& why,
                                         const std::map<std::string, std::string>& before,
                                         const fs::path& dir) {
  EXPECT_EQ(r.code, 1) << path << ": " << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_NE(r.err.find("'" + path), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(why), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find(".tmp-sonoslice"), std::string::npos) << r.err;
  const auto after = snapshot(dir);
  EXPECT_EQ(after.size(), before.size()) << path << ": files appeared or went";
  EXPECT_TRUE(after == before) << path << ": the previous output changed";
}

const char* kOutputs[] = {"o.nii", "o.nii.gz", "o.mha", "o.mhd", "o.nrrd", "o.npy", "pngs"};

// Once, .nii, .nii.gz and .mha exited 0 with the old output replaced by a truncated
// one; the PNG folder was written with ITK's unchecked 2-D writer.
TEST_F(Cli, FileSizeLimitKeepsEveryPreviousOutput) {
  test::TempDir out;
  write_poses_text(out.file("many.txt"), phantom_random_poses(300, 9));
  fs::create_directory(out.file("o"));
  for (const char* name : kOutputs) {
    const std::string path = out.file(std::string("o/") + name);
    ASSERT_EQ(run("slice --volume " + ct() + " --probe " + fan() + " --poses " + poses() +
                      " --out " + quote(path) + " -q",
                  out)
                  .code,
              0);
    const auto before = snapshot(out.file("o"));
    // 4 KiB: less than one 120x100 PNG of the phantom, far less than 300 float images.
    const CliRun r = run_in_child("slice --volume " + ct() + " --probe " + fan() + " --poses " +
                                      quote(out.file("many.txt")) + " --out " + quote(path) + " -q",
                                  out, 4096);
    expect_failed_write_changed_nothing(r, path, "file too large", before, out.file("o"));
  }
}

// A real full disk: a 2 MiB tmpfs, as a bad-input probe found (it crashed with SIGSEGV in ITK's PNG
// writer).
TEST_F(Cli, FullDiskKeepsEveryPreviousOutput) {
  test::TempDir out;
  const std::string small = out.file("small");
  fs::create_directory(small);
  if (::mount("tmpfs", small.c_str(), "tmpfs", 0, "size=2m") != 0)
    GTEST_SKIP() << "cannot mount a 2 MiB tmpfs here (" << std::strerror(errno)
                 << "; needs root): the full-disk case is left to FileSizeLimitKeepsEvery"
                    "PreviousOutput, which fails writes the same way";
  struct Unmount {
    std::string path;
    ~Unmount() { ::umount2(path.c_str(), MNT_DETACH); }
  } unmount{small};
  write_poses_text(out.file("many.txt"), phantom_random_poses(2000, 9));
  for (const char* name : kOutputs) {
    const std::string path = small + "/" + name;
    ASSERT_EQ(run("slice --volume " + ct() + " --probe " + fan() + " --poses " + poses() +
                      " --out " + quote(path) + " -q",
                  out)
                  .code,
              0);
    const auto before = snapshot(small);
    const CliRun r = run("slice --volume " + ct() + " --probe " + fan() + " --poses " +
                             quote(out.file("many.txt")) + " --out " + quote(path) + " -q",
                         out);
    // .npy checks the free space before it starts; the others find out while writing.
    expect_failed_write_changed_nothing(
        r, path, std::string(name) == "o.npy" ? "on disk but only" : "no space left on device",
        before, small);
    for (const auto& e : fs::directory_iterator(small)) fs::remove_all(e.path());
  }
}

TEST_F(Cli, PlantedLinkAtTheOldTemporaryNameIsNotFollowed) {
  test::TempDir out;
  std::ofstream(out.file("victim.txt")) << "precious";
  const std::string victim = out.file("victim.txt"), dir = out.path().string();
  // The names sonoslice used to open without O_EXCL: .tmp-sonoslice-<pid>-<n>.<name>.
  const CliRun r = run_in_child(
      "slice --volume " + ct() + " --probe " + fan() + " --poses " + poses() + " --out " +
          quote(out.file("o.npy")) + " -q",
      out, RLIM_INFINITY, [&] {
        for (int n = 0; n < 4; ++n)
          fs::create_symlink(victim, dir + "/.tmp-sonoslice-" + std::to_string(::getpid()) + "-" +
                                         std::to_string(n) + ".o.npy");
      });
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in(victim);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), "precious");
  EXPECT_EQ(read_npy(out.file("o.npy")).shape, (std::vector<int64_t>{12, 100, 120}));
}

TEST_F(Cli, PngFolderNeverDeletesSomeoneElsesFiles) {
  test::TempDir out;
  const std::string work = out.file("work");
  fs::create_directory(work);
  fs::copy_file(data_file("ph/ct.nii.gz"), work + "/ct.nii.gz");
  std::ofstream(work + "/notes.txt") << "mine";
  const std::string rest = " --probe " + fan() + " --poses " + poses() + " -q";
  // The folder holding the input, named three ways from inside it, and from outside.
  for (const std::string& out_flag : std::vector<std::string>{".", "../work", "./", quote(work)}) {
    const CliRun r = run_in_child("slice --volume ct.nii.gz --out " + out_flag + rest, out,
                                  RLIM_INFINITY, [&] { (void)!::chdir(work.c_str()); });
    EXPECT_EQ(r.code, 1) << out_flag;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
  // A folder holding one foreign file: refused, the file survives.
  fs::create_directory(out.file("pngs"));
  std::ofstream(out.file("pngs/keep.txt")) << "keep";
  CliRun r = run("slice --volume " + ct() + " --out " + quote(out.file("pngs")) + rest, out);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("'keep.txt', which sonoslice did not write"), std::string::npos) << r.err;
  EXPECT_EQ(snapshot(work).size(), 2u);
  EXPECT_EQ(snapshot(out.file("pngs")).size(), 1u);
  // A folder of sonoslice's own images is replaced as a whole.
  fs::remove(out.file("pngs/keep.txt"));
  ASSERT_EQ(run("slice --volume " + ct() + " --out " + quote(out.file("pngs")) + rest, out).code,
            0);
  write_poses_text(out.file("three.txt"), phantom_random_poses(3, 1));
  r = run("slice --volume " + ct() + " --probe " + fan() + " --poses " +
              quote(out.file("three.txt")) + " --out " + quote(out.file("pngs")) + " -q",
          out);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(snapshot(out.file("pngs")).size(), 4u);  // img_00000..2 and poses.txt
  EXPECT_EQ(entries(out), (std::vector<std::string>{"pngs", "three.txt", "work"}));
}

// The outputs of one run go into place together: --weights failing (a file-size limit that the
// uint8 volume fits under and its float32 weights do not) leaves the old --out too. Before, --out
// was replaced and the run then failed.
TEST_F(Cli, CompoundOutputsGoIntoPlaceTogether) {
  SONOSLICE_REQUIRE_DATA();
  test::TempDir out;
  const std::string plus = test::data_dir() + "/plus/";
  const std::string inputs =
      "compound --sequence " + quote(plus + "NwirePhantomFreehand.igs.mha") + " --config " +
      quote(plus + "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml") + " -q";
  fs::create_directory(out.file("o"));
  for (const char* ext : {".npy", ".nii"}) {
    const std::string v = out.file(std::string("o/v") + ext),
                      w = out.file(std::string("o/w") + ext);
    const std::string outputs = " --out " + quote(v) + " --weights " + quote(w);
    ASSERT_EQ(run(inputs + " --spacing 2" + outputs, out).code, 0);
    const auto before = snapshot(out.file("o"));
    // 101x105x74 voxels: 0.78 MB of uint8 fit under 1 MB, 3.1 MB of float32 weights do not.
    const CliRun r = run_in_child(inputs + outputs, out, 1 << 20);
    expect_failed_write_changed_nothing(r, w, "file too large", before, out.file("o"));
  }
}

// main.cpp installs install_output_cleanup_on_signals(): a signal mid-write removes the temporary.
TEST_F(Cli, SigtermDuringALongSliceLeavesNoTemporary) {
  test::TempDir out;
  write_poses_npy(out.file("long.npy"), phantom_random_poses(20000, 3));
  const ProbeGeometry big = test::curvilinear_probe(40, 120, 70, 400, 300, 0.3);
  std::ofstream(out.file("big.json")) << probe_to_json(big);
  std::ofstream(out.file("out.npy")) << "previous good data";
  const std::string cmd = "exec " + std::string(SONOSLICE_CLI) + " slice --volume " + ct() +
                          " --probe " + quote(out.file("big.json")) + " --poses " +
                          quote(out.file("long.npy")) + " --threads 1 -q --out " +
                          quote(out.file("out.npy")) + " 2>/dev/null";
  for (int sig : {SIGTERM, SIGINT}) {
    const pid_t pid = ::fork();
    if (pid == 0) {
      ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    // Signal once the temporary exists: the slicing has started (20000 images of 400x300 take
    // minutes on one thread).
    bool started = false;
    for (int i = 0; i < 3000 && !started; ++i) {
      for (const std::string& name : entries(out))
        started = started || name.rfind(".tmp-sonoslice", 0) == 0;
      if (!started) ::usleep(10 * 1000);
    }
    ::kill(pid, sig);
    int status = 0;
    ::waitpid(pid, &status, 0);
    EXPECT_TRUE(started);
    EXPECT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == sig) << strsignal(sig);
    EXPECT_EQ(entries(out), (std::vector<std::string>{"big.json", "long.npy", "out.npy"}))
        << strsignal(sig);
  }
  std::ifstream in(out.file("out.npy"));
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), "previous good data");
}

}  // namespace
}  // namespace sonoslice
