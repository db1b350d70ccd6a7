#include "Common.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <map>
#include <sstream>

#include "sonoslice/core/Error.h"
#include "sonoslice/core/Memory.h"
#include "sonoslice/io/AtomicFile.h"

namespace sonoslice {
namespace cli {

void VolumeFlags::add_to(CLI::App& app, bool path_required, const std::string& path_flag) {
  auto* opt = app.add_option(
      path_flag, path, "Volume: .nii/.nii.gz, .mha/.mhd, .nrrd/.nhdr, .npy, or a DICOM directory");
  if (path_required) opt->required();
  app.add_option("--series", series,
                 "DICOM directory: SeriesInstanceUID to read (default: largest)");
  app.add_option("--spacing", spacing, ".npy volume: voxel spacing sx,sy,sz in mm");
  app.add_option("--origin", origin, ".npy volume: world position of voxel (0,0,0) in mm");
  app.add_option("--direction", direction,
                 ".npy volume: 9 numbers, row-major 3x3 (index axes as columns)");
  app.add_option("--npy-config", npy_config,
                 "fan-slicer npy_config JSON for a fan-slicer .npy volume (axes [Y,X,Z])");
}

VolumeReadOptions VolumeFlags::options() const {
  VolumeReadOptions o;
  o.series_uid = series;
  if (!spacing.empty()) {
    const auto v = parse_numbers(spacing, 3, "--spacing");
    o.spacing_mm = Vec3{v[0], v[1], v[2]};
  }
  if (!origin.empty()) {
    const auto v = parse_numbers(origin, 3, "--origin");
    o.origin_mm = Vec3{v[0], v[1], v[2]};
  }
  if (!direction.empty()) {
    const auto v = parse_numbers(direction, 9, "--direction");
    Mat3 d;
    for (int i = 0; i < 9; ++i) d.m[i / 3][i % 3] = v[size_t(i)];
    o.direction = d;
  }
  o.fanslicer_npy_config = npy_config;
  return o;
}

StackSpec probe_stack_spec(const ProbeGeometry& probe, PixelType type,
                           const std::vector<Pose>& poses) {
  StackSpec spec;
  spec.type = type;
  spec.width = probe.image.width;
  spec.height = probe.image.height;
  spec.count = int64_t(poses.size());
  spec.spacing_mm[0] = probe.image.spacing_mm[0];
  spec.spacing_mm[1] = probe.image.spacing_mm[1];
  spec.poses = poses;
  return spec;
}

std::string gib(uint64_t bytes) {
  std::ostringstream s;
  s.precision(3);
  s << double(bytes) / double(1ull << 30) << " GiB";
  return s.str();
}

uint64_t check_stack_resources(const std::string& out, const StackSpec& spec, int64_t chunk,
                               uint64_t extra_held) {
  const uint64_t held = stack_memory_bytes(out, spec, chunk) + extra_held;
  const uint64_t available = available_memory_bytes();
  if (held > available)
    throw ResourceError("output '" + out + "' needs " + gib(held) + " in memory (" +
                        std::to_string(spec.count) + " images of " + std::to_string(spec.width) +
                        "x" + std::to_string(spec.height) + " " + to_string(spec.type) +
                        ") but only " + gib(available) +
                        " is available; write .npy or a PNG directory (streamed) instead");
  if (stack_format(out) == StackFormat::Npy) {
    const uint64_t total = uint64_t(spec.count) * uint64_t(spec.width) * uint64_t(spec.height) *
                           pixel_size(spec.type) * uint64_t(spec.components);
    const uint64_t free_bytes = free_disk_bytes(out);
    if (total > free_bytes)
      throw ResourceError("output '" + out + "' needs " + gib(total) + " on disk but only " +
                          gib(free_bytes) + " is free");
  }
  return held;
}

std::string flag_of(const std::string& parameter) {
  static const std::map<std::string, std::string> renamed = {
      {"spacing_mm", "--spacing"},
      {"margin_mm", "--margin"},
      {"probe_downsampling", "--downsampling"},
      {"origin_mm", "--origin"},
      {"series_uid", "--series"},
      {"interpolation", "--interp"},
      {"mode", "--compounding"},
      {"clip_rectangle", "--clip-rect"},
      {"transform", "--image-to-reference"},
      {"output_type", "--dtype"},
      {"max_memory_bytes", "--max-memory"},
      {"hole_filling", "the XML's hole-filling elements"}};
  const auto it = renamed.find(parameter);
  return it != renamed.end() ? it->second : flag_named(parameter);
}

std::string flag_named(const std::string& parameter) {
  std::string flag = "--" + parameter;
  for (char& c : flag)
    if (c == '_') c = '-';
  return flag;
}

std::string default_text(double value) {
  std::ostringstream out;
  out << "(" << value << ")";
  return out.str();
}

std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> items;
  // Every item between commas, the empty ones too ("1,,3", "1,2,"), which getline would drop
  // at the end; an empty text has none.
  for (size_t at = 0; !text.empty() && at <= text.size();) {
    const size_t comma = std::min(text.find(',', at), text.size());
    items.push_back(text.substr(at, comma - at));
    at = comma + 1;
  }
  return items;
}

std::vector<double> parse_numbers(const std::string& text, size_t count, const std::string& flag) {
  std::vector<double> out;
  for (const std::string& item : split_commas(text)) {
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);
    while (end && *end == ' ') ++end;
    if (item.empty() || *end != '\0' || !std::isfinite(v))
      throw InputError(flag + " '" + text + "': '" + item + "' is not a finite number");
    out.push_back(v);
  }
  if (out.size() != count)
    throw InputError(flag + " '" + text + "': expected " + std::to_string(count) +
                     " comma-separated numbers");
  return out;
}

