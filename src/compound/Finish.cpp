// Finishing a reconstruction on CPU threads: the per-voxel code of FinishImpl.h (values, PLUS's
// hole filling), with the hole-filling elements set up as PLUS sets them up, and a shortcut that
// skips holes with no reached voxel within reach.
#include "Finish.h"

#include <algorithm>
#include <cmath>
#include <type_traits>

#include "../backend/Convert.h"
#include "../backend/ParallelFor.h"

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

/// Per (y, z) row, the x range [lo, hi] within which a hole may have known voxels within
/// `reach` voxels: the known range of every row within `reach` in y and z, widened by `reach`.
/// Holes outside it (most of a big, sparse grid) are skipped without looking at neighbours.
std::vector<std::pair<int, int>> reachable_ranges(const FinishInput& in, int reach) {
  const AccumulatorView& g = in.g;
  const std::pair<int, int> none{1 << 30, -(1 << 30)};
  std::vector<std::pair<int, int>> rows(size_t(g.ny) * g.nz, none), tmp(rows.size(), none);
  backend::parallel_for(g.nz, [&](int64_t z) {
    for (int y = 0; y < g.ny; ++y) {
      auto& r = rows[size_t(z) * g.ny + y];
      const int64_t base = g.offset(0, y, int(z));
      for (int x = 0; x < g.nx; ++x)
        if (is_known(in, base + x)) {
          r.first = std::min(r.first, x);
          r.second = x;
        }
    }
  });
  const auto merge = [](std::pair<int, int>& a, const std::pair<int, int>& b) {
    a.first = std::min(a.first, b.first);
    a.second = std::max(a.second, b.second);
  };
  backend::parallel_for(g.nz, [&](int64_t z) {  // along y
    for (int y = 0; y < g.ny; ++y)
      for (int d = std::max(0, y - reach); d <= std::min(g.ny - 1, y + reach); ++d)
        merge(tmp[size_t(z) * g.ny + y], rows[size_t(z) * g.ny + d]);
  });
  backend::parallel_for(g.nz, [&](int64_t z) {  // along z
    for (int y = 0; y < g.ny; ++y) {
      auto& r = rows[size_t(z) * g.ny + y];
      r = none;
      for (int d = std::max<int>(0, int(z) - reach); d <= std::min<int>(g.nz - 1, int(z) + reach);
           ++d)
        merge(r, tmp[size_t(d) * g.ny + y]);
      r.first -= reach;
      r.second += reach;
    }
  });
  return rows;
}

template <typename TOut>
void finish_typed(const FinishInput& in, int reach, TOut* out) {
  const AccumulatorView& g = in.g;
  std::vector<std::pair<int, int>> ranges;
  if (in.element_count > 0) ranges = reachable_ranges(in, reach);
  backend::parallel_for(g.nz, [&](int64_t z64) {
    const int z = int(z64);
    for (int y = 0; y < g.ny; ++y) {
      const std::pair<int, int> range =
          in.element_count == 0 ? std::pair<int, int>{1, 0} : ranges[size_t(z) * g.ny + y];
      const int64_t base = g.offset(0, y, z);
      for (int x = 0; x < g.nx; ++x)
        out[base + x] = finished_voxel<TOut>(in, x, y, z, x >= range.first && x <= range.second);
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

int fill_reach(const std::vector<HoleFillingKernel>& kernels) {
  int reach = 0;
  for (const auto& k : kernels) reach = std::max(reach, k.reach());
  return reach;
}

void finish_volume(const AccumulatorView& grid, Mode mode,
                   const std::vector<HoleFillingKernel>& kernels, PixelType out_type, void* out) {
  const FillSetup setup = setup_fill_elements(kernels);
  FinishInput in;
  in.g = grid;
  in.mode = mode;
  in.elements = setup.elements.data();
  in.element_count = int(setup.elements.size());
  const int reach = fill_reach(kernels);
  visit_pixel_type(out_type, [&](auto zero) {
    using T = decltype(zero);
    finish_typed<T>(in, reach, static_cast<T*>(out));
  });
}

}  // namespace compound_impl
}  // namespace sonoslice
