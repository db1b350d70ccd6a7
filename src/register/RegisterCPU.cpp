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
}  // namespace register_impl
}  // namespace sonoslice
