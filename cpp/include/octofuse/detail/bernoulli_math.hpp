// octofuse: scalar information measures of Bernoulli variables in log-odds (KL divergence,
// entropy) and the Chernoff weights of the WEP rules. Internal to rules.hpp.
#pragma once

#include <cmath>
#include <limits>

namespace octofuse::detail {

inline constexpr double kInf = std::numeric_limits<double>::infinity();
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Speed notes. glibc's exp and log take about a third of the time of its log1p and expm1,
// so log1p is computed from log (log1p_fast) and expm1 is only called where its argument is
// small enough for exp(x) - 1 to cancel. sigmoid(l), sigmoid(-l) and softplus(l) all come from
// the one exp(-|l|). Nothing here relies on -ffast-math: infinities and signed zeros behave.

/// log(1 + x) for x > -1 (finite, or +inf), accurate to a few ulps: with u = fl(1 + x),
/// log1p(x) = log(u) * x / (u - 1) (Goldberg, "What every computer scientist should know
/// about floating-point arithmetic", theorem 4).
inline double log1p_fast(double x) {
  const double u = 1.0 + x;
  if (u == 1.0) return x;
  if (u == kInf) return kInf;
  return std::log(u) * (x / (u - 1.0));
}

/// log(1 + e^x), stable for all finite x.
inline double softplus(double x) {
  const double e = std::exp(-std::fabs(x));
  return (x > 0.0 ? x : 0.0) + log1p_fast(e);
}

/// Logistic sigmoid 1 / (1 + e^-x), stable.
inline double sigmoid(double x) {
  if (x >= 0.0) return 1.0 / (1.0 + std::exp(-x));
  const double e = std::exp(x);
  return e / (1.0 + e);
}

/// KL(q || p) between Bernoullis in log-odds, for lq = y <= 0 and lp = y + d, given
/// s = sigmoid(y) (so s <= 1/2): KL = log1p(s expm1(d)) - s d.
inline double kl_core(double s, double y, double d) {
  const double ad = std::fabs(d);
  if (ad < 1e-3) {
    // Taylor series of the softplus Bregman divergence (no cancellation for tiny d):
    // KL = sum_k sigmoid^(k-1)(y) d^k / k!, with sigmoid' = v, sigmoid'' = v (1 - 2s), ...
    const double v = s * (1.0 - s), t = 1.0 - 2.0 * s;
    return v * d * d *
           (0.5 + d * (t / 6.0 + d * ((1.0 - 6.0 * v) / 24.0 +
                                      d * (t * (1.0 - 12.0 * v) / 120.0 +
                                           d * (1.0 + v * (120.0 * v - 30.0)) / 720.0))));
  }
  double x;  // s * expm1(d) = (1 + e^lp) / (1 + e^lq) - 1
  if (ad < 0.5) {
    x = s * std::expm1(d);
  } else if (d < 700.0) {
    x = s * (std::exp(d) - 1.0);  // |e^d - 1| >= 0.39: no cancellation
  } else {
    const double kl = softplus(y + d) - softplus(y) - s * d;  // e^d would overflow
    return kl > 0.0 ? kl : 0.0;
  }
  const double kl = log1p_fast(x) - s * d;
  return kl > 0.0 ? kl : 0.0;  // rounding can give -1e-17
}

/// KL(q || p) between Bernoullis given in log-odds (lq, lp), finite:
/// KL = softplus(lp) - softplus(lq) - sigmoid(lq) (lp - lq). KL is unchanged by
/// (lq, lp) -> (-lq, -lp), which is used to keep sigmoid(lq) <= 1/2.
inline double kl_logodds(double lq, double lp) {
  if (lq > 0.0) {
    lq = -lq;
    lp = -lp;
  }
  const double e = std::exp(lq);
  return kl_core(e / (1.0 + e), lq, lp - lq);
}

/// Shannon entropy (nats) of a Bernoulli with log-odds l:
/// H = softplus(l) - sigmoid(l) l = log1p(e^-|l|) + |l| sigmoid(-|l|) (two positive terms).
inline double entropy_logodds(double l) {
  const double al = std::fabs(l);
  const double e = std::exp(-al);
  return log1p_fast(e) + al * (e / (1.0 + e));
}

/// Chernoff point: the log-odds l* with KL(p* || p_a) = KL(p* || p_b) (closed form).
/// Requires finite la != lb. With A = log(p_a/p_b), B = log((1-p_a)/(1-p_b)):
/// p* = B / (B - A), so logit(p*) = log(-B / A). A and B have opposite signs.
inline double chernoff_logodds(double la, double lb) {
  const double d = la - lb;
  double A, B;  // B = softplus(lb) - softplus(la), A = softplus(-lb) - softplus(-la)
  if (std::fabs(d) < 0.5) {
    // B = -log1p(sigmoid(lb) expm1(d)), A = -log1p(sigmoid(-lb) expm1(-d))
    const double eb = std::exp(-std::fabs(lb));
    const double r = 1.0 / (1.0 + eb);
    const double s = lb >= 0.0 ? r : eb * r, sm = lb >= 0.0 ? eb * r : r;
    const double em = std::expm1(d);
    B = -log1p_fast(s * em);
    A = -log1p_fast(sm * (-em / (1.0 + em)));
  } else {
    // softplus(+-l) = max(+-l, 0) + log1p(e^-|l|): the log1p terms are shared
    const double dl = log1p_fast(std::exp(-std::fabs(lb))) - log1p_fast(std::exp(-std::fabs(la)));
    B = ((lb > 0.0 ? lb : 0.0) - (la > 0.0 ? la : 0.0)) + dl;
    A = ((lb < 0.0 ? -lb : 0.0) - (la < 0.0 ? -la : 0.0)) + dl;
  }
  return std::log(std::fabs(B / A));
}

/// Chernoff weight on a for finite la, lb (clamped to [0, 1]).
inline double chernoff_weight(double la, double lb) {
  const double d = la - lb;
  if (std::fabs(d) < 1e-6) {
    // second-order expansion of the equal-KLD condition around the midpoint
    return 0.5 + (1.0 - 2.0 * sigmoid(lb + 0.5 * d)) * d / 24.0;
  }
  const double w = (chernoff_logodds(la, lb) - lb) / d;
  return w < 0.0 ? 0.0 : (w > 1.0 ? 1.0 : w);
}

/// Solves c_a KL(p_w || p_a) = c_b KL(p_w || p_b) for w in [0, 1], given w0, the Chernoff
/// weight (the solution for c_a = c_b). g(w) = c_a KL_a - c_b KL_b is >= 0 at w = 0, <= 0
/// at w = 1 and decreasing; the iteration keeps a bracket [lo, hi] of its root.
///
/// Newton's method is applied to h(w) = sqrt(c_a KL_a) - sqrt(c_b KL_b), which has the same
/// root and is nearly linear in w (sqrt(KL(p_w || p_x)) ~ |l_w - l_x| sqrt(sigmoid'/2)), from
/// the start that the same linearisation gives: w/(1-w) = sqrt(c_a/c_b) w0/(1-w0). Steps
/// that leave the bracket are replaced by bisection. It stops when g vanishes to rounding
/// (|g| <= 1e-15 (c_a KL_a + c_b KL_b)), or when a step or the bracket is below 1e-14, or,
/// for |la|, |lb| <= 8 (maps clamp to [-2, 3.5] by default), once Newton converges
/// quadratically and the error left after its step (about step^3 / previous step^2) is below
/// 1e-18: that saves the evaluation that would only confirm the root (l within 2e-13 of the
/// converged one).
inline double weighted_chernoff_weight(double la, double lb, double ca, double cb, double w0) {
  const double d = la - lb;
  if (std::fabs(d) < 1e-6) {
    // leading order: c_a (1-w)^2 = c_b w^2
    const double ra = std::sqrt(ca), rb = std::sqrt(cb);
    return ra / (ra + rb);
  }
  double lo = 0.0, hi = 1.0;
  double w = (w0 > 0.0 && w0 < 1.0) ? w0 : 0.5;
  const double rho = std::sqrt(ca / cb);
  if (rho > 0.0 && std::isfinite(rho)) {
    const double ws = rho * w / (rho * w + (1.0 - w));
    if (ws > 0.0 && ws < 1.0) w = ws;
  }
  const bool stops_early = std::fabs(la) <= 8.0 && std::fabs(lb) <= 8.0;
  double last_step = 1.0;
  for (int it = 0; it < 100; ++it) {
    const double lw = lb + w * d;
    // both KLs share sigmoid(l_w); evaluate them with l_w <= 0 (KL is symmetric in sign)
    const double sg = lw > 0.0 ? -1.0 : 1.0;
    const double y = sg * lw;
    const double e = std::exp(y);
    const double s = e / (1.0 + e);
    const double ka = ca * kl_core(s, y, sg * la - y), kb = cb * kl_core(s, y, sg * lb - y);
    const double g = ka - kb;
    if (std::fabs(g) <= 1e-15 * (ka + kb)) return w;
    if (g > 0.0)
      lo = w;
    else
      hi = w;
    // dKL(p_w||p_x)/dw = sigmoid'(l_w) (l_w - l_x) d;  dsqrt(k)/dw = (dk/dw) / (2 sqrt(k))
    const double ra = std::sqrt(ka), rb = std::sqrt(kb);
    const double dh = 0.5 * d * s * (1.0 - s) * (ca * (lw - la) / ra - cb * (lw - lb) / rb);
    double next = (dh != 0.0 && std::isfinite(dh)) ? w - (ra - rb) / dh : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    const double step = std::fabs(next - w);
    if (step < 1e-14 || hi - lo < 1e-14) return next;
    const bool converged =
        step < 1e-3 * last_step && step * step * step < 1e-18 * last_step * last_step;
    if (stops_early && converged) return next;
    last_step = step;
    w = next;
  }
  return w;
}

}  // namespace octofuse::detail
