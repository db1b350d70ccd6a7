#include "CudaRuntime.h"

#include <cuda_runtime.h>

#include <algorithm>
#include <cstring>
#include <mutex>
#include <sstream>

#include "CudaChecks.h"
#include "ParallelFor.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace cuda {
namespace {

struct Availability {
  int count = 0;
  std::string reason;
};

// Asked once: the first CUDA call initialises the runtime (and loads the driver, if any).
const Availability& availability() {
  static Availability a;
  static std::once_flag once;
  std::call_once(once, [] {
    int n = 0;
    const cudaError_t err = cudaGetDeviceCount(&n);
    if (err == cudaSuccess && n > 0) {
      a.count = n;
      return;
    }
    cudaGetLastError();  // clear the sticky error
    int runtime = 0, driver = 0;
    cudaRuntimeGetVersion(&runtime);
    cudaDriverGetVersion(&driver);
    std::ostringstream s;
    if (driver == 0) {
      s << "no NVIDIA driver found (is there a GPU?)";
    } else if (err == cudaErrorInsufficientDriver) {
      s << "the NVIDIA driver is too old for this build (CUDA runtime " << runtime / 1000 << "."
        << (runtime % 1000) / 10 << ", driver supports "
        << (driver ? std::to_string(driver / 1000) + "." + std::to_string((driver % 1000) / 10)
                   : std::string("none"))
        << ")";
    } else if (err == cudaErrorNoDevice || (err == cudaSuccess && n == 0)) {
      s << "no CUDA-capable GPU found";
    } else {
      s << cudaGetErrorString(err);
    }
    a.reason = s.str();
  });
  return a;
}

}  // namespace

int device_count() {
  return availability().count;
}

std::string unavailable_reason() {
  return availability().reason;
}

std::string describe_devices() {
  if (device_count() == 0) return "cuda: not available (" + unavailable_reason() + ")\n";
  std::ostringstream s;
  for (int i = 0; i < device_count(); ++i) {
    cudaDeviceProp p;
    if (cudaGetDeviceProperties(&p, i) != cudaSuccess) continue;
    s << "cuda:" << i << ": " << p.name << ", " << (p.totalGlobalMem >> 20) << " MiB, compute "
      << p.major << "." << p.minor << ", " << p.multiProcessorCount << " multiprocessors\n";
  }
  return s.str();
}

void check(int error, const std::string& what) {
  const auto err = static_cast<cudaError_t>(error);
  if (err == cudaSuccess) return;
  cudaGetLastError();
  if (err == cudaErrorMemoryAllocation) throw ResourceError(what + ": out of GPU memory");
  throw Error(what + ": " + cudaGetErrorString(err));
}

void use_device(int index) {
  if (device_count() == 0)
    throw Error("cuda:" + std::to_string(index) + ": not available (" + unavailable_reason() + ")");
  if (index < 0 || index >= device_count())
    throw Error("cuda:" + std::to_string(index) + ": no such GPU (this machine has " +
                std::to_string(device_count()) + ")");
  check(cudaSetDevice(index), "cuda:" + std::to_string(index) + ": selecting the device");
}

Owner::Owner(int index)
    : device(index), name("cuda:" + std::to_string(index)), process(current_process()) {
  use_device(index);
}

void Owner::enter(const std::string& what) const {
  check_not_forked(process, name + " " + what);
  use_device(device);
}

void memory_info(size_t* free_bytes, size_t* total_bytes) {
  check(cudaMemGetInfo(free_bytes, total_bytes), "cuda: querying device memory");
}

DeviceBuffer::~DeviceBuffer() {
  if (data_) cudaFree(data_);
}

void DeviceBuffer::reserve(size_t bytes, const std::string& what) {
  if (bytes <= capacity_) return;
  if (data_) cudaFree(data_);
  data_ = nullptr;
  capacity_ = 0;
  size_t free_bytes = 0, total = 0;
  memory_info(&free_bytes, &total);
  if (bytes > free_bytes) {
    std::ostringstream s;
    s << what << ": needs " << (bytes >> 20) << " MiB of GPU memory, " << (free_bytes >> 20)
      << " MiB free";
    throw ResourceError(s.str());
  }
  check(cudaMalloc(&data_, bytes), what);
  capacity_ = bytes;
}

PinnedBuffer::~PinnedBuffer() {
  if (data_) cudaFreeHost(data_);
}

void PinnedBuffer::reserve(size_t bytes, const std::string& what) {
  if (bytes <= capacity_) return;
  if (data_) cudaFreeHost(data_);
  data_ = nullptr;
  capacity_ = 0;
  check(cudaMallocHost(&data_, bytes), what);
  capacity_ = bytes;
}

Stream::Stream() {
  cudaStream_t s = nullptr;
  check(cudaStreamCreateWithFlags(&s, cudaStreamNonBlocking), "cuda: creating a stream");
  stream_ = s;
}

