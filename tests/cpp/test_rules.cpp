// Defining properties of the per-voxel rules (see MATH.md), checked over a grid of inputs.
#include "octofuse/fuse_arrays.hpp"
#include "octofuse/rules.hpp"
#include "octofuse/voxel_fusion.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

using namespace octofuse;
using octofuse::detail::entropy_logodds;
using octofuse::detail::kl_logodds;

namespace {

std::vector<double> grid() {
  std::vector<double> g;
  for (double l = -6.0; l <= 6.0; l += 0.37) g.push_back(l);
  g.push_back(0.0);
  g.push_back(3.5);
  g.push_back(-2.0);
  return g;
}

// Brute-force KL(q || p) straight from the probabilities.
double kl_direct(double lq, double lp) {
  const double q = 1.0 / (1.0 + std::exp(-lq)), p = 1.0 / (1.0 + std::exp(-lp));
  return q * std::log(q / p) + (1 - q) * std::log((1 - q) / (1 - p));
}

}  // namespace

TEST(Rules, KlMatchesDefinition) {
  for (double a : grid())
    for (double b : grid()) EXPECT_NEAR(kl_logodds(a, b), kl_direct(a, b), 1e-12);
}

TEST(Rules, ChernoffEqualisesKlds) {
  for (double a : grid())
    for (double b : grid()) {
      if (a == b) continue;
      const Fused f = fuse_logodds(Rule::Chernoff, a, b);
      EXPECT_NEAR(kl_logodds(f.l, a), kl_logodds(f.l, b), 1e-10) << a << " " << b;
    }
}

TEST(Rules, WeightedChernoffEqualisesWeightedKlds) {
  for (double a : grid())
    for (double b : grid()) {
      if (a == b) continue;
      const Fused e = fuse_logodds(Rule::EntropyWeightedChernoff, a, b);
      EXPECT_NEAR(kl_logodds(e.l, a) / entropy_logodds(a), kl_logodds(e.l, b) / entropy_logodds(b),
                  1e-9)
          << a << " " << b;
      const double ca = kl_logodds(a, 0.0), cb = kl_logodds(b, 0.0);
      if (ca > 0 && cb > 0) {
        const Fused k = fuse_logodds(Rule::KldWeightedChernoff, a, b);
        EXPECT_NEAR(ca * kl_logodds(k.l, a), cb * kl_logodds(k.l, b), 1e-9) << a << " " << b;
      }
    }
}

namespace {

// The weighted Chernoff root c_a KL(p_w || p_a) = c_b KL(p_w || p_b), in log-odds, found by
// bisection in long double (no code shared with the Newton iteration).
long double weighted_root_by_bisection(long double la, long double lb, long double ca,
                                       long double cb) {
  const auto kl = [](long double lq, long double lp) {
    if (lq > 0) lq = -lq, lp = -lp;  // KL is unchanged; then sigmoid(lq) <= 1/2
    const long double s = 1 / (1 + std::exp(-lq)), d = lp - lq;
    return std::log1p(s * std::expm1(d)) - s * d;
  };
  long double lo = 0, hi = 1;  // g(w) = c_a KL_a - c_b KL_b falls from >= 0 to <= 0
  for (int i = 0; i < 200 && hi - lo > 1e-19L; ++i) {
    const long double w = (lo + hi) / 2, lw = lb + w * (la - lb);
    (ca * kl(lw, la) - cb * kl(lw, lb) > 0 ? lo : hi) = w;
  }
  return lb + (lo + hi) / 2 * (la - lb);
}

}  // namespace

TEST(Rules, WeightedChernoffRootIsTheRootToRounding) {
  // the fused log-odds within 1e-13 |la - lb| of the root (w within 1e-13), inside the maps'
  // range (where the iteration stops once Newton has converged) and beyond it
  std::vector<double> values;
  for (double l = -8.0; l <= 8.0; l += 0.23) values.push_back(l);
  for (double l : {-30.0, -12.5, 9.0, 14.0, 25.0}) values.push_back(l);
  for (double a : values)
    for (double b : values) {
      if (std::fabs(a - b) < 1e-3) continue;
      for (const auto& [ca, cb] :
           {std::pair{entropy_logodds(b), entropy_logodds(a)},
            std::pair{kl_logodds(a, 0.0), kl_logodds(b, 0.0)}, std::pair{0.3, 2.0}}) {
        if (!(ca > 0 && cb > 0)) continue;
        const double w0 = detail::chernoff_weight_start(a, b);  // as the rules start
        const double w = detail::weighted_chernoff_weight(a, b, ca, cb, w0);
        const double l = b + w * (a - b);
        const long double ref = weighted_root_by_bisection(a, b, ca, cb);
        ASSERT_LE(std::fabs(static_cast<double>(l - ref)), 1e-13 * std::max(1.0, std::fabs(a - b)))
            << a << " " << b << " " << ca << " " << cb;
      }
    }
}

TEST(Rules, ChernoffWeightStartIsTheChernoffWeight) {
  // the weighted rules' start: the series within 1e-8 where it is used (|la - lb| < 1)
  for (double a = -8.0; a <= 8.0; a += 0.0517)
    for (double d : {-0.999, -0.6, -0.31, -0.05, -1e-4, 1e-5, 0.02, 0.27, 0.7, 0.998, 1.2, 3.0}) {
      const double b = a + d;
      const double start = detail::chernoff_weight_start(a, b);
      const double exact = detail::chernoff_weight(a, b);
      if (std::fabs(a - b) < 1.0) {
        EXPECT_NEAR(start, exact, 1e-8) << a << " " << b;
      } else {
        EXPECT_EQ(start, exact);
      }
    }
}

