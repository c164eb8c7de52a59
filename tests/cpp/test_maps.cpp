// OccupancyMap file I/O and tree fusion against the per-voxel rule on expanded trees.
#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/map_file.hpp"

#include "test_trees.hpp"

#include <gtest/gtest.h>
#include <octomap/OcTree.h>

#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <random>
#include <tuple>

using namespace octofuse;

namespace {

using octofuse_test::expand;
using octofuse_test::Key;
using octofuse_test::random_map;

std::string tmp_path(const char* name) { return std::string("/tmp/octofuse_cpp_test_") + name; }

}  // namespace

TEST(Fuse, EqualsPerVoxelRuleOnExpandedTrees) {
  for (unsigned seed = 1; seed <= 6; ++seed) {
    const OccupancyMap a = random_map(seed, 0.9), b = random_map(100 + seed, 0.3);
    const auto ea = expand(a.tree()), eb = expand(b.tree());
    for (int r = 0; r < kNumRules; ++r)
      for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior}) {
        const FusionResult res = fuse_maps(a, b, static_cast<Rule>(r), pol);
        const auto ef = expand(res.map->tree()), el = expand(*res.info_loss);
        std::map<Key, std::pair<float, float>> expected;
        std::map<Key, std::pair<bool, bool>> seen;
        for (auto& [k, v] : ea) seen[k].first = true;
        for (auto& [k, v] : eb) seen[k].second = true;
        ASSERT_EQ(ef.size(), seen.size());
        for (auto& [k, s] : seen) {
          double la = s.first ? ea.at(k) : 0.0, lb = s.second ? eb.at(k) : 0.0;
          float want, loss;
          if ((!s.first || !s.second) && pol == UnknownPolicy::Copy) {
            want = static_cast<float>(s.first ? la : lb);
            loss = 0.0f;
          } else {
            const Fused f = fuse_logodds(static_cast<Rule>(r), la, lb);
            want = static_cast<float>(
                std::clamp(f.l, double(a.clamp_min_logodds()), double(a.clamp_max_logodds())));
            loss = static_cast<float>(f.info_loss);
          }
          ASSERT_EQ(ef.at(k), want) << rule_name(static_cast<Rule>(r));
          ASSERT_EQ(el.at(k), loss);
        }
      }
  }
}

// Every inner node holds the max of its children, as OctoMap keeps them.
template <class Tree, class Node>
void expect_inner_max(const Tree& t, const Node* n, int& checked) {
  if (!t.nodeHasChildren(n)) return;
  float mx = -std::numeric_limits<float>::infinity();
  for (unsigned i = 0; i < 8; ++i) {
    if (!t.nodeChildExists(n, i)) continue;
    const Node* c = t.getNodeChild(n, i);
    expect_inner_max(t, c, checked);
    mx = std::max(mx, c->getValue());
  }
  ASSERT_EQ(n->getValue(), mx);
  ++checked;
}

TEST(Fuse, InnerNodesHoldTheMaxOfTheirChildren) {
  const OccupancyMap a = random_map(21, 0.9), b = random_map(22, 0.3);
  for (int r = 0; r < kNumRules; ++r)
    for (UnknownPolicy pol : {UnknownPolicy::Copy, UnknownPolicy::Prior}) {
      const FusionResult res = fuse_maps(a, b, static_cast<Rule>(r), pol);
      int checked = 0;
      expect_inner_max(res.map->tree(), res.map->tree().getRoot(), checked);
      expect_inner_max(*res.info_loss, res.info_loss->getRoot(), checked);
      EXPECT_GT(checked, 100);
    }
}

TEST(Fuse, NaiveBayesEqualsOctomapUpdateNodeMerge) {
  const OccupancyMap a = random_map(7, 0.9), b = random_map(8, 0.9);
  OccupancyMap merged(a);
  OccupancyTree bb(b.tree());
  bb.expand();
  for (auto it = bb.begin_leafs(); it != bb.end_leafs(); ++it)
    merged.settled_tree().updateNode(it.getKey(), it->getLogOdds());
  const FusionResult res = fuse_maps(a, b, Rule::NaiveBayes, UnknownPolicy::Copy);
  EXPECT_EQ(expand(res.map->tree()), expand(merged.tree()));
}