void add_threads_option(CLI::App& cmd, std::optional<int>& threads) {
  cmd.add_option_function<int>(
      "--threads", [&threads](const int& n) { threads = n; },
      "CPU threads, at least 1 (default: all hardware threads)");
}

void add_seed_option(CLI::App& cmd, std::function<void(uint64_t)> set,
                     const std::string& description) {
  cmd.add_option_function<std::string>(
      "--seed",
      [set](const std::string& text) {
        const char* p = text.c_str();
        uint64_t value = 0;
        bool ok = *p != '\0';
        for (; *p && ok; ++p) {
          const unsigned digit = unsigned(*p - '0');
          ok = digit <= 9 && value <= (UINT64_MAX - digit) / 10;
          value = value * 10 + digit;
        }
        if (!ok)
          throw InputError("--seed " + text +
                           ": expected a whole number from 0 to 18446744073709551615");
        set(value);
      },
      description);
}

double mesh_voxel_size(const std::optional<double>& given, bool voxelised,
                       const std::string& which) {
  if (given && !voxelised)
    throw InputError("--voxel-size: applies only to meshes that are voxelised (" + which + ")");
  const double size = given.value_or(0.5);
  if (!(size > 0)) throw InputError("--voxel-size must be > 0 mm");
  return size;
}

void setup_threads(const std::optional<int>& threads) {
  if (threads)
    set_cpu_threads(*threads);
  else
    reset_cpu_threads();
}

Device setup_device(const std::string& device, const std::optional<int>& threads) {
  setup_threads(threads);
  const Device d = Device::parse(device);
  require_device(d);
  return d;
}

ProgressBar::ProgressBar(std::string label, int64_t total, bool enabled)
    : label_(std::move(label)), total_(total), enabled_(enabled && ::isatty(STDERR_FILENO)) {}

ProgressBar::~ProgressBar() {
  if (enabled_ && !finished_ && last_draw_ >= 0) std::fputc('\n', stderr);
}

void ProgressBar::update(int64_t done) {
  if (!enabled_) return;
  const double t = clock_.seconds();
  if (done < total_ && t - last_draw_ < 0.1) return;  // at most 10 redraws per second
  last_draw_ = t;
  last_done_ = done;
  const int width = 30;
  const double f = total_ > 0 ? double(done) / double(total_) : 1.0;
  const int filled = int(f * width);
  std::string bar(size_t(filled), '=');
  if (filled < width) bar += '>' + std::string(size_t(width - filled - 1), ' ');
  std::fprintf(stderr, "\r%s [%s] %3d%% %lld/%lld  %.0f/s ", label_.c_str(), bar.c_str(),
               int(f * 100), static_cast<long long>(done), static_cast<long long>(total_),
               t > 0 ? double(done) / t : 0.0);
  std::fflush(stderr);
}

void ProgressBar::finish() {
  if (!enabled_ || finished_) return;
  if (last_done_ != total_) update(total_);
  std::fputc('\n', stderr);
  finished_ = true;
}

void write_mask(const std::string& path, const ProbeGeometry& probe,
                const std::vector<uint8_t>& mask, OutputSet* together) {
  std::vector<uint8_t> out(mask);
  if (image_format(path, "--mask") == ImageFormat::Png)
    for (auto& v : out) v = v ? 255 : 0;
  write_image(path, out.data(), PixelType::UInt8, {probe.image.width, probe.image.height},
              {probe.image.spacing_mm[0], probe.image.spacing_mm[1]}, 1, together);
}

namespace {
std::atomic<bool> g_stop{false};
extern "C" void request_stop(int) {
  g_stop.store(true);
}
}  // namespace

StopOnSignals::StopOnSignals() {
  g_stop.store(false);
  struct sigaction a {};
  a.sa_handler = request_stop;
  sigemptyset(&a.sa_mask);
  ::sigaction(SIGINT, &a, nullptr);
  ::sigaction(SIGTERM, &a, nullptr);
}

StopOnSignals::~StopOnSignals() {
  install_output_cleanup_on_signals();
}

const std::atomic<bool>& StopOnSignals::stop_requested() {
  return g_stop;
}

}  // namespace cli
}  // namespace sonoslice
