// The prune rule by its defining properties: eight children merge exactly when they are all
// present leaves of one value; otherwise their parent holds the max of their values.
#include "octofuse/tree.hpp"

#include "prune_or_max.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>

using namespace octofuse;

namespace {

// One child as a walk sees it.
struct Child {
  bool present;
  bool leaf;
  float value;
};

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kNone = -std::numeric_limits<float>::infinity();

detail::PruneRule judged(const Child (&kids)[8]) {
  detail::PruneRule rule(kNone);
  for (const Child& c : kids) {
    if (c.present) {
      rule.child(c.value, c.leaf);
    } else {
      rule.absent();
    }
  }
  return rule;
}

// Eight children drawn from few values (ties are common), signed zeros and NaN included.
void random_kids(std::mt19937& rng, Child (&kids)[8]) {
  const float values[] = {-1.0f, 0.5f, -0.0f, 0.0f, kNaN};
  std::uniform_int_distribution<int> value(0, 4), kind(0, 19);
  const bool alike = kind(rng) < 10;  // then merging is likely
  const float shared = values[value(rng)];
  for (Child& c : kids) {
    const int k = kind(rng);
    c.present = k != 1;
    c.leaf = k != 2;
    c.value = alike && k < 18 ? shared : values[value(rng)];
  }
}

}  // namespace

TEST(PruneRule, MergesExactlyEightPresentLeavesOfOneValue) {
  std::mt19937 rng(3);
  int merged = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    Child kids[8];
    random_kids(rng, kids);
    bool want = true;
    for (const Child& c : kids) want = want && c.present && c.leaf && c.value == kids[0].value;
    ASSERT_EQ(judged(kids).merges(), want) << "trial " << trial;
    merged += want;
  }
  EXPECT_GT(merged, 1000);  // both outcomes were tried
  EXPECT_LT(merged, 19000);
}

TEST(PruneRule, OneChildOffKeepsThemApart) {
  const Child leaf{true, true, 0.5f};
  for (unsigned i = 0; i < 8; ++i) {
    for (const Child odd : {Child{false, true, 0.5f}, Child{true, false, 0.5f},
                            Child{true, true, 0.25f}, Child{true, true, kNaN}}) {
      Child kids[8] = {leaf, leaf, leaf, leaf, leaf, leaf, leaf, leaf};
      kids[i] = odd;
      EXPECT_FALSE(judged(kids).merges()) << "child " << i;
    }
  }
  Child same[8] = {leaf, leaf, leaf, leaf, leaf, leaf, leaf, leaf};
  EXPECT_TRUE(judged(same).merges());
  for (Child& c : same) c.value = kNaN;  // NaN equals nothing, not even itself
  EXPECT_FALSE(judged(same).merges());
}

TEST(PruneRule, HoldsTheMaxOfThePresentChildren) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 20000; ++trial) {
    Child kids[8];
    random_kids(rng, kids);
    float want = kNone;
    bool any = false;
    for (const Child& c : kids) {
      if (!c.present) continue;
      any = true;
      if (c.value > want) want = c.value;  // NaN is never the max
    }
    const detail::PruneRule rule = judged(kids);
    ASSERT_EQ(rule.no_children(), !any);
    const float got = rule.max();
    ASSERT_EQ(std::memcmp(&want, &got, sizeof want), 0) << "trial " << trial;
  }
}

TEST(PruneRule, MayMergeUntilTheFirstChildOff) {
  detail::PruneRule rule(kNone);
  for (unsigned i = 0; i < 5; ++i) {
    rule.child(2.0f, true);
    EXPECT_TRUE(rule.may_merge());
    EXPECT_FALSE(rule.merges());  // not eight yet
  }
  rule.child(3.0f, true);
  EXPECT_FALSE(rule.may_merge());
  rule.child(2.0f, true);
  EXPECT_FALSE(rule.may_merge());  // once off, for good
  EXPECT_EQ(rule.max(), 3.0f);
}

// prune_or_max applies the rule to a node of a tree.

