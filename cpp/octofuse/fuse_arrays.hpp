// octofuse: the per-voxel rules applied element-wise over arrays.
#pragma once

#include "octofuse/rules.hpp"

#include <cmath>
#include <cstddef>

namespace octofuse {

/// Why an element could not be fused.
enum class BadInput { None = 0, NaN = 1, OutOfRange = 2, Contradiction = 3 };

/// First offending element of an array fusion (index and which input), if any.
struct ArrayStatus {
  BadInput what = BadInput::None;
  std::size_t index = 0;
  int input = 0;  ///< 0 = a, 1 = b, 2 = both (contradiction)
};

/// Log-odds of a probability; p = 0 and p = 1 give -inf and +inf.
inline double logit(double p) { return std::log(p) - std::log1p(-p); }

/// Fuses n element pairs. With `probabilities`, a and b hold probabilities in [0, 1] and
/// `value` receives the fused probability; otherwise they hold log-odds and `value` the
/// fused log-odds. Stops at the first NaN, out-of-range or contradictory pair and reports it.
inline ArrayStatus fuse_arrays(Rule rule, const double* a, const double* b, std::size_t n,
                               bool probabilities, double l0, double* value, double* omega,
                               double* info_loss) {
  ArrayStatus st;
  for (std::size_t i = 0; i < n; ++i) {
    double xa = a[i], xb = b[i];
    if (std::isnan(xa) || std::isnan(xb)) {
      return {BadInput::NaN, i, std::isnan(xa) ? 0 : 1};
    }
    if (probabilities) {
      if (!(xa >= 0.0 && xa <= 1.0) || !(xb >= 0.0 && xb <= 1.0)) {
        return {BadInput::OutOfRange, i, (xa >= 0.0 && xa <= 1.0) ? 1 : 0};
      }
      xa = logit(xa);
      xb = logit(xb);
    }
    const Fused f = fuse_logodds(rule, xa, xb, l0);
    if (std::isnan(f.l)) return {BadInput::Contradiction, i, 2};
    value[i] = probabilities ? detail::sigmoid(f.l) : f.l;
    omega[i] = f.omega;
    info_loss[i] = f.info_loss;
  }
  return st;
}

}  // namespace octofuse
