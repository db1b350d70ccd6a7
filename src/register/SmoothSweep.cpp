// smooth-sweep (Optimizers.h): every frame's correction refined jointly, Gauss–Newton / LM on
// the frames' costs plus a smoothness prior along the sweep, solved by block elimination.
#include <algorithm>
#include <cmath>
#include <vector>

#include "../backend/ParallelFor.h"
#include "Optimizers.h"

namespace sonoslice {
namespace register_impl {

SweepOutcome smooth_sweep(const SweepTerms& p, const RegistrationSettings& s, const Pose& start) {
  const size_t n = p.centres.size();
  SweepOutcome out;
  std::vector<Pose> X(n, start);
  const double tol_rad = s.tolerance_deg * kPi / 180;
  // The sweep's cost at corrections Y: frames outside the volume counted first (fewer is
  // better), then the frames' costs plus the prior.
  struct Total {
    size_t outside = 0;
    double value = 0;
    bool operator<(const Total& o) const {
      return outside != o.outside ? outside < o.outside : value < o.value;
    }
  };
  const auto descriptor = [&](const std::vector<Pose>& Y, size_t k, double d[6]) {
    const Vec3 moved = Y[k].transform_point(p.centres[k]);
    for (int i = 0; i < 3; ++i) d[i] = moved[i] - p.centres[k][i];
    const Vec3 r = rotation_vector(Y[k].linear());
    for (int i = 0; i < 3; ++i) d[3 + i] = r[i];
  };
  const auto prior = [&](const std::vector<Pose>& Y, const double w[6]) {
    double total = 0, a[6], b[6];
    for (size_t k = 0; k + 1 < n; ++k) {
      descriptor(Y, k, a);
      descriptor(Y, k + 1, b);
      for (int i = 0; i < 6; ++i) total += w[i] * (b[i] - a[i]) * (b[i] - a[i]);
    }
    return total;
  };
  const auto costs = [&](const std::vector<Pose>& Y, int f, std::vector<double>& each) {
    each.assign(n, 0.0);
    backend::parallel_for(int64_t(n), [&](int64_t k) {
      const Vec3 c = Y[size_t(k)].transform_point(p.centres[size_t(k)]);
      each[size_t(k)] = metric_cost(s.metric, p.terms(size_t(k), Y[size_t(k)], f, c, false));
    });
    out.evaluations += 1;
  };
  const auto total = [&](const std::vector<double>& each, const std::vector<Pose>& Y,
                         const double w[6]) {
    Total t;
    for (double c : each) {
      if (std::isfinite(c))
        t.value += c;
      else
        ++t.outside;
    }
    t.value += prior(Y, w);
    return t;
  };

  for (int f : *s.pyramid) {
    double lambda = 1e-3, w[6] = {0, 0, 0, 0, 0, 0};
    for (int it = 0; it < s.max_iterations; ++it) {
      // Every frame's gradient and Gauss–Newton matrix, about its current centre.
      std::vector<double> each(n), g(6 * n, 0.0), H(36 * n, 0.0);
      backend::parallel_for(int64_t(n), [&](int64_t k) {
        const size_t i = size_t(k);
        const Vec3 c = X[i].transform_point(p.centres[i]);
        each[i] = metric_cost(s.metric, p.terms(i, X[i], f, c, true), &g[6 * i], &H[36 * i]);
        if (!std::isfinite(each[i])) {
          std::fill(&g[6 * i], &g[6 * i] + 6, 0.0);
          std::fill(&H[36 * i], &H[36 * i] + 36, 0.0);
        }
      });
      out.evaluations += 1;
      if (it == 0) {
        // The prior's weight for this level, from the frames' own curvature.
        double sum[2] = {0, 0};
        size_t used = 0;
        for (size_t i = 0; i < n; ++i)
          if (std::isfinite(each[i])) {
            ++used;
            for (int k = 0; k < 6; ++k) sum[k / 3] += H[36 * i + 7 * k] / 3;
          }
        if (used == 0) break;  // no frame inside the volume at this level
        for (int k = 0; k < 6; ++k) w[k] = *s.smoothness * sum[k / 3] / double(used);
      }
      const Total current = total(each, X, w);
      ++out.iterations;
      std::vector<double> d(6 * n);
      for (size_t i = 0; i < n; ++i) descriptor(X, i, &d[6 * i]);
      bool moved = false, converged = false;
      for (int attempt = 0; attempt < 12; ++attempt) {
        const double damping =
            s.optimizer == RegistrationOptimizer::LevenbergMarquardt ? lambda : 0;
        // Block elimination along the sweep: D'_i = D_i − B·D'_{i−1}⁻¹·B, b'_i likewise, with
        // the off-diagonal blocks B = −2W (diagonal).
        std::vector<double> inverse(36 * n), rhs(6 * n), xi(6 * n);
        bool ok = true;
        for (size_t i = 0; i < n && ok; ++i) {
          double D[36], b[6];
          for (int k = 0; k < 36; ++k) D[k] = H[36 * i + k];
          for (int k = 0; k < 6; ++k) {
            const int degree = (i > 0) + (i + 1 < n);
            D[7 * k] += damping * H[36 * i + 7 * k] + 2 * degree * w[k] +
                        1e-12 * (1 + std::fabs(H[36 * i + 7 * k]));
            b[k] = -g[6 * i + k];
            if (i > 0) b[k] -= 2 * w[k] * (d[6 * i + k] - d[6 * (i - 1) + k]);
            if (i + 1 < n) b[k] -= 2 * w[k] * (d[6 * i + k] - d[6 * (i + 1) + k]);
          }
          if (i > 0) {
            const double* P = &inverse[36 * (i - 1)];  // D'_{i−1}⁻¹
            for (int r = 0; r < 6; ++r) {
              for (int c = 0; c < 6; ++c) D[6 * r + c] -= 4 * w[r] * P[6 * r + c] * w[c];
              double a = 0;
              for (int c = 0; c < 6; ++c) a += P[6 * r + c] * rhs[6 * (i - 1) + c];
              b[r] += 2 * w[r] * a;  // − B·D'⁻¹·b' with B = −2W
            }
          }
          ok = invert6(D, &inverse[36 * i]);
          std::copy(b, b + 6, &rhs[6 * i]);
        }
        if (!ok) {
          lambda *= 10;
          continue;
        }
        for (size_t i = n; i-- > 0;) {
          double b[6];
          for (int k = 0; k < 6; ++k)
            b[k] = rhs[6 * i + k] + (i + 1 < n ? 2 * w[k] * xi[6 * (i + 1) + k] : 0);
          for (int r = 0; r < 6; ++r) {
            double a = 0;
            for (int c = 0; c < 6; ++c) a += inverse[36 * i + 6 * r + c] * b[c];
            xi[6 * i + r] = a;
          }
        }
        // Each frame's step: backtracking for Gauss–Newton, inside the trust region.
        std::vector<Pose> candidate(n);
        double largest_mm = 0, largest_rad = 0;
        for (size_t i = 0; i < n; ++i) {
          double* x = &xi[6 * i];
          double step_mm, step_rad;
          limit_step(s, attempt, x, &step_mm, &step_rad);
          largest_mm = std::max(largest_mm, step_mm);
          largest_rad = std::max(largest_rad, step_rad);
          candidate[i] = apply_increment(X[i], x, X[i].transform_point(p.centres[i]));
        }
        std::vector<double> tried_each;
        costs(candidate, f, tried_each);
        const Total tried = total(tried_each, candidate, w);
        if (tried < current) {
          X = std::move(candidate);
          lambda = std::max(lambda / 3, 1e-9);
          moved = true;
          converged = largest_mm < s.tolerance_mm && largest_rad < tol_rad;
          break;
        }
        if (largest_mm < s.tolerance_mm && largest_rad < tol_rad) {
          converged = true;
          break;
        }
        lambda *= 4;
      }
      if (!moved || converged) break;
    }
  }
  out.corrections = X;
  costs(X, 1, out.costs);
  return out;
}

}  // namespace register_impl
}  // namespace sonoslice
