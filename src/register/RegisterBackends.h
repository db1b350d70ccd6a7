#pragma once
/// @file How registration's metrics (Metrics.cpp) reach the row kernels (RegisterImpl.h) in each
/// of their builds: one entry point per CPU instruction set (RegisterCPU.cpp,
/// RegisterCPUAvx2.cpp) chosen by CpuIsa, as every kernel folder wires its backends
/// (docs/architecture.md). Both give the same terms bit for bit.
#include "RegisterImpl.h"
#include "sonoslice/backend/Device.h"

namespace sonoslice {
namespace register_impl {

/// The terms of one frame at one pose (L), added to `total` row by row.
void terms_cpu_generic(const TermsLaunch& L, PoseTerms& total);
void terms_cpu_avx2(const TermsLaunch& L, PoseTerms& total);
inline void terms_cpu(CpuIsa isa, const TermsLaunch& L, PoseTerms& total) {
  switch (isa) {
    case CpuIsa::Avx2:
      return terms_cpu_avx2(L, total);
    case CpuIsa::Generic:
      return terms_cpu_generic(L, total);
  }
}

/// LC2's per-pixel terms of row v (lc2_row_terms) into the row's `q`.
void lc2_row_terms_generic(const TermsLaunch& L, int v, double* q);
void lc2_row_terms_avx2(const TermsLaunch& L, int v, double* q);
inline void lc2_row_terms_cpu(CpuIsa isa, const TermsLaunch& L, int v, double* q) {
  switch (isa) {
    case CpuIsa::Avx2:
      return lc2_row_terms_avx2(L, v, q);
    case CpuIsa::Generic:
      return lc2_row_terms_generic(L, v, q);
  }
}

/// LC2's (local NCC's) patches of one row (score_patch_row).
void score_patch_row_generic(const double* sums, const uint8_t* centre, int W, double least,
                             bool lncc, double& weighted, double& weight);
void score_patch_row_avx2(const double* sums, const uint8_t* centre, int W, double least, bool lncc,
                          double& weighted, double& weight);
inline void score_patch_row_cpu(CpuIsa isa, const double* sums, const uint8_t* centre, int W,
                                double least, bool lncc, double& weighted, double& weight) {
  switch (isa) {
    case CpuIsa::Avx2:
      return score_patch_row_avx2(sums, centre, W, least, lncc, weighted, weight);
    case CpuIsa::Generic:
      return score_patch_row_generic(sums, centre, W, least, lncc, weighted, weight);
  }
}

}  // namespace register_impl
}  // namespace sonoslice
