// octofuse: per-voxel weighted exponential product (WEP) fusion rules on Bernoulli log-odds.
//
// Pure functions on doubles, no OctoMap types. All rules work in log-odds l = log(p / (1 - p));
// a WEP fusion p_w ∝ p_a^w p_b^(1-w) is linear in log-odds: l_w = w l_a + (1 - w) l_b.
// See MATH.md of the design notes for the derivations.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
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

// ---------------------------------------------------------------------------------------------
// The Chernoff rule on packs of pairs.
//
// chernoff_pack<N>() fuses N pairs at once with code in which every lane goes through the same
// operations: both sides of each choice are computed and one is selected per lane (a side that
// no lane needs may be skipped, which changes nothing). Its exp, expm1 and log are the
// polynomials below, not the C library's. So a pair gets the same bits in any lane of any
// pack: the array kernel fuses packs of kArrayLanes pairs (independent work that the CPU
// overlaps), fuse_logodds<Chernoff>() a pack of kPackLanes copies of its one pair, and the
// two agree exactly. Nothing relies on -ffast-math, and the lanes of a pack never mix.

#if defined(__GNUC__) && !defined(__clang__)
// Packs wider than a register only pass between inline functions, so the x86-64 ABI note on
// passing them is moot. (GCC reports it at the end of the file, so it stays off.)
#pragma GCC diagnostic ignored "-Wpsabi"
#endif

#if defined(__GNUC__)
/// Two doubles (one SSE2 register), the bits of its lanes, and the result of comparing two:
/// GCC/Clang vector extension.
typedef double Pack2 __attribute__((vector_size(16)));
typedef unsigned long long PackBits2 __attribute__((vector_size(16)));
typedef long long PackMask2 __attribute__((vector_size(16)));
/// Operations on packs of N doubles, a GCC/Clang vector type computed lane by lane (SSE2 on
/// x86-64, two lanes per register), with integer and comparison types of the same shape.
template <class V_, class Bits_, class Mask_, int N>
struct PackOps {
  using V = V_;
  using Bits = Bits_;
  using Mask = Mask_;
  static V splat(double x) {
    V v;
    for (int i = 0; i < N; ++i) v[i] = x;
    return v;
  }
  static Bits bits(const V& x) { return (Bits)x; }
  static V from_bits(const Bits& b) { return (V)b; }
  /// a where m is true, else b.
  static V select(const Mask& m, const V& a, const V& b) {
    return (V)(((Bits)a & (Bits)m) | ((Bits)b & ~(Bits)m));
  }
  /// a < b lane by lane, in registers of two lanes (GCC would compare wider packs one lane
  /// at a time).
  static Mask lt(const V& a, const V& b) {
    if constexpr (N <= 2) {
      return a < b;
    } else {
      constexpr int kRegs = N / 2;
      Pack2 x[kRegs], y[kRegs];
      PackMask2 r[kRegs];
      std::memcpy(x, &a, sizeof x);
      std::memcpy(y, &b, sizeof y);
      for (int i = 0; i < kRegs; ++i) r[i] = x[i] < y[i];
      Mask m;
      std::memcpy(&m, r, sizeof m);
      return m;
    }
  }
  /// Whether m is true in some lane / in every lane.
  static bool any(const Mask& m) {
    long long r = 0;
    for (int i = 0; i < N; ++i) r |= m[i];
    return r != 0;
  }
  static bool all(const Mask& m) {
    long long r = -1;
    for (int i = 0; i < N; ++i) r &= m[i];
    return r != 0;
  }
  /// table[i] in each lane (i in range).
  static V gather(const double* table, const Bits& i) {
    V r;
    for (int l = 0; l < N; ++l) r[l] = table[i[l]];
    return r;
  }
  static V sqrt(const V& x) {
    V r;
    for (int i = 0; i < N; ++i) r[i] = __builtin_sqrt(x[i]);
    return r;
  }
};
/// Eight doubles (four SSE2 registers), for the array kernel.
typedef double Pack8 __attribute__((vector_size(64)));
typedef unsigned long long PackBits8 __attribute__((vector_size(64)));
typedef long long PackMask8 __attribute__((vector_size(64)));
template <int N>
struct PackOf;
template <>
struct PackOf<2> : PackOps<Pack2, PackBits2, PackMask2, 2> {};
template <>
struct PackOf<8> : PackOps<Pack8, PackBits8, PackMask8, 8> {};
/// Lanes of the pack that fuse_logodds<Chernoff>() fills with its pair (one SSE2 register).
inline constexpr int kPackLanes = 2;
/// Lanes of the packs of the array kernel (four SSE2 registers per value).
inline constexpr int kArrayLanes = 8;
#else
/// Other compilers: packs of one double.
template <int N>
struct PackOf {
  using V = double;
  using Bits = std::uint64_t;
  using Mask = bool;
  static V splat(double x) { return x; }
  static Bits bits(V x) {
    Bits b;
    std::memcpy(&b, &x, sizeof b);
    return b;
  }
  static V from_bits(Bits b) {
    V x;
    std::memcpy(&x, &b, sizeof x);
    return x;
  }
  static V select(bool m, V a, V b) { return m ? a : b; }
  static bool lt(V a, V b) { return a < b; }
  static bool any(bool m) { return m; }
  static bool all(bool m) { return m; }
  static V gather(const double* table, Bits i) { return table[i]; }
  static V sqrt(V x) { return std::sqrt(x); }
};
inline constexpr int kPackLanes = 1;
inline constexpr int kArrayLanes = 1;
#endif

