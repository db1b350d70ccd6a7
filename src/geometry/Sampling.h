#pragma once
/// @file docs/conventions.md §5, written once: how every capability reads a volume at a
/// continuous voxel index c. The inside test, the trilinear value (alone, or with its gradient
/// along the index axes, or as the eight corners and their weights) and the nearest voxel, as
/// host/device functions for every backend (CPU scalar and AVX2 lanes, CUDA). Slicing,
/// simulation, registration, the differentiable slice and the pose samplers call these; none
/// has its own copy, so they cannot drift apart.
///
/// Two edge rules, both documented in conventions.md §5:
/// - EdgeRule::Clamped, *the* rule (what `slice` makes, ITK's IsInsideBuffer): a sample is inside
///   iff −0.5 ≤ c < n − 0.5 on every axis; its cell is floor(c) with neighbour indices clamped to
///   [0, n − 1], so the outer half voxel repeats the face voxel.
/// - EdgeRule::Interior, registration's variant: a sample is inside iff 0 ≤ c ≤ n − 1 on every
///   axis (and n ≥ 2); its cell is the one whose eight corners are all distinct voxels. In the
///   clamped half-voxel rim the image is flat across the face, so a pixel there would count in a
///   similarity metric but give no pose derivative; registration leaves the rim out so that cost
///   and derivatives come from the same pixels.
#include <cstdint>

#include "../backend/Convert.h"
#include "sonoslice/backend/HostDevice.h"

namespace sonoslice {
namespace geometry {

/// A volume's extent and memory strides (in voxels; x is contiguous), as kernels see it.
struct VolumeView {
  int nx = 0, ny = 0, nz = 0;
  int64_t stride_y = 0;  ///< = nx
  int64_t stride_z = 0;  ///< = nx · ny

