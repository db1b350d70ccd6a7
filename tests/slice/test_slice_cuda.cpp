// The CUDA backend: equivalence with the CPU backend, GPU-resident outputs, batches larger than
// one chunk; and, on machines without a GPU, a clear "not available" instead of a crash.
// Everything needing a GPU reports itself as skipped where there is none.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstring>

#include "../../src/backend/CudaChecks.h"
#ifdef SONOSLICE_HAVE_CUDA
#include "../../src/backend/CudaRuntime.h"
#endif
#include "../../src/backend/ParallelFor.h"
#include "../common/TestUtil.h"
#include "sonoslice/core/Error.h"
#include "sonoslice/phantom/Phantom.h"
#include "sonoslice/phantom/Workloads.h"
#include "sonoslice/slice/Slicer.h"

namespace sonoslice {
namespace {

const Device kCuda{DeviceType::CUDA, 0};

using Cuda = test::GpuTest;
using test::gpu_available;

// The small phantom turned to an oblique, off-centre grid, so direction cosines matter.
Volume oblique(const Volume& v) {
  Volume out = v;
  out.grid().direction = test::rotation({1, 2, 2}, 23);
  out.grid().origin_mm = {15, -20, 7};
  return out;
}

ProbeGeometry half_w1() {
  ProbeGeometry p = workload_w1_fan_probe();
  p.image.width /= 2;
  p.image.height /= 2;
  p.image.spacing_mm[0] *= 2;
  p.image.spacing_mm[1] *= 2;
  return p;
}

struct Diff {
  double max_abs = 0;
  size_t differing = 0;
};
Diff compare(const std::vector<float>& a, const std::vector<float>& b) {
  Diff d;
  for (size_t i = 0; i < a.size(); ++i) {
    const double e = std::isnan(a[i]) && std::isnan(b[i]) ? 0 : std::fabs(double(a[i]) - b[i]);
    d.max_abs = std::max(d.max_abs, e);
    d.differing += e > 0;
  }
  return d;
}

// CPU and CUDA agree to 1e-4 of the value range (linear) and exactly (nearest) on intensity
// (float32, int16) and label (uint8) volumes, both probe types, oblique directions, and poses
// that leave the volume.
TEST_F(Cuda, EquivalentToCpu) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const Volume ct16 = oblique(ph.ct), ct32 = oblique(ph.ct.converted(PixelType::Float32));
  const Volume labels = oblique(ph.labels);
  auto poses = phantom_random_poses(60, 21);
  for (Pose& p : poses) p.m[0][3] += 80;  // a good share of the fans now leave the volume
  for (const Volume* v : {&ct32, &ct16, &labels}) {
    const auto range = v->value_range();
    for (const ProbeGeometry& probe : {half_w1(), workload_w2_linear_probe()}) {
      for (Interpolation interp : {Interpolation::Linear, Interpolation::Nearest}) {
        if (v == &labels && interp == Interpolation::Linear) continue;  // labels are nearest
        SliceSettings s;
        s.interpolation = interp;
        s.fill_value = -5;
        const auto cpu = Slicer(*v, probe, s).slice<float>(poses);
        const auto gpu = Slicer(*v, probe, s, kCuda).slice<float>(poses);
        const Diff d = compare(cpu, gpu);
        SCOPED_TRACE(to_string(v->pixel_type()) + " " + probe.describe() + " " + to_string(interp));
        std::printf("[ cuda vs cpu ] %s %s %s: max |difference| %.3g (%.3g of the range)\n",
                    to_string(v->pixel_type()).c_str(),
                    probe.type == ProbeType::Linear ? "linear" : "fan", to_string(interp),
                    d.max_abs, d.max_abs / (range.second - range.first));
        if (interp == Interpolation::Nearest)
          EXPECT_EQ(d.differing, 0u);
        else
          EXPECT_LE(d.max_abs, 1e-4 * (range.second - range.first));
      }
    }
  }
}

// Integer outputs saturate the same way on the GPU.
TEST_F(Cuda, IntegerOutputsMatchCpu) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const auto poses = phantom_random_poses(20, 4);
  for (PixelType t : {PixelType::Int16, PixelType::UInt8, PixelType::UInt16}) {
    SliceSettings s;
    s.output_type = t;
    std::vector<unsigned char> cpu(20 * half_w1().image.pixel_count() * pixel_size(t));
    std::vector<unsigned char> gpu(cpu.size());
    Slicer(ph.ct, half_w1(), s).slice(poses.data(), poses.size(), cpu.data());
    Slicer(ph.ct, half_w1(), s, kCuda).slice(poses.data(), poses.size(), gpu.data());
    // Rounding ties may differ by one unit where the lerps round differently (FMA).
    size_t off_by_more = 0;
    visit_pixel_type(t, [&](auto zero) {
      using T = decltype(zero);
      const T* a = reinterpret_cast<const T*>(cpu.data());
      const T* b = reinterpret_cast<const T*>(gpu.data());
      for (size_t i = 0; i < cpu.size() / sizeof(T); ++i)
        off_by_more += std::abs(int(a[i]) - int(b[i])) > 1;
    });
    EXPECT_EQ(off_by_more, 0u) << to_string(t);
  }
}

