#pragma once
/// @file What the machine can give: checked before large allocations so that a job that cannot
/// fit stops with a message instead of swapping or being killed.

namespace sonoslice {

constexpr unsigned long long kKiB = 1ull << 10;
constexpr unsigned long long kMiB = 1ull << 20;
constexpr unsigned long long kGiB = 1ull << 30;

/// Memory the OS reports as available (MemAvailable), in bytes.
unsigned long long available_memory_bytes();

}  // namespace sonoslice
