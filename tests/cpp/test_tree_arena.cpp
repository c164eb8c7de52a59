// Trees built in arenas of their own (fuse_maps): the same trees, freed by slabs while every
// node is the arena's, node by node once pool nodes were added; no block lost either way.
#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/node_pool.hpp"
#include "octofuse/tree_arena.hpp"
#include "test_trees.hpp"

#include <gtest/gtest.h>

#include <cstddef>
#include <limits>
#include <sstream>
#include <string>
#include <thread>
#include <utility>

using namespace octofuse;
using octofuse_test::dense_map;
using octofuse_test::expand;
using octofuse_test::random_map;

namespace {

constexpr std::size_t kAlways = 0;
constexpr std::size_t kNever = std::numeric_limits<std::size_t>::max();

// Blocks of both pools not back in their slabs (the calling thread's free lists included):
// measured on the main thread around work done on a thread that has exited, the blocks that
// work did not give back.
std::pair<std::size_t, std::size_t> pool_blocks_in_use() {
  return {detail::NodePool::stats().blocks_in_use, detail::ChildrenPool::stats().blocks_in_use};
}

template <class F>
void on_a_thread(F f) {
  std::thread(f).join();
}

std::string stream_of(const OccupancyMap& m) {
  std::stringstream s;
  m.tree().writeData(s);
  return s.str();
}

}  // namespace

TEST(TreeArena, FusedTreesAreTheSameWithOrWithoutArenas) {
  const OccupancyMap a = random_map(21, 0.3), b = random_map(22, 0.3);
  for (int r = 0; r < kNumRules; ++r) {
    for (int u = 0; u < kNumUnknownPolicies; ++u) {
      const Rule rule = static_cast<Rule>(r);
      const UnknownPolicy unknown = static_cast<UnknownPolicy>(u);
      const FusionResult in_arena = fuse_maps(a, b, rule, unknown, kAlways);
      const FusionResult pooled = fuse_maps(a, b, rule, unknown, kNever);
      ASSERT_NE(in_arena.map->tree().arena(), nullptr);
      ASSERT_NE(in_arena.info_loss->arena(), nullptr);
      EXPECT_EQ(pooled.map->tree().arena(), nullptr);
      EXPECT_EQ(stream_of(*in_arena.map), stream_of(*pooled.map));
      EXPECT_EQ(in_arena.map->num_nodes(), pooled.map->num_nodes());
      EXPECT_EQ(expand(*in_arena.info_loss), expand(*pooled.info_loss));
      EXPECT_EQ(in_arena.info_loss->size(), pooled.info_loss->size());
      EXPECT_EQ(in_arena.counts.fused, pooled.counts.fused);
      // every node of both trees is its arena's
      EXPECT_EQ(in_arena.map->tree().arena()->live_nodes(), in_arena.map->num_nodes());
      EXPECT_EQ(in_arena.info_loss->arena()->live_nodes(), in_arena.info_loss->size());
    }
  }
}

TEST(TreeArena, ATreeOfItsArenaOnlyIsFreedBySlabs) {
  const OccupancyMap a = dense_map(64), b = dense_map(40);
  const auto in_use = pool_blocks_in_use();
  const std::size_t arenas = detail::arena_bytes();
  on_a_thread([&] {
    FusionResult r = fuse_maps(a, b, Rule::MinInfoLoss, UnknownPolicy::Copy);  // the default
    ASSERT_NE(r.map->tree().arena(), nullptr);
    EXPECT_GT(a.num_nodes() + b.num_nodes(), kArenaMinNodes);
    EXPECT_GE(detail::arena_bytes(), arenas + 2 * detail::kSlabBytes);
    // the slabs hold the nodes and arrays, with at most one slab partly used per size
    const std::size_t nodes = r.map->num_nodes() + r.info_loss->size();
    EXPECT_LE(detail::arena_bytes() - arenas, 16 * nodes + 64 * nodes / 8 + 4 * detail::kSlabBytes);
  });
  EXPECT_EQ(detail::arena_bytes(), arenas);
  EXPECT_EQ(pool_blocks_in_use(), in_use);  // no pool block was used
}

