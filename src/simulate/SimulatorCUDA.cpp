// Host side of the CUDA simulation backend: the volume and tables uploaded once per simulator,
// then batches of images through every stage (SimulateCUDA.cu) and back to host memory.
#include <algorithm>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "../backend/CudaRuntime.h"
#include "SimulateBackends.h"
#include "SimulateModel.h"
#include "sonoslice/core/Error.h"

namespace sonoslice {
namespace simulate_impl {

struct CudaSimulateState : cuda::Owner {
  explicit CudaSimulateState(int device) : cuda::Owner(device) {}
  ImageModel base;  // the model with device pointers
  cuda::DeviceBuffer volume, label_props, hu_table, speckle, axial_specular, lateral_speckle,
      lateral_specular, lateral_speckle_range, lateral_specular_range, mask, scan_index,
      scan_sample, scan_steps, scan_weights;
  cuda::DeviceBuffer models, work, out;  // one batch's poses, stage buffers and images
  cuda::PinnedBuffer staging;            // the batch's images on their way to the caller
  std::unique_ptr<cuda::Stream> stream;
  std::mutex batch;  // simulate() is const: callers on several threads take turns
  void enter() const { cuda::Owner::enter("simulator"); }
};

namespace {

template <typename T>
const T* upload(const CudaSimulateState& st, cuda::DeviceBuffer& to, const T* data, size_t count,
                const std::string& what) {
  if (!data || count == 0) return nullptr;
  const size_t bytes = count * sizeof(T);
  to.reserve(bytes, st.name + ": " + what + " (" + std::to_string(bytes >> 20) + " MiB)");
  cuda::copy_to_device(to.data(), data, bytes, st.stream->get(), st.name + ": uploading " + what);
  return static_cast<const T*>(to.data());
}
template <typename T>
const T* upload(const CudaSimulateState& st, cuda::DeviceBuffer& to, const std::vector<T>& v,
                const std::string& what) {
  return upload(st, to, v.data(), v.size(), what);
}

// Floats of stage buffers per image (CudaBatch's list).
int64_t work_floats(int beams, int samples) {
  const int64_t bs = int64_t(beams) * samples;
  return 2 * bs + 2 * bs + bs + bs + bs + 2 * bs + int64_t(tgc_knot_count(samples)) * beams +
         tgc_knot_count(samples) + samples;
}

}  // namespace

std::shared_ptr<CudaSimulateState> cuda_prepare(const Model& m, int device) {
  auto st = std::make_shared<CudaSimulateState>(device);
  st->stream = std::make_unique<cuda::Stream>();
  ImageModel& b = st->base;
  b = m.base;
  // The volume as the kernel reads it: float or int16 HU, or uint16 labels (m.volume holds it).
  const void* voxels = m.base.hu     ? static_cast<const void*>(m.base.hu)
                       : m.base.hu16 ? static_cast<const void*>(m.base.hu16)
                                     : static_cast<const void*>(m.base.labels);
  if (voxels != m.volume.data()) throw Error(st->name + ": the simulator's volume is not its own");
  const auto* volume =
      upload(*st, st->volume, static_cast<const uint8_t*>(m.volume.data()), m.volume.byte_size(),
             "the volume (" + to_string(m.volume.pixel_type()) + ")");
  b.hu = m.base.hu ? reinterpret_cast<const float*>(volume) : nullptr;
  b.hu16 = m.base.hu16 ? reinterpret_cast<const int16_t*>(volume) : nullptr;
  b.labels = m.base.labels ? reinterpret_cast<const uint16_t*>(volume) : nullptr;
  b.label_props = upload(*st, st->label_props, m.label_props, "the label table");
  b.hu_table = upload(*st, st->hu_table, m.hu_table, "the HU table");
  b.speckle = upload(*st, st->speckle, m.speckle, "the speckle table");
  b.axial_specular = upload(*st, st->axial_specular, m.axial_specular, "the axial filters");
  b.lateral_speckle = upload(*st, st->lateral_speckle, m.lateral_speckle, "the lateral filters");
  b.lateral_specular = upload(*st, st->lateral_specular, m.lateral_specular, "the lateral filters");
  b.lateral_speckle_range =
      upload(*st, st->lateral_speckle_range, m.lateral_speckle_range, "the lateral filters");
  b.lateral_specular_range =
      upload(*st, st->lateral_specular_range, m.lateral_specular_range, "the lateral filters");
  b.mask = upload(*st, st->mask, m.mask, "the probe mask");
  b.scan_index = upload(*st, st->scan_index, m.scan_index, "the scan conversion");
  b.scan_sample = upload(*st, st->scan_sample, m.scan_sample, "the scan conversion");
  b.scan_steps = upload(*st, st->scan_steps, m.scan_steps, "the scan conversion");
  b.scan_weights = upload(*st, st->scan_weights, m.scan_weights, "the scan conversion");
  st->stream->synchronize(st->name + ": uploading the simulator's tables");
  return st;
}

void cuda_simulate(CudaSimulateState& st, const IndexMap* maps, size_t count, uint8_t* out,
                   size_t image_bytes) {
  st.enter();
  std::lock_guard<std::mutex> lock(st.batch);
  const int B = st.base.beams, S = st.base.samples;
  const int64_t floats = work_floats(B, S);
  const size_t per_image = size_t(floats) * sizeof(float) + image_bytes + sizeof(ImageModel);
  // Batches of up to 1024 images (enough threads to fill a large GPU in every stage) within a
  // quarter of the free memory.
  size_t free_bytes = 0, total = 0;
  cuda::memory_info(&free_bytes, &total);
  const size_t budget = std::clamp<size_t>(free_bytes / 4, size_t(64) << 20, size_t(8) << 30);
  const size_t chunk = std::clamp<size_t>(budget / per_image, 1, std::min<size_t>(count, 1024));
  if (per_image > free_bytes)
    throw ResourceError(st.name + ": one simulated image needs " + std::to_string(per_image >> 20) +
                        " MiB of GPU memory, " + std::to_string(free_bytes >> 20) + " MiB free");
  st.models.reserve(chunk * sizeof(ImageModel), st.name + ": poses");
  st.work.reserve(chunk * size_t(floats) * sizeof(float), st.name + ": simulation buffers");
  st.out.reserve(chunk * image_bytes, st.name + ": output images");
  st.staging.reserve(chunk * image_bytes, st.name + ": pinned staging buffer");
  std::vector<ImageModel> models(chunk, st.base);
  void* stream = st.stream->get();
  for (size_t first = 0; first < count; first += chunk) {
    const size_t n = std::min(chunk, count - first);
    for (size_t k = 0; k < n; ++k) {
      models[k] = st.base;
      set_pose(models[k], maps[first + k]);
    }
    cuda::copy_to_device(st.models.data(), models.data(), n * sizeof(ImageModel), stream,
                         st.name + ": uploading poses");
    CudaBatch b;
    b.models = static_cast<const ImageModel*>(st.models.data());
    b.count = int64_t(n);
    b.beams = B;
    b.samples = S;
    b.knots_per_image = tgc_knot_count(S);
    b.pixels = int64_t(st.base.width) * st.base.height;
    b.image_bytes = image_bytes;
    b.tgc_auto = st.base.tgc_auto;
    float* w = static_cast<float*>(st.work.data());
    const int64_t bs = int64_t(n) * B * S;
    const auto take = [&](int64_t k) {
      float* p = w;
      w += k;
      return p;
    };
    b.echo = take(2 * bs);
    b.echo_filtered = take(2 * bs);
    b.specular = take(bs);
    b.specular_filtered = take(bs);
    b.loss = take(bs);
    b.tmp = take(2 * bs);
    b.select = take(int64_t(n) * b.knots_per_image * B);
    b.knots = take(int64_t(n) * b.knots_per_image);
    b.level = take(int64_t(n) * S);
    b.out = static_cast<uint8_t*>(st.out.data());
    simulate_cuda_launch(b, stream);
    cuda::copy_to_host(st.staging.data(), st.out.data(), n * image_bytes, stream,
                       st.name + ": copying images to the host");
    st.stream->synchronize(st.name + ": simulating");
    std::memcpy(out + first * image_bytes, st.staging.data(), n * image_bytes);
  }
}

}  // namespace simulate_impl
}  // namespace sonoslice