Stream::~Stream() {
  if (stream_) cudaStreamDestroy(static_cast<cudaStream_t>(stream_));
}

void Stream::synchronize(const std::string& what) const {
  cuda::synchronize(stream_, what);
}

void synchronize(void* stream, const std::string& what) {
  check(cudaStreamSynchronize(static_cast<cudaStream_t>(stream)), what);
}

Event::Event() {
  cudaEvent_t e = nullptr;
  check(cudaEventCreateWithFlags(&e, cudaEventDisableTiming), "cuda: creating an event");
  event_ = e;
}

Event::~Event() {
  if (event_) cudaEventDestroy(static_cast<cudaEvent_t>(event_));
}

void Event::record(void* stream, const std::string& what) {
  check(cudaEventRecord(static_cast<cudaEvent_t>(event_), static_cast<cudaStream_t>(stream)), what);
}

void Event::make_wait(void* stream, const std::string& what) const {
  check(cudaStreamWaitEvent(static_cast<cudaStream_t>(stream), static_cast<cudaEvent_t>(event_), 0),
        what);
}

void Event::synchronize(const std::string& what) const {
  check(cudaEventSynchronize(static_cast<cudaEvent_t>(event_)), what);
}

namespace {
PointerKind pointer_kind(const void* p, int* device) {
  cudaPointerAttributes a{};
  const cudaError_t err = cudaPointerGetAttributes(&a, p);
  *device = a.device;
  if (err != cudaSuccess) {
    cudaGetLastError();  // an unknown pointer is not a sticky error
    return PointerKind::Unregistered;
  }
  if (a.type == cudaMemoryTypeDevice) return PointerKind::Device;
  if (a.type == cudaMemoryTypeManaged) return PointerKind::Managed;
  if (a.type == cudaMemoryTypeHost) return PointerKind::Host;
  return PointerKind::Unregistered;
}
}  // namespace

void check_device_pointer(const void* p, int device, const std::string& what) {
  int pointer_device = -1;
  const PointerKind kind = pointer_kind(p, &pointer_device);
  const std::string problem = pointer_problem(kind, pointer_device, device, what);
  if (!problem.empty()) throw InputError(problem);
}

bool is_page_locked(const void* p, size_t bytes) {
  if (!p || !bytes) return false;
  int device = -1;
  const char* last = static_cast<const char*>(p) + (bytes - 1);
  return pointer_kind(p, &device) == PointerKind::Host &&
         pointer_kind(last, &device) == PointerKind::Host;
}

void* malloc_async(size_t bytes, void* stream, const std::string& what) {
  void* p = nullptr;
  check(cudaMallocAsync(&p, bytes, static_cast<cudaStream_t>(stream)), what);
  return p;
}

void free_async(void* data, void* stream) {
  if (data) cudaFreeAsync(data, static_cast<cudaStream_t>(stream));
}

void copy_to_device(void* dst, const void* src, size_t bytes, void* stream,
                    const std::string& what) {
  check(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyHostToDevice, static_cast<cudaStream_t>(stream)),
        what);
}

void copy_to_host(void* dst, const void* src, size_t bytes, void* stream, const std::string& what) {
  check(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyDeviceToHost, static_cast<cudaStream_t>(stream)),
        what);
}

void download(void* dst, const void* src, size_t bytes, void* stream, PinnedBuffer staging[2],
              const std::string& what) {
  if (is_page_locked(dst, bytes)) {
    copy_to_host(dst, src, bytes, stream, what);
    synchronize(stream, what);
    return;
  }
  // Pageable memory: the driver would stage it on one thread (and fault in fresh pages there).
  // Chunks go to our pinned buffers instead, and every CPU thread copies one chunk onwards while
  // the next one travels.
  const size_t chunk = std::min<size_t>(bytes, size_t(32) << 20);
  if (!chunk) return;
  Event travelled[2];
  struct Pending {
    size_t first = 0, n = 0;
  } pending[2];
  auto land = [&](int k) {
    if (!pending[k].n) return;
    travelled[k].synchronize(what);
    backend::parallel_memcpy(static_cast<char*>(dst) + pending[k].first, staging[k].data(),
                             pending[k].n);
    pending[k].n = 0;
  };
  for (int k = 0; k < 2; ++k) staging[k].reserve(chunk, what + ": pinned staging buffer");
  int k = 0;
  for (size_t first = 0; first < bytes; first += chunk, k ^= 1) {
    land(k);
    const size_t n = std::min(chunk, bytes - first);
    copy_to_host(staging[k].data(), static_cast<const char*>(src) + first, n, stream, what);
    travelled[k].record(stream, what);
    pending[k] = {first, n};
  }
  land(k);
  land(k ^ 1);
}

}  // namespace cuda
}  // namespace sonoslice