// Output kept on the GPU, copied back, and written into caller-owned GPU memory.
TEST_F(Cuda, DeviceResidentOutputs) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const auto poses = phantom_random_poses(40, 8);
  const ProbeGeometry probe = half_w1();
  const Slicer cpu(ph.ct, probe);
  const Slicer gpu(ph.ct, probe, {}, kCuda);
  const auto expected = cpu.slice<float>(poses);

  const DeviceImages images = gpu.slice_on_device(poses.data(), poses.size());
  ASSERT_NE(images.data, nullptr);
  EXPECT_EQ(images.count, 40);
  EXPECT_EQ(images.height, probe.image.height);
  EXPECT_EQ(images.width, probe.image.width);
  EXPECT_EQ(images.bytes(), expected.size() * sizeof(float));
  std::vector<float> back(expected.size());
  images.copy_to_host(back.data());
  EXPECT_LE(compare(expected, back).max_abs, 0.05);  // HU; FMA-level differences

  // Caller-owned device memory: here, another slicer's buffer of the right size.
  const Slicer other(ph.ct, probe, {}, kCuda);
  const DeviceImages target = other.slice_on_device(poses.data(), poses.size());
  target.synchronize();
  std::vector<Pose> shifted = poses;
  for (Pose& p : shifted) p.m[2][3] += 10;
  gpu.slice_into_device(shifted.data(), shifted.size(), target.data);
  std::vector<float> into(expected.size());
  DeviceImages view = target;
  view.stream = nullptr;  // queued on the legacy default stream, slice_into_device's default
  view.copy_to_host(into.data());
  EXPECT_LE(compare(cpu.slice<float>(shifted), into).max_abs, 0.05);

  EXPECT_THROW(cpu.slice_on_device(poses.data(), 1), InputError);
}

// Each slice_on_device result owns its buffer: a later, larger batch neither overwrites nor
// frees an earlier one (before, every result was the slicer's one growing buffer).
TEST_F(Cuda, EachDeviceResultOwnsItsBuffer) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const ProbeGeometry probe = half_w1();
  const Slicer cpu(ph.ct, probe);
  const Slicer gpu(ph.ct, probe, {}, kCuda);
  const auto first_poses = phantom_random_poses(10, 3), later_poses = phantom_random_poses(500, 4);
  const DeviceImages first = gpu.slice_on_device(first_poses.data(), first_poses.size());
  const DeviceImages later = gpu.slice_on_device(later_poses.data(), later_poses.size());
  EXPECT_NE(first.data, later.data);
  std::vector<float> back(first_poses.size() * size_t(probe.image.pixel_count()));
  first.copy_to_host(back.data());
  EXPECT_LE(compare(cpu.slice<float>(first_poses), back).max_abs, 0.05);
  std::vector<float> back_later(later_poses.size() * size_t(probe.image.pixel_count()));
  later.copy_to_host(back_later.data());
  EXPECT_LE(compare(cpu.slice<float>(later_poses), back_later).max_abs, 0.05);
}

// The caller's stream, the legacy default one, and the slicer's own stream joined back to the
// caller's: all three give the CPU's images when the caller then reads on its stream.
TEST_F(Cuda, StreamsTheCallerNames) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const ProbeGeometry probe = workload_w2_linear_probe();
  const Slicer cpu(ph.ct, probe);
  const Slicer gpu(ph.ct, probe, {}, kCuda);
  const auto poses = phantom_random_poses(200, 5);
  const auto expected = cpu.slice<float>(poses);
  const DeviceImages target = gpu.slice_on_device(poses.data(), poses.size());
  target.synchronize();
  for (const CudaStream& stream :
       {CudaStream::legacy_default(), CudaStream::own_then_join(nullptr)}) {
    std::vector<Pose> moved = poses;
    for (Pose& p : moved) p.m[0][3] += 3;  // something else first, then the poses wanted
    gpu.slice_into_device(moved.data(), moved.size(), target.data, stream);
    gpu.slice_into_device(poses.data(), poses.size(), target.data, stream);
    DeviceImages view = target;
    view.stream = nullptr;  // the caller reads on the legacy default stream
    std::vector<float> back(expected.size(), std::nanf(""));
    view.copy_to_host(back.data());
    EXPECT_LE(compare(expected, back).max_abs, 0.05) << "own stream: " << stream.slicer_stream;
  }
}

