#pragma once
// Internal, CUDA builds only: the host side of the CUDA backend (devices, errors, buffers,
// streams). Plain C++ over the CUDA runtime API; kernels live in .cu files. cudaStream_t is
// passed around as void* so that code outside the backend needs no CUDA header.
#include <cstddef>
#include <string>

namespace sonoslice {
namespace cuda {

/// GPUs the runtime sees; 0 when there is no driver or no GPU (never throws, never hangs).
int device_count();
/// Why device_count() is 0, in words ("no CUDA-capable GPU", "driver too old ..."); "" otherwise.
std::string unavailable_reason();
/// One line per GPU: name, memory, compute capability.
std::string describe_devices();

/// Makes `index` the calling thread's device; Error naming cuda:index when it cannot.
void use_device(int index);
/// What every holder of GPU state records about itself: its device, its name in messages
/// ("cuda:K") and the process that made it (CUDA state does not survive fork()).
struct Owner {
  int device = 0;
  std::string name;
  long process = 0;
  Owner() = default;
  /// For cuda:`device`, made by this process; makes the device current.
  explicit Owner(int device);
  /// At every entry point: Error in a forked child (`what` names the object, e.g. "slicer"),
  /// then the device made current.
  void enter(const std::string& what) const;
};

/// Throws for a failed runtime call: ResourceError for out-of-memory, Error otherwise; `what`
/// says which operation (e.g. "cuda:0: uploading the volume (200 MiB)").
void check(int error, const std::string& what);
/// Free and total memory of the current device, in bytes.
void memory_info(size_t* free_bytes, size_t* total_bytes);

/// Device memory that only grows (reallocating only when a larger size is asked for).
class DeviceBuffer {
 public:
  DeviceBuffer() = default;
  ~DeviceBuffer();
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  void reserve(size_t bytes, const std::string& what);
  void* data() const { return data_; }

 private:
  void* data_ = nullptr;
  size_t capacity_ = 0;
};

/// Page-locked host memory (fast, asynchronous device↔host copies); grows like DeviceBuffer.
class PinnedBuffer {
 public:
  PinnedBuffer() = default;
  ~PinnedBuffer();
  PinnedBuffer(const PinnedBuffer&) = delete;
  PinnedBuffer& operator=(const PinnedBuffer&) = delete;
  void reserve(size_t bytes, const std::string& what);
  void* data() const { return data_; }

 private:
  void* data_ = nullptr;
  size_t capacity_ = 0;
};

/// A non-blocking stream on the current device.
class Stream {
 public:
  Stream();
  ~Stream();
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;
  void* get() const { return stream_; }
  void synchronize(const std::string& what) const;

 private:
  void* stream_ = nullptr;
};

/// An event without timing, for ordering work between streams.
class Event {
 public:
  Event();
  ~Event();
  Event(const Event&) = delete;
  Event& operator=(const Event&) = delete;
  /// Marks the work queued on `stream` so far.
  void record(void* stream, const std::string& what);
  /// Makes later work on `stream` wait for the recorded work (the host does not wait).
  void make_wait(void* stream, const std::string& what) const;
  /// Makes the host wait for the recorded work.
  void synchronize(const std::string& what) const;

 private:
  void* event_ = nullptr;
};

/// InputError (via pointer_problem, CudaChecks.h) unless kernels on cuda:`device` can write the
/// `bytes` at `p`: GPU memory of that device, or managed memory. `what` names the pointer.
void check_device_pointer(const void* p, int device, const std::string& what);

/// Whether the `bytes` at host address `p` are page-locked memory that CUDA knows (cudaHostAlloc,
/// cudaHostRegister, a torch tensor with pin_memory=True): device → host copies can land there
/// directly, at the full bandwidth of the bus.
bool is_page_locked(const void* p, size_t bytes);

/// Stream-ordered scratch memory (cudaMallocAsync / cudaFreeAsync): safe to free right after
/// queuing the kernels that use it, whatever the caller's stream.
void* malloc_async(size_t bytes, void* stream, const std::string& what);
void free_async(void* data, void* stream);

/// Waits for everything queued on `stream`.
void synchronize(void* stream, const std::string& what);

/// Asynchronous copies on `stream`.
void copy_to_device(void* dst, const void* src, size_t bytes, void* stream,
                    const std::string& what);
void copy_to_host(void* dst, const void* src, size_t bytes, void* stream, const std::string& what);

/// Copies `bytes` of device memory into host memory after the work queued on `stream`, and waits:
/// straight into page-locked memory, else through the two pinned `staging` buffers (grown as
/// needed, kept for the next call), each chunk copied on into `dst` by every CPU thread.
void download(void* dst, const void* src, size_t bytes, void* stream, PinnedBuffer staging[2],
              const std::string& what);

}  // namespace cuda
}  // namespace sonoslice
