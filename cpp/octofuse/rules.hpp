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

/// log(1 + e^x), stable for all finite x.
inline double softplus(double x) {
  return x > 0.0 ? x + std::log1p(std::exp(-x)) : std::log1p(std::exp(x));
}

/// Logistic sigmoid 1 / (1 + e^-x), stable.
inline double sigmoid(double x) {
  if (x >= 0.0) return 1.0 / (1.0 + std::exp(-x));
  const double e = std::exp(x);
  return e / (1.0 + e);
}

/// softplus(y + d) - softplus(y), given s = sigmoid(y); accurate when |d| is small.
inline double softplus_diff(double y, double d, double s) {
  if (std::fabs(d) < 1.0) return std::log1p(s * std::expm1(d));
  return softplus(y + d) - softplus(y);
}

/// KL(q || p) between Bernoullis given in log-odds (lq, lp), finite:
/// KL = softplus(lp) - softplus(lq) - sigmoid(lq) (lp - lq).
inline double kl_logodds(double lq, double lp) {
  const double d = lp - lq;
  const double sq = sigmoid(lq);
  if (std::fabs(d) < 1e-3) {
    // Taylor series of the softplus Bregman divergence (no cancellation for tiny d)
    const double v = sq * (1.0 - sq);
    return v * d * d * (0.5 + d * ((1.0 - 2.0 * sq) / 6.0 + d * (1.0 - 6.0 * v) / 24.0));
  }
  const double kl = softplus_diff(lq, d, sq) - sq * d;
  return kl > 0.0 ? kl : 0.0;  // rounding can give -1e-17
}

/// Shannon entropy (nats) of a Bernoulli with log-odds l: H = softplus(l) - sigmoid(l) l.
inline double entropy_logodds(double l) { return softplus(l) - sigmoid(l) * l; }

/// Chernoff point: the log-odds l* with KL(p* || p_a) = KL(p* || p_b) (closed form).
/// Requires finite la != lb. With A = log(p_a/p_b), B = log((1-p_a)/(1-p_b)):
/// p* = B / (B - A), so logit(p*) = log(-B / A). A and B have opposite signs.
inline double chernoff_logodds(double la, double lb) {
  const double d = la - lb;
  const double s = sigmoid(lb), sm = sigmoid(-lb);
  // B = -(sp(la) - sp(lb)), A = -(sp(-la) - sp(-lb))
  const double B = -softplus_diff(lb, d, s);
  const double A = -softplus_diff(-lb, -d, sm);
  return std::log(std::fabs(B)) - std::log(std::fabs(A));
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

/// Solves c_a KL(p_w || p_a) = c_b KL(p_w || p_b) for w in [0, 1] by safeguarded Newton
/// iterations starting from w0. g(w) is >= 0 at w = 0, <= 0 at w = 1 and decreasing.
inline double weighted_chernoff_weight(double la, double lb, double ca, double cb, double w0) {
  const double d = la - lb;
  if (std::fabs(d) < 1e-6) {
    // leading order: c_a (1-w)^2 = c_b w^2
    const double ra = std::sqrt(ca), rb = std::sqrt(cb);
    return ra / (ra + rb);
  }
  double lo = 0.0, hi = 1.0;
  double w = (w0 > 0.0 && w0 < 1.0) ? w0 : 0.5;
  for (int it = 0; it < 100; ++it) {
    const double lw = lb + w * d;
    const double g = ca * kl_logodds(lw, la) - cb * kl_logodds(lw, lb);
    if (g == 0.0) return w;
    if (g > 0.0) lo = w; else hi = w;
    // dKL(p_w||p_x)/dl_w = s'(lw) (lw - lx); dl_w/dw = d
    const double sw = sigmoid(lw);
    const double dg = d * sw * (1.0 - sw) * (ca * (lw - la) - cb * (lw - lb));
    double next = (dg != 0.0 && std::isfinite(dg)) ? w - g / dg : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::fabs(next - w) < 1e-14 || hi - lo < 1e-14) return next;
    w = next;
  }
  return w;
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

/// Chooses the WEP weight w (weight on a) of a rule for finite log-odds la, lb.
/// `l0` is the common prior's log-odds (0 for OctoMap). Not defined for naive-bayes (NaN).
inline double wep_weight(Rule rule, double la, double lb, double l0) {
  using namespace detail;
  if (la == lb) return 0.5;  // every w gives the same value
  switch (rule) {
    case Rule::Bhattacharyya:
      return 0.5;
    case Rule::MinEntropy:  // ties prefer a
      return std::fabs(la) >= std::fabs(lb) ? 1.0 : 0.0;
    case Rule::Chernoff:
      return chernoff_weight(la, lb);
    case Rule::EntropyWeightedChernoff: {
      const double ha = entropy_logodds(la), hb = entropy_logodds(lb);
      if (ha == hb) return chernoff_weight(la, lb);
      // c = 1/H, both scaled by H_a H_b: c_a -> H_b, c_b -> H_a
      return weighted_chernoff_weight(la, lb, hb, ha, chernoff_weight(la, lb));
    }
    case Rule::KldWeightedChernoff: {
      const double ca = kl_logodds(la, l0), cb = kl_logodds(lb, l0);
      if (ca <= 0.0 && cb <= 0.0) return 0.5;
      if (ca <= 0.0) return 0.0;  // a learnt nothing over the prior: take b
      if (cb <= 0.0) return 1.0;
      return weighted_chernoff_weight(la, lb, ca, cb, chernoff_weight(la, lb));
    }
    case Rule::MinInfoLoss: {
      const double w = (la + lb - l0 - lb) / (la - lb);
      return w < 0.0 ? 0.0 : (w > 1.0 ? 1.0 : w);
    }
    case Rule::NaiveBayes:
      break;
  }
  return kNaN;
}

/// Fuses one voxel given in log-odds. Infinite inputs (p = 0 or 1) are certainties that
/// dominate; NaN inputs or contradictory certainties (+inf with -inf) give NaN in every
/// field (callers validate and report those).
inline Fused fuse_logodds(Rule rule, double la, double lb, double l0 = 0.0) {
  using namespace detail;
  if (std::isnan(la) || std::isnan(lb)) return {kNaN, kNaN, kNaN};
  if (std::isinf(la) || std::isinf(lb)) {
    Fused f;
    if (!fuse_certain(la, lb, f)) return {kNaN, kNaN, kNaN};
    if (rule == Rule::NaiveBayes) f.omega = kNaN;
    return f;
  }
  const double lnb = la + lb - l0;
  if (rule == Rule::NaiveBayes) return {lnb, kNaN, 0.0};
  const double lo = la < lb ? la : lb, hi = la < lb ? lb : la;
  if (rule == Rule::MinInfoLoss) {
    // exact projection, so the loss is exactly 0 when l_NB lies between the inputs
    const double l = lnb < lo ? lo : (lnb > hi ? hi : lnb);
    return {l, wep_weight(rule, la, lb, l0), l == lnb ? 0.0 : kl_logodds(lnb, l)};
  }
  const double w = wep_weight(rule, la, lb, l0);
  double l = w * la + (1.0 - w) * lb;  // exact at w = 0 and w = 1
  l = l < lo ? lo : (l > hi ? hi : l);
  return {l, w, kl_logodds(lnb, l)};
}

}  // namespace octofuse
