// Finishing a reconstruction: value = sum / weight (mean, latest) or the maximum, then hole
// filling with PLUS's elements and PLUS's rules (IGSIO's vtkIGSIOFillHolesInVolume; the
// differences that remain are in docs/compounding.md). Sources are always the voxels samples
// reached, never filled ones (as in PLUS), so the order in which holes are visited does not
// matter and any thread count gives the same volume.
#include "Finish.h"

#include <algorithm>
#include <cmath>
#include <type_traits>

#include "../backend/Convert.h"
#include "../backend/ParallelFor.h"

namespace sonoslice {
namespace compound_impl {
namespace {

/// PLUS's accumulation buffer for a voxel of splat weight w: 256 per unit of weight, rounded,
/// saturating at 65535 (vtkIGSIOPasteSliceIntoVolume: ACCUMULATION_MULTIPLIER, _MAXIMUM).
double plus_accumulation(float w) {
  return std::min(65535.0, std::floor(double(w) * 256.0 + 0.5));
}

/// Read access to the reached ("known") voxels. With hole filling, a voxel is known exactly when
/// PLUS's accumulation buffer would not be 0 there (vtkIGSIOFillHolesInVolume's test): a voxel
/// reached only by linear splat weights summing to less than 1/512 is a hole.
struct Known {
  const AccumulatorView& g;
  Mode mode;
  bool plus_holes;
  bool is_known(int64_t i) const {
    const float w = g.cells[i].weight;
    return plus_holes ? plus_accumulation(w) != 0 : w > 0.f;
  }
  double value(int64_t i) const {
    const Accumulator& a = g.cells[i];
    return mode == Mode::Max ? double(a.value) : double(a.value) / double(a.weight);
  }
  double accumulation(int64_t i) const { return plus_accumulation(g.cells[i].weight); }
};

/// One element, set up as vtkIGSIOFillHolesInVolume sets up its FillHolesInVolumeElement: the
/// ratio is held as a float, the kernels are float arrays computed with PLUS's expressions.
/// `as_output` converts a value to the output type and back, as PLUS's (T) casts do (integers:
/// truncated toward zero; float: rounded to float).
struct Element {
  HoleFillingKernel k;
  int size = 3, range = 1;
  double min_ratio = 0;       // (double)(float)minimum_known_ratio, as PLUS compares it
  std::vector<float> kernel;  // size³, index size·size·z + size·y + x, as PLUS's
  double (*as_output)(double) = nullptr;
};

// The cube's known voxels in PLUS's order (x outer, then y, then z), inside the grid.
template <typename F>
int for_known_in_cube(const Known& kn, int x, int y, int z, int range, F&& f) {
  int known = 0;
  for (int xx = x - range; xx <= x + range; ++xx)
    for (int yy = y - range; yy <= y + range; ++yy)
      for (int zz = z - range; zz <= z + range; ++zz) {
        if (!kn.g.contains(xx, yy, zz)) continue;
        const int64_t i = kn.g.offset(xx, yy, zz);
        if (!kn.is_known(i)) continue;
        ++known;
        f(i, xx - (x - range), yy - (y - range), zz - (z - range));
      }
  return known;
}

// The ratio test of every element but the stick: known voxels over the whole size³ cube (voxels
// outside the grid and the hole itself count in the denominator), strictly greater.
bool enough_known(const Element& e, int known) {
  return double(known) / double(e.size * e.size * e.size) > e.min_ratio;
}

// Gaussian, Gaussian × accumulation, inverse distance: the kernel-weighted mean of the known
// voxels of the cube (applyGaussian, applyGaussianAccumulation, applyDistanceWeightInverse).
bool fill_weighted(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  double sum = 0, wsum = 0;
  const int known = for_known_in_cube(kn, x, y, z, e.range, [&](int64_t i, int kx, int ky, int kz) {
    const float g = e.kernel[size_t((kz * e.size + ky) * e.size + kx)];
    // PLUS: `double weight = currentAccumulation * kernel[...]`, an int times a float: float.
    const double w = e.k.type == HoleFillingKernel::GaussianAccumulation
                         ? double(float(kn.accumulation(i)) * g)
                         : double(g);
    sum += kn.value(i) * w;
    wsum += w;
  });
  if (wsum == 0 || !enough_known(e, known)) return false;
  *result = e.as_output(sum / wsum);
  return true;
}

// Nearest neighbour: the plain mean of the known voxels in the smallest cube (radius 1, 2, ...,
// (size-1)/2) that has any; the ratio test counts those against the whole size³ cube.
bool fill_nearest(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  for (int radius = 1; radius <= e.range; ++radius) {
    double sum = 0;
    const int known = for_known_in_cube(kn, x, y, z, radius,
                                        [&](int64_t i, int, int, int) { sum += kn.value(i); });
    if (known == 0) continue;
    if (!enough_known(e, known)) return false;
    *result = e.as_output(sum / known);
    return true;
  }
  return false;
}

// The 13 line directions through a voxel, in PLUS's order (allocateSticks).
constexpr int kStickDirections[13][3] = {{1, 0, 0},  {0, 1, 0},  {0, 0, 1},  {1, 1, 0},  {1, 0, 1},
                                         {0, 1, 1},  {1, -1, 0}, {1, 0, -1}, {0, 1, -1}, {1, 1, 1},
                                         {-1, 1, 1}, {1, -1, 1}, {-1, -1, 1}};

// Walks from (x, y, z) along d for at most `limit` steps; the steps to the first known voxel
// (0: none before the limit or the grid's edge).
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

// Sticks (applySticks): for each direction, the first known voxel forward (at most L - 1 steps)
// and backward (at most L - 1 - forward steps), so a stick spans at most L voxels, ends included.
// A stick's value weights its forward end by (back + 1) / (forward + back + 1), PLUS's formula
// (not the linear interpolation (back / (forward + back)) it approximates), and is converted to
// the output type; its score is 1 / ((forward + back + 1) · |d|). The best scores are taken
// until sticks_to_use are used, every stick tied at a best score with it, and averaged weighted
// by score.
bool fill_stick(const Known& kn, const Element& e, int x, int y, int z, double* result) {
  double value[13], score[13];
  const int limit = e.k.stick_length_limit;
  for (int s = 0; s < 13; ++s) {
    score[s] = 0;
    const int* d = kStickDirections[s];
    int64_t fwd_i = 0, back_i = 0;
    const int fwd = walk_to_known(kn, x, y, z, d, limit - 1, &fwd_i);
    if (fwd == 0) continue;
    const int back_d[3] = {-d[0], -d[1], -d[2]};
    const int back = walk_to_known(kn, x, y, z, back_d, limit - 1 - fwd, &back_i);
    if (back == 0) continue;
    const double total = double(fwd + back + 1);
    const double weight_fwd = double(back + 1) / total;
    const double weight_back = 1.0 - weight_fwd;
    score[s] = 1.0 / (total * std::sqrt(double(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])));
    value[s] = e.as_output(weight_back * kn.value(back_i) + weight_fwd * kn.value(fwd_i));
  }
  double sum = 0, wsum = 0;
  int used = 0;
  while (used < e.k.sticks_to_use) {
    double best = 0;
    for (int s = 0; s < 13; ++s)
      if (score[s] > best) best = score[s];
    if (best == 0) break;
    for (int s = 0; s < 13; ++s)
      if (score[s] == best) {
        sum += value[s] * score[s];
        wsum += score[s];
        ++used;
        score[s] = 0;
      }
  }
  if (wsum == 0) return false;
  *result = e.as_output(sum / wsum);
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

/// A value converted to the output type T as a C cast does it (integers: toward zero, saturated
/// here where PLUS's cast would be undefined) and back to double.
template <typename T>
double as_output_type(double v) {
  if constexpr (std::is_floating_point<T>::value)
    return double(static_cast<T>(v));
  else
    return double(backend::saturate_cast<T>(std::trunc(v)));
}

template <typename T>
Element make_element(const HoleFillingKernel& k) {
  Element e;
  e.k = k;
  e.size = k.size;
  e.range = (k.size - 1) / 2;
  e.min_ratio = double(float(k.minimum_known_ratio));
  e.as_output = &as_output_type<T>;
  if (k.type == HoleFillingKernel::Stick || k.type == HoleFillingKernel::NearestNeighbor) return e;
  // allocateGaussianMatrix / allocateDistanceWeightInverse, expression by expression: float
  // variables where PLUS has them, so that the weights are PLUS's to the last bit.
  const int size = e.size;
  const float range = float((size - 1) / 2.);
  e.kernel.resize(size_t(size) * size * size);
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
          e.kernel[index++] = distance != 0.f ? std::fabs(1.0f / distance) : 0.0f;
        } else {
          const double x_exp = std::pow(double(x) - range, 2) / divisor;
          const double y_exp = std::pow(double(y) - range, 2) / divisor;
          const double z_exp = std::pow(double(z) - range, 2) / divisor;
          e.kernel[index++] =
              float(double(1.0f / term_divisor) * std::exp(-(x_exp + y_exp + z_exp)));
        }
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
  const Known kn{g, mode, !kernels.empty()};
  std::vector<Element> elements;
  int reach = 0;
  for (const auto& k : kernels) {
    elements.push_back(make_element<TOut>(k));
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
          // Unfilled holes stay 0 (PLUS writes 0 when no element can fill).
          for (const Element& e : elements)
            if (fill(kn, e, x, y, z, &v)) break;
        }
        // Filled values are already in the output type (as_output): this only rounds known ones.
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
