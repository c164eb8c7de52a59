// octofuse: the Chernoff rule on packs of pairs. Internal to rules.hpp and fuse_arrays.hpp.
//
// chernoff_pack<N>() fuses N pairs at once with code in which every lane goes through the same
// operations: both sides of each choice are computed and one is selected per lane (a side that
// no lane needs may be skipped, which changes nothing). Its exp, expm1 and log are the
// polynomials of fastmath.hpp, not the C library's. So a pair gets the same bits in any lane of
// any pack: the array kernel fuses packs of kArrayLanes pairs (independent work that the CPU
// overlaps), fuse_logodds<Chernoff>() a pack of kPackLanes copies of its one pair, and the
// two agree exactly. Nothing relies on -ffast-math, and the lanes of a pack never mix.
#pragma once

#include "octofuse/detail/fastmath.hpp"

#include <cmath>
#include <cstring>

namespace octofuse::detail {

/// Largest |log-odds| that chernoff_pack() takes (every exponential stays a normal number).
inline constexpr double kChernoffPackMax = 150.0;

/// The Chernoff weight's series around the midpoint m of the pair (a, b): w = 1/2 + S with
/// S = t d sum_k c_k(t) d^(2k), d = a - b, t = 1 - 2 sigmoid(m), four terms (truncation below
/// 1e-16 for |d| < 0.1, about 1e-9 for |d| < 1). V: a double or a pack of them.
template <class V>
inline V chernoff_midpoint_series(const V& t, const V& d) {
  const V t2 = t * t, d2 = d * d;
  return t * d *
         (0.041666666666666664 +
          d2 * ((-0.0010416666666666667 + t2 * 0.0006944444444444445) +
                d2 * ((2.635168650793651e-05 +
                       t2 * (-4.357501102292769e-05 + t2 * 2.273478835978836e-05)) +
                      d2 * (-6.674038249559083e-07 +
                            t2 * (1.976376488095238e-06 +
                                  t2 * (-2.333760471781305e-06 + t2 * 9.214478615520283e-07))))));
}

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
  const V ev = eu * (1.0 + eD1);                        // e^v
  const V enb = eu * ev;                                // e^y
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
    const V S = chernoff_midpoint_series((1.0 - em) / (1.0 + em), D);
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
    const V odd = dk * ts *
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

}  // namespace octofuse::detail
