// The registration row kernel for CPUs with AVX2 and FMA: the same RegisterImpl.h, built with
// -mavx2 -mfma (and no FMA contraction), which samples four pixels at a time by gathers.
// Chosen at run time (Metrics.cpp).
#define SONOSLICE_KERNEL_ISA avx2
#include "RegisterBackends.h"

namespace sonoslice {
namespace register_impl {
void terms_cpu_avx2(const TermsLaunch& L, PoseTerms& total) {
  accumulate_rows(L, total);
}
void patch_score_avx2(const TermsLaunch& L, int half, double least, bool lncc, double& weighted,
                      double& weight) {
  patch_score(L, half, least, lncc, weighted, weight);
}
}  // namespace register_impl
}  // namespace sonoslice
