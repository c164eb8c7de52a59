// fuse_into on several threads against fuse_into on one: every node (inner ones included),
// every value and the node counts must be the same, for the map and the loss tree.
#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"

#include "test_trees.hpp"

#include <gtest/gtest.h>

#include <random>

using namespace octofuse;
using octofuse_test::random_map;

namespace {

// Same shape and bits, node for node (a coarse leaf differs from its expansion here).
template <class Tree, class Node>
void expect_same_nodes(const Tree& x, const Node* nx, const Tree& y, const Node* ny, int& diffs) {
  if ((nx == nullptr) != (ny == nullptr)) {
    ++diffs;
    return;
  }
  if (nx == nullptr) return;
  if (!(nx->getValue() == ny->getValue()) || x.nodeHasChildren(nx) != y.nodeHasChildren(ny)) {
    if (diffs == 0)
      ADD_FAILURE() << "first difference: values " << nx->getValue() << " / " << ny->getValue()
                    << ", children " << x.nodeHasChildren(nx) << " / " << y.nodeHasChildren(ny);
    ++diffs;
    return;
  }
  if (!x.nodeHasChildren(nx)) return;
  for (unsigned i = 0; i < 8; ++i)
    expect_same_nodes(x, x.nodeChildExists(nx, i) ? x.getNodeChild(nx, i) : nullptr, y,
                      y.nodeChildExists(ny, i) ? y.getNodeChild(ny, i) : nullptr, diffs);
}

template <class Tree>
int node_differences(const Tree& x, const Tree& y) {
  int d = 0;
  expect_same_nodes(x, x.getRoot(), y, y.getRoot(), d);
  return d;
}

// A map away from the tree's centre (as real maps lie in one octant): sparse voxels over a
// 48^3 block at `offset`, values from the sensor model or continuous, and saturated blocks.
OccupancyMap offset_map(unsigned seed, unsigned offset, bool continuous) {
  OccupancyMap m(MapParams{});
  OccupancyTree& t = m.settled_tree();
  std::mt19937 rng(seed);
  const float values[] = {-2.0f, -1.2f, -0.4f, 0.45f, 0.85f, 1.7f, 3.5f};
  std::uniform_int_distribution<int> v(0, 6), c(0, 47), coin(0, 99);
  std::uniform_real_distribution<float> u(-2.0f, 3.5f);
  const unsigned base = 32768 + offset;
  for (int i = 0; i < 4000; ++i) {
    octomap::OcTreeKey k(base + c(rng), base + c(rng), base + c(rng) / 3);
    t.setNodeValue(k, continuous ? u(rng) : values[v(rng)], true);
  }
  for (int i = 0; i < 12; ++i) {  // saturated 8^3 blocks prune to depth-13 leaves
    const unsigned bx = base + 8 * (c(rng) / 8), by = base + 8 * (c(rng) / 8),
                   bz = base + 8 * (c(rng) / 24);
    const float val = coin(rng) < 70 ? -2.0f : 3.5f;
    for (unsigned x = 0; x < 8; ++x)
      for (unsigned y = 0; y < 8; ++y)
        for (unsigned z = 0; z < 8; ++z)
          t.setNodeValue(octomap::OcTreeKey(bx + x, by + y, bz + z), val, true);
  }
  t.updateInnerOccupancy();
  t.prune();
  return m;
}

void expect_parallel_same(const OccupancyMap& a, const OccupancyMap& b, const ScalarTree* loss0) {
  for (int r = 0; r < kNumRules; ++r)
    for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior}) {
      const Rule rule = static_cast<Rule>(r);
      OccupancyMap want(a);
      ScalarTree want_loss(a.params().resolution);
      if (loss0 != nullptr) accumulate_loss(want_loss, *loss0);
      const FuseIntoStats ws = fuse_into(want, b, rule, pol, &want_loss, 1);
      for (unsigned threads : {2u, 3u, 8u}) {
        OccupancyMap got(a);
        ScalarTree got_loss(a.params().resolution);
        if (loss0 != nullptr) accumulate_loss(got_loss, *loss0);
        const FuseIntoStats gs = fuse_into(got, b, rule, pol, &got_loss, threads);
        ASSERT_EQ(node_differences(want.tree(), got.tree()), 0)
            << rule_name(rule) << " " << threads;
        ASSERT_EQ(node_differences(want_loss, got_loss), 0)
            << rule_name(rule) << " " << kUnknownPolicyNames[static_cast<int>(pol)] << " "
            << threads;
        EXPECT_EQ(got.num_nodes(), want.num_nodes());
        EXPECT_EQ(got.num_nodes(), got.tree().calcNumNodes());
        EXPECT_EQ(got_loss.size(), got_loss.calcNumNodes());
        EXPECT_EQ(gs.fused, ws.fused);
        EXPECT_EQ(gs.copied, ws.copied);
        // without a loss tree as well
        OccupancyMap plain(a);
        fuse_into(plain, b, rule, pol, nullptr, threads);
        ASSERT_EQ(node_differences(want.tree(), plain.tree()), 0) << rule_name(rule);
        EXPECT_EQ(plain.num_nodes(), plain.tree().calcNumNodes());
      }
    }
}

}  // namespace

TEST(ParallelFuseInto, SameNodesAsOneThreadOnRandomMaps) {
  for (unsigned seed = 1; seed <= 3; ++seed)
    expect_parallel_same(random_map(seed, 0.9), random_map(70 + seed, 0.3), nullptr);
}

TEST(ParallelFuseInto, SameNodesAsOneThreadAwayFromTheCentre) {
  for (bool continuous : {false, true}) {
    const OccupancyMap a = offset_map(5, 1000, continuous), b = offset_map(6, 1040, continuous);
    expect_parallel_same(a, b, nullptr);
    // a loss tree that already holds values (coarse leaves included), as agents accumulate it
    const FusionResult earlier = fuse_maps(b, a, Rule::MinInfoLoss, UnknownPolicy::Prior);
    expect_parallel_same(a, b, earlier.info_loss.get());
  }
}

TEST(ParallelFuseInto, EmptyMapsAndEqualMaps) {
  const OccupancyMap a = offset_map(9, 500, false), empty(MapParams{});
  for (unsigned threads : {1u, 2u}) {
    OccupancyMap d1(empty), d2(a), d3(a);
    fuse_into(d1, a, Rule::MinInfoLoss, UnknownPolicy::Copy, nullptr, threads);
    EXPECT_EQ(node_differences(d1.tree(), a.tree()), 0);
    fuse_into(d2, empty, Rule::MinInfoLoss, UnknownPolicy::Prior, nullptr, threads);
    OccupancyMap want(a);
    fuse_into(want, empty, Rule::MinInfoLoss, UnknownPolicy::Prior, nullptr, 1);
    EXPECT_EQ(node_differences(d2.tree(), want.tree()), 0);
    fuse_into(d3, a, Rule::NaiveBayes, UnknownPolicy::Copy, nullptr, threads);
    OccupancyMap want3(a);
    fuse_into(want3, a, Rule::NaiveBayes, UnknownPolicy::Copy, nullptr, 1);
    EXPECT_EQ(node_differences(d3.tree(), want3.tree()), 0);
    EXPECT_EQ(d3.num_nodes(), d3.tree().calcNumNodes());
  }
}
