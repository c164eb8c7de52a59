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

namespace detail {

/// Fuses element i (already read into xa, xb) with rule R; false (with st set) if it is bad.
template <Rule R>
inline bool fuse_element(double xa, double xb, std::size_t i, bool probabilities, double l0,
                         double* value, double* omega, double* info_loss, ArrayStatus& st) {
  if (std::isnan(xa) || std::isnan(xb)) {
    st = {BadInput::NaN, i, std::isnan(xa) ? 0 : 1};
    return false;
  }
  if (probabilities) {
    if (!(xa >= 0.0 && xa <= 1.0) || !(xb >= 0.0 && xb <= 1.0)) {
      st = {BadInput::OutOfRange, i, (xa >= 0.0 && xa <= 1.0) ? 1 : 0};
      return false;
    }
    xa = logit(xa);
    xb = logit(xb);
  }
  const Fused f = fuse_logodds<R>(xa, xb, l0);
  if (std::isnan(f.l)) {
    st = {BadInput::Contradiction, i, 2};
    return false;
  }
  value[i] = probabilities ? sigmoid(f.l) : f.l;
  omega[i] = f.omega;
  info_loss[i] = f.info_loss;
  return true;
}

/// The array loop for one rule (a compile-time constant, so that the rule's code is inlined
/// into the loop instead of being chosen again for every element).
template <Rule R>
inline ArrayStatus fuse_arrays_rule(const double* a, const double* b, std::size_t n,
                                    bool probabilities, double l0, double* value, double* omega,
                                    double* info_loss) {
  ArrayStatus st;
  for (std::size_t i = 0; i < n; ++i) {
    if (!fuse_element<R>(a[i], b[i], i, probabilities, l0, value, omega, info_loss, st)) break;
  }
  return st;
}

/// The Chernoff rule over log-odds arrays with prior log-odds 0: chernoff_pack() on
/// kArrayLanes consecutive pairs at a time, each pair lower first as fuse_logodds() fuses it.
/// A pack with a pair that chernoff_pack() does not take (infinite, NaN or beyond its range)
/// and the last n % kArrayLanes pairs are done pair by pair by fuse_logodds(), which gives the
/// pairs that chernoff_pack() takes the same bits.
inline ArrayStatus fuse_arrays_chernoff(const double* a, const double* b, std::size_t n,
                                        double* value, double* omega, double* info_loss) {
  ArrayStatus st;
  std::size_t i = 0;
  for (; i + kArrayLanes <= n; i += kArrayLanes) {
    bool fits = true;
    for (int j = 0; j < kArrayLanes; ++j) {
      fits &= std::fabs(a[i + j]) <= kChernoffPackMax && std::fabs(b[i + j]) <= kChernoffPackMax;
    }
    if (fits) {
      double lo[kArrayLanes], hi[kArrayLanes];
      for (int j = 0; j < kArrayLanes; ++j) {
        const bool swap = a[i + j] > b[i + j];
        lo[j] = swap ? b[i + j] : a[i + j];
        hi[j] = swap ? a[i + j] : b[i + j];
      }
      chernoff_pack<kArrayLanes>(lo, hi, value + i, omega + i, info_loss + i);
      for (int j = 0; j < kArrayLanes; ++j) {
        if (a[i + j] > b[i + j]) omega[i + j] = 1.0 - omega[i + j];  // the weight on a
      }
      continue;
    }
    for (std::size_t j = i; j < i + kArrayLanes; ++j) {
      if (!fuse_element<Rule::Chernoff>(a[j], b[j], j, false, 0.0, value, omega, info_loss, st)) {
        return st;
      }
    }
  }
  for (; i < n; ++i) {
    if (!fuse_element<Rule::Chernoff>(a[i], b[i], i, false, 0.0, value, omega, info_loss, st)) {
      return st;
    }
  }
  return st;
}

}  // namespace detail

/// Fuses n element pairs. With `probabilities`, a and b hold probabilities in [0, 1] and
/// `value` receives the fused probability; otherwise they hold log-odds and `value` the
/// fused log-odds. Stops at the first NaN, out-of-range or contradictory pair and reports it.
inline ArrayStatus fuse_arrays(Rule rule, const double* a, const double* b, std::size_t n,
                               bool probabilities, double l0, double* value, double* omega,
                               double* info_loss) {
  if (rule == Rule::Chernoff && !probabilities && l0 == 0.0) {
    return detail::fuse_arrays_chernoff(a, b, n, value, omega, info_loss);
  }
  return with_rule(rule, [&](auto r) {
    return detail::fuse_arrays_rule<decltype(r)::value>(a, b, n, probabilities, l0, value, omega,
                                                        info_loss);
  });
}

}  // namespace octofuse
