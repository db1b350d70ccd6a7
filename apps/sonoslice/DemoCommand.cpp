// sonoslice demo: the phantom, probes on the skin looking inward, fan and linear images, and a
// contact sheet a person can look at. Needs nothing but this program.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>

#include "Commands.h"
#include "Common.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/io/AtomicFile.h"
#include "sonoslice/io/PoseFile.h"
#include "sonoslice/io/ProbeFile.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/simulate/Simulator.h"

namespace fs = std::filesystem;

namespace sonoslice {
namespace cli {
namespace {

struct DemoFlags {
  std::string out_dir, size = "full";
  int poses = 8;
  std::optional<int> threads;  // unset: all hardware threads
  bool quiet = false;
};

// Abdominal soft-tissue window (level 40 HU, width 400 HU).
constexpr double kLevel = 40, kWidth = 400;

// A grey canvas that images are pasted into.
struct Canvas {
  int width, height;
  std::vector<uint8_t> pixels;
  Canvas(int w, int h, uint8_t background)
      : width(w), height(h), pixels(size_t(w) * h, background) {}
  void paste(const uint8_t* image, int w, int h, int x0, int y0) {
    for (int v = 0; v < h; ++v)
      std::memcpy(&pixels[size_t(y0 + v) * width + x0], image + size_t(v) * w, size_t(w));
  }
  void dot(int x, int y, int radius, uint8_t value) {
    for (int dy = -radius; dy <= radius; ++dy)
      for (int dx = -radius; dx <= radius; ++dx)
        if (x + dx >= 0 && x + dx < width && y + dy >= 0 && y + dy < height &&
            dx * dx + dy * dy <= radius * radius)
          pixels[size_t(y + dy) * width + x + dx] = value;
  }
};

std::vector<uint8_t> windowed(const std::vector<float>& images, size_t offset, size_t pixels) {
  std::vector<uint8_t> out(pixels);
  apply_window(images.data() + offset, PixelType::Float32, pixels, kLevel, kWidth, out.data());
  return out;
}

// Writes one image per pose, of `type`, as a PNG directory shown with `window` (level, width).
void write_png_stack(const std::string& dir, const ProbeGeometry& probe,
                     const std::vector<Pose>& poses, PixelType type,
                     std::pair<double, double> window, const void* images) {
  StackSpec spec = probe_stack_spec(probe, type, poses);
  spec.window = window;
  auto writer = StackWriter::create(dir, spec);
  std::memcpy(writer->buffer(0, spec.count), images,
              size_t(spec.count) * size_t(probe.image.pixel_count()) * pixel_size(type));
  writer->write(0, spec.count);
  writer->commit();
}

// Slices all poses with one probe and writes them as a PNG directory; returns the images.
std::vector<float> slice_and_write(const Volume& ct, const ProbeGeometry& probe,
                                   const std::vector<Pose>& poses, const std::string& dir) {
  SliceSettings settings;
  settings.fill_value = -1024;  // black outside the fan with the soft-tissue window
  const Slicer slicer(ct, probe, settings);
  std::vector<float> images(poses.size() * size_t(probe.image.pixel_count()));
  slicer.slice(poses.data(), poses.size(), images.data());
  write_png_stack(dir, probe, poses, PixelType::Float32, {kLevel, kWidth}, images.data());
  return images;
}

// Simulated ultrasound of the CT at the fan poses (the "lus" preset's 6.5 MHz), written as a PNG
// directory; returns the B-mode images.
std::vector<uint8_t> simulate_and_write(const Volume& ct, const ProbeGeometry& probe,
                                        const std::vector<Pose>& poses, const std::string& dir) {
  SimulationSettings settings;
  settings.preset = "lus";  // its frequency; the probe is the same W1 fan
  const Simulator sim(ct, SimulationSource::HounsfieldUnits, probe, {}, settings);
  std::vector<uint8_t> images(poses.size() * sim.image_bytes());
  sim.simulate(poses.data(), poses.size(), images.data());
  write_png_stack(dir, probe, poses, PixelType::UInt8, {127.5, 255.0},  // grey levels as they are
                  images.data());
  return images;
}

void run_demo(const DemoFlags& f) {
  setup_threads(f.threads);
  if (f.poses < 1 || f.poses > 64)
    throw InputError("--poses " + std::to_string(f.poses) + ": use 1..64");
  std::error_code ec;
  fs::create_directories(f.out_dir, ec);
  if (ec) throw FileError("cannot create directory '" + f.out_dir + "': " + ec.message());
  const fs::path out(f.out_dir);
  Stopwatch clock;

  const Phantom phantom = make_phantom(parse_phantom_size(f.size));
  const ProbeGeometry fan = workload_w1_fan_probe(), linear = workload_w2_linear_probe();
  const std::vector<Pose> fan_poses = phantom_surface_poses(size_t(f.poses), fan.face_y_mm);
  const std::vector<Pose> linear_poses = phantom_surface_poses(size_t(f.poses), linear.face_y_mm);
  const auto fan_images = slice_and_write(phantom.ct, fan, fan_poses, (out / "fan").string());
  const auto linear_images =
      slice_and_write(phantom.ct, linear, linear_poses, (out / "linear").string());
  const auto simulated =
      simulate_and_write(phantom.ct, fan, fan_poses, (out / "simulated").string());
  write_text_file((out / "fan_probe.json").string(), probe_to_json(fan) + "\n");
  write_text_file((out / "linear_probe.json").string(), probe_to_json(linear) + "\n");
  write_poses_text((out / "fan_poses.txt").string(), fan_poses);
  write_poses_text((out / "linear_poses.txt").string(), linear_poses);

  // Overview: the axial CT slice at the probes' mean height, with each probe's contact point
  // (large dot) and beam direction (small dots, 10 mm apart).
  const VolumeGrid& g = phantom.ct.grid();
  double mean_z = 0;
  for (const Pose& p : fan_poses) mean_z += p.m[2][3] / double(fan_poses.size());
  const int k = std::clamp(int(std::lround((mean_z - g.origin_mm[2]) / g.spacing_mm[2])), 0,
                           int(g.dims[2] - 1));
  const int nx = int(g.dims[0]), ny = int(g.dims[1]);
  std::vector<uint8_t> axial(size_t(nx) * ny);
  apply_window(phantom.ct.data_as<int16_t>() + size_t(k) * nx * ny, PixelType::Int16, axial.size(),
               kLevel, kWidth, axial.data());
  // Display at a fixed 512 px whatever the phantom size (nearest neighbour).
  const int overview = 512;
  Canvas axial_view(overview, overview, 0);
  for (int v = 0; v < overview; ++v)
    for (int u = 0; u < overview; ++u)
      axial_view.pixels[size_t(v) * overview + u] =
          axial[size_t(v * ny / overview) * nx + u * nx / overview];
  auto to_view = [&](const Vec3& p, int* u, int* v) {
    *u = int((p[0] - g.origin_mm[0]) / g.spacing_mm[0] * overview / nx);
    *v = int((p[1] - g.origin_mm[1]) / g.spacing_mm[1] * overview / ny);
  };
  for (const Pose& p : fan_poses) {
    int u, v;
    for (int d = 10; d <= 110; d += 10) {
      to_view(p.transform_point({0, double(d), 0}), &u, &v);
      axial_view.dot(u, v, 1, 255);
    }
    to_view(p.transform_point({0, fan.face_y_mm, 0}), &u, &v);
    axial_view.dot(u, v, 5, 255);
  }
  write_image((out / "overview.png").string(), axial_view.pixels.data(), PixelType::UInt8,
              {overview, overview}, {1.0, 1.0});
  // The same axial slice of the label map, one grey level per tissue.
  Canvas label_view(overview, overview, 0);
  const uint8_t* labels = phantom.labels.data_as<uint8_t>() + size_t(k) * nx * ny;
  for (int v = 0; v < overview; ++v)
    for (int u = 0; u < overview; ++u)
      label_view.pixels[size_t(v) * overview + u] =
          uint8_t(labels[size_t(v * ny / overview) * nx + u * nx / overview] * 255 /
                  (kPhantomLabelCount - 1));

  // Contact sheet: on the left the axial CT with the probes and the label map; on the right the
  // fan images, the simulated ultrasound at the same poses, and the linear images from the same
  // skin positions.
  const int gap = 8, columns = 4;
  const int rows = (f.poses + columns - 1) / columns;
  const int cell_w = std::max(fan.image.width, linear.image.width);
  const int width = gap + overview + gap + columns * (cell_w + gap);
  const int height =
      std::max(gap + 2 * (overview + gap),
               gap + 2 * rows * (fan.image.height + gap) + rows * (linear.image.height + gap));
  Canvas sheet(width, height, 48);
  sheet.paste(axial_view.pixels.data(), overview, overview, gap, gap);
  sheet.paste(label_view.pixels.data(), overview, overview, gap, gap + overview + gap);
  const int x_images = gap + overview + gap;
  auto paste_one = [&](const uint8_t* img, const ProbeGeometry& probe, int n, int y_top) {
    const int x = x_images + (n % columns) * (cell_w + gap) + (cell_w - probe.image.width) / 2;
    const int y = y_top + (n / columns) * (probe.image.height + gap);
    sheet.paste(img, probe.image.width, probe.image.height, x, y);
  };
  auto paste_all = [&](const std::vector<float>& images, const ProbeGeometry& probe, int y_top) {
    const size_t pixels = size_t(probe.image.pixel_count());
    for (int n = 0; n < f.poses; ++n)
      paste_one(windowed(images, size_t(n) * pixels, pixels).data(), probe, n, y_top);
  };
  const int fan_rows_h = rows * (fan.image.height + gap);
  paste_all(fan_images, fan, gap);
  for (int n = 0; n < f.poses; ++n)
    paste_one(simulated.data() + size_t(n) * size_t(fan.image.pixel_count()), fan, n,
              gap + fan_rows_h);
  paste_all(linear_images, linear, gap + 2 * fan_rows_h);
  const std::string sheet_path = (out / "contact_sheet.png").string();
  write_image(sheet_path, sheet.pixels.data(), PixelType::UInt8, {width, height}, {1.0, 1.0});

  if (!f.quiet)
    std::fprintf(
        stderr,
        "sonoslice: demo in %.1f s: %s (left: axial CT with the %d probe positions, and its "
        "labels; right: fan images, simulated ultrasound at the same poses, then linear images "
        "at the same positions); PNG stacks in %s, %s and %s\n",
        clock.seconds(), sheet_path.c_str(), f.poses, (out / "fan").c_str(),
        (out / "simulated").c_str(), (out / "linear").c_str());
}

}  // namespace

void add_demo_command(CLI::App& app) {
  auto flags = std::make_shared<DemoFlags>();
  CLI::App* cmd = app.add_subcommand(
      "demo", "Phantom -> fan and linear images from probes on the skin -> contact sheet PNG");
  cmd->add_option("out_dir", flags->out_dir, "Output directory (created if missing)")->required();
  cmd->add_option("--size", flags->size, "Phantom size: full (default) or small");
  cmd->add_option("--poses", flags->poses, "Probe positions (default 8)");
  add_threads_option(*cmd, flags->threads);
  cmd->add_flag("--quiet,-q", flags->quiet, "No summary");
  cmd->callback([flags] { run_demo(*flags); });
}

}  // namespace cli
}  // namespace sonoslice
