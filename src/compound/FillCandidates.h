#pragma once
// Internal: which holes each hole-filling element may fill, found for the whole grid at once with
// bit operations (64 voxels per word), so that the CPU driver visits voxel by voxel only the holes
// an element can fill. Most holes of a sparse sweep have no known voxel within any element's
// reach; PLUS visits them all.
#include <cstdint>
#include <vector>

#include "FinishImpl.h"

namespace sonoslice {
namespace compound_impl {

/// A set of voxels as bits: per (y, z) one row of `words` 64-bit words, x fastest, the rows of a
/// slice one after the other (a pass over a slice is one loop) with `pad` zero words between
/// them, so that a row read shifted by up to 64·(pad − 1) voxels needs no bounds checks.
/// Bits past nx in a row's last word may be set by shifted operations; they are never read as
/// voxels. `guard` more zero words before and after the whole let a shifted read of the first or
/// last row's padding stay in the buffer.
struct BitVolume {
  int nx = 0, ny = 0, nz = 0, words = 0, pad = 0;
  std::vector<uint64_t> bits;

  BitVolume() = default;
  BitVolume(int nx, int ny, int nz, int max_shift);
  size_t stride() const { return size_t(words + pad); }
  size_t slice_words() const { return size_t(ny) * stride(); }
  size_t guard() const { return size_t(2 * pad + 1); }
  const uint64_t* slice(int z) const { return bits.data() + guard() + size_t(z) * slice_words(); }
  uint64_t* slice(int z) { return bits.data() + guard() + size_t(z) * slice_words(); }
  const uint64_t* row(int y, int z) const { return slice(z) + size_t(y) * stride() + pad; }
  uint64_t* row(int y, int z) { return slice(z) + size_t(y) * stride() + pad; }
  bool test(int x, int y, int z) const { return (row(y, z)[x >> 6] >> (x & 63)) & 1; }
};

/// The known voxels (is_known, with hole filling) as bits.
BitVolume find_known(const FinishInput& in);

/// Per element, a superset of the holes it fills: a hole is left out only where the element
/// surely cannot fill it.
/// - Cube elements (Gaussian, Gaussian × accumulation, inverse distance, nearest neighbour): no
///   known voxel in the element's cube.
/// - Sticks of at most L voxels: along no direction a known voxel within L − 1 steps forward
///   and one within L − 2 steps backward (the backward walk has at most L − 1 − forward steps).
struct FillCandidates {
  std::vector<BitVolume> per_element;
  BitVolume any;  // the union over the elements
};
FillCandidates find_fill_candidates(const FinishInput& in, const BitVolume& known);

}  // namespace compound_impl
}  // namespace sonoslice