// Output pointers are checked: host memory is refused with a message naming `out`.
TEST_F(Cuda, HostMemoryAsDeviceOutputIsRefused) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const Slicer gpu(ph.ct, half_w1(), {}, kCuda);
  const auto poses = phantom_random_poses(2, 1);
  std::vector<float> host(2 * size_t(half_w1().image.pixel_count()));
  try {
    gpu.slice_into_device(poses.data(), poses.size(), host.data());
    FAIL() << "host memory was taken as device memory";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("out: is host memory"), std::string::npos) << e.what();
  }
}

// A CUDA slicer made before fork() fails clearly in the child (a torch DataLoader worker),
// instead of crashing or hanging there.
TEST_F(Cuda, SlicerMadeBeforeForkFailsClearlyInTheChild) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const Slicer gpu(ph.ct, half_w1(), {}, kCuda);
  const auto poses = phantom_random_poses(2, 1);
  std::vector<float> out(2 * size_t(half_w1().image.pixel_count()));
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    int code = 3;
    try {
      gpu.slice(poses.data(), poses.size(), out.data());
      code = 1;
    } catch (const Error& e) {
      code = std::string(e.what()).find("CUDA cannot be used across fork()") != std::string::npos
                 ? 0
                 : 2;
    }
    _exit(code);
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "1: the child sliced; 2: another error";
  gpu.slice(poses.data(), poses.size(), out.data());  // the parent carries on
}

// A batch far larger than one GPU chunk streams through in pieces, copies overlapping kernels.
TEST_F(Cuda, LargeBatchStreamsInChunks) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const auto poses = phantom_random_poses(3000, 12);
  const ProbeGeometry probe = workload_w2_linear_probe();  // 800 kB per image: 3000 = 2.4 GB
  const Slicer gpu(ph.ct, probe, {}, kCuda);
  std::vector<float> out(poses.size() * size_t(probe.image.pixel_count()));
  gpu.slice(poses.data(), poses.size(), out.data());
  // Check the first, a middle and the last images against the CPU.
  const Slicer cpu(ph.ct, probe);
  for (size_t n : {size_t(0), size_t(1499), size_t(2999)}) {
    const auto one = cpu.slice<float>({poses[n]});
    const std::vector<float> got(out.begin() + std::ptrdiff_t(n * one.size()),
                                 out.begin() + std::ptrdiff_t((n + 1) * one.size()));
    EXPECT_LE(compare(one, got).max_abs, 0.05) << "image " << n;
  }
}

// A volume of more than 2^31 voxels: the kernel takes 64-bit voxel offsets there (32-bit ones
// below), and fans near the far end of the buffer read the same voxels as the CPU's.
TEST_F(Cuda, VolumeOverTwoBillionVoxelsUsesWideOffsets) {
  VolumeGrid grid;
  grid.dims = {1300, 1300, 1300};  // 2.197e9 voxels > 2^31
  Volume v = Volume::allocate(PixelType::UInt8, grid);
  auto* p = static_cast<uint8_t*>(v.data());
  backend::parallel_for(grid.dims[2], [&](int64_t k) {
    for (int64_t j = 0; j < grid.dims[1]; ++j)
      for (int64_t i = 0; i < grid.dims[0]; ++i)
        p[(k * grid.dims[1] + j) * grid.dims[0] + i] = uint8_t((i * 7 + j * 13 + k * 29) & 255);
  });
  // Planes at z = 1290 (voxel offsets about 2.18e9) and one tilted through z 1260–1299.
  const std::vector<Pose> poses = {
      test::make_pose(Mat3::identity(), {650, 300, 1290}),
      test::make_pose(test::rotation({1, 0, 0}, 8), {400, 700, 1285}),
      test::make_pose(test::rotation({0, 1, 1}, 30), {1000, 900, 1280})};
  const ProbeGeometry probe = workload_w2_linear_probe();
  for (Interpolation interp : {Interpolation::Nearest, Interpolation::Linear}) {
    SliceSettings s;
    s.interpolation = interp;
    const auto cpu = Slicer(v, probe, s).slice<float>(poses);
    const auto gpu = Slicer(v, probe, s, kCuda).slice<float>(poses);
    const Diff d = compare(cpu, gpu);
    size_t inside = 0;
    for (float x : cpu) inside += x != 0;
    EXPECT_GT(inside, cpu.size() / 4) << "the fans should lie mostly inside the volume";
    if (interp == Interpolation::Nearest)
      EXPECT_EQ(d.differing, 0u);
    else
      EXPECT_LE(d.max_abs, 1e-4 * 255);
  }
}

