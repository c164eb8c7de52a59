// octofuse: per-voxel weighted exponential product (WEP) fusion rules on Bernoulli log-odds.
//
// Pure functions on doubles, no OctoMap types. All rules work in log-odds l = log(p / (1 - p));
// a WEP fusion p_w ∝ p_a^w p_b^(1-w) is linear in log-odds: l_w = w l_a + (1 - w) l_b.
// See MATH.md of the design notes for the derivations.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <type_traits>

namespace octofuse {

/// The fusion rules. The numeric values are stable (they cross the Python boundary).
enum class Rule : std::uint8_t {
  NaiveBayes = 0,          ///< l = l_a + l_b - l_0 (assumes independence; baseline)
  Bhattacharyya = 1,       ///< w = 1/2
  MinEntropy = 2,          ///< argmin_w H(p_w): the endpoint with the larger |l - 0|
  Chernoff = 3,            ///< KL(p_w || p_a) = KL(p_w || p_b), closed form
  EntropyWeightedChernoff = 4,  ///< KL(p_w||p_a)/H(p_a) = KL(p_w||p_b)/H(p_b), root finding
  KldWeightedChernoff = 5,      ///< KL(p_a||p_0) KL(p_w||p_a) = KL(p_b||p_0) KL(p_w||p_b)
  MinInfoLoss = 6,         ///< argmin_w KL(p_NB || p_w): l_NB projected onto [l_a, l_b]
};

/// Number of rules in `Rule`.
inline constexpr int kNumRules = 7;

/// Canonical rule names, indexed by the numeric value of `Rule`.
inline constexpr const char* kRuleNames[kNumRules] = {
    "naive-bayes", "bhattacharyya", "min-entropy", "chernoff",
    "entropy-weighted-chernoff", "kld-weighted-chernoff", "min-info-loss"};

/// Name of a rule (as used on the command line and in Python).
inline const char* rule_name(Rule r) { return kRuleNames[static_cast<int>(r)]; }

/// Parses a rule name; returns false if the name is unknown.
inline bool parse_rule(std::string_view name, Rule& out) {
  for (int i = 0; i < kNumRules; ++i) {
    if (name == kRuleNames[i]) {
      out = static_cast<Rule>(i);
      return true;
    }
  }
  return false;
}

/// Result of fusing one voxel.
struct Fused {
  double l;          ///< fused log-odds (not clamped)
  double omega;      ///< chosen WEP weight on a (NaN for naive-bayes)
  double info_loss;  ///< KL(p_NB || p_fused) in nats (0 for naive-bayes)
};

namespace detail {

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

/// softplus(y + d) - softplus(y), given s = sigmoid(y); accurate when |d| is small.
inline double softplus_diff(double y, double d, double s) {
  if (std::fabs(d) < 1.0) return log1p_fast(s * std::expm1(d));
  return softplus(y + d) - softplus(y);
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
           (0.5 + d * (t / 6.0 +
                       d * ((1.0 - 6.0 * v) / 24.0 +
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
/// (|g| <= 1e-15 (c_a KL_a + c_b KL_b)), or when a step or the bracket is below 1e-14.
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
    if (g > 0.0) lo = w; else hi = w;
    // dKL(p_w||p_x)/dw = sigmoid'(l_w) (l_w - l_x) d;  dsqrt(k)/dw = (dk/dw) / (2 sqrt(k))
    const double ra = std::sqrt(ka), rb = std::sqrt(kb);
    const double dh = 0.5 * d * s * (1.0 - s) * (ca * (lw - la) / ra - cb * (lw - lb) / rb);
    double next = (dh != 0.0 && std::isfinite(dh)) ? w - (ra - rb) / dh : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::fabs(next - w) < 1e-14 || hi - lo < 1e-14) return next;
    w = next;
  }
  return w;
}

/// Chernoff fusion of finite la, lb with |la - lb| >= 0.5 and |la|, |lb| <= 150 (prior
/// log-odds 0) in four steps that share their exponentials: with e_x = exp(-|l_x|),
/// e^l* = |B / A| and exp(-|l_NB|) follow from e_a and e_b, so the KL needs no exp of its own.
/// The array kernel runs each step over a block of pairs (independent work for the CPU to
/// overlap) and chernoff_fuse_wide() runs them one after the other: the same operations,
/// so the same results.
struct ChernoffWide {
  /// Whether the fast path applies to (la, lb) (finite, prior log-odds l0 = 0).
  static bool applies(double la, double lb, double l0) {
    return l0 == 0.0 && std::fabs(la - lb) >= 0.5 && std::fabs(la) <= 150.0 &&
           std::fabs(lb) <= 150.0;
  }
  /// Step 1: e_a = exp(-|la|), e_b = exp(-|lb|).
  static void exps(double la, double lb, double& ea, double& eb) {
    ea = std::exp(-std::fabs(la));
    eb = std::exp(-std::fabs(lb));
  }
  /// Step 2: log1p(e_b) - log1p(e_a) = log1p((e_b - e_a) / (1 + e_a)), the shared part of
  /// softplus(+-l_b) - softplus(+-l_a). When l_a and l_b have the same sign,
  /// |e_b - e_a| >= (1 - e^-0.5) max(e_a, e_b), so the difference is accurate to a few ulps;
  /// otherwise the result is small beside the other terms of B and A.
  static double dlog(double ea, double eb) { return log1p_fast((eb - ea) / (1.0 + ea)); }
  /// Step 3: r = e^l*, then w (clamped to [0, 1]) and l (clamped to the inputs) exactly as
  /// chernoff_weight() and fuse_logodds() compute them from l* = log(r). Returns false if a
  /// clamp changed w or l (then the KL is computed the general way).
  static bool weight(double la, double lb, double dl, double& r, double& w, double& l) {
    const double d = la - lb;
    const double B = ((lb > 0.0 ? lb : 0.0) - (la > 0.0 ? la : 0.0)) + dl;
    const double A = ((lb < 0.0 ? -lb : 0.0) - (la < 0.0 ? -la : 0.0)) + dl;
    r = std::fabs(B / A);
    w = (std::log(r) - lb) / d;
    w = w < 0.0 ? 0.0 : (w > 1.0 ? 1.0 : w);
    const double lo = la < lb ? la : lb, hi = la < lb ? lb : la;
    const double lw = w * la + (1.0 - w) * lb;
    l = lw < lo ? lo : (lw > hi ? hi : lw);
    return w > 0.0 && w < 1.0 && l == lw;
  }
  /// Step 4: KL(p_NB || p_l), l_NB = la + lb, in kl_core's form (l_q <= 0); e^l = r to
  /// rounding.
  static double info_loss(double la, double lb, double ea, double eb, double r, double l) {
    const double lnb = la + lb;
    const double enb = (la >= 0.0) == (lb >= 0.0)
                           ? ea * eb
                           : (std::fabs(la) > std::fabs(lb) ? ea / eb : eb / ea);
    const double s = enb / (1.0 + enb);  // sigmoid(-|l_NB|)
    const double y = lnb > 0.0 ? -lnb : lnb;
    const double dk = lnb > 0.0 ? lnb - l : l - lnb;
    if (std::fabs(dk) < 0.5) return kl_core(s, y, dk);
    const double E = lnb > 0.0 ? 1.0 / (enb * r) : r / enb;  // exp(dk)
    const double kl = log1p_fast(s * (E - 1.0)) - s * dk;
    return kl > 0.0 ? kl : 0.0;
  }
};

/// The Chernoff fusion of one pair for which ChernoffWide::applies().
inline Fused chernoff_fuse_wide(double la, double lb) {
  double ea, eb, r, w, l;
  ChernoffWide::exps(la, lb, ea, eb);
  const double dl = ChernoffWide::dlog(ea, eb);
  if (!ChernoffWide::weight(la, lb, dl, r, w, l)) return {l, w, kl_logodds(la + lb, l)};
  return {l, w, ChernoffWide::info_loss(la, lb, ea, eb, r, l)};
}

/// Both inputs certain or one certain (infinite log-odds): a certainty dominates.
/// Returns false for contradictory certainties (+inf with -inf), which have no fusion.
inline bool fuse_certain(double la, double lb, Fused& out) {
  const bool ia = std::isinf(la), ib = std::isinf(lb);
  if (ia && ib) {
    if ((la > 0) != (lb > 0)) return false;
    out = {la, 0.5, 0.0};
  } else if (ia) {
    out = {la, 1.0, 0.0};
  } else {
    out = {lb, 0.0, 0.0};
  }
  return true;
}

}  // namespace detail

/// Chooses the WEP weight w (weight on a) of rule R for finite log-odds la, lb.
/// `l0` is the common prior's log-odds (0 for OctoMap). Not defined for naive-bayes (NaN).
template <Rule R>
inline double wep_weight(double la, double lb, double l0) {
  using namespace detail;
  if (la == lb) return 0.5;  // every w gives the same value
  if constexpr (R == Rule::Bhattacharyya) {
    return 0.5;
  } else if constexpr (R == Rule::MinEntropy) {  // ties prefer a
    return std::fabs(la) >= std::fabs(lb) ? 1.0 : 0.0;
  } else if constexpr (R == Rule::Chernoff) {
    return chernoff_weight(la, lb);
  } else if constexpr (R == Rule::EntropyWeightedChernoff) {
    const double ha = entropy_logodds(la), hb = entropy_logodds(lb);
    if (ha == hb) return chernoff_weight(la, lb);
    // c = 1/H, both scaled by H_a H_b: c_a -> H_b, c_b -> H_a
    return weighted_chernoff_weight(la, lb, hb, ha, chernoff_weight(la, lb));
  } else if constexpr (R == Rule::KldWeightedChernoff) {
    const double ca = kl_logodds(la, l0), cb = kl_logodds(lb, l0);
    if (ca <= 0.0 && cb <= 0.0) return 0.5;
    if (ca <= 0.0) return 0.0;  // a learnt nothing over the prior: take b
    if (cb <= 0.0) return 1.0;
    return weighted_chernoff_weight(la, lb, ca, cb, chernoff_weight(la, lb));
  } else if constexpr (R == Rule::MinInfoLoss) {
    const double w = (la + lb - l0 - lb) / (la - lb);
    return w < 0.0 ? 0.0 : (w > 1.0 ? 1.0 : w);
  } else {
    return kNaN;
  }
}

/// Fuses one voxel given in log-odds with rule R (a compile-time constant; see the overload
/// taking the rule at run time). Infinite inputs (p = 0 or 1) are certainties that
/// dominate; NaN inputs or contradictory certainties (+inf with -inf) give NaN in every
/// field (callers validate and report those).
template <Rule R>
inline Fused fuse_logodds(double la, double lb, double l0 = 0.0) {
  using namespace detail;
  if (std::isnan(la) || std::isnan(lb)) return {kNaN, kNaN, kNaN};
  if (std::isinf(la) || std::isinf(lb)) {
    Fused f;
    if (!fuse_certain(la, lb, f)) return {kNaN, kNaN, kNaN};
    if (R == Rule::NaiveBayes) f.omega = kNaN;
    return f;
  }
  const double lnb = la + lb - l0;
  if constexpr (R == Rule::NaiveBayes) {
    return {lnb, kNaN, 0.0};
  } else {
    const double lo = la < lb ? la : lb, hi = la < lb ? lb : la;
    if constexpr (R == Rule::MinInfoLoss) {
      // exact projection, so the loss is exactly 0 when l_NB lies between the inputs
      const double l = lnb < lo ? lo : (lnb > hi ? hi : lnb);
      return {l, wep_weight<R>(la, lb, l0), l == lnb ? 0.0 : kl_logodds(lnb, l)};
    } else {
      if constexpr (R == Rule::Chernoff) {
        if (ChernoffWide::applies(la, lb, l0)) return chernoff_fuse_wide(la, lb);
      }
      const double w = wep_weight<R>(la, lb, l0);
      double l = w * la + (1.0 - w) * lb;  // exact at w = 0 and w = 1
      l = l < lo ? lo : (l > hi ? hi : l);
      return {l, w, kl_logodds(lnb, l)};
    }
  }
}

/// Calls f(std::integral_constant<Rule, rule>{}): runs code specialised for one rule.
template <class F>
inline decltype(auto) with_rule(Rule rule, F&& f) {
  switch (rule) {
    case Rule::Bhattacharyya:
      return f(std::integral_constant<Rule, Rule::Bhattacharyya>{});
    case Rule::MinEntropy:
      return f(std::integral_constant<Rule, Rule::MinEntropy>{});
    case Rule::Chernoff:
      return f(std::integral_constant<Rule, Rule::Chernoff>{});
    case Rule::EntropyWeightedChernoff:
      return f(std::integral_constant<Rule, Rule::EntropyWeightedChernoff>{});
    case Rule::KldWeightedChernoff:
      return f(std::integral_constant<Rule, Rule::KldWeightedChernoff>{});
    case Rule::MinInfoLoss:
      return f(std::integral_constant<Rule, Rule::MinInfoLoss>{});
    case Rule::NaiveBayes:
      break;
  }
  return f(std::integral_constant<Rule, Rule::NaiveBayes>{});
}

/// Chooses the WEP weight w (weight on a) of a rule for finite log-odds la, lb.
/// `l0` is the common prior's log-odds (0 for OctoMap). Not defined for naive-bayes (NaN).
inline double wep_weight(Rule rule, double la, double lb, double l0) {
  return with_rule(rule, [&](auto r) { return wep_weight<decltype(r)::value>(la, lb, l0); });
}

/// Fuses one voxel given in log-odds. Infinite inputs (p = 0 or 1) are certainties that
/// dominate; NaN inputs or contradictory certainties (+inf with -inf) give NaN in every
/// field (callers validate and report those).
inline Fused fuse_logodds(Rule rule, double la, double lb, double l0 = 0.0) {
  return with_rule(rule, [&](auto r) { return fuse_logodds<decltype(r)::value>(la, lb, l0); });
}

}  // namespace octofuse
