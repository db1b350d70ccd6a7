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

/// The instruction sets the CPU kernels are compiled for: every kernel source is built once per
/// set (XCPU.cpp, XCPUAvx2.cpp) and the dispatch layer runs the one cpu_kernel_isa() names.
enum class CpuIsa {
  Generic,  ///< the build's baseline (x86-64, or any other CPU)
  Avx2      ///< AVX2 + FMA: eight-lane fast paths
};
const char* to_string(CpuIsa isa);  ///< "generic" / "avx2"

/// The instruction set the CPU kernels use: Avx2 when the build has those kernels and the CPU
/// supports AVX2 and FMA, else Generic. The environment variable SONOSLICE_CPU_ISA=generic
/// forces the generic kernels.
CpuIsa cpu_kernel_isa();
/// Whether the kernels for `isa` can run here (built for it, and the CPU has it).
bool cpu_kernel_isa_available(CpuIsa isa);
/// Sets the instruction set; InputError when it is not available here.
void set_cpu_kernel_isa(CpuIsa isa);
/// The same by name: "auto" (the default choice above), "generic" or "avx2".
void set_cpu_kernel_isa(const std::string& name);

/// Throws Error("... built without CUDA" / "cuda:K: not available") when `device` cannot run
/// here; returns normally for the CPU.
void require_device(const Device& device);

/// One line per device for `sonoslice info --devices`.
std::string describe_devices();

}  // namespace sonoslice
