#pragma once
// The reconstruction flags `sonoslice compound` and `sonoslice live compound` share: the grid,
// the splats, compounding and hole filling, the clip, the output type, the device and memory.
#include <optional>
#include <string>

#include <CLI/CLI.hpp>

#include "sonoslice/compound/Reconstruction.h"

namespace sonoslice {
namespace cli {

struct ReconstructionFlags {
  std::string spacing, origin, extent, interp, compounding, fill_holes, clip_rect;
  std::string device = "cpu", max_memory, dtype;
  std::optional<double> rejection_threshold;
  std::optional<int> threads;  // unset: all hardware threads

  void add_to(CLI::App& cmd);
  /// Sets the options the flags give (the device is set up by the caller).
  void apply(ReconstructionOptions& options) const;
};

}  // namespace cli
}  // namespace sonoslice
