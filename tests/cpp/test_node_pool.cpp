// The pooled tree types: same trees and files as OctoMap's own, nodes safe across threads.
#include "octofuse/node_pool.hpp"
#include "octofuse/occupancy_map.hpp"

#include "prune_or_max.hpp"
#include "walk.hpp"

#include "test_trees.hpp"

#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

using namespace octofuse;
using octofuse_test::dense_map;
using octofuse_test::expand;
using octofuse_test::random_map;

TEST(NodePool, NodesAreSixteenBytes) {
  EXPECT_EQ(sizeof(OccupancyNode), 16u);
  EXPECT_EQ(sizeof(ScalarNode), 16u);
  EXPECT_EQ(sizeof(OccupancyNode), sizeof(octomap::OcTreeNode));
}

TEST(NodePool, SameStreamsAndValuesAsOctomapsOwnTree) {
  const OccupancyMap m = random_map(3, 0.5);
  // the pooled tree written with OctoMap's writer, read back by plain OctoMap
  std::stringstream full, binary;
  m.tree().writeData(full);
  m.tree().writeBinaryData(binary);
  octomap::OcTree plain(m.params().resolution);
  plain.readData(full);
  EXPECT_EQ(expand(plain), expand(m.tree()));
  EXPECT_EQ(plain.size(), m.num_nodes());
  // and plain OctoMap's streams read into the pooled tree, node for node
  std::stringstream again;
  plain.writeData(again);
  OccupancyTree back(m.params().resolution);
  back.readData(again);
  EXPECT_EQ(expand(back), expand(m.tree()));
  // byte for byte the same streams
  std::stringstream plain_full, plain_binary;
  plain.writeData(plain_full);
  plain.writeBinaryData(plain_binary);
  EXPECT_EQ(plain_full.str(), full.str());
  EXPECT_EQ(plain_binary.str(), binary.str());
}

TEST(NodePool, DeepCopyIsIndependentAndPooled) {
  const OccupancyMap m = random_map(5, 0.3);
  auto want = expand(m.tree());
  {
    OccupancyMap c(m);
    EXPECT_EQ(expand(c.tree()), want);
    EXPECT_EQ(c.num_nodes(), c.tree().calcNumNodes());
    OccupancyTree& t = c.settled_tree();
    for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) it->setLogOdds(1.0f);
  }  // the copy's nodes go back to the pool; the original is untouched
  EXPECT_EQ(expand(m.tree()), want);
}

TEST(NodePool, TreesBuiltOnOneThreadFreedOnAnother) {
  // nodes change threads: built by workers, freed by the main thread, reused by new workers
  for (int round = 0; round < 3; ++round) {
    std::vector<std::unique_ptr<OccupancyMap>> maps(4);
    std::vector<std::thread> workers;
    for (unsigned w = 0; w < maps.size(); ++w)
      workers.emplace_back([&maps, w, round] {
        maps[w] = std::make_unique<OccupancyMap>(random_map(100 * round + w, 0.2));
      });
    for (auto& t : workers) t.join();
    for (unsigned w = 0; w < maps.size(); ++w) {
      EXPECT_EQ(expand(maps[w]->tree()), expand(random_map(100 * round + w, 0.2).tree()));
    }
    maps.clear();
  }
  // what the workers freed was handed back: the pool did not grow for later rounds' trees
  const std::size_t before = detail::NodePool::stats().slab_bytes;
  for (int k = 0; k < 20; ++k) {
    std::thread([] { OccupancyMap m = random_map(7, 0.2); }).join();
  }
  EXPECT_EQ(detail::NodePool::stats().slab_bytes, before);
}

TEST(NodePool, FreedTreesAreReusedAndEmptySlabsTrimmed) {
  // a tree freed and built again reuses the freed blocks: the pool does not grow
  auto pool_bytes = [] {
    return detail::NodePool::stats().slab_bytes + detail::ChildrenPool::stats().slab_bytes;
  };
  std::size_t one_tree = 0;
  std::thread([&] {
    const std::size_t before = pool_bytes();
    { OccupancyMap m = dense_map(64); }
    one_tree = pool_bytes() - before;
    for (int k = 0; k < 5; ++k) {
      OccupancyMap again = dense_map(64);
      OccupancyMap copy(again);
      EXPECT_EQ(copy.num_nodes(), again.num_nodes());
    }
    EXPECT_LE(pool_bytes(), before + 2 * one_tree + (std::size_t(4) << 20));
  }).join();  // the thread's lists go back to the slabs
  // with every tree of that thread gone, trim() gives empty slabs back to the system
  const std::size_t before = pool_bytes();
  const std::size_t freed = detail::NodePool::trim() + detail::ChildrenPool::trim();
  EXPECT_EQ(pool_bytes(), before - freed);
  EXPECT_GT(freed, 0u);
  OccupancyMap after = random_map(12, 0.2);  // and the pool still works
  EXPECT_EQ(expand(after.tree()), expand(random_map(12, 0.2).tree()));
}

