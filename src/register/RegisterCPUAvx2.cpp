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
void lc2_row_terms_avx2(const TermsLaunch& L, int v, double* q) {
  lc2_row_terms(L, v, q);
}
void score_patch_row_avx2(const double* sums, const uint8_t* centre, int W, double least, bool lncc,
                          double& weighted, double& weight) {
  score_patch_row(sums, centre, W, least, lncc, weighted, weight);
}
}  // namespace register_impl
}  // namespace sonoslice
