#pragma once
/// @file What the machine can give: checked before large allocations so that a job that cannot
/// fit stops with a message instead of swapping or being killed.

namespace sonoslice {

/// Memory the OS reports as available (MemAvailable), in bytes.
unsigned long long available_memory_bytes();

}  // namespace sonoslice
