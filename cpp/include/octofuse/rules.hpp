// octofuse: per-voxel weighted exponential product (WEP) fusion rules on Bernoulli log-odds.
//
// Pure functions on doubles, no OctoMap types. All rules work in log-odds l = log(p / (1 - p));
// a WEP fusion p_w ∝ p_a^w p_b^(1-w) is linear in log-odds: l_w = w l_a + (1 - w) l_b.
// See MATH.md of the design notes for the derivations. The numerics live in detail/.
#pragma once

#include "octofuse/detail/bernoulli_math.hpp"
#include "octofuse/detail/chernoff_pack.hpp"

#include <cmath>
#include <cstdint>
#include <type_traits>

namespace octofuse {

/// The fusion rules. The numeric values are stable (they cross the Python boundary).
enum class Rule : std::uint8_t {
  NaiveBayes = 0,               ///< l = l_a + l_b - l_0 (assumes independence; baseline)
  Bhattacharyya = 1,            ///< w = 1/2
  MinEntropy = 2,               ///< argmin_w H(p_w): the endpoint with the larger |l - 0|
  Chernoff = 3,                 ///< KL(p_w || p_a) = KL(p_w || p_b), closed form
  EntropyWeightedChernoff = 4,  ///< KL(p_w||p_a)/H(p_a) = KL(p_w||p_b)/H(p_b), root finding
  KldWeightedChernoff = 5,      ///< KL(p_a||p_0) KL(p_w||p_a) = KL(p_b||p_0) KL(p_w||p_b)
  MinInfoLoss = 6,              ///< argmin_w KL(p_NB || p_w): l_NB projected onto [l_a, l_b]
};

/// Number of rules in `Rule`.
inline constexpr int kNumRules = 7;

/// Canonical rule names (command line, configuration, Python), indexed by `Rule`.
inline constexpr const char* kRuleNames[kNumRules] = {"naive-bayes",
                                                      "bhattacharyya",
                                                      "min-entropy",
                                                      "chernoff",
                                                      "entropy-weighted-chernoff",
                                                      "kld-weighted-chernoff",
                                                      "min-info-loss"};

/// Name of a rule.
inline const char* rule_name(Rule r) { return kRuleNames[static_cast<int>(r)]; }

/// Result of fusing one voxel.
struct Fused {
  double l;          ///< fused log-odds (not clamped)
  double omega;      ///< chosen WEP weight on a (NaN for naive-bayes)
  double info_loss;  ///< KL(p_NB || p_fused) in nats (0 for naive-bayes)
};

/// Fuses one voxel given in log-odds with rule R. Infinite inputs (p = 0 or 1) are
/// certainties that dominate; NaN inputs or contradictory certainties (+inf with -inf) give
/// NaN in every field (callers validate and report those). `l0` is the common prior.
template <Rule R>
Fused fuse_logodds(double la, double lb, double l0 = 0.0);

/// The WEP weight w (weight on a) of rule R for finite la != lb (NaN for naive-bayes).
template <Rule R>
double wep_weight(double la, double lb, double l0);

/// Calls f(std::integral_constant<Rule, rule>{}): runs code specialised for one rule. Call it
/// once, outside loops over voxels.
template <class F>
decltype(auto) with_rule(Rule rule, F&& f);

/// fuse_logodds<R>() with the rule chosen at run time (for single values and tests).
inline Fused fuse_logodds(Rule rule, double la, double lb, double l0 = 0.0);

// ---------------------------------------------------------------------------------------------
// Definitions.

template <class F>
decltype(auto) with_rule(Rule rule, F&& f) {
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

namespace detail {

/// The Chernoff fusion of one pair for which chernoff_pack_applies(): chernoff_pack() on a pack
/// holding the pair in every lane (so the same bits as when the pair is fused in an array).
inline Fused chernoff_fuse_one(double la, double lb) {
  double a[kPackLanes], b[kPackLanes], l[kPackLanes], w[kPackLanes], loss[kPackLanes];
  for (int i = 0; i < kPackLanes; ++i) {
    a[i] = la;
    b[i] = lb;
  }
  chernoff_pack<kPackLanes>(a, b, l, w, loss);
  return {l[0], w[0], loss[0]};
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

/// Whether R is one of the weighted Chernoff rules (a factor per map, then a root finding).
constexpr bool is_weighted_chernoff(Rule r) {
  return r == Rule::EntropyWeightedChernoff || r == Rule::KldWeightedChernoff;
}

/// Whether R fuses a pair in the order (lower, higher) whatever order it comes in: the rules
/// whose arithmetic is not symmetric in a and b as written (a closed form or a root finding),
/// so that fusing (a, b) and (b, a) gives the same bits.
constexpr bool fuses_lower_first(Rule r) { return r == Rule::Chernoff || is_weighted_chernoff(r); }

/// Whether R's fused value and loss do not depend on the order of the pair, bit for bit:
/// every rule but min-entropy (whose ties prefer a). Naive Bayes, Bhattacharyya and
/// min-info-loss are symmetric as written; the others fuse lower first.
constexpr bool is_order_free(Rule r) { return r != Rule::MinEntropy; }

/// A weighted Chernoff rule's factor of one map's value: its entropy (entropy-weighted: the
/// rule balances KL / H) or its KL from the prior (KLD-weighted: the rule balances c KL).
template <Rule R>
inline double chernoff_factor(double l, double l0) {
  static_assert(is_weighted_chernoff(R));
  if constexpr (R == Rule::EntropyWeightedChernoff) {
    return entropy_logodds(l);
  } else {
    return kl_logodds(l, l0);
  }
}

/// The Chernoff weight of finite la != lb as the weighted rules' iteration starts from: by the
/// midpoint series where |la - lb| < 1 (within 1e-8 of it, at a third of its cost), else exact.
inline double chernoff_weight_start(double la, double lb) {
  const double d = la - lb;
  if (!(std::fabs(d) < 1.0)) return chernoff_weight(la, lb);
  const double m = 0.5 * (la + lb), e = std::exp(-std::fabs(m));
  const double t = (m > 0.0 ? e - 1.0 : 1.0 - e) / (1.0 + e);  // 1 - 2 sigmoid(m)
  return 0.5 + chernoff_midpoint_series(t, d);
}

/// The weight of a weighted Chernoff rule for finite la != lb, given both maps' factors.
template <Rule R>
inline double weighted_chernoff_weight(double la, double lb, double ca, double cb) {
  static_assert(is_weighted_chernoff(R));
  if constexpr (R == Rule::EntropyWeightedChernoff) {
    if (ca == cb) return chernoff_weight(la, lb);
    // c = 1/H, both scaled by H_a H_b: c_a -> H_b, c_b -> H_a
    return weighted_chernoff_weight(la, lb, cb, ca, chernoff_weight_start(la, lb));
  } else {
    if (ca <= 0.0 && cb <= 0.0) return 0.5;
    if (ca <= 0.0) return 0.0;  // a learnt nothing over the prior: take b
    if (cb <= 0.0) return 1.0;
    return weighted_chernoff_weight(la, lb, ca, cb, chernoff_weight_start(la, lb));
  }
}

/// The WEP fusion of finite la, lb with weight w on a: the fused log-odds (kept between the
/// inputs), w and the loss against naive Bayes.
inline Fused wep_fuse(double la, double lb, double l0, double w) {
  const double lo = la < lb ? la : lb, hi = la < lb ? lb : la;
  double l = w * la + (1.0 - w) * lb;  // exact at w = 0 and w = 1
  l = l < lo ? lo : (l > hi ? hi : l);
  return {l, w, kl_logodds(la + lb - l0, l)};
}

}  // namespace detail

template <Rule R>
inline double wep_weight(double la, double lb, double l0) {
  using namespace detail;
  if (la == lb) return 0.5;  // every w gives the same value
  if constexpr (fuses_lower_first(R)) {
    if (la > lb) return 1.0 - wep_weight<R>(lb, la, l0);
  }
  if constexpr (R == Rule::Bhattacharyya) {
    return 0.5;
  } else if constexpr (R == Rule::MinEntropy) {  // ties prefer a
    return std::fabs(la) >= std::fabs(lb) ? 1.0 : 0.0;
  } else if constexpr (R == Rule::Chernoff) {
    return chernoff_weight(la, lb);
  } else if constexpr (is_weighted_chernoff(R)) {
    return weighted_chernoff_weight<R>(la, lb, chernoff_factor<R>(la, l0),
                                       chernoff_factor<R>(lb, l0));
  } else if constexpr (R == Rule::MinInfoLoss) {
    const double w = (la + lb - l0 - lb) / (la - lb);
    return w < 0.0 ? 0.0 : (w > 1.0 ? 1.0 : w);
  } else {
    return kNaN;
  }
}

template <Rule R>
inline Fused fuse_logodds(double la, double lb, double l0) {
  using namespace detail;
  if (std::isnan(la) || std::isnan(lb)) return {kNaN, kNaN, kNaN};
  if (std::isinf(la) || std::isinf(lb)) {
    Fused f;
    if (!fuse_certain(la, lb, f)) return {kNaN, kNaN, kNaN};
    if (R == Rule::NaiveBayes) f.omega = kNaN;
    return f;
  }
  if constexpr (fuses_lower_first(R)) {
    if (la > lb) {  // fused as (lb, la): the same bits in either order
      Fused f = fuse_logodds<R>(lb, la, l0);
      f.omega = 1.0 - f.omega;
      return f;
    }
  }
  const double lnb = la + lb - l0;
  if constexpr (R == Rule::NaiveBayes) {
    return {lnb, kNaN, 0.0};
  } else {
    if constexpr (R == Rule::MinInfoLoss) {
      // exact projection, so the loss is exactly 0 when l_NB lies between the inputs
      const double lo = la < lb ? la : lb, hi = la < lb ? lb : la;
      const double l = lnb < lo ? lo : (lnb > hi ? hi : lnb);
      return {l, wep_weight<R>(la, lb, l0), l == lnb ? 0.0 : kl_logodds(lnb, l)};
    } else {
      if constexpr (R == Rule::Chernoff) {
        if (chernoff_pack_applies(la, lb, l0)) return chernoff_fuse_one(la, lb);
      }
      return wep_fuse(la, lb, l0, wep_weight<R>(la, lb, l0));
    }
  }
}

inline Fused fuse_logodds(Rule rule, double la, double lb, double l0) {
  return with_rule(rule, [&](auto r) { return fuse_logodds<decltype(r)::value>(la, lb, l0); });
}

}  // namespace octofuse