/// The PackOf of a pack type.
template <class V>
using PackFor = PackOf<static_cast<int>(sizeof(V) / sizeof(double))>;

/// ln 2 = kLn2Hi + kLn2Lo; kLn2Hi has 32 trailing zero bits, so k kLn2Hi is exact for |k| < 2^20.
inline constexpr double kLn2Hi = 6.93147180369123816490e-01;
inline constexpr double kLn2Lo = 1.90821492927058770002e-10;
inline constexpr double kLog2e = 1.44269504088896338700e+00;
/// 1.5 * 2^52: x + kRoundShift holds round(x) in its low bits for |x| < 2^51.
inline constexpr double kRoundShift = 6755399441055744.0;

/// Splits x (|x| <= 708) as k ln2 + r with |r| <= 0.35; returns expm1(r) and sets scale = 2^k.
/// expm1(r) is its Taylor polynomial to r^13 (truncation below 1e-17 relative), evaluated in
/// Estrin's scheme (short dependency chains).
template <class V>
inline V exp_split(const V& x, V& scale) {
  using P = PackFor<V>;
  const V t = x * kLog2e + kRoundShift;  // round(x / ln2) in the low bits of t
  const V k = t - kRoundShift;
  const V r = (x - k * kLn2Hi) - k * kLn2Lo;
  scale = P::from_bits((P::bits(t) - P::bits(P::splat(kRoundShift)) + 1023ull) << 52);
  const V r2 = r * r, r4 = r2 * r2, r8 = r4 * r4;
  const V q = ((0.5 + r * 0.16666666666666666) +
               r2 * (0.041666666666666664 + r * 0.008333333333333333)) +
              r4 * ((0.001388888888888889 + r * 0.0001984126984126984) +
                    r2 * (2.48015873015873e-05 + r * 2.7557319223985893e-06)) +
              r8 * ((2.755731922398589e-07 + r * 2.505210838544172e-08) +
                    r2 * (2.08767569878681e-09 + r * 1.6059043836821613e-10));
  return r + r2 * q;
}

/// e^x for |x| <= 708, within about 1 ulp.
template <class V>
inline V pack_exp(const V& x) {
  V scale;
  const V p = exp_split(x, scale);
  return scale * (1.0 + p);
}

/// e^x - 1 for |x| <= 708, within about 2 ulps (and no cancellation near 0).
template <class V>
inline V pack_expm1(const V& x) {
  V scale;
  const V p = exp_split(x, scale);
  return scale * p + (scale - 1.0);
}

/// Splits a finite normal x > 0 as 2^k m with sqrt(1/2) <= m < sqrt(2); returns m, sets k.
template <class V>
inline V log_split(const V& x, V& k) {
  using P = PackFor<V>;
  const typename P::Bits bits = P::bits(x);
  const V m = P::from_bits((bits & 0x000fffffffffffffull) | 0x3ff0000000000000ull);  // [1, 2)
  // the exponent as a double: the biased exponent in the low bits of 2^52, minus 2^52 + 1023
  k = P::from_bits((bits >> 52) | 0x4330000000000000ull) - (4503599627370496.0 + 1023.0);
  const typename P::Mask big = P::lt(P::splat(1.4142135623730951), m);
  k = P::select(big, k + 1.0, k);
  return P::select(big, m * 0.5, m);
}

