#include "sonoslice/slice/Slicer.h"

#include <cmath>
#include <limits>

#include "SliceBackends.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {

bool is_slice_output_type(PixelType type) {
  return type == PixelType::Float32 || type == PixelType::Int16 || type == PixelType::UInt8 ||
         type == PixelType::UInt16;
}

Slicer::Slicer(Volume volume, ProbeGeometry probe, SliceSettings settings, Device device)
    : volume_(std::move(volume)), probe_(probe), settings_(settings), device_(device) {
  if (volume_.empty()) throw InputError("slicer: the volume is empty");
  volume_.grid().validate("volume");
  // The kernels index with int per axis and int64 offsets.
  for (int a = 0; a < 3; ++a)
    if (volume_.grid().dims[a] > std::numeric_limits<int>::max() / 2)
      throw InputError("volume: too many voxels along axis " + std::to_string(a));
  probe_.validate("probe");
  if (!is_slice_output_type(settings_.output_type))
    throw InputError("output type " + to_string(settings_.output_type) +
                     ": expected float32, int16, uint8 or uint16");
  if (std::isnan(settings_.fill_value)) {
    // NaN is a legitimate fill for float output (marks "no data"); integers cannot hold it.
    if (settings_.output_type != PixelType::Float32)
      throw InputError("fill value NaN needs float32 output");
  }
  require_device(device_);
  mask_ = probe_.mask();
#ifdef SONOSLICE_HAVE_CUDA
  if (device_.type == DeviceType::CUDA)
    cuda_ = slice_impl::cuda_prepare(volume_, mask_, device_.index);
#endif
}

size_t Slicer::image_bytes() const {
  return size_t(probe_.image.pixel_count()) * pixel_size(settings_.output_type);
}

void Slicer::check_output_type(PixelType type) const {
  if (type != settings_.output_type)
    throw InputError("slicer: output buffer type " + to_string(type) +
                     " does not match the output type " + to_string(settings_.output_type));
}

namespace {

// Per image, the pixel grid's map into the volume's index (VolumeGrid::index_map) as the
// kernels step through it: pixel (0, 0)'s index and its change per column and per row, computed
// in double, handed to the kernels as floats.
std::vector<slice_impl::PixelToIndex> pixel_to_index(const VolumeGrid& g, const ImageGrid& im,
                                                     const Pose* poses, size_t count) {
  std::vector<slice_impl::PixelToIndex> affines(count);
  for (size_t n = 0; n < count; ++n) {
    const IndexMap m = g.index_map(poses[n]);
    const Vec3 origin = m({im.origin_mm[0], im.origin_mm[1], 0.0});
    const Vec3 per_column = m.direction({im.spacing_mm[0], 0.0, 0.0});
    const Vec3 per_row = m.direction({0.0, im.spacing_mm[1], 0.0});
    for (int k = 0; k < 3; ++k) {
      affines[n].origin[k] = float(origin[k]);
      affines[n].per_column[k] = float(per_column[k]);
      affines[n].per_row[k] = float(per_row[k]);
    }
  }
  return affines;
}

}  // namespace

slice_impl::SliceLaunch Slicer::launch_template() const {
  const VolumeGrid& g = volume_.grid();
  slice_impl::SliceLaunch launch{};
  launch.volume = volume_.data();
  launch.volume_type = volume_.pixel_type();
  launch.grid = geometry::VolumeView::of(g.dims[0], g.dims[1], g.dims[2]);
  launch.mask = mask_.data();
  launch.output_type = settings_.output_type;
  launch.width = probe_.image.width;
  launch.height = probe_.image.height;
  launch.fill_value = settings_.fill_value;
  launch.linear = settings_.interpolation == Interpolation::Linear;
  return launch;
}

std::vector<slice_impl::PixelToIndex> Slicer::checked_affines(const Pose* poses, size_t count,
                                                              size_t first_index) const {
  validate_poses(poses, count, "poses", first_index, /*warn_non_orthonormal=*/false);
  return pixel_to_index(volume_.grid(), probe_.image, poses, count);
}

void Slicer::require_cuda(const char* what) const {
  if (device_.type != DeviceType::CUDA)
    throw InputError(std::string(what) + ": this slicer runs on " + device_.to_string() +
                     "; create it with a CUDA device");
}

void Slicer::slice(const Pose* poses, size_t count, void* out, size_t first_index) const {
  if (count == 0) return;
  const auto affines = checked_affines(poses, count, first_index);
  slice_impl::SliceLaunch launch = launch_template();
#ifdef SONOSLICE_HAVE_CUDA
  if (device_.type == DeviceType::CUDA) {
    slice_impl::cuda_slice_to_host(*cuda_, launch, affines, out);
    return;
  }
#endif
  launch.poses = affines.data();
  launch.count = int64_t(count);
  launch.out = out;
  // The AVX2 fast path addresses voxels with int32 offsets.
  const bool int32_offsets = volume_.grid().voxel_count() < (int64_t(1) << 31) - 4;
  slice_impl::slice_cpu(int32_offsets ? cpu_kernel_isa() : CpuIsa::Generic, launch);
}

DeviceImages Slicer::slice_on_device(const Pose* poses, size_t count, size_t first_index) const {
  require_cuda("slice_on_device");
  const auto affines = checked_affines(poses, count, first_index);
  DeviceImages images;
  images.count = int64_t(count);
  images.height = height();
  images.width = width();
  images.type = settings_.output_type;
  images.device = device_;
#ifdef SONOSLICE_HAVE_CUDA
  if (count > 0) {
    images.owner =
        slice_impl::cuda_slice_to_new_buffer(cuda_, launch_template(), affines, &images.stream);
    images.data = images.owner.get();
  }
#endif
  return images;
}

void Slicer::slice_into_device(const Pose* poses, size_t count, void* device_out, CudaStream stream,
                               size_t first_index) const {
  require_cuda("slice_into_device");
  if (count == 0) return;
  if (!device_out) throw InputError("slice_into_device: the output pointer is null");
  const auto affines = checked_affines(poses, count, first_index);
#ifdef SONOSLICE_HAVE_CUDA
  slice_impl::cuda_slice_into_device(*cuda_, launch_template(), affines, device_out, stream);
#else
  (void)stream;
  (void)affines;
#endif
}

void DeviceImages::synchronize() const {
#ifdef SONOSLICE_HAVE_CUDA
  if (stream) slice_impl::cuda_synchronize(stream, device.index);
#endif
}

void DeviceImages::copy_to_host(void* host_out) const {
  if (!data || bytes() == 0) return;
#ifdef SONOSLICE_HAVE_CUDA
  slice_impl::cuda_copy_to_host(host_out, data, bytes(), stream, device.index);
#else
  (void)host_out;
  throw Error("this sonoslice was built without CUDA");
#endif
}

}  // namespace sonoslice
