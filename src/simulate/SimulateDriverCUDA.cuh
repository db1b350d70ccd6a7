#pragma once
/// @file The CUDA driver of the simulation kernel (SimulateImpl.h): each stage launched over
/// (image, item) for a batch of images, one thread per item, in the order the CPU driver
/// (SimulateDriverCPU.h) runs them for one image. No atomics and no reductions across threads:
/// the bytes are the same on every run; they differ from the CPU's in rounding (fused
/// multiply-adds, the GPU's exp2/log2/sqrt), docs/simulation.md §4. SimulateCUDA.cu includes
/// this file; buffers and streams are host code (SimulatorCUDA.cpp).
#include <cstdint>

#include "../backend/ParallelForCUDA.cuh"
#include "SimulateBackends.h"
#include "SimulateImpl.h"

namespace sonoslice {
namespace simulate_impl {
inline namespace SONOSLICE_KERNEL_ISA {

// Image n's buffers start at n times each one's per-image size (CudaBatch).
struct TraceBeams {
  CudaBatch b;
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / b.beams;
    const int beam = int(i % b.beams);
    trace_beam(b.models[n], beam, b.echo + n * 2 * b.beam_samples(),
               b.specular + n * b.beam_samples(), b.loss + n * b.beam_samples());
  }
};

struct AddSpeckle {
  CudaBatch b;
  int groups;  // speckle groups per beam
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / (int64_t(b.beams) * groups);
    const int64_t r = i % (int64_t(b.beams) * groups);
    const int beam = int(r / groups), group = int(r % groups);
    const ImageModel& m = b.models[n];
    float q0[3], dq[3];
    speckle_line(m, beam, q0, dq);
    add_speckle_group(m, q0, dq, group * kSpeckleLanes,
                      b.echo + n * 2 * b.beam_samples() + 2 * int64_t(beam) * b.samples);
  }
};

struct FilterAxial {
  CudaBatch b;
  bool speckle;  // the complex echo (2 channels), else the specular echo
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / b.beams;
    const int beam = int(i % b.beams);
    const ImageModel& m = b.models[n];
    float* tmp = b.tmp + i * 2 * b.samples;
    if (speckle)
      filter_axial_speckle(m, beam, b.echo + (n * b.beam_samples() + int64_t(beam) * b.samples) * 2,
                           tmp);
    else
      filter_axial(b.specular + n * b.beam_samples() + int64_t(beam) * b.samples, b.samples, 1,
                   m.axial_specular, m.axial_specular_radius, tmp);
  }
};

struct FilterLateral {
  CudaBatch b;
  bool speckle;
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / b.beams;
    const int beam = int(i % b.beams);
    const ImageModel& m = b.models[n];
    if (speckle) {
      const int level = lateral_level(m, beam);
      filter_lateral(b.echo + n * 2 * b.beam_samples(),
                     b.echo_filtered + (n * b.beam_samples() + int64_t(beam) * b.samples) * 2,
                     b.beams, b.samples, 2, lateral_speckle_taps(m, level),
                     lateral_speckle_ranges(m, level), m.lateral_radius, beam);
    } else {
      filter_lateral(b.specular + n * b.beam_samples(),
                     b.specular_filtered + n * b.beam_samples() + int64_t(beam) * b.samples,
                     b.beams, b.samples, 1, m.lateral_specular, m.lateral_specular_range,
                     m.lateral_radius, beam);
    }
  }
};

// Over every sample of the batch: the buffers are contiguous across images.
struct AddSpecular {
  CudaBatch b;
  __device__ void operator()(int64_t i) const {
    add_specular(b.echo_filtered, b.specular_filtered, i);
  }
};

struct TgcKnots {
  CudaBatch b;
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / b.knots_per_image;
    const int k = int(i % b.knots_per_image);
    b.knots[i] = tgc_knot(b.models[n], b.loss + n * b.beam_samples(), k, b.select + i * b.beams);
  }
};

struct TgcLevels {
  CudaBatch b;
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / b.samples;
    b.level[i] = tgc_level(b.models[n], b.knots + n * b.knots_per_image, int(i % b.samples));
  }
};

struct ScanPixels {
  CudaBatch b;
  __device__ void operator()(int64_t i) const {
    const int64_t n = i / b.pixels;
    scan_pixel(b.models[n], b.echo_filtered + n * 2 * b.beam_samples(), b.level + n * b.samples,
               i % b.pixels, b.out + n * int64_t(b.image_bytes));
  }
};

/// Every stage for the batch, in order, on `stream`.
inline void simulate_batch(const CudaBatch& b, void* stream) {
  using backend::parallel_for;
  const int64_t images = b.count, beams = images * b.beams;
  const int groups = (b.samples + kSpeckleLanes - 1) / kSpeckleLanes;
  parallel_for(beams, TraceBeams{b}, stream);
  parallel_for(beams * groups, AddSpeckle{b, groups}, stream);
  parallel_for(beams, FilterAxial{b, true}, stream);
  parallel_for(beams, FilterAxial{b, false}, stream);
  parallel_for(beams, FilterLateral{b, true}, stream);
  parallel_for(beams, FilterLateral{b, false}, stream);
  parallel_for(images * b.beam_samples(), AddSpecular{b}, stream);
  if (b.tgc_auto) parallel_for(images * b.knots_per_image, TgcKnots{b}, stream);
  parallel_for(images * b.samples, TgcLevels{b}, stream);
  parallel_for(images * b.pixels, ScanPixels{b}, stream);
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace simulate_impl
}  // namespace sonoslice
