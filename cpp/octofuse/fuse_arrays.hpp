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

/// The array loop for one rule (a compile-time constant, so that the rule's code is inlined
/// into the loop instead of being chosen again for every element).
template <Rule R>
inline ArrayStatus fuse_arrays_rule(const double* a, const double* b, std::size_t n,
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
    const Fused f = fuse_logodds<R>(xa, xb, l0);
    if (std::isnan(f.l)) return {BadInput::Contradiction, i, 2};
    value[i] = probabilities ? sigmoid(f.l) : f.l;
    omega[i] = f.omega;
    info_loss[i] = f.info_loss;
  }
  return st;
}

/// The Chernoff rule over log-odds arrays, in blocks: the pairs of a block for which
/// ChernoffWide applies go through its four steps one step at a time over the whole block,
/// so that the CPU overlaps the exp/log latency of independent pairs (one pair alone is a
/// chain of dependent exp, log and divisions); the other pairs take fuse_logodds(). Same
/// operations per pair as fuse_logodds<Chernoff>(), so the same results. A block holding a
/// bad input is redone by the element-wise loop, which reports it.
inline ArrayStatus fuse_arrays_chernoff(const double* a, const double* b, std::size_t n,
                                        double l0, double* value, double* omega,
                                        double* info_loss) {
  constexpr std::size_t kBlock = 128;
  std::size_t idx[kBlock];
  double ea[kBlock], eb[kBlock], dl[kBlock], r[kBlock];
  for (std::size_t start = 0; start < n; start += kBlock) {
    const std::size_t m = n - start < kBlock ? n - start : kBlock;
    const double *pa = a + start, *pb = b + start;
    std::size_t k = 0;
    bool bad = false;
    for (std::size_t i = 0; i < m; ++i) {
      const double xa = pa[i], xb = pb[i];
      if (std::isnan(xa) || std::isnan(xb) || (std::isinf(xa) && std::isinf(xb) && (xa > 0) != (xb > 0))) {
        bad = true;
        break;
      }
      if (!std::isinf(xa) && !std::isinf(xb) && ChernoffWide::applies(xa, xb, l0)) {
        idx[k++] = i;
      } else {
        const Fused f = fuse_logodds<Rule::Chernoff>(xa, xb, l0);
        value[start + i] = f.l;
        omega[start + i] = f.omega;
        info_loss[start + i] = f.info_loss;
      }
    }
    if (bad) {
      ArrayStatus st = fuse_arrays_rule<Rule::Chernoff>(pa, pb, m, false, l0, value + start,
                                                        omega + start, info_loss + start);
      st.index += start;
      return st;
    }
    for (std::size_t j = 0; j < k; ++j) ChernoffWide::exps(pa[idx[j]], pb[idx[j]], ea[j], eb[j]);
    for (std::size_t j = 0; j < k; ++j) dl[j] = ChernoffWide::dlog(ea[j], eb[j]);
    for (std::size_t j = 0; j < k; ++j) {
      const std::size_t i = start + idx[j];
      double w, l;
      if (ChernoffWide::weight(a[i], b[i], dl[j], r[j], w, l)) {
        omega[i] = w;
        value[i] = l;
      } else {
        omega[i] = w;
        value[i] = l;
        info_loss[i] = kl_logodds(a[i] + b[i], l);
        r[j] = -1.0;  // loss done
      }
    }
    for (std::size_t j = 0; j < k; ++j) {
      if (r[j] < 0.0) continue;
      const std::size_t i = start + idx[j];
      info_loss[i] = ChernoffWide::info_loss(a[i], b[i], ea[j], eb[j], r[j], value[i]);
    }
  }
  return {};
}

}  // namespace detail

/// Fuses n element pairs. With `probabilities`, a and b hold probabilities in [0, 1] and
/// `value` receives the fused probability; otherwise they hold log-odds and `value` the
/// fused log-odds. Stops at the first NaN, out-of-range or contradictory pair and reports it.
inline ArrayStatus fuse_arrays(Rule rule, const double* a, const double* b, std::size_t n,
                               bool probabilities, double l0, double* value, double* omega,
                               double* info_loss) {
  if (rule == Rule::Chernoff && !probabilities) {
    return detail::fuse_arrays_chernoff(a, b, n, l0, value, omega, info_loss);
  }
  return with_rule(rule, [&](auto r) {
    return detail::fuse_arrays_rule<decltype(r)::value>(a, b, n, probabilities, l0, value, omega,
                                                        info_loss);
  });
}

}  // namespace octofuse