  static VolumeView of(int64_t nx, int64_t ny, int64_t nz) {
    return VolumeView{int(nx), int(ny), int(nz), nx, nx * ny};
  }
};

enum class EdgeRule {
  Clamped,  ///< conventions.md §5: −0.5 ≤ c < n − 0.5, neighbours clamped
  Interior  ///< registration: 0 ≤ c ≤ n − 1, whole cells only
};

/// A trilinear cell: the row offsets of its four (y, z) corners, its two x indices and the
/// fractions of c within it. Which voxels these are depends on the edge rule (linear_cell).
/// `Index` is the type of the flat voxel offsets: int64_t for any volume, int32_t where a kernel
/// knows the volume has fewer than 2^31 voxels (on a GPU, 64-bit offset arithmetic costs several
/// instructions per corner).
template <typename Acc, typename Index = int64_t>
struct LinearCell {
  Index r00, r10, r01, r11;  ///< rows (y0, z0), (y1, z0), (y0, z1), (y1, z1)
  int x0, x1;
  Acc fx, fy, fz;
};

// The functions below are compiled once per instruction set (generic, AVX2 + FMA, CUDA).
inline namespace SONOSLICE_KERNEL_ISA {

using backend::lerp;

/// Whether c lies inside the volume under `Rule`. Written so that NaN is outside.
template <EdgeRule Rule = EdgeRule::Clamped, typename Acc>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE bool inside(const VolumeView& g, Acc cx, Acc cy, Acc cz) {
  if constexpr (Rule == EdgeRule::Clamped) {
    return cx >= Acc(-0.5) && cx < Acc(g.nx) - Acc(0.5) && cy >= Acc(-0.5) &&
           cy < Acc(g.ny) - Acc(0.5) && cz >= Acc(-0.5) && cz < Acc(g.nz) - Acc(0.5);
  } else {
    return g.nx > 1 && g.ny > 1 && g.nz > 1 && cx >= Acc(0) && cy >= Acc(0) && cz >= Acc(0) &&
           cx <= Acc(g.nx - 1) && cy <= Acc(g.ny - 1) && cz <= Acc(g.nz - 1);
  }
}

/// Trilinear blend of a cell's eight corners v[x][y][z] at fractions (fx, fy, fz): the one
/// formula (lerp along x, then y, then z). A template over the lane type: float or double
/// scalars, or eight AVX2 lanes in the slicing kernel's fast path.
template <typename F>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE F trilinear(F fx, F fy, F fz, F v000, F v100, F v010, F v110,
                                                   F v001, F v101, F v011, F v111) {
  const F c00 = lerp(v000, v100, fx), c10 = lerp(v010, v110, fx);
  const F c01 = lerp(v001, v101, fx), c11 = lerp(v011, v111, fx);
  return lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz);
}

/// The cell and fractions of c, which must be inside<Rule>.
template <EdgeRule Rule = EdgeRule::Clamped, typename Index = int64_t, typename Acc>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE LinearCell<Acc, Index> linear_cell(const VolumeView& g,
                                                                          Acc cx, Acc cy, Acc cz) {
  int x0, x1, y0, y1, z0, z1;
  LinearCell<Acc, Index> k;
  if constexpr (Rule == EdgeRule::Clamped) {
    // Inside, c >= -0.5, so truncating c + 1 is floor(c) + 1 without a call to floor (which
    // baseline x86-64 cannot inline). When c + 1 rounds up to an integer, f comes out as -ulp
    // instead of 1 - ulp at the neighbouring cell: the same value to float precision.
    const int ix = int(cx + Acc(1)) - 1, iy = int(cy + Acc(1)) - 1, iz = int(cz + Acc(1)) - 1;
    k.fx = cx - Acc(ix);
    k.fy = cy - Acc(iy);
    k.fz = cz - Acc(iz);
    // Inside, -1 <= i <= n - 1, so one-sided clamps suffice.
    x0 = ix < 0 ? 0 : ix;
    x1 = ix + 1 < g.nx ? ix + 1 : g.nx - 1;
    y0 = iy < 0 ? 0 : iy;
    y1 = iy + 1 < g.ny ? iy + 1 : g.ny - 1;
    z0 = iz < 0 ? 0 : iz;
    z1 = iz + 1 < g.nz ? iz + 1 : g.nz - 1;
  } else {
    // 0 <= c <= n - 1: the cell below c, or the last whole cell at c = n - 1.
    x0 = cx < Acc(g.nx - 1) ? int(cx) : g.nx - 2;
    y0 = cy < Acc(g.ny - 1) ? int(cy) : g.ny - 2;
    z0 = cz < Acc(g.nz - 1) ? int(cz) : g.nz - 2;
    x1 = x0 + 1;
    y1 = y0 + 1;
    z1 = z0 + 1;
    k.fx = cx - Acc(x0);
    k.fy = cy - Acc(y0);
    k.fz = cz - Acc(z0);
  }
  k.x0 = x0;
  k.x1 = x1;
  const Index sy = Index(g.stride_y), sz = Index(g.stride_z);
  k.r00 = Index(z0) * sz + Index(y0) * sy;
  k.r10 = k.r00 + Index(y1 - y0) * sy;
  k.r01 = k.r00 + Index(z1 - z0) * sz;
  k.r11 = k.r01 + Index(y1 - y0) * sy;
  return k;
}

/// Voxel i of a volume: `voxels` is a pointer to its values, or (host code reading a volume of
/// any pixel type) a callable voxels(i).
template <typename T, typename Index>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T voxel_at(const T* voxels, Index i) {
#if defined(__CUDA_ARCH__)
  return __ldg(voxels + i);  // through the read-only data path: volumes never change in a kernel
#else
  return voxels[i];
#endif
}
template <typename Read>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE auto voxel_at(const Read& voxels, int64_t i)
    -> decltype(voxels(i)) {
  return voxels(i);
}

/// The trilinear value of the voxels over cell k.
template <typename Acc, typename Voxels, typename Index>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE Acc linear_value(const Voxels& v,
                                                        const LinearCell<Acc, Index>& k) {
  return trilinear(k.fx, k.fy, k.fz, Acc(voxel_at(v, k.r00 + k.x0)), Acc(voxel_at(v, k.r00 + k.x1)),
                   Acc(voxel_at(v, k.r10 + k.x0)), Acc(voxel_at(v, k.r10 + k.x1)),
                   Acc(voxel_at(v, k.r01 + k.x0)), Acc(voxel_at(v, k.r01 + k.x1)),
                   Acc(voxel_at(v, k.r11 + k.x0)), Acc(voxel_at(v, k.r11 + k.x1)));
}

/// The trilinear value over cell k and its exact derivative along each index axis (`gradient`;
/// 0 along an axis whose two neighbours were clamped onto one voxel).
template <typename Acc, typename Voxels>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE Acc linear_value_gradient(const Voxels& v,
                                                                 const LinearCell<Acc>& k,
                                                                 Acc gradient[3]) {
  const Acc v000 = Acc(voxel_at(v, k.r00 + k.x0)), v100 = Acc(voxel_at(v, k.r00 + k.x1));
  const Acc v010 = Acc(voxel_at(v, k.r10 + k.x0)), v110 = Acc(voxel_at(v, k.r10 + k.x1));
  const Acc v001 = Acc(voxel_at(v, k.r01 + k.x0)), v101 = Acc(voxel_at(v, k.r01 + k.x1));
  const Acc v011 = Acc(voxel_at(v, k.r11 + k.x0)), v111 = Acc(voxel_at(v, k.r11 + k.x1));
  const Acc a00 = lerp(v000, v100, k.fx), a10 = lerp(v010, v110, k.fx);
  const Acc a01 = lerp(v001, v101, k.fx), a11 = lerp(v011, v111, k.fx);
  const Acc b0 = lerp(a00, a10, k.fy), b1 = lerp(a01, a11, k.fy);
  const Acc dx00 = v100 - v000, dx10 = v110 - v010, dx01 = v101 - v001, dx11 = v111 - v011;
  gradient[0] = lerp(lerp(dx00, dx10, k.fy), lerp(dx01, dx11, k.fy), k.fz);
  gradient[1] = lerp(a10 - a00, a11 - a01, k.fz);
  gradient[2] = b1 - b0;
  return lerp(b0, b1, k.fz);
}

/// Cell k's eight corners (flat voxel offsets, corner q = x + 2y + 4z bits) and their trilinear
/// weights: the transpose of linear_value, for spreading a value back over the voxels (clamped
/// corners coincide, and their weights add up there).
template <typename Acc>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE void linear_corners(const LinearCell<Acc>& k,
                                                           int64_t offset[8], Acc weight[8]) {
  const int64_t rows[4] = {k.r00, k.r10, k.r01, k.r11};
  for (int q = 0; q < 8; ++q) {
    offset[q] = rows[q >> 1] + (q & 1 ? k.x1 : k.x0);
    weight[q] = (q & 1 ? k.fx : Acc(1) - k.fx) * (q & 2 ? k.fy : Acc(1) - k.fy) *
                (q & 4 ? k.fz : Acc(1) - k.fz);
  }
}

/// docs/conventions.md §5 `linear` at c, which must be inside (EdgeRule::Clamped).
template <typename Acc, typename Index = int64_t, typename Voxels>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE Acc sample_linear(const Voxels& volume, const VolumeView& g,
                                                         Acc cx, Acc cy, Acc cz) {
  return linear_value<Acc>(volume, linear_cell<EdgeRule::Clamped, Index>(g, cx, cy, cz));
}

/// docs/conventions.md §5 `nearest`: the flat offset of voxel floor(c + 0.5), clamped (c inside).
template <typename Index = int64_t, typename Acc>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE Index nearest_offset(const VolumeView& g, Acc cx, Acc cy,
                                                            Acc cz) {
  // c + 0.5 >= 0 inside the buffer: truncation is floor. Inside, floor(c + 0.5) <= n - 1 in
  // exact arithmetic; the clamp keeps float rounding (axes beyond 2^23 voxels) in the volume.
  int ix = int(cx + Acc(0.5)), iy = int(cy + Acc(0.5)), iz = int(cz + Acc(0.5));
  ix = ix < 0 ? 0 : (ix >= g.nx ? g.nx - 1 : ix);
  iy = iy < 0 ? 0 : (iy >= g.ny ? g.ny - 1 : iy);
  iz = iz < 0 ? 0 : (iz >= g.nz ? g.nz - 1 : iz);
  return Index(iz) * Index(g.stride_z) + Index(iy) * Index(g.stride_y) + Index(ix);
}

/// docs/conventions.md §5 `nearest`: the voxel at floor(c + 0.5), clamped (c inside).
template <typename Index = int64_t, typename T, typename Acc>
SONOSLICE_HOST_DEVICE SONOSLICE_INLINE T sample_nearest(const T* __restrict__ volume,
                                                        const VolumeView& g, Acc cx, Acc cy,
                                                        Acc cz) {
  return voxel_at(volume, nearest_offset<Index>(g, cx, cy, cz));
}

}  // namespace SONOSLICE_KERNEL_ISA
}  // namespace geometry
}  // namespace sonoslice
