#pragma once
/// @file Slicing: a batch of probe poses through a volume → a batch of ultrasound-shaped images.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "sonoslice/backend/Device.h"
#include "sonoslice/core/Interpolation.h"
#include "sonoslice/geometry/Pose.h"
#include "sonoslice/geometry/Probe.h"
#include "sonoslice/volume/Volume.h"

namespace sonoslice {

namespace slice_impl {
struct CudaSliceState;
struct SliceLaunch;
struct PixelToIndex;
}  // namespace slice_impl

/// The output types the slicer writes: float32, int16, uint8, uint16.
bool is_slice_output_type(PixelType type);

struct SliceSettings {
  Interpolation interpolation = Interpolation::Linear;
  /// Value of pixels outside the probe shape or outside the volume (in output units).
  double fill_value = 0.0;
  /// float32 (default), int16, uint8 or uint16; integer outputs round and saturate.
  PixelType output_type = PixelType::Float32;
};

/// Which CUDA stream slice_into_device() queues its work on.
struct CudaStream {
  /// A cudaStream_t of the caller; null is the legacy default stream (a valid stream, which
  /// orders with every blocking stream), as torch reports for its default stream.
  void* handle = nullptr;
  /// Run on the slicer's own stream instead: it first waits for the work queued on `handle`
  /// (so that the output memory is free), and `handle` then waits for the slicing (so that its
  /// later work sees the images). Neither makes the host wait.
  bool slicer_stream = false;

  CudaStream() = default;
  /* implicit */ CudaStream(void* caller_stream) : handle(caller_stream) {}
  static CudaStream legacy_default() { return CudaStream(); }
  static CudaStream own_then_join(void* caller_stream) {
    CudaStream s(caller_stream);
    s.slicer_stream = true;
    return s;
  }
};

/// A batch of images in GPU memory (CUDA devices). Each result owns its buffer (shared by its
/// copies), so a later slice never overwrites or frees it.
struct DeviceImages {
  void* data = nullptr;  ///< device pointer to a C-order (count, height, width) array of `type`
  int64_t count = 0, height = 0, width = 0;
  PixelType type = PixelType::Float32;
  Device device;
  void* stream = nullptr;  ///< the cudaStream_t the kernel was queued on (not yet synchronized)
  std::shared_ptr<void> owner;  ///< keeps `data` alive; freed after the work on `stream`
  size_t bytes() const { return size_t(count * height * width) * pixel_size(type); }
  /// Waits for the kernel and copies the images into host memory of bytes() bytes.
  void copy_to_host(void* host_out) const;
  /// Waits for the kernel (and everything else queued on `stream`).
  void synchronize() const;
};

/// Bound to one volume, one probe and one device. The volume is shared, not copied; on a CUDA
/// device it is uploaded once, in its own pixel type, and stays there for the slicer's life.
/// A slicer serves one caller at a time (copies share their GPU buffers).
class Slicer {
 public:
  Slicer(Volume volume, ProbeGeometry probe, SliceSettings settings = {},
         Device device = Device::cpu());

  const Volume& volume() const { return volume_; }
  const ProbeGeometry& probe() const { return probe_; }
  const SliceSettings& settings() const { return settings_; }
  const Device& device() const { return device_; }
  int width() const { return probe_.image.width; }
  int height() const { return probe_.image.height; }
  /// The H×W fan mask (1 inside the probe shape), row-major.
  const std::vector<uint8_t>& mask() const { return mask_; }
  /// Bytes of one output image.
  size_t image_bytes() const;

  /// Slices `count` poses (probe mm → world mm, LPS) into `out`, a C-order (count, H, W) array
  /// of settings().output_type. Poses are checked first (InputError naming "pose <i>", with i
  /// counted from `first_index`); nothing is written when one is bad.
  void slice(const Pose* poses, size_t count, void* out, size_t first_index = 0) const;

  /// CUDA: slices into a new GPU buffer that the result owns (valid as long as the result or a
  /// copy of it lives), queued on the slicer's own stream. InputError on a CPU slicer.
  DeviceImages slice_on_device(const Pose* poses, size_t count, size_t first_index = 0) const;

  /// CUDA: slices into caller-owned GPU memory (count·H·W elements of output_type) without
  /// waiting for it, queued on `stream` (default: the legacy default stream; see CudaStream).
  /// `device_out` must be memory of the slicer's GPU (or managed memory): InputError otherwise.
  /// For handing the images to PyTorch and friends without a copy.
  void slice_into_device(const Pose* poses, size_t count, void* device_out,
                         CudaStream stream = CudaStream(), size_t first_index = 0) const;

  /// Convenience: slices into a new buffer of count·H·W elements of type T (T must match
  /// settings().output_type).
  template <typename T>
  std::vector<T> slice(const std::vector<Pose>& poses) const {
    std::vector<T> out(poses.size() * size_t(width()) * size_t(height()));
    check_output_type(PixelTypeOf<T>::value);
    slice(poses.data(), poses.size(), out.data());
    return out;
  }

 private:
  void check_output_type(PixelType type) const;
  slice_impl::SliceLaunch launch_template() const;
  /// The poses checked and turned into the kernels' per-image affines.
  std::vector<slice_impl::PixelToIndex> checked_affines(const Pose* poses, size_t count,
                                                        size_t first_index) const;
  /// InputError naming `what` unless this slicer runs on CUDA.
  void require_cuda(const char* what) const;

  Volume volume_;
  ProbeGeometry probe_;
  SliceSettings settings_;
  Device device_;
  std::vector<uint8_t> mask_;
  std::shared_ptr<slice_impl::CudaSliceState> cuda_;  // CUDA devices: resident volume, buffers
};

}  // namespace sonoslice