TEST(Fuse, RejectsIncompatibleMaps) {
  MapParams p;
  OccupancyMap a(p);
  p.resolution = 0.1;
  OccupancyMap b(p);
  EXPECT_THROW(fuse_maps(a, b, Rule::Chernoff, UnknownPolicy::Copy), std::invalid_argument);
  p = MapParams{};
  p.clamp_max = 0.99;
  OccupancyMap c(p);
  EXPECT_THROW(check_compatible(a, c), std::invalid_argument);
}

TEST(Fuse, AccumulateAddsVoxelByVoxel) {
  const OccupancyMap a = random_map(3, 0.9), b = random_map(4, 0.2);
  const FusionResult r1 = fuse_maps(a, b, Rule::Chernoff, UnknownPolicy::Prior);
  const FusionResult r2 = fuse_maps(b, a, Rule::Bhattacharyya, UnknownPolicy::Prior);
  ScalarTree acc(*r1.info_loss);
  accumulate_loss(acc, *r2.info_loss);
  const auto e1 = expand(*r1.info_loss), e2 = expand(*r2.info_loss), ea = expand(acc);
  for (auto& [k, v] : ea) EXPECT_FLOAT_EQ(v, e1.at(k) + e2.at(k));
}

TEST(MapFiles, RoundTripKeepsEveryValue) {
  const OccupancyMap a = random_map(11, 0.5);
  write_map_file(a, tmp_path("rt.ot"));
  auto b = read_map_file(tmp_path("rt.ot"));
  EXPECT_EQ(expand(a.tree()), expand(b->tree()));
  EXPECT_EQ(b->tree().size(), a.tree().size());
  write_map_file(a, tmp_path("rt.bt"));
  auto c = read_map_file(tmp_path("rt.bt"));
  const auto ea = expand(a.tree()), ec = expand(c->tree());
  ASSERT_EQ(ea.size(), ec.size());
  const float thr = a.tree().getOccupancyThresLog();
  for (auto& [k, v] : ea) EXPECT_EQ(ec.at(k) > thr, v > thr);
}

TEST(MapFiles, TruncatedForeignAndMissingFilesThrow) {
  const OccupancyMap a = random_map(12, 0.5);
  for (const char* ext : {"ot", "bt"}) {
    const std::string path = tmp_path((std::string("full.") + ext).c_str());
    write_map_file(a, path);
    std::ifstream in(path, std::ios::binary);
    std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    for (std::size_t cut : {data.size() / 2, data.size() - 1, std::size_t(20)}) {
      const std::string t = tmp_path((std::string("cut.") + ext).c_str());
      std::ofstream(t, std::ios::binary) << data.substr(0, cut);
      EXPECT_THROW(read_map_file(t), MapFileError) << ext << " cut at " << cut;
    }
  }
  std::ofstream(tmp_path("foreign.ot")) << "hello, not a map\n";
  EXPECT_THROW(read_map_file(tmp_path("foreign.ot")), MapFileError);
  EXPECT_THROW(read_map_file(tmp_path("does-not-exist.ot")), MapFileError);
}

TEST(MapFiles, ReadsOctomapsOwnBinaryFile) {
  const std::string path = std::string(OCTOFUSE_SHARED_DATA) + "/geb079.bt";
  if (!std::ifstream(path)) GTEST_SKIP() << "shared data not present: " << path;
  auto m = read_map_file(path);
  octomap::OcTree ref(0.1);
  ASSERT_TRUE(ref.readBinary(path));
  EXPECT_EQ(m->num_leaves(), ref.getNumLeafNodes());
  EXPECT_DOUBLE_EQ(m->params().resolution, ref.getResolution());
}