// A root with 8 random children: absent, a leaf or an inner node; values that often tie,
// signed zeros and NaN included.
template <class Tree>
void random_children(Tree& t, std::mt19937& rng) {
  using Node = typename detail::TreeAccess<Tree>::Node;
  const float values[] = {-1.0f, 0.5f, 0.5f, 0.5f, -0.0f, 0.0f, std::nanf("")};
  std::uniform_int_distribution<int> kind(0, 9), v(0, 6);
  Node* root = detail::TreeAccess<Tree>::ensure_root(t);
  const bool all_leaves = kind(rng) < 5;  // then pruning is likely
  const float shared = values[v(rng)];
  for (unsigned i = 0; i < 8; ++i) {
    const int k = all_leaves ? 9 : kind(rng);
    if (k == 0) continue;
    Node* c = t.createNodeChild(root, i);
    c->setValue(all_leaves && kind(rng) < 8 ? shared : values[v(rng)]);
    if (k == 1) t.createNodeChild(c, 3)->setValue(values[v(rng)]);
  }
}

template <class Tree>
std::string bits_of(const Tree& t) {
  std::ostringstream s;
  s << t.size() << ':';
  const auto* root = t.getRoot();
  float rv = root->getValue();
  std::uint32_t u;
  std::memcpy(&u, &rv, 4);
  s << u << (t.nodeHasChildren(root) ? "[" : "");
  for (unsigned i = 0; i < 8 && t.nodeHasChildren(root); ++i) {
    if (!t.nodeChildExists(root, i)) {
      s << "-,";
      continue;
    }
    float cv = t.getNodeChild(root, i)->getValue();
    std::memcpy(&u, &cv, 4);
    s << u << (t.nodeHasChildren(t.getNodeChild(root, i)) ? "+," : ",");
  }
  return s.str();
}

TEST(NodePool, PruneOrMaxIsOctomapsPruneThenMax) {
  std::mt19937 rng(11);
  int pruned = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    OccupancyTree a(0.1);
    octomap::OcTree plain(0.1);  // the same node, in OctoMap's own tree
    std::mt19937 same = rng;
    random_children(a, rng);
    random_children(plain, same);
    OccupancyTree b(a);
    OccupancyNode* ra = a.getRoot();
    const bool octomap_pruned = plain.pruneNode(plain.getRoot());
    EXPECT_EQ(a.pruneNode(ra), octomap_pruned);  // octofuse's pruneNode is OctoMap's
    EXPECT_EQ(bits_of(a), bits_of(plain));
    EXPECT_EQ(a.size(), plain.size());
    if (!octomap_pruned && a.nodeHasChildren(ra)) ra->setLogOdds(ra->getMaxChildLogOdds());
    EXPECT_EQ(detail::prune_or_max(b, b.getRoot()), octomap_pruned);
    EXPECT_EQ(bits_of(b), bits_of(a)) << "trial " << trial;
    pruned += octomap_pruned;

    // scalar trees: the max of the children from -inf, as the loss trees keep it
    ScalarTree s(0.1);
    random_children(s, rng);
    ScalarTree s2(s);
    ScalarNode* rs = s.getRoot();
    const bool s_pruned = s.pruneNode(rs);
    if (!s_pruned && s.nodeHasChildren(rs)) {
      float mx = -std::numeric_limits<float>::infinity();
      for (unsigned i = 0; i < 8; ++i)
        if (s.nodeChildExists(rs, i)) mx = std::max(mx, s.getNodeChild(rs, i)->getValue());
      rs->setValue(mx);
    }
    EXPECT_EQ(detail::prune_or_max(s2, s2.getRoot()), s_pruned);
    EXPECT_EQ(bits_of(s2), bits_of(s)) << "trial " << trial;
  }
  EXPECT_GT(pruned, 300);  // both outcomes were tried
  EXPECT_LT(pruned, 2700);
}

TEST(NodePool, LeafWalkIsOctomapsLeafIterator) {
  // the same leaves in the same order with the same keys and depths (an empty tree: none)
  for (unsigned seed = 0; seed < 20; ++seed) {
    const OccupancyMap m = random_map(seed, 0.5);
    std::vector<std::tuple<unsigned, unsigned, unsigned, unsigned, float>> walked, iterated;
    detail::for_each_leaf(m.tree(),
                          [&](const OccupancyNode& n, const octomap::OcTreeKey& k, unsigned d) {
                            walked.emplace_back(k[0], k[1], k[2], d, n.getLogOdds());
                          });
    for (auto it = m.tree().begin_leafs(); it != m.tree().end_leafs(); ++it) {
      const octomap::OcTreeKey& k = it.getKey();
      iterated.emplace_back(k[0], k[1], k[2], it.getDepth(), it->getLogOdds());
    }
    EXPECT_EQ(walked, iterated);
    EXPECT_GT(walked.size(), 100u);
  }
  ScalarTree empty(0.1);
  int calls = 0;
  detail::for_each_leaf(empty,
                        [&](const ScalarNode&, const octomap::OcTreeKey&, unsigned) { ++calls; });
  EXPECT_EQ(calls, 0);
}
