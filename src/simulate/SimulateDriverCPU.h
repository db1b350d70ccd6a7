#pragma once
/// @file The CPU driver of the simulation kernel (SimulateImpl.h): one image per task, its
/// stages run in a fixed order on one thread with that thread's buffers, so the bytes do not
/// depend on the number of threads. Included by SimulateCPU.cpp (generic x86-64) and
/// SimulateCPUAvx2.cpp (AVX2 + FMA); Simulator.cpp picks one at run time.
#include <cstring>
#include <vector>

#include "../backend/ParallelFor.h"
#include "SimulateImpl.h"

namespace sonoslice {
namespace simulate_impl {
inline namespace SONOSLICE_KERNEL_ISA {

/// One thread's buffers for one image at a time (beam-major, sample s of beam b at b·S + s).
struct Scratch {
  std::vector<float> echo, echo_filtered, specular, loss, tmp, level, across, knots;
  std::vector<uint8_t> has_specular;  // per beam: any specular echo
};

/// One image: trace every beam (eight at a time on AVX2 lanes), the speckle, the PSF (axial along
/// each beam, then lateral across the beams at each depth), TGC levels, then scan conversion,
/// envelope and log compression.
inline void simulate_image(const ImageModel& m, void* out, Scratch& w) {
  const int B = m.beams, S = m.samples;
  const size_t n = size_t(B) * size_t(S);
  w.echo.resize(2 * n);
  w.echo_filtered.resize(2 * n);
  w.specular.resize(n);
  w.loss.resize(n);
  w.tmp.resize(2 * size_t(S));
  w.level.resize(size_t(S));
  w.across.resize(size_t(B));
  w.has_specular.resize(size_t(B));
  int traced = 0;
#if defined(__AVX2__) && defined(__FMA__)
  for (; traced + 8 <= B; traced += 8)
    trace_beams8(m, traced, w.echo.data(), w.specular.data(), w.loss.data());
  // The last beams as the last eight (a beam traced twice gets the same values): one beam at a
  // time costs about as much as eight.
  if (traced < B && B >= 8) {
    trace_beams8(m, B - 8, w.echo.data(), w.specular.data(), w.loss.data());
    traced = B;
  }
#endif
  for (int b = traced; b < B; ++b)
    trace_beam(m, b, w.echo.data(), w.specular.data(), w.loss.data());
  for (int b = 0; b < B; ++b)
    w.has_specular[size_t(b)] = any_nonzero(w.specular.data() + size_t(b) * S, S);
  for (int b = 0; b < B; ++b) add_speckle(m, b, w.echo.data());
  for (int b = 0; b < B; ++b) {
    filter_axial_speckle(m, b, w.echo.data() + 2 * size_t(b) * S, w.tmp.data());
    if (w.has_specular[size_t(b)])
      filter_axial(w.specular.data() + size_t(b) * S, S, 1, m.axial_specular,
                   m.axial_specular_radius, w.tmp.data());
  }
  // Across the beams: the speckle's filter, then the specular echoes' (into one beam's buffer,
  // contiguous, so that it vectorises) added to the real parts.
  for (int b = 0; b < B; ++b) {
    float* filtered = w.echo_filtered.data() + 2 * size_t(b) * S;
    const int level = lateral_level(m, b);
    filter_lateral(w.echo.data(), filtered, B, S, 2, lateral_speckle_taps(m, level),
                   lateral_speckle_ranges(m, level), m.lateral_radius, b);
    filter_lateral(w.specular.data(), w.tmp.data(), B, S, 1, m.lateral_specular,
                   m.lateral_specular_range, m.lateral_radius, b, w.has_specular.data());
    for (int s = 0; s < S; ++s) add_specular(filtered, w.tmp.data(), s);
  }
  if (m.tgc_auto) {
    const int knots = tgc_knot_count(S);
    w.knots.resize(size_t(knots));
    for (int k = 0; k < knots; ++k)
      w.knots[size_t(k)] = tgc_knot(m, w.loss.data(), k, w.across.data());
  }
  for (int s = 0; s < S; ++s) w.level[size_t(s)] = tgc_level(m, w.knots.data(), s);
  const int64_t pixels = int64_t(m.width) * m.height;
  std::memset(out, 0, size_t(pixels) * (m.bmode ? 1 : sizeof(float)));
  for (int64_t k = 0; k < m.scan_count; ++k) {
    const ScanEntry& e = m.scan_order[k];
    scan_value(m, w.echo_filtered.data(), w.level.data(), e.index, e.sample, e.steps, e.tb, e.ts,
               e.pixel, out);
  }
}

/// `count` images, pose n's map maps[n], into out (image n at n·image_bytes).
inline void simulate_images(const ImageModel& base, const IndexMap* maps, size_t count,
                            uint8_t* out, size_t image_bytes) {
  backend::parallel_for(int64_t(count), [&](int64_t n) {
    ImageModel im = base;
    set_pose(im, maps[n]);
    thread_local Scratch scratch;
    simulate_image(im, out + size_t(n) * image_bytes, scratch);
  });
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace simulate_impl
}  // namespace sonoslice
