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

/// LC2's (local NCC's) patches of one frame at one pose (patch_score).
void patch_score_generic(const TermsLaunch& L, int half, double least, bool lncc, double& weighted,
                         double& weight);
void patch_score_avx2(const TermsLaunch& L, int half, double least, bool lncc, double& weighted,
                      double& weight);
inline void patch_score_cpu(CpuIsa isa, const TermsLaunch& L, int half, double least, bool lncc,
                            double& weighted, double& weight) {
  switch (isa) {
    case CpuIsa::Avx2:
      return patch_score_avx2(L, half, least, lncc, weighted, weight);
    case CpuIsa::Generic:
      return patch_score_generic(L, half, least, lncc, weighted, weight);
  }
}

}  // namespace register_impl
}  // namespace sonoslice
