// octofuse: exp, expm1, log and log1p on packs of doubles (GCC/Clang vector extension), with
// the same bits in every lane. Internal to the Chernoff pack kernel (chernoff_pack.hpp).
#pragma once

#include <cstdint>
#include <cstring>

namespace octofuse::detail {

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
  const V q =
      ((0.5 + r * 0.16666666666666666) + r2 * (0.041666666666666664 + r * 0.008333333333333333)) +
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
    -0.3522205935893521,   -0.33024168687057687, -0.3087354816496133,   -0.2876820724517809,
    -0.26706278524904525,  -0.24686007793152578, -0.22705745063534608,  -0.2076393647782445,
    -0.18859116980755003,  -0.16989903679539747, -0.15154989812720093,  -0.13353139262452263,
    -0.1158318155251217,   -0.09844007281325252, -0.0813456394539524,   -0.06453852113757118,
    -0.048009219186360606, -0.0317486983145803,  -0.015748356968139168, 0.0,
    0.015504186535965254,  0.030771658666753687, 0.0458095360312942,    0.06062462181643484,
    0.07522342123758753,   0.08961215868968714,  0.10379679368164356,   0.11778303565638346,
    0.13157635778871926,   0.1451820098444979,   0.15860503017663857,   0.17185025692665923,
    0.184922338494012,     0.19782574332991987,  0.21056476910734964,   0.22314355131420976,
    0.2355660713127669,    0.24783616390458127,  0.25995752443692605,   0.27193371548364176,
    0.2837681731306446,    0.2954642128938359,   0.3070250352949119,    0.3184537311185346,
    0.329753286372468,     0.3409265869705932,   0.3519764231571782};
/// 1 / c_j, to nearest.
inline constexpr double kInvNode[47] = {1.4222222222222223, 1.391304347826087,
                                        1.3617021276595744, 1.3333333333333333,
                                        1.3061224489795917, 1.28,
                                        1.2549019607843137, 1.2307692307692308,
                                        1.2075471698113207, 1.1851851851851851,
                                        1.1636363636363636, 1.1428571428571428,
                                        1.1228070175438596, 1.103448275862069,
                                        1.0847457627118644, 1.0666666666666667,
                                        1.0491803278688525, 1.032258064516129,
                                        1.0158730158730158, 1.0,
                                        0.9846153846153847, 0.9696969696969697,
                                        0.9552238805970149, 0.9411764705882353,
                                        0.927536231884058,  0.9142857142857143,
                                        0.9014084507042254, 0.8888888888888888,
                                        0.8767123287671232, 0.8648648648648649,
                                        0.8533333333333334, 0.8421052631578947,
                                        0.8311688311688312, 0.8205128205128205,
                                        0.810126582278481,  0.8,
                                        0.7901234567901234, 0.7804878048780488,
                                        0.7710843373493976, 0.7619047619047619,
                                        0.7529411764705882, 0.7441860465116279,
                                        0.735632183908046,  0.7272727272727273,
                                        0.7191011235955056, 0.7111111111111111,
                                        0.7032967032967034};

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
  const V scale = P::from_bits((P::bits(P::splat(kRoundShift)) + 1023ull - P::bits(k_shift)) << 52);
  return log_kernel(k, m, c * scale);
}

}  // namespace octofuse::detail