#ifdef SONOSLICE_HAVE_CUDA
// Page-locked output (cudaHostAlloc, a pinned torch tensor) is copied into straight from the GPU,
// chunk after chunk on both streams; the images are those of pageable output.
TEST_F(Cuda, PinnedHostOutputIsFilledDirectly) {
  const Phantom ph = make_phantom(PhantomSize::Small);
  const auto poses = phantom_random_poses(3000, 13);
  const ProbeGeometry probe = workload_w2_linear_probe();  // 3000 × 800 kB: several chunks
  const Slicer gpu(ph.ct, probe, {}, kCuda);
  const size_t count = poses.size() * size_t(probe.image.pixel_count());
  std::vector<float> pageable(count);
  EXPECT_FALSE(cuda::is_page_locked(pageable.data(), count * sizeof(float)));
  gpu.slice(poses.data(), poses.size(), pageable.data());
  cuda::PinnedBuffer pinned;
  pinned.reserve(count * sizeof(float), "test output");
  ASSERT_TRUE(cuda::is_page_locked(pinned.data(), count * sizeof(float)));
  std::memset(pinned.data(), 0xff, count * sizeof(float));  // NaN everywhere
  gpu.slice(poses.data(), poses.size(), static_cast<float*>(pinned.data()));
  EXPECT_EQ(std::memcmp(pinned.data(), pageable.data(), count * sizeof(float)), 0);
}
#endif

// A CUDA build on a machine without a GPU: says so, and slices on the CPU as ever.
TEST(CudaAvailability, CpuOnlyMachineSaysNotAvailable) {
  std::string why;
  if (gpu_available(&why)) GTEST_SKIP() << "a GPU is present";
  EXPECT_NE(describe_devices().find("cuda: not available"), std::string::npos)
      << describe_devices();
  const Phantom ph = make_phantom(PhantomSize::Small);
  test::expect_cuda_unavailable([&] { Slicer(ph.ct, half_w1(), {}, kCuda); });
  EXPECT_EQ(Slicer(ph.ct, half_w1()).slice<float>(phantom_random_poses(2)).size(),
            size_t(2 * half_w1().image.pixel_count()));
}

}  // namespace
}  // namespace sonoslice

namespace sonoslice {
namespace {

// The decisions behind the CUDA checks, on every machine (CudaChecks.h: plain C++).
TEST(CudaChecks, PointerKindsAndDevices) {
  using cuda::PointerKind;
  EXPECT_EQ(cuda::pointer_problem(PointerKind::Device, 0, 0, "out"), "");
  EXPECT_EQ(cuda::pointer_problem(PointerKind::Managed, -2, 1, "out"), "");
  EXPECT_EQ(cuda::pointer_problem(PointerKind::Device, 1, 0, "out"),
            "out: is memory of cuda:1 but the slicer runs on cuda:0");
  for (PointerKind host : {PointerKind::Host, PointerKind::Unregistered})
    EXPECT_EQ(cuda::pointer_problem(host, -1, 0, "out")
                  .rfind("out: is host memory, not GPU memory "
                         "of cuda:0",
                         0),
              0u);
}

TEST(CudaChecks, ForkedChildIsRefused) {
  const long parent = cuda::current_process();
  EXPECT_NO_THROW(cuda::check_not_forked(parent, "cuda:0 slicer"));
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    try {
      cuda::check_not_forked(parent, "cuda:0 slicer");
      _exit(1);
    } catch (const Error& e) {
      const std::string m = e.what();
      _exit(m.rfind("cuda:0 slicer: was created in process " + std::to_string(parent), 0) == 0 &&
                    m.find("'spawn'") != std::string::npos
                ? 0
                : 2);
    }
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

}  // namespace
}  // namespace sonoslice