TEST(TreeArena, ChangedTreesAreFreedNodeByNode) {
  const OccupancyMap a = random_map(31, 0.3), b = random_map(32, 0.3), c = random_map(33, 0.5);
  OccupancyMap far(MapParams{});  // a voxel none of the others has
  far.settled_tree().setNodeValue(octomap::OcTreeKey(100, 200, 300), 0.7f, true);
  const auto in_use = pool_blocks_in_use();
  const std::size_t arenas = detail::arena_bytes();
  on_a_thread([&] {
    FusionResult in_arena = fuse_maps(a, b, Rule::Chernoff, UnknownPolicy::Copy, kAlways);
    FusionResult pooled = fuse_maps(a, b, Rule::Chernoff, UnknownPolicy::Copy, kNever);
    // fusing into the results adds pool nodes and frees arena nodes (pruning); so does a scan
    for (FusionResult* r : {&in_arena, &pooled}) {
      fuse_into(*r->map, c, Rule::NaiveBayes, UnknownPolicy::Copy, r->info_loss.get());
      const double xyz[6] = {0.3, 0.2, 0.1, -0.25, 0.1, 0.3}, origin[3] = {0, 0, 0};
      r->map->insert_scan(xyz, 2, origin, -1.0);
      OccupancyTree& t = r->map->settled_tree();
      t.expand();
      t.prune();
      const FusionResult far_loss = fuse_maps(far, far, Rule::NaiveBayes, UnknownPolicy::Copy);
      accumulate_loss(*r->info_loss, *far_loss.info_loss);
    }
    EXPECT_EQ(expand(in_arena.map->tree()), expand(pooled.map->tree()));
    EXPECT_EQ(expand(*in_arena.info_loss), expand(*pooled.info_loss));
    EXPECT_NE(in_arena.map->tree().arena()->live_nodes(), in_arena.map->num_nodes());
    EXPECT_NE(in_arena.info_loss->arena()->live_nodes(), in_arena.info_loss->size());
  });
  EXPECT_EQ(detail::arena_bytes(), arenas);
  EXPECT_EQ(pool_blocks_in_use(), in_use);  // the pool nodes added went back
}

TEST(TreeArena, ArenaNodesFreedOnAnotherThreadAreCounted) {
  const OccupancyMap a = random_map(41, 0.2), b = random_map(42, 0.2);
  const auto in_use = pool_blocks_in_use();
  const std::size_t arenas = detail::arena_bytes();
  on_a_thread([&] {
    FusionResult r = fuse_maps(a, b, Rule::MinInfoLoss, UnknownPolicy::Prior, kAlways);
    OccupancyTree& t = r.map->settled_tree();
    on_a_thread([&] {  // every leaf the same value: pruning frees all nodes below the root
      for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) it->setLogOdds(1.0f);
      t.updateInnerOccupancy();
      t.prune();
    });
    EXPECT_EQ(t.arena()->live_nodes(), t.size());
    EXPECT_EQ(expand(t).begin()->second, 1.0f);
  });
  EXPECT_EQ(detail::arena_bytes(), arenas);
  EXPECT_EQ(pool_blocks_in_use(), in_use);
}

TEST(TreeArena, CopiesAreThePoolsAndClearingDropsTheArena) {
  const OccupancyMap a = random_map(51, 0.3), b = random_map(52, 0.3);
  const std::size_t arenas = detail::arena_bytes();
  FusionResult r = fuse_maps(a, b, Rule::Bhattacharyya, UnknownPolicy::Copy, kAlways);
  const auto want = expand(r.map->tree());
  OccupancyMap copy(*r.map);
  EXPECT_EQ(copy.tree().arena(), nullptr);
  r.map.reset();
  EXPECT_EQ(expand(copy.tree()), want);
  r.info_loss->clear();
  EXPECT_EQ(r.info_loss->arena(), nullptr);
  EXPECT_EQ(r.info_loss->size(), 0u);
  EXPECT_EQ(detail::arena_bytes(), arenas);
}
