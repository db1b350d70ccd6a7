#pragma once
/// @file Where computations run: a runtime value, so call sites never need #ifdef.
#include <string>

namespace sonoslice {

enum class DeviceType { CPU, CUDA };

/// A compute device: "cpu", "cuda" (= cuda:0) or "cuda:K".
struct Device {
  DeviceType type = DeviceType::CPU;
  int index = 0;

  static Device cpu() { return Device{}; }
  static Device parse(const std::string& text);  ///< InputError for unknown names
  std::string to_string() const;
  bool operator==(const Device& o) const { return type == o.type && index == o.index; }
};

/// True when this build includes the CUDA backend (whether or not a GPU is present).
bool built_with_cuda();

/// Number of CPU threads the CPU backend uses (default: all hardware threads).
int cpu_threads();
/// Sets the CPU thread count, 1 to 4096. ParameterError("threads", ...) otherwise: 0 or a
/// negative count is a mistake (a script's arithmetic gone wrong), not a request for the
/// default; reset_cpu_threads() restores that.
void set_cpu_threads(int n);
/// Restores the default: all hardware threads.
void reset_cpu_threads();

/// The instruction set the CPU kernels use: "avx2" (eight-lane fast paths, when the build has
/// them and the CPU supports AVX2 and FMA) or "generic". The environment variable
/// SONOSLICE_CPU_ISA=generic forces the generic kernels.
std::string cpu_kernel_isa();
/// "auto", "generic" or "avx2"; InputError when "avx2" is not available here.
void set_cpu_kernel_isa(const std::string& isa);

/// Throws Error("... built without CUDA" / "cuda:K: not available") when `device` cannot run
/// here; returns normally for the CPU.
void require_device(const Device& device);

/// One line per device for `sonoslice info --devices`.
std::string describe_devices();

}  // namespace sonoslice
