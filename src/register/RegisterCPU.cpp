// The registration row kernel for any x86-64 (or other) CPU: RegisterImpl.h with scalar
// sampling.
#include "RegisterBackends.h"

namespace sonoslice {
namespace register_impl {
void terms_cpu_generic(const TermsLaunch& L, PoseTerms& total) {
  accumulate_rows(L, total);
}
void lc2_row_terms_generic(const TermsLaunch& L, int v, double* q) {
  lc2_row_terms(L, v, q);
}
void score_patch_row_generic(const double* sums, const uint8_t* centre, int W, double least,
                             bool lncc, double& weighted, double& weight) {
  score_patch_row(sums, centre, W, least, lncc, weighted, weight);
}
}  // namespace register_impl
}  // namespace sonoslice
