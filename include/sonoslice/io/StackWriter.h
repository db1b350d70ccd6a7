#pragma once
/// @file Writing a batch of N images (docs/conventions.md §6): one W×H×N image (NIfTI/MHA/NRRD,
/// spacing (sx, sy, 1)), a C-order (N, H, W) .npy, or a directory of 8-bit PNGs plus poses.txt. The
/// caller slices straight into the buffers the writer hands out, so in-memory formats cost no extra
/// copy and streamed formats (.npy, PNG) keep memory bounded by one chunk.
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "sonoslice/geometry/Pose.h"
#include "sonoslice/volume/PixelType.h"

namespace sonoslice {

class OutputSet;

struct StackSpec {
  PixelType type = PixelType::Float32;
  int width = 0, height = 0;
  int64_t count = 0;                  ///< N images
  double spacing_mm[2] = {1.0, 1.0};  ///< pixel spacing (sx, sy)
  /// PNG only: display window (level, width); default: robust auto-window (0.5th–99.5th
  /// percentile of the first chunk's pixels inside `mask`).
  std::optional<std::pair<double, double>> window;
  const uint8_t* mask = nullptr;  ///< H×W probe mask for the auto-window (may be null)
  std::vector<Pose> poses;        ///< PNG only: written to poses.txt
  int components = 1;             ///< 3: RGB colour images (uint8), written without a window
};

enum class StackFormat { Npy, ItkImage, PngDirectory };

/// The format `path` asks for: .npy, an ITK image extension, or (no extension / trailing '/')
/// a PNG directory. InputError for extensions sonoslice does not write.
StackFormat stack_format(const std::string& path);

class StackWriter {
 public:
  virtual ~StackWriter() = default;
  /// Creates the writer; checks the output path up front (FileError when unwritable).
  static std::unique_ptr<StackWriter> create(const std::string& path, const StackSpec& spec);

  /// True when memory stays bounded by one chunk (otherwise the whole stack is held).
  virtual bool streams() const = 0;
  /// A buffer for images [first, first + n) in C order (n, H, W); valid until the next call.
  virtual void* buffer(int64_t first, int64_t n) = 0;
  /// The images of the last buffer() are complete.
  virtual void write(int64_t first, int64_t n) = 0;
  /// All N images are written: check them and move the output into place.
  void commit();
  /// The same, but the output goes into place with the other outputs of the run, when
  /// `together.commit()` runs (a failure in any of them then leaves all of them as they were).
  virtual void finish(OutputSet& together) = 0;
};

/// Bytes the writer holds in memory at most for a stack `spec` written in chunks of `chunk`.
uint64_t stack_memory_bytes(const std::string& path, const StackSpec& spec, int64_t chunk);

/// Images per chunk so that one chunk of output stays under `bytes`: at least 1, at most `count`.
int64_t chunk_images(size_t image_bytes, int64_t count, size_t bytes = size_t(64) << 20);

/// Converts images to 8-bit with the window (level, width).
void apply_window(const void* images, PixelType type, size_t pixels, double level, double width,
                  uint8_t* out);

/// Robust window (level, width) from the values inside `mask` of `n` images.
std::pair<double, double> auto_window(const void* images, PixelType type, int64_t n,
                                      size_t image_pixels, const uint8_t* mask);

}  // namespace sonoslice
