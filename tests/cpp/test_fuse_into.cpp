// The in-place walks (fuse_into, fuse_mutual) against the new-tree walk (fuse_maps): the same
// per-voxel policy must give the same bits.
#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"

#include "test_trees.hpp"

#include <gtest/gtest.h>

using namespace octofuse;
using octofuse_test::expand;
using octofuse_test::random_map;

TEST(FuseInto, EqualsFuseMapsForEveryRuleAndPolicy) {
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const OccupancyMap a = random_map(seed, 0.9), b = random_map(50 + seed, 0.3);
    for (int r = 0; r < kNumRules; ++r)
      for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior}) {
        const Rule rule = static_cast<Rule>(r);
        const FusionResult want = fuse_maps(a, b, rule, pol);
        OccupancyMap dst(a);
        ScalarTree loss(a.params().resolution);
        const FuseIntoStats st = fuse_into(dst, b, rule, pol, &loss);
        ASSERT_EQ(expand(dst.tree()), expand(want.map->tree())) << rule_name(rule);
        if (pol == UnknownPolicy::Prior) {
          ASSERT_EQ(expand(loss), expand(*want.info_loss)) << rule_name(rule);
        }
        EXPECT_GT(st.fused, 0u);
      }
  }
}

TEST(FuseMutual, EqualsTwoFuseIntoForEveryRuleAndPolicy) {
  const OccupancyMap a = random_map(31, 0.8), b = random_map(32, 0.4);
  for (int r = 0; r < kNumRules; ++r)
    for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior}) {
      const Rule rule = static_cast<Rule>(r);
      OccupancyMap ia(a), ib(b), ma(a), mb(b);
      ScalarTree la(0.05), lb(0.05), mla(0.05), mlb(0.05);
      fuse_into(ia, b, rule, pol, &la);
      fuse_into(ib, a, rule, pol, &lb);
      fuse_mutual(ma, mb, rule, pol, &mla, &mlb);
      ASSERT_EQ(expand(ma.tree()), expand(ia.tree())) << rule_name(rule);
      ASSERT_EQ(expand(mb.tree()), expand(ib.tree())) << rule_name(rule);
      ASSERT_EQ(expand(mla), expand(la)) << rule_name(rule);
      ASSERT_EQ(expand(mlb), expand(lb)) << rule_name(rule);
    }
}
