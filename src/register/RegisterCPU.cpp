// The registration row kernel for any x86-64 (or other) CPU: RegisterImpl.h with scalar
// sampling.
#include "RegisterBackends.h"

namespace sonoslice {
namespace register_impl {
void terms_cpu_generic(const TermsLaunch& L, PoseTerms& total) {
  accumulate_rows(L, total);
}
void patch_score_generic(const TermsLaunch& L, int half, double least, bool lncc, double& weighted,
                         double& weight) {
  patch_score(L, half, least, lncc, weighted, weight);
}
}  // namespace register_impl
}  // namespace sonoslice
