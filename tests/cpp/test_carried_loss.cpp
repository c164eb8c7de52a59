// Maps that carry their loss maps against maps that do not: the same fusions and insertions
// must leave the same maps and, once settled, the same loss trees, node for node.
#include "octofuse/carried_loss.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/insert.hpp"
#include "octofuse/leaf_lookup.hpp"

#include "map_access.hpp"

#include "test_trees.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <vector>

using namespace octofuse;
using octofuse_test::random_map;

namespace {

// A map and its loss tree, carried or not.
struct Agent {
  OccupancyMap map;
  ScalarTree loss{0.05};
  Agent(const OccupancyMap& m, bool carried) : map(m) {
    if (carried) map.carry_loss(&loss);
  }
};

// Scans of the maps' 16^3 block: rays from random origins to points of a smaller block, many
// of them, so that voxels saturate and merge.
void insert_scans(OccupancyMap& m, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> wide(-0.39, 0.39), hit(-0.2, 0.1);
  for (int s = 0; s < 12; ++s) {
    const double origin[3] = {wide(rng), wide(rng), wide(rng)};
    std::vector<double> xyz;
    for (int i = 0; i < 150; ++i)
      for (int a = 0; a < 3; ++a) xyz.push_back(hit(rng));
    insert_scan_batched(m, xyz.data(), xyz.size() / 3, origin, -1.0);
  }
}

// The same steps on a set of agents: exchanges, fusions on one and two threads, insertions.
void run_steps(std::vector<Agent>& g, Rule rule, UnknownPolicy pol, ScalarTree& foreign) {
  fuse_mutual(g[0].map, g[1].map, rule, pol, &g[0].loss, &g[1].loss);
  insert_scans(g[0].map, 1);
  insert_scans(g[2].map, 2);
  fuse_into(g[2].map, g[0].map, rule, pol, &g[2].loss, 2);
  fuse_into(g[0].map, g[2].map, rule, pol, &g[0].loss, 1);
  fuse_mutual(g[1].map, g[2].map, rule, pol, &g[1].loss, &g[2].loss);
  insert_scans(g[1].map, 3);
  fuse_mutual(g[0].map, g[1].map, rule, pol, &g[0].loss, &g[1].loss);
  fuse_into(g[1].map, g[0].map, rule, pol, &foreign, 1);  // a loss tree g[1] does not carry
  insert_scans(g[0].map, 4);
  fuse_into(g[0].map, g[1].map, rule, pol, &g[0].loss, 2);
}

}  // namespace

TEST(CarriedLoss, SameMapsAndLossTreesAsLossTreesAlone) {
  std::size_t carried_seen = 0, moved_aside = 0;
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const OccupancyMap m0 = random_map(seed, 0.9), m1 = random_map(seed + 50, 0.3),
                       m2 = random_map(seed + 100, 0.6);
    for (int r = 0; r < kNumRules; ++r)
      for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior}) {
        const Rule rule = static_cast<Rule>(r);
        std::vector<Agent> plain, carried;
        for (const OccupancyMap* m : {&m0, &m1, &m2}) {
          plain.emplace_back(*m, false);
          carried.emplace_back(*m, true);
        }
        ScalarTree plain_foreign(0.05), carried_foreign(0.05);
        run_steps(plain, rule, pol, plain_foreign);
        run_steps(carried, rule, pol, carried_foreign);
        for (std::size_t k = 0; k < plain.size(); ++k) {
          const OccupancyTree& t = carried[k].map.tree();
          for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it)
            carried_seen += it->carries_loss();
          if (k != 1) moved_aside += carried[k].loss.size();  // agent 1 settled for `foreign`
          std::vector<float> values, want_values;
          std::vector<std::uint8_t> depths, want_depths;
          settled_loss_leaves(t, carried[k].loss, values, depths);  // read before settling
          carried[k].map.settle_loss();
          scalar_values_and_depths(carried[k].loss, want_values, want_depths);
          ASSERT_EQ(depths, want_depths) << rule_name(rule) << " agent " << k;
          ASSERT_EQ(0, std::memcmp(values.data(), want_values.data(), 4 * values.size()))
              << rule_name(rule) << " agent " << k;
          for (auto it = t.begin_tree(); it != t.end_tree(); ++it) ASSERT_FALSE(it->carries_loss());
          ASSERT_TRUE(t == plain[k].map.tree()) << rule_name(rule) << " agent " << k;
          ASSERT_TRUE(carried[k].loss == plain[k].loss) << rule_name(rule) << " agent " << k;
          EXPECT_EQ(carried[k].loss.size(), carried[k].loss.calcNumNodes());
        }
        ASSERT_TRUE(carried_foreign == plain_foreign) << rule_name(rule);
      }
  }
  EXPECT_GT(carried_seen, 0u);  // the losses were carried, and
  EXPECT_GT(moved_aside, 0u);   // some were moved aside before the maps merged their voxels
}

TEST(CarriedLoss, CopiesCarryNothingAndExpandedLeavesPassItOn) {
  OccupancyMap m = random_map(7, 0.9);
  const OccupancyMap other(m);  // the same coarse leaves: fused as they are
  ScalarTree loss(0.05);
  m.carry_loss(&loss);
  fuse_into(m, other, Rule::Chernoff, UnknownPolicy::Copy, &loss);
  const OccupancyMap copy(m);
  std::size_t carried = 0;
  for (auto it = m.tree().begin_leafs(); it != m.tree().end_leafs(); ++it)
    carried += it->carries_loss();
  EXPECT_GT(carried, 0u);
  EXPECT_EQ(copy.carried_loss(), nullptr);
  for (auto it = copy.tree().begin_tree(); it != copy.tree().end_tree(); ++it)
    ASSERT_FALSE(it->carries_loss());
  // a carrying coarse leaf expanded: its children carry its loss, it carries none
  OccupancyTree& t = detail::CarryingAccess::tree(m);
  for (auto it = t.begin_leafs(); it != t.end_leafs(); ++it) {
    if (it.getDepth() == 16 || !it->carries_loss()) continue;
    OccupancyNode* n = &*it;
    const std::uint32_t bits = n->carried_bits();
    t.expandNode(n);
    EXPECT_FALSE(n->carries_loss());
    for (unsigned i = 0; i < 8; ++i) EXPECT_EQ(t.getNodeChild(n, i)->carried_bits(), bits);
    return;
  }
  ADD_FAILURE() << "no carrying coarse leaf";
}
