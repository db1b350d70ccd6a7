#pragma once
// Pieces shared by the sonoslice subcommands: volume input flags, the progress bar, timing,
// the built-in probes and the chunked slice-and-write loop.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "sonoslice/backend/Device.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/io/StackWriter.h"
#include "sonoslice/io/VolumeFile.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace cli {

/// A command called without what it needs (a required flag, one of several inputs): exit status
/// 2 with a pointer to the command's --help, as CLI11's own usage errors.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// Flags every command that reads a volume accepts.
struct VolumeFlags {
  std::string path;
  std::string series;
  std::string spacing, origin, direction;  // comma-separated numbers (.npy only)
  std::string npy_config;

  void add_to(CLI::App& app, bool path_required, const std::string& path_flag = "--volume");
  VolumeReadOptions options() const;
};

/// The flag that sets a library parameter (ParameterError::parameter()): "spacing_mm" →
/// "--spacing", "series_uid" → "--series", "clip_rectangle" → "--clip-rect", ...; otherwise
/// "--" + the name with '-' for '_'. Commands whose flag differs catch and rename themselves.
std::string flag_of(const std::string& parameter);

/// A setting whose flag has its name: "--" + the name with '-' for '_' ("search_rot_deg" →
/// "--search-rot-deg"). A ParameterNames for commands whose flags all follow the rule.
std::string flag_named(const std::string& parameter);

/// "(10)", "(0.3)": a library default for a flag's help text, so that it is written once.
std::string default_text(double value);

/// "a,b,,c" → {"a", "b", "", "c"}: every item between commas, empty ones included (a list
/// flag refuses them by name); an empty text has none.
std::vector<std::string> split_commas(const std::string& text);

/// Parses "a,b,c" into exactly `count` finite numbers; InputError naming `flag` otherwise.
std::vector<double> parse_numbers(const std::string& text, size_t count, const std::string& flag);

/// Adds --threads N to a command: unset means all hardware threads; an explicit N must be at
/// least 1 (set_cpu_threads refuses 0 and negative counts: "--threads 0: must be at least 1").
void add_threads_option(CLI::App& cmd, std::optional<int>& threads);

/// Adds --seed S to a command: a whole number from 0 to 2^64 − 1, written in decimal; anything
/// else (-1, 2^64, 1.5) is refused with an InputError naming the flag rather than wrapped or
/// clamped.
void add_seed_option(CLI::App& cmd, std::function<void(uint64_t)> set,
                     const std::string& description);

/// The --voxel-size of `slice` and `simulate` (meshes are voxelised at it; default 0.5 mm), where
/// `voxelised` says whether this run voxelises meshes (`which`: the flags that make it): given
/// otherwise, it would change nothing, so it is refused (InputError), as is a size not > 0.
double mesh_voxel_size(const std::optional<double>& given, bool voxelised,
                       const std::string& which = "--meshes");

/// Sets the CPU thread count from --threads (unset: all hardware threads).
void setup_threads(const std::optional<int>& threads);

/// setup_threads(threads), then parses --device and checks that it can be used (InputError /
/// Error otherwise).
Device setup_device(const std::string& device, const std::optional<int>& threads);

/// While alive, SIGINT and SIGTERM set stop_requested() instead of ending the process (a live run
/// or a viewer then ends cleanly, its outputs written); afterwards the usual handlers (which
/// remove half-written outputs) are back.
struct StopOnSignals {
  StopOnSignals();
  ~StopOnSignals();
  StopOnSignals(const StopOnSignals&) = delete;
  StopOnSignals& operator=(const StopOnSignals&) = delete;
  /// Set by a signal since the last StopOnSignals was made.
  static const std::atomic<bool>& stop_requested();
};

/// Wall-clock seconds since construction.
class Stopwatch {
 public:
  Stopwatch() : start_(std::chrono::steady_clock::now()) {}
  double seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

/// A one-line progress bar on stderr, drawn only when stderr is a terminal and not --quiet.
class ProgressBar {
 public:
  ProgressBar(std::string label, int64_t total, bool enabled);
  ~ProgressBar();
  void update(int64_t done);
  void finish();

 private:
  std::string label_;
  int64_t total_;
  bool enabled_, finished_ = false;
  Stopwatch clock_;
  double last_draw_ = -1;
  int64_t last_done_ = -1;
};

/// The stack of one `type` image per pose of `probe` (size, pixel spacing, poses); the caller
/// adds the window, the mask and the components where it has them.
StackSpec probe_stack_spec(const ProbeGeometry& probe, PixelType type,
                           const std::vector<Pose>& poses);

/// "1.5 GiB": a byte count for messages.
std::string gib(uint64_t bytes);

/// Before writing a stack of `spec` to `out` in chunks of `chunk` images: ResourceError when the
/// writer's buffers (plus `extra_held` bytes) do not fit in the available memory, or a .npy does
/// not fit on its disk. Returns the bytes the writers hold in memory.
uint64_t check_stack_resources(const std::string& out, const StackSpec& spec, int64_t chunk,
                               uint64_t extra_held = 0);

/// Writes the H×W probe mask: .png scaled to 0/255, other formats as 0/1 uint8 (`together`: as
/// for write_image).
void write_mask(const std::string& path, const ProbeGeometry& probe,
                const std::vector<uint8_t>& mask, OutputSet* together = nullptr);

}  // namespace cli
}  // namespace sonoslice