namespace {

// A root with eight leaf children of `value` each.
OccupancyNode* root_with_leaves(OccupancyTree& t, float value) {
  OccupancyNode* root = detail::TreeAccess<OccupancyTree>::ensure_root(t);
  for (unsigned i = 0; i < 8; ++i) t.createNodeChild(root, i)->setLogOdds(value);
  return root;
}

}  // namespace

TEST(PruneOrMax, EqualLeavesMergeIntoTheirParent) {
  OccupancyTree t(0.1);
  OccupancyNode* root = root_with_leaves(t, 0.7f);
  root->setLogOdds(-5.0f);
  EXPECT_TRUE(detail::prune_or_max(t, root));
  EXPECT_FALSE(t.nodeHasChildren(root));
  EXPECT_FALSE(detail::ChildrenAccess<OccupancyNode>::has_array(root));  // the array is freed
  EXPECT_EQ(root->getLogOdds(), 0.7f);
  EXPECT_EQ(t.size(), 1u);
}

TEST(PruneOrMax, OtherwiseTheParentHoldsTheMax) {
  OccupancyTree t(0.1);
  OccupancyNode* root = root_with_leaves(t, 0.7f);
  t.getNodeChild(root, 5)->setLogOdds(1.5f);
  t.deleteNodeChild(root, 2);
  EXPECT_FALSE(detail::prune_or_max(t, root));
  EXPECT_EQ(root->getLogOdds(), 1.5f);
  EXPECT_EQ(t.size(), 8u);  // the root and seven children, untouched
  EXPECT_FALSE(t.nodeChildExists(root, 2));
}

TEST(PruneOrMax, AChildlessNodeIsLeftAsItIs) {
  OccupancyTree t(0.1);
  OccupancyNode* root = detail::TreeAccess<OccupancyTree>::ensure_root(t);
  root->setLogOdds(0.25f);
  EXPECT_FALSE(detail::prune_or_max(t, root));
  EXPECT_EQ(root->getLogOdds(), 0.25f);
  // an array whose children were all deleted: still no child to take a max of
  t.createNodeChild(root, 4);
  t.deleteNodeChild(root, 4);
  EXPECT_FALSE(detail::prune_or_max(t, root));
  EXPECT_EQ(root->getLogOdds(), 0.25f);
}

TEST(PruneOrMax, AChildWithAnEmptyArrayIsALeaf) {
  OccupancyTree t(0.1);
  OccupancyNode* root = root_with_leaves(t, -0.4f);
  OccupancyNode* c = t.getNodeChild(root, 6);
  t.createNodeChild(c, 0);
  t.deleteNodeChild(c, 0);
  c->setLogOdds(-0.4f);
  EXPECT_TRUE(detail::prune_or_max(t, root));
}

TEST(PruneOrMax, LeavesCarryingDifferentLossesMergeOnlyIfMovedAside) {
  OccupancyTree t(0.1);
  OccupancyNode* root = root_with_leaves(t, 0.7f);
  t.getNodeChild(root, 3)->set_carried_loss(0.125f);
  EXPECT_FALSE(detail::prune_or_max(t, root));  // kept apart by default
  EXPECT_EQ(root->getLogOdds(), 0.7f);
  unsigned asked = 0;
  const auto move_aside = [&](OccupancyNode* const* kids) {
    ++asked;
    for (unsigned i = 0; i < 8; ++i) kids[i]->drop_carried_loss();
    return true;
  };
  EXPECT_TRUE(detail::prune_or_max(t, root, move_aside));
  EXPECT_EQ(asked, 1u);
  EXPECT_FALSE(root->carries_loss());
}

TEST(PruneOrMax, LeavesCarryingOneLossMergeAndPassItOn) {
  OccupancyTree t(0.1);
  OccupancyNode* root = root_with_leaves(t, 0.7f);
  for (unsigned i = 0; i < 8; ++i) t.getNodeChild(root, i)->set_carried_loss(0.5f);
  EXPECT_TRUE(detail::prune_or_max(t, root));
  EXPECT_TRUE(root->carries_loss());
  EXPECT_EQ(root->carried_loss(), 0.5f);
}
