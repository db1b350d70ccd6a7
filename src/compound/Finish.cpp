// Finishing a reconstruction: value = sum / weight (mean, latest) or the maximum, then hole
// filling with PLUS's elements. Sources are always the voxels samples reached, so the order in
// which holes are visited does not matter and any thread count gives the same volume.
#include "Finish.h"

#include <algorithm>
#include <cmath>

#include "../backend/Convert.h"
#include "../backend/ParallelFor.h"

namespace sonoslice {
namespace compound_impl {
namespace {

/// Read access to the reached ("known") voxels.
struct Known {
  const AccumulatorView& g;
  Mode mode;
  bool is_known(int64_t i) const { return g.cells[i].weight > 0.f; }
  double value(int64_t i) const {
    const Accumulator& a = g.cells[i];
    return mode == Mode::Max ? double(a.value) : double(a.value) / double(a.weight);
  }
};

/// One element, with its weights precomputed.
struct Element {
  HoleFillingKernel k;
  int r = 1;                   // cube radius (voxels)
  std::vector<double> weight;  // (2r+1)³, z slowest
};

// Weighted mean over the cube: Gaussian, Gaussian × splat weight, inverse distance.
bool fill_weighted(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  const int r = e.r, n = 2 * r + 1;
  double sum = 0, wsum = 0;
  int known = 0;
  for (int dz = -r; dz <= r; ++dz)
    for (int dy = -r; dy <= r; ++dy)
      for (int dx = -r; dx <= r; ++dx) {
        if (!kn.g.contains(x + dx, y + dy, z + dz)) continue;
        const int64_t i = kn.g.offset(x + dx, y + dy, z + dz);
        if (!kn.is_known(i)) continue;
        ++known;
        double w = e.weight[((dz + r) * n + (dy + r)) * n + (dx + r)];
        if (e.k.type == HoleFillingKernel::GaussianAccumulation) w *= kn.g.cells[i].weight;
        sum += w * kn.value(i);
        wsum += w;
      }
  if (!(double(known) / (double(n) * n * n) > e.k.minimum_known_ratio) || !(wsum > 0)) return false;
  *result = sum / wsum;
  return true;
}

// Mean of the known voxels of the smallest cube (radius 1 .. r) that has any.
bool fill_nearest(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  for (int radius = 1; radius <= e.r; ++radius) {
    double sum = 0;
    int known = 0;
    for (int dz = -radius; dz <= radius; ++dz)
      for (int dy = -radius; dy <= radius; ++dy)
        for (int dx = -radius; dx <= radius; ++dx) {
          if (!kn.g.contains(x + dx, y + dy, z + dz)) continue;
          const int64_t i = kn.g.offset(x + dx, y + dy, z + dz);
          if (kn.is_known(i)) {
            ++known;
            sum += kn.value(i);
          }
        }
    if (known == 0) continue;
    const double n = 2.0 * radius + 1;
    if (!(known / (n * n * n) > e.k.minimum_known_ratio)) return false;
    *result = sum / known;
    return true;
  }
  return false;
}

// The 13 line directions through a voxel (each line counted once).
constexpr int kStickDirections[13][3] = {{1, 0, 0},  {0, 1, 0},  {0, 0, 1},  {1, 1, 0},  {1, 0, 1},
                                         {0, 1, 1},  {1, -1, 0}, {1, 0, -1}, {0, 1, -1}, {1, 1, 1},
                                         {-1, 1, 1}, {1, -1, 1}, {-1, -1, 1}};

// Walks from (x, y, z) along d for at most `limit` steps; the steps to the first known voxel.
int walk_to_known(const Known& kn, int x, int y, int z, const int* d, int limit, int64_t* found) {
  for (int j = 1; j <= limit; ++j) {
    const int px = x + j * d[0], py = y + j * d[1], pz = z + j * d[2];
    if (!kn.g.contains(px, py, pz)) return 0;
    const int64_t i = kn.g.offset(px, py, pz);
    if (kn.is_known(i)) {
      *found = i;
      return j;
    }
  }
  return 0;
}

// Sticks: lines through the hole with a known voxel at each end, at most stick_length_limit
// voxels long (ends included). The value is interpolated linearly along each stick; the
// shortest sticks (physical length) are averaged with weights 1 / length.
bool fill_stick(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  double value[13], score[13];
  bool valid[13];
  int count = 0;
  const int limit = e.k.stick_length_limit;
  for (int s = 0; s < 13; ++s) {
    valid[s] = false;
    const int* d = kStickDirections[s];
    int64_t fwd_i = 0, back_i = 0;
    const int fwd = walk_to_known(kn, x, y, z, d, limit - 2, &fwd_i);
    if (fwd == 0) continue;
    const int back_d[3] = {-d[0], -d[1], -d[2]};
    const int back = walk_to_known(kn, x, y, z, back_d, limit - 1 - fwd, &back_i);
    if (back == 0) continue;
    // The hole is `back` steps from the back end and `fwd` steps from the front end.
    value[s] = (kn.value(back_i) * fwd + kn.value(fwd_i) * back) / double(fwd + back);
    const double step = std::sqrt(double(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]));
    score[s] = 1.0 / ((fwd + back) * step);
    valid[s] = true;
    ++count;
  }
  if (count == 0) return false;
  // The best `sticks_to_use` scores (ties at the last place all taken), weighted by score.
  double sum = 0, wsum = 0;
  int used = 0;
  while (used < e.k.sticks_to_use) {
    double best = 0;
    for (int s = 0; s < 13; ++s)
      if (valid[s]) best = std::max(best, score[s]);
    if (best <= 0) break;
    for (int s = 0; s < 13; ++s)
      if (valid[s] && score[s] == best) {
        sum += score[s] * value[s];
        wsum += score[s];
        valid[s] = false;
        ++used;
      }
  }
  *result = sum / wsum;
  return true;
}

bool fill(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  switch (e.k.type) {
    case HoleFillingKernel::NearestNeighbor:
      return fill_nearest(kn, e, x, y, z, result);
    case HoleFillingKernel::Stick:
      return fill_stick(kn, e, x, y, z, result);
    case HoleFillingKernel::Gaussian:
    case HoleFillingKernel::GaussianAccumulation:
    case HoleFillingKernel::DistanceWeightInverse:
      return fill_weighted(kn, e, x, y, z, result);
  }
  return false;
}

Element make_element(const HoleFillingKernel& k) {
  Element e;
  e.k = k;
  e.r = std::max(1, (k.size - 1) / 2);
  const int n = 2 * e.r + 1;
  e.weight.resize(size_t(n) * n * n);
  for (int z = -e.r; z <= e.r; ++z)
    for (int y = -e.r; y <= e.r; ++y)
      for (int x = -e.r; x <= e.r; ++x) {
        const double d2 = double(x * x + y * y + z * z);
        double w = 0;
        if (k.type == HoleFillingKernel::DistanceWeightInverse)
          w = d2 > 0 ? 1.0 / std::sqrt(d2) : 0.0;
        else
          w = std::exp(-d2 / (2 * k.stdev * k.stdev));
        e.weight[((z + e.r) * n + (y + e.r)) * n + (x + e.r)] = w;
      }
  return e;
}

/// Per (y, z) row, the x range [lo, hi] within which a hole may have known voxels within
/// `reach` voxels: the known range of every row within `reach` in y and z, widened by `reach`.
/// Holes outside it (most of a big, sparse grid) are skipped without looking at neighbours.
std::vector<std::pair<int, int>> reachable_ranges(const Known& kn, int reach) {
  const AccumulatorView& g = kn.g;
  const std::pair<int, int> none{1 << 30, -(1 << 30)};
  std::vector<std::pair<int, int>> rows(size_t(g.ny) * g.nz, none), tmp(rows.size(), none);
  backend::parallel_for(g.nz, [&](int64_t z) {
    for (int y = 0; y < g.ny; ++y) {
      auto& r = rows[size_t(z) * g.ny + y];
      const int64_t base = kn.g.offset(0, y, int(z));
      for (int x = 0; x < g.nx; ++x)
        if (kn.is_known(base + x)) {
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
void finish_typed(const AccumulatorView& g, Mode mode,
                  const std::vector<HoleFillingKernel>& kernels, TOut* out) {
  const Known kn{g, mode};
  std::vector<Element> elements;
  int reach = 0;
  for (const auto& k : kernels) {
    elements.push_back(make_element(k));
    reach = std::max(reach, k.reach());
  }
  std::vector<std::pair<int, int>> ranges;
  if (!elements.empty()) ranges = reachable_ranges(kn, reach);
  backend::parallel_for(g.nz, [&](int64_t z64) {
    const int z = int(z64);
    for (int y = 0; y < g.ny; ++y) {
      const int64_t base = kn.g.offset(0, y, z);
      const std::pair<int, int> range =
          elements.empty() ? std::pair<int, int>{1, 0} : ranges[size_t(z) * g.ny + y];
      for (int x = 0; x < g.nx; ++x) {
        const int64_t i = base + x;
        double v = 0;
        if (kn.is_known(i)) {
          v = kn.value(i);
        } else if (x >= range.first && x <= range.second) {
          for (const Element& e : elements)
            if (fill(kn, e, x, y, z, &v)) break;
        }
        out[i] = backend::saturate_cast<TOut>(v);
      }
    }
  });
}

}  // namespace

void finish_volume(const AccumulatorView& grid, Mode mode,
                   const std::vector<HoleFillingKernel>& kernels, PixelType out_type, void* out) {
  visit_pixel_type(out_type, [&](auto zero) {
    using T = decltype(zero);
    finish_typed<T>(grid, mode, kernels, static_cast<T*>(out));
  });
}

}  // namespace compound_impl
}  // namespace sonoslice
