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

namespace {

// Inner nodes whose 8 children are equal leaves: none in a pruned tree.
unsigned collapsible_nodes(const ScalarTree& t, const ScalarNode* n) {
  if (n == nullptr || !t.nodeHasChildren(n)) return 0;
  unsigned found = t.isNodeCollapsible(n) ? 1 : 0;
  for (unsigned i = 0; i < 8; ++i)
    if (t.nodeChildExists(n, i)) found += collapsible_nodes(t, t.getNodeChild(n, i));
  return found;
}

}  // namespace

TEST(FuseInto, LossAddedIntoAnEarlierLossTreeIsTheSumPerVoxel) {
  // the earlier loss has coarse leaves where the message is finer; naive Bayes adds zeros,
  // min-info-loss zeros and other values, Chernoff other values
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const OccupancyMap a = random_map(seed, 0.9), b = random_map(40 + seed, 0.2);
    const FusionResult earlier = fuse_maps(a, a, Rule::Bhattacharyya, UnknownPolicy::Copy);
    for (Rule rule : {Rule::NaiveBayes, Rule::MinInfoLoss, Rule::Chernoff})
      for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior})
        for (unsigned threads : {1u, 2u}) {
          OccupancyMap dst(a), fresh_dst(a);
          ScalarTree loss(0.05), fresh(0.05);
          accumulate_loss(loss, *earlier.info_loss);
          fuse_into(dst, b, rule, pol, &loss, threads);
          fuse_into(fresh_dst, b, rule, pol, &fresh, 1);
          std::map<octofuse_test::Key, float> want = expand(*earlier.info_loss);
          for (const auto& [key, v] : expand(fresh)) {
            const auto it = want.find(key);
            if (it == want.end()) {
              want[key] = v;
            } else {
              it->second += v;
            }
          }
          ASSERT_EQ(expand(loss), want) << rule_name(rule) << " " << threads;
          EXPECT_EQ(collapsible_nodes(loss, loss.getRoot()), 0u) << rule_name(rule);
          EXPECT_EQ(loss.size(), loss.calcNumNodes());
        }
  }
}
