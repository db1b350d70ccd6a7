// Finishing a reconstruction on CPU threads: the per-voxel code of FinishImpl.h (values, PLUS's
// hole filling), with the hole-filling elements set up as PLUS sets them up; only the holes an
// element may fill (FillCandidates.h) are visited voxel by voxel.
#include "Finish.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "../backend/Convert.h"
#include "../backend/ParallelFor.h"
#include "CompoundBackends.h"
#include "FillCandidates.h"

namespace sonoslice {
namespace compound_impl {
namespace {

FillElement::Type element_type(HoleFillingKernel::Type t) {
  switch (t) {
    case HoleFillingKernel::NearestNeighbor:
      return FillElement::NearestNeighbor;
    case HoleFillingKernel::Gaussian:
      return FillElement::Gaussian;
    case HoleFillingKernel::GaussianAccumulation:
      return FillElement::GaussianAccumulation;
    case HoleFillingKernel::DistanceWeightInverse:
      return FillElement::DistanceWeightInverse;
    case HoleFillingKernel::Stick:
      break;
  }
  return FillElement::Stick;
}

// allocateGaussianMatrix / allocateDistanceWeightInverse, expression by expression: float
// variables where PLUS has them, so that the weights are PLUS's to the last bit.
std::vector<float> plus_kernel(const HoleFillingKernel& k) {
  const int size = k.size;
  const float range = float((size - 1) / 2.);
  std::vector<float> kernel(size_t(size) * size * size);
  const float stdev = float(k.stdev);
  const double pi = 3.1415926535897932384626433832795;
  const float divisor = float(stdev * stdev * 2.0);
  const float term_divisor = float(std::pow(2 * pi, 3. / 2) * std::pow(double(stdev), 3));
  size_t index = 0;
  for (int z = 0; z < size; ++z)
    for (int y = 0; y < size; ++y)
      for (int x = 0; x < size; ++x) {
        if (k.type == HoleFillingKernel::DistanceWeightInverse) {
          const float dx = float(x) - range, dy = float(y) - range, dz = float(z) - range;
          const float distance = std::sqrt(dx * dx + dy * dy + dz * dz);
          kernel[index++] = distance != 0.f ? std::fabs(1.0f / distance) : 0.0f;
        } else {
          const double x_exp = std::pow(double(x) - range, 2) / divisor;
          const double y_exp = std::pow(double(y) - range, 2) / divisor;
          const double z_exp = std::pow(double(z) - range, 2) / divisor;
          kernel[index++] = float(double(1.0f / term_divisor) * std::exp(-(x_exp + y_exp + z_exp)));
        }
      }
  return kernel;
}

template <typename TOut>
void finish_typed(const FinishInput& in, TOut* out) {
  const AccumulatorView& g = in.g;
  if (in.element_count == 0) {  // the values alone: the vectorised pass of each instruction set
    const CpuIsa isa = cpu_kernel_isa();
    backend::parallel_for_chunks(int64_t(g.nx) * g.ny * g.nz, int64_t(1) << 16,
                                 [&](int64_t, int64_t b, int64_t e) {
                                   finish_values_cpu(isa, in, PixelTypeOf<TOut>::value, b, e, out);
                                 });
    return;
  }
  // With hole filling: voxel by voxel only where a voxel is known or an element may fill it.
  const BitVolume known = find_known(in);
  const FillCandidates candidates = find_fill_candidates(in, known);
  backend::parallel_for(g.nz, [&](int64_t z64) {
    const int z = int(z64);
    for (int y = 0; y < g.ny; ++y) {
      const int64_t base = g.offset(0, y, z);
      const uint64_t *known_bits = known.row(y, z), *fillable = candidates.any.row(y, z);
      for (int w = 0; w < known.words; ++w) {
        const int x0 = 64 * w, x1 = std::min(g.nx, x0 + 64);
        uint64_t visit = known_bits[w] | fillable[w];
        if (!visit) {  // 64 holes no element can fill
          std::fill(out + base + x0, out + base + x1, TOut(0));
          continue;
        }
        for (int x = x0; x < x1; ++x, visit >>= 1)
          out[base + x] =
              visit & 1
                  ? finished_voxel<TOut>(
                        in, x, y, z,
                        [&](int e) { return candidates.per_element[size_t(e)].test(x, y, z); })
                  : TOut(0);
      }
    }
  });
}

}  // namespace

FillSetup setup_fill_elements(const std::vector<HoleFillingKernel>& kernels) {
  FillSetup setup;
  for (const HoleFillingKernel& k : kernels) {
    FillElement e;
    e.type = element_type(k.type);
    e.size = k.size;
    e.range = (k.size - 1) / 2;
    e.min_ratio = double(float(k.minimum_known_ratio));  // PLUS holds it as a float
    e.stick_length_limit = k.stick_length_limit;
    e.sticks_to_use = k.sticks_to_use;
    setup.elements.push_back(e);
    setup.kernels.push_back(k.type == HoleFillingKernel::Stick ||
                                    k.type == HoleFillingKernel::NearestNeighbor
                                ? std::vector<float>{}
                                : plus_kernel(k));
  }
  for (size_t k = 0; k < setup.elements.size(); ++k)
    setup.elements[k].kernel = setup.kernels[k].empty() ? nullptr : setup.kernels[k].data();
  return setup;
}

void finish_volume(const AccumulatorView& grid, Mode mode,
                   const std::vector<HoleFillingKernel>& kernels, PixelType out_type, void* out) {
  const FillSetup setup = setup_fill_elements(kernels);
  FinishInput in;
  in.g = grid;
  in.mode = mode;
  in.elements = setup.elements.data();
  in.element_count = int(setup.elements.size());
  visit_pixel_type(out_type, [&](auto zero) {
    using T = decltype(zero);
    finish_typed<T>(in, static_cast<T*>(out));
  });
}

}  // namespace compound_impl
}  // namespace sonoslice
