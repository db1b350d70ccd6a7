#pragma once
/// @file The one clock of the live and view paths: latencies, rates and time limits are
/// differences of it (steady, so a wall-clock change never makes a negative latency).
#include <chrono>

namespace sonoslice {

/// Steady-clock seconds (an arbitrary origin: only differences mean anything).
inline double now_seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace sonoslice