TEST(Rules, EntropyWeightedReducesToChernoffAtEqualEntropy) {
  for (double a : grid()) {
    if (a == 0.0) continue;
    const Fused c = fuse_logodds(Rule::Chernoff, a, -a);
    const Fused e = fuse_logodds(Rule::EntropyWeightedChernoff, a, -a);
    EXPECT_NEAR(c.omega, e.omega, 1e-12);
  }
}

TEST(Rules, KldWeightedTakesTheInformedSideWhenOneLearntNothing) {
  const Fused f = fuse_logodds(Rule::KldWeightedChernoff, 0.0, 2.0);
  EXPECT_EQ(f.omega, 0.0);
  EXPECT_EQ(f.l, 2.0);
}

TEST(Rules, MinInfoLossIsTheMinimumOverAFineGrid) {
  for (double a : grid())
    for (double b : grid()) {
      const Fused f = fuse_logodds(Rule::MinInfoLoss, a, b);
      for (int i = 0; i <= 1000; ++i) {
        const double w = i / 1000.0;
        EXPECT_LE(f.info_loss, kl_logodds(a + b, w * a + (1 - w) * b) + 1e-12);
      }
      EXPECT_EQ(f.info_loss == 0.0, a * b <= 0.0) << a << " " << b;
    }
}

TEST(Rules, WepResultsLieBetweenTheInputs) {
  for (int r = 1; r < kNumRules; ++r)
    for (double a : grid())
      for (double b : grid()) {
        const Fused f = fuse_logodds(static_cast<Rule>(r), a, b);
        EXPECT_GE(f.l, std::min(a, b));
        EXPECT_LE(f.l, std::max(a, b));
        EXPECT_GE(f.omega, 0.0);
        EXPECT_LE(f.omega, 1.0);
      }
}

TEST(Rules, CertaintiesDominateAndContradictionsAreFlagged) {
  const double inf = std::numeric_limits<double>::infinity();
  for (int r = 0; r < kNumRules; ++r) {
    EXPECT_EQ(fuse_logodds(static_cast<Rule>(r), inf, 1.0).l, inf);
    EXPECT_EQ(fuse_logodds(static_cast<Rule>(r), 1.0, -inf).l, -inf);
    EXPECT_TRUE(std::isnan(fuse_logodds(static_cast<Rule>(r), inf, -inf).l));
  }
  const double a[] = {0.3, 1.0}, b[] = {std::nan(""), 0.0};
  double v[2], w[2], l[2];
  ArrayStatus st = fuse_arrays(Rule::Chernoff, a, b, 2, true, 0.0, v, w, l);
  EXPECT_EQ(st.what, BadInput::NaN);
  EXPECT_EQ(st.index, 0u);
  st = fuse_arrays(Rule::Chernoff, a + 1, b + 1, 1, true, 0.0, v, w, l);
  EXPECT_EQ(st.what, BadInput::Contradiction);
}

// A tree walk's per-voxel fusion (memos of pairs, and of each map's factor for the weighted
// Chernoff rules) gives exactly what fuse_logodds gives, clamped and stored as floats.
template <Rule R>
void expect_voxel_fusion_is_fuse_logodds() {
  const float cmin = -2.0f, cmax = 3.5f;
  VoxelFusion<R, UnknownPolicy::Copy> vf(cmin, cmax);
  std::uint64_t state = 12345;
  auto next = [&] {  // few distinct values (as sensor-model sums), so that the memos hit
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>(static_cast<int>((state >> 33) % 41) - 20) * 0.17f;
  };
  for (int i = 0; i < 20000; ++i) {
    const float a = next(), b = i % 7 == 0 ? a : next();
    const Fused f = fuse_logodds<R>(a, b, 0.0);
    const double l = f.l < cmin ? cmin : (f.l > cmax ? cmax : f.l);
    const VoxelValue v = vf.both(a, b);
    ASSERT_EQ(v.value, static_cast<float>(l)) << rule_name(R) << " " << a << " " << b;
    ASSERT_EQ(v.loss, static_cast<float>(f.info_loss)) << rule_name(R) << " " << a << " " << b;
  }
  const float inf = std::numeric_limits<float>::infinity();
  EXPECT_EQ(vf.both(inf, 1.0f).value, cmax);  // certainties: through fuse_logodds
  EXPECT_EQ(vf.both(-1.0f, -inf).value, cmin);
}

TEST(Rules, TreeWalkVoxelFusionIsFuseLogodds) {
  expect_voxel_fusion_is_fuse_logodds<Rule::Bhattacharyya>();
  expect_voxel_fusion_is_fuse_logodds<Rule::Chernoff>();
  expect_voxel_fusion_is_fuse_logodds<Rule::EntropyWeightedChernoff>();
  expect_voxel_fusion_is_fuse_logodds<Rule::KldWeightedChernoff>();
  expect_voxel_fusion_is_fuse_logodds<Rule::MinInfoLoss>();
}