/// log(c_j) for the nodes c_j = 1 + j/64, j = -19..27 (index j + 19), to nearest.
inline constexpr double kLogNode[47] = {
    -0.3522205935893521, -0.33024168687057687, -0.3087354816496133, -0.2876820724517809,
    -0.26706278524904525, -0.24686007793152578, -0.22705745063534608, -0.2076393647782445,
    -0.18859116980755003, -0.16989903679539747, -0.15154989812720093, -0.13353139262452263,
    -0.1158318155251217, -0.09844007281325252, -0.0813456394539524, -0.06453852113757118,
    -0.048009219186360606, -0.0317486983145803, -0.015748356968139168, 0.0, 0.015504186535965254,
    0.030771658666753687, 0.0458095360312942, 0.06062462181643484, 0.07522342123758753,
    0.08961215868968714, 0.10379679368164356, 0.11778303565638346, 0.13157635778871926,
    0.1451820098444979, 0.15860503017663857, 0.17185025692665923, 0.184922338494012,
    0.19782574332991987, 0.21056476910734964, 0.22314355131420976, 0.2355660713127669,
    0.24783616390458127, 0.25995752443692605, 0.27193371548364176, 0.2837681731306446,
    0.2954642128938359, 0.3070250352949119, 0.3184537311185346, 0.329753286372468,
    0.3409265869705932, 0.3519764231571782};
/// 1 / c_j, to nearest.
inline constexpr double kInvNode[47] = {
    1.4222222222222223, 1.391304347826087, 1.3617021276595744, 1.3333333333333333,
    1.3061224489795917, 1.28, 1.2549019607843137, 1.2307692307692308, 1.2075471698113207,
    1.1851851851851851, 1.1636363636363636, 1.1428571428571428, 1.1228070175438596,
    1.103448275862069, 1.0847457627118644, 1.0666666666666667, 1.0491803278688525,
    1.032258064516129, 1.0158730158730158, 1.0, 0.9846153846153847, 0.9696969696969697,
    0.9552238805970149, 0.9411764705882353, 0.927536231884058, 0.9142857142857143,
    0.9014084507042254, 0.8888888888888888, 0.8767123287671232, 0.8648648648648649,
    0.8533333333333334, 0.8421052631578947, 0.8311688311688312, 0.8205128205128205,
    0.810126582278481, 0.8, 0.7901234567901234, 0.7804878048780488, 0.7710843373493976,
    0.7619047619047619, 0.7529411764705882, 0.7441860465116279, 0.735632183908046,
    0.7272727272727273, 0.7191011235955056, 0.7111111111111111, 0.7032967032967034};

/// k ln2 + log(m + e) for sqrt(1/2) <= m < sqrt(2) and |e| <= ulp(m), within about 1 ulp
/// (no division): with c the node nearest to m, log(m + e) = log(c) + log1p(r),
/// r = (m - c + e) / c with m - c exact and |r| < 0.0112, and log1p(r) is its Taylor
/// polynomial to r^8 (truncation below 3e-17 relative). Near m = 1 the node is 1 itself, so
/// results near 0 keep their relative accuracy.
template <class V>
inline V log_kernel(const V& k, const V& m, const V& e) {
  using P = PackFor<V>;
  const V t = (m - 1.0) * 64.0 + kRoundShift;  // j = round(64 (m - 1)) in the low bits of t
  const V c = 1.0 + (t - kRoundShift) * 0.015625;
  const typename P::Bits j = P::bits(t) - P::bits(P::splat(kRoundShift)) + 19ull;
  const V r = ((m - c) + e) * P::gather(kInvNode, j);
  const V r2 = r * r, r4 = r2 * r2;
  const V q = ((-0.5 + r * 0.3333333333333333) + r2 * (-0.25 + r * 0.2)) +
              r4 * ((-0.16666666666666666 + r * 0.14285714285714285) - r2 * 0.125);
  return k * kLn2Hi + (P::gather(kLogNode, j) + ((r + r2 * q) + k * kLn2Lo));
}

