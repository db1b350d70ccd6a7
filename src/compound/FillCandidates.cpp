// Which holes each hole-filling element may fill, with whole-grid bit operations
// (FillCandidates.h).
#include "FillCandidates.h"

#include <algorithm>
#include <cstddef>
#include <cstdlib>
#include <utility>

#include "../backend/ParallelFor.h"
#include "sonoslice/backend/Device.h"

namespace sonoslice {
namespace compound_impl {

BitVolume::BitVolume(int nx_, int ny_, int nz_, int max_shift)
    : nx(nx_),
      ny(ny_),
      nz(nz_),
      words((nx_ + 63) / 64),
      pad(std::min(std::max(max_shift, 0), nx_) / 64 + 1),
      bits(size_t(nz_) * slice_words() + 2 * guard(), 0) {}

namespace {

BitVolume like(const BitVolume& v) {
  return BitVolume(v.nx, v.ny, v.nz, 64 * (v.pad - 1));
}

/// The farthest along x any search below reads a row shifted.
int max_row_shift(const FinishInput& in) {
  int shift = 0;
  for (int e = 0; e < in.element_count; ++e) {
    const FillElement& el = in.elements[e];
    shift = std::max(shift, el.type == FillElement::Stick ? el.stick_length_limit : el.range);
  }
  return std::min(shift, in.g.nx);
}

/// Word i of a slice read shifted by `shift` voxels along x: bit x of the result is voxel
/// x + shift (|shift| < 64·pad; the padding reads as zeros).
struct Shift {
  int words, bits;  // shift = 64·words + bits, 0 <= bits < 64
  explicit Shift(int shift)
      : words(shift >= 0 ? shift / 64 : -((63 - shift) / 64)), bits(shift - 64 * words) {}
  uint64_t operator()(const uint64_t* src, std::ptrdiff_t i) const {
    const uint64_t lo = src[i + words], hi = src[i + words + 1];
    return (lo >> bits) | ((hi << 1) << (63 - bits));
  }
};

/// Per word of a slice: all ones on the rows' data words, 0 on their padding.
std::vector<uint64_t> data_words(const BitVolume& v) {
  std::vector<uint64_t> m(v.slice_words(), 0);
  for (int y = 0; y < v.ny; ++y)
    for (int w = 0; w < v.words; ++w) m[size_t(y) * v.stride() + size_t(v.pad + w)] = ~uint64_t(0);
  return m;
}

/// For every word g (counted from slice 0's start, rows and padding) of dst:
/// dst[g] = op(g, s), s = src(p + o) there (0 where p + o is outside the grid, and on the padding
/// by `mask`, data_words()). One loop per slice over its rows and their padding.
template <typename Op>
void shifted_pass(BitVolume& dst, const BitVolume& src, int ox, int oy, int oz,
                  const std::vector<uint64_t>& mask, Op op) {
  const size_t stride = dst.stride(), slice_words = dst.slice_words();
  const Shift shift(ox);
  const bool x_inside = std::abs(ox) < src.nx;
  uint64_t* out = dst.slice(0);
  backend::parallel_for(dst.nz, [&](int64_t z64) {
    const int z = int(z64), sz = z + oz;
    const size_t base = size_t(z) * slice_words;
    // Rows y0 <= y < y1 read source rows y + oy inside the grid; the others read zeros.
    int y0 = std::max(0, -oy), y1 = std::min(dst.ny, dst.ny - oy);
    if (sz < 0 || sz >= src.nz || !x_inside || y0 >= y1) y0 = y1 = 0;
    for (size_t i = 0; i < size_t(y0) * stride; ++i) out[base + i] = op(base + i, uint64_t(0));
    if (y0 < y1) {
      // Word i of this slice reads word i + oy·stride of the source slice (from its rows and
      // their padding, or the guard words before the first).
      const uint64_t* s = src.slice(sz);
      const std::ptrdiff_t rows = std::ptrdiff_t(oy) * std::ptrdiff_t(stride);
      for (size_t i = size_t(y0) * stride; i < size_t(y1) * stride; ++i)
        out[base + i] = op(base + i, shift(s, std::ptrdiff_t(i) + rows) & mask[i]);
    }
    for (size_t i = size_t(y1) * stride; i < slice_words; ++i)
      out[base + i] = op(base + i, uint64_t(0));
  });
}

/// dst(p) = a(p) | src(p + o) (a null: 0). dst may be a, not src.
void or_shifted(BitVolume& dst, const BitVolume* a, const BitVolume& src, int ox, int oy, int oz,
                const std::vector<uint64_t>& mask) {
  if (!a) {
    shifted_pass(dst, src, ox, oy, oz, mask, [](size_t, uint64_t s) { return s; });
    return;
  }
  const uint64_t* A = a->slice(0);
  shifted_pass(dst, src, ox, oy, oz, mask, [A](size_t g, uint64_t s) { return A[g] | s; });
}

/// A_k(p), the union of known(p + j·d) for j = 1..k, built by doubling: A_1, then
/// A_2i(p) = A_i(p) | A_i(p + i·d) up to the largest power of two j <= k in `power`; then
/// A_k(p) = A_j(p) | A_j(p + (k − j)·d), the union of two overlapping runs, which `last`
/// combines (it is given the word g of A_j and of A_j shifted). Doubling reads A_i only
/// further along d, where a walk that left the grid stays outside it, so the grid's zeros
/// outside are right. `half` is scratch.
template <typename Last>
void any_within(const BitVolume& known, const int* d, int k, BitVolume& power, BitVolume& half,
                BitVolume& dst, const std::vector<uint64_t>& mask, Last last) {
  or_shifted(power, nullptr, known, d[0], d[1], d[2], mask);
  int j = 1;
  for (; 2 * j <= k; j *= 2) {
    std::swap(half.bits, power.bits);
    or_shifted(power, &half, half, j * d[0], j * d[1], j * d[2], mask);
  }
  const int r = k - j;
  const uint64_t* P = power.slice(0);
  shifted_pass(dst, power, r * d[0], r * d[1], r * d[2], mask,
               [&](size_t g, uint64_t shifted) { return last(g, P[g] | shifted); });
}

/// The holes a stick of at most `limit` voxels may fill: along some direction d a known voxel
/// within L − 1 steps forward (A_L−1 along d) and one within L − 2 steps backward (A_L−2 along
/// −d). The 13 directions are shared among a few tasks, each running its directions' passes on
/// one thread with its own buffers: a pass over a small grid is too short to share among threads
/// (waking them cost more than the pass), and a few tasks bound the buffers' memory.
BitVolume stick_candidates(const BitVolume& known, int limit) {
  const std::vector<uint64_t> mask = data_words(known);
  const int longest = std::max({known.nx, known.ny, known.nz});  // farther is outside the grid
  const int m = std::min(limit - 1, longest), n = std::min(limit - 2, longest);
  const int tasks = std::max(1, std::min({cpu_threads(), kStickDirections, 4}));
  std::vector<BitVolume> holes(size_t(tasks), like(known));
  if (n < 1) return std::move(holes[0]);  // no stick fits
  backend::parallel_for(tasks, [&](int64_t t) {
    BitVolume power = like(known), half = like(known), forward = like(known);
    BitVolume& mine = holes[size_t(t)];
    const uint64_t *F = forward.slice(0), *H = mine.slice(0);
    for (int s = int(t); s < kStickDirections; s += tasks) {  // the passes run on this thread
      int d[3], minus_d[3];
      stick_direction(s, d);
      for (int a = 0; a < 3; ++a) minus_d[a] = -d[a];
      any_within(known, d, m, power, half, forward, mask, [](size_t, uint64_t a) { return a; });
      // holes(p) |= forward(p) & A_n(p) along −d
      any_within(known, minus_d, n, power, half, mine, mask,
                 [F, H](size_t g, uint64_t back) { return H[g] | (F[g] & back); });
    }
  });
  uint64_t* all = holes[0].slice(0);
  backend::parallel_for(known.nz, [&](int64_t z) {
    const size_t words = known.slice_words(), base = size_t(z) * words;
    for (int t = 1; t < tasks; ++t) {
      const uint64_t* other = holes[size_t(t)].slice(0);
      for (size_t g = base; g < base + words; ++g) all[g] |= other[g];
    }
  });
  return std::move(holes[0]);
}

BitVolume cube_candidates(const BitVolume& known, int range) {
  const std::vector<uint64_t> mask = data_words(known);
  BitVolume along_x = like(known), along_y = like(known), holes = like(known);
  for (int dx = -range; dx <= range; ++dx) or_shifted(along_x, &along_x, known, dx, 0, 0, mask);
  for (int dy = -range; dy <= range; ++dy) or_shifted(along_y, &along_y, along_x, 0, dy, 0, mask);
  for (int dz = -range; dz <= range; ++dz) or_shifted(holes, &holes, along_y, 0, 0, dz, mask);
  return holes;
}

}  // namespace

BitVolume find_known(const FinishInput& in) {
  const AccumulatorView& g = in.g;
  BitVolume k(g.nx, g.ny, g.nz, max_row_shift(in));
  backend::parallel_for(g.nz, [&](int64_t z) {
    for (int y = 0; y < g.ny; ++y) {
      const Accumulator* __restrict cells = g.cells + g.offset(0, y, int(z));
      uint64_t* __restrict row = k.row(y, int(z));
      for (int w = 0; w < k.words; ++w) {
        const int n = std::min(64, g.nx - 64 * w);
        uint64_t word = 0;
        for (int b = 0; b < n; ++b)
          word |= uint64_t(reached_for_filling(cells[64 * w + b].weight)) << b;
        row[w] = word;
      }
    }
  });
  return k;
}

FillCandidates find_fill_candidates(const FinishInput& in, const BitVolume& known) {
  FillCandidates c;
  c.any = like(known);
  for (int e = 0; e < in.element_count; ++e) {
    const FillElement& el = in.elements[e];
    c.per_element.push_back(el.type == FillElement::Stick
                                ? stick_candidates(known, el.stick_length_limit)
                                : cube_candidates(known, el.range));
    const BitVolume& mine = c.per_element.back();
    const uint64_t *M = mine.slice(0), *K = known.slice(0);
    uint64_t* any = c.any.slice(0);
    backend::parallel_for(c.any.nz, [&](int64_t z) {
      const size_t n = c.any.slice_words(), base = size_t(z) * n;
      for (size_t g = base; g < base + n; ++g) any[g] |= M[g] & ~K[g];
    });
  }
  return c;
}

}  // namespace compound_impl
}  // namespace sonoslice
