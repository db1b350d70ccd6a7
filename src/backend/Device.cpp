#include "sonoslice/backend/Device.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <sstream>
#include <thread>

#include "../core/Text.h"
#include "ThreadPool.h"
#include "sonoslice/core/Error.h"
#ifdef SONOSLICE_HAVE_CUDA
#include "CudaRuntime.h"
#endif

namespace sonoslice {

// More threads than any machine we target has cores; a larger number is a typo.
constexpr int kMaxCpuThreads = 4096;

Device Device::parse(const std::string& text) {
  const std::string t = text::lower(text);
  if (t == "cpu") return Device::cpu();
  if (t == "cuda" || t == "gpu") return Device{DeviceType::CUDA, 0};
  if (t.rfind("cuda:", 0) == 0 && t.size() > 5 &&
      std::all_of(t.begin() + 5, t.end(), [](unsigned char c) { return std::isdigit(c); }) &&
      t.size() < 9)
    return Device{DeviceType::CUDA, std::stoi(t.substr(5))};
  throw InputError("device '" + text + "': expected cpu, cuda or cuda:K");
}

std::string Device::to_string() const {
  return type == DeviceType::CPU ? "cpu" : "cuda:" + std::to_string(index);
}

bool built_with_cuda() {
#ifdef SONOSLICE_HAVE_CUDA
  return true;
#else
  return false;
#endif
}

namespace {
int hardware_threads() {
  static const int n = backend::available_cpus();  // the affinity mask at first use
  return n;
}
int g_threads = 0;  // 0 = default
}  // namespace

int cpu_threads() {
  return g_threads > 0 ? g_threads : hardware_threads();
}

void set_cpu_threads(int n) {
  if (n < 1)
    throw ParameterError("threads", std::to_string(n) +
                                        ": must be at least 1 (leave it unset for all hardware "
                                        "threads)");
  if (n > kMaxCpuThreads)
    throw ParameterError("threads", std::to_string(n) + ": more than " +
                                        std::to_string(kMaxCpuThreads) + " threads");
  g_threads = n;
}

void reset_cpu_threads() {
  g_threads = 0;
}

const char* to_string(CpuIsa isa) {
  switch (isa) {
    case CpuIsa::Generic:
      return "generic";
    case CpuIsa::Avx2:
      return "avx2";
  }
  return "?";
}

bool cpu_kernel_isa_available(CpuIsa isa) {
  switch (isa) {
    case CpuIsa::Generic:
      return true;
    case CpuIsa::Avx2:
#if defined(SONOSLICE_HAVE_AVX2_KERNELS) && (defined(__x86_64__) || defined(__i386__))
      return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
      return false;
#endif
  }
  return false;
}

namespace {
CpuIsa default_isa() {
  const char* env = std::getenv("SONOSLICE_CPU_ISA");
  if (env && std::string(env) == "generic") return CpuIsa::Generic;
  return cpu_kernel_isa_available(CpuIsa::Avx2) ? CpuIsa::Avx2 : CpuIsa::Generic;
}
CpuIsa g_isa = default_isa();
}  // namespace

CpuIsa cpu_kernel_isa() {
  return g_isa;
}

void set_cpu_kernel_isa(CpuIsa isa) {
  if (!cpu_kernel_isa_available(isa))
    throw InputError(std::string("CPU kernels '") + to_string(isa) +
                     "': not available on this CPU/build");
  g_isa = isa;
}

void set_cpu_kernel_isa(const std::string& name) {
  if (name == "auto") {
    g_isa = cpu_kernel_isa_available(CpuIsa::Avx2) ? CpuIsa::Avx2 : CpuIsa::Generic;
    return;
  }
  for (CpuIsa isa : {CpuIsa::Generic, CpuIsa::Avx2})
    if (name == to_string(isa)) return set_cpu_kernel_isa(isa);
  throw InputError("CPU kernels '" + name + "': expected auto, generic or avx2");
}

void require_device(const Device& device) {
  if (device.type == DeviceType::CPU) return;
#ifdef SONOSLICE_HAVE_CUDA
  cuda::use_device(device.index);  // "cuda:K: not available (why)" / "no such GPU"
#else
  throw Error("device " + device.to_string() + ": this sonoslice was built without CUDA");
#endif
}

std::string describe_devices() {
  std::ostringstream s;
  s << "cpu: " << cpu_threads() << " threads (" << hardware_threads() << " hardware threads), "
    << to_string(cpu_kernel_isa()) << " kernels\n";
#ifdef SONOSLICE_HAVE_CUDA
  s << cuda::describe_devices();
#else
  s << "cuda: not available (this sonoslice was built without CUDA)\n";
#endif
  return s.str();
}

}  // namespace sonoslice