/// log(x) for finite normal x > 0, within about 1 ulp.
template <class V>
inline V pack_log(const V& x) {
  V k;
  const V m = log_split(x, k);
  return log_kernel(k, m, PackFor<V>::splat(0.0));
}

/// log(1 + x) for -0.5 <= x < 1e300, within about 1 ulp: with u = fl(1 + x) = 2^k m and c
/// its rounding error (exact, Dekker's Fast2Sum), 1 + x = 2^k (m + c 2^-k). (Unlike
/// log1p_fast(), no division.)
template <class V>
inline V pack_log1p(const V& x) {
  using P = PackFor<V>;
  const V u = 1.0 + x;
  V k;
  const V m = log_split(u, k);
  const V c = P::select(P::lt(P::splat(1.0), x), 1.0 - (u - x), x - (u - 1.0));
  const V k_shift = k + kRoundShift;  // -k in the low bits below, for 2^-k
  const V scale =
      P::from_bits((P::bits(P::splat(kRoundShift)) + 1023ull - P::bits(k_shift)) << 52);
  return log_kernel(k, m, c * scale);
}

/// Largest |log-odds| that chernoff_pack() takes (every exponential stays a normal number).
inline constexpr double kChernoffPackMax = 150.0;

/// The Chernoff fusion of N pairs (prior log-odds 0), every |a[i]|, |b[i]| <= 150: fused
/// log-odds l, weight w on a and information loss KL(p_NB || p_l), l_NB = a + b.
///
/// The Chernoff point l* solves sigmoid(l*) = (softplus(v) - softplus(u)) / D, the mean of
/// sigmoid over [u, v] = [min, max] of the inputs, D = v - u. The pair is first negated if
/// needed so that y = l_NB <= 0 (the rule commutes with negation; the weight is unchanged):
/// then sigmoid(l*) <= 1/2, and
///   P = softplus(v) - softplus(u) = log1p(sigmoid(u) expm1(D)) <= D/2,   Q = D - P >= D/2
/// both come to a few ulps (log1p of a positive number, a subtraction that cannot cancel),
/// and e^l* = P / Q. w D is the logarithm of a ratio: w = (l* - u) / D = log(P / (Q e^u)) / D
/// when a is the upper end, w = (v - l*) / D = log(Q e^v / P) / D otherwise (absolute error a
/// few ulps / D). For D < 0.1 (and D = 0) w comes from its
/// series around the midpoint m instead: w = 1/2 +- sum_k c_k(t) D^(2k-1) with
/// t = 1 - 2 sigmoid(m), four terms (truncation below 1e-16).
///
/// The loss is kl_core()'s log1p(s expm1(d)) - s d with s = sigmoid(y), taken at l* (d* =
/// l* - y) plus its first-order change (sigmoid(l*) - s) (l - l*) to the returned l, which
/// differs from l* by rounding. For |d*| >= 0.5 it needs no exponential of its own,
/// e^d* = P / (Q e^y), so it does not wait for w; below, expm1(d*). For |l - y| < 0.02,
/// where the formula cancels, the Taylor series of the loss in l - y to the 8th power.
template <int N>
inline void chernoff_pack(const double* a, const double* b, double* l_out, double* w_out,
                          double* loss_out) {
  using P = PackOf<N>;
  using V = typename P::V;
  using M = typename P::Mask;
  V la, lb;
  std::memcpy(&la, a, sizeof la);
  std::memcpy(&lb, b, sizeof lb);
  const V zero = P::splat(0.0), one = P::splat(1.0);
  const V sum = la + lb;
  const V sg = P::select(P::lt(zero, sum), P::splat(-1.0), one);
  const V xa = sg * la, xb = sg * lb, y = sg * sum;  // negated frame: y = l_NB <= 0
  const M a_up = P::lt(xb, xa);
  const V u = P::select(a_up, xb, xa), v = P::select(a_up, xa, xb);  // u <= y / 2 <= 0
  const V D = v - u;
  const V inv_d = 1.0 / D;
  const V eu = pack_exp(u);
  const V eD1 = pack_expm1(D);
  const V ev = eu * (1.0 + eD1);  // e^v
  const V enb = eu * ev;          // e^y
  const V su = eu / (1.0 + eu), s = enb / (1.0 + enb);  // sigmoid(u), sigmoid(y)
  const V Pv = pack_log1p(su * eD1);
  const V Qv = D - Pv;
  const V num = P::select(a_up, Pv, Qv * ev), den = P::select(a_up, Qv * eu, Pv);
  const V wD = pack_log(num / den);  // w D
  V w = wD * inv_d;
  const M small = P::lt(D, P::splat(0.1));
  if (P::any(small)) {
    // t = 1 - 2 sigmoid(m) = (1 - e^m) / (1 + e^m), e^m = sqrt(e^y)
    const V em = P::sqrt(enb);
    const V t = (1.0 - em) / (1.0 + em), t2 = t * t, D2 = D * D;
    const V S =
        t * D *
        (0.041666666666666664 +
         D2 * ((-0.0010416666666666667 + t2 * 0.0006944444444444445) +
               D2 * ((2.635168650793651e-05 +
                      t2 * (-4.357501102292769e-05 + t2 * 2.273478835978836e-05)) +
                     D2 * (-6.674038249559083e-07 +
                           t2 * (1.976376488095238e-06 +
                                 t2 * (-2.333760471781305e-06 + t2 * 9.214478615520283e-07))))));
    w = P::select(small, 0.5 + P::select(a_up, S, -S), w);
  }
  w = P::select(P::lt(w, zero), zero, P::select(P::lt(one, w), one, w));
  const M a_lo = P::lt(la, lb);
  const V lo = P::select(a_lo, la, lb), hi = P::select(a_lo, lb, la);
  V l = w * la + (1.0 - w) * lb;
  l = P::select(P::lt(l, lo), lo, P::select(P::lt(hi, l), hi, l));
  // the loss in the negated frame; l* to rounding (the returned l itself when D is too small
  // for P and Q)
  const V ln = sg * l;
  const M has_d = P::lt(P::splat(1e-200), D);
  const V ls = P::select(has_d, P::select(a_up, u + wD, v - wD), ln);
  const V ds = ls - y;
  const V ads = P::from_bits(P::bits(ds) & 0x7fffffffffffffffull);
  const M far = has_d & P::lt(P::splat(0.5), ads);
  V x = s * (Pv / (Qv * enb) - 1.0);
  if (!P::all(far)) x = P::select(far, x, s * pack_expm1(ds));
  V loss = pack_log1p(x) - s * ds + P::select(has_d, (Pv * inv_d - s) * (ln - ls), zero);
  const V dk = ln - y;
  const V adk = P::from_bits(P::bits(dk) & 0x7fffffffffffffffull);
  const M near = P::lt(adk, P::splat(0.02));
  if (P::any(near)) {
    // sum_k sigmoid^(k-1)(y) d^k / k! with sigmoid' = vs, sigmoid'' = vs ts, ...
    const V vs = s * (1.0 - s), ts = 1.0 - 2.0 * s, d2 = dk * dk;
    const V even =
        0.5 + d2 * ((0.041666666666666664 - 0.25 * vs) +
                    d2 * ((0.001388888888888889 +
                           vs * (-0.041666666666666664 + vs * 0.16666666666666666)) +
                          d2 * (2.48015873015873e-05 +
                                vs * (-0.003125 + vs * (0.041666666666666664 - vs * 0.125)))));
    const V odd =
        dk * ts *
        (0.16666666666666666 +
         d2 * ((0.008333333333333333 - 0.1 * vs) +
               d2 * (0.0001984126984126984 +
                     vs * (-0.011904761904761904 + vs * 0.07142857142857142))));
    loss = P::select(near, vs * d2 * (even + odd), loss);
  }
  loss = P::select(P::lt(zero, loss), loss, zero);  // rounding can give -1e-17
  std::memcpy(l_out, &l, sizeof l);
  std::memcpy(w_out, &w, sizeof w);
  std::memcpy(loss_out, &loss, sizeof loss);
}

/// Whether chernoff_pack() takes the pair (within its range, prior log-odds 0; false for NaN).
inline bool chernoff_pack_applies(double la, double lb, double l0) {
  return l0 == 0.0 && std::fabs(la) <= kChernoffPackMax && std::fabs(lb) <= kChernoffPackMax;
}

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
        if (chernoff_pack_applies(la, lb, l0)) return chernoff_fuse_one(la, lb);
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
