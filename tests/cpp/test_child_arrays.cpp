// Arrays of child pointers: when a node gets one, what it holds, and where it goes when
// freed (node_pool.hpp, tree.hpp).
#include "octofuse/node_pool.hpp"
#include "octofuse/tree.hpp"

#include <gtest/gtest.h>

#include <thread>

using namespace octofuse;

namespace {

using Array = octomap::AbstractOcTreeNode**;

OccupancyNode* new_root(OccupancyTree& t) {
  return detail::TreeAccess<OccupancyTree>::ensure_root(t);
}

}  // namespace

TEST(ChildArrays, AnArrayIsEightPointersInAPoolBlock) {
  EXPECT_EQ(detail::ChildrenPool::kBlock, 8 * sizeof(void*));
  OccupancyTree t(0.1);
  OccupancyNode* root = new_root(t);
  EXPECT_EQ(root->children_array(), nullptr);  // a new node has none
  EXPECT_EQ(detail::arena_of(t.createNodeChild(root, 0)), nullptr);
  EXPECT_EQ(detail::arena_of(root->children_array()), nullptr);  // the pools', not an arena's
}

TEST(ChildArrays, TheFirstChildBringsAnArrayOfNoOtherChild) {
  OccupancyTree t(0.1);
  OccupancyNode* root = new_root(t);
  OccupancyNode* c = t.createNodeChild(root, 5);
  ASSERT_NE(root->children_array(), nullptr);
  for (unsigned i = 0; i < 8; ++i) EXPECT_EQ(t.nodeChildExists(root, i), i == 5) << i;
  EXPECT_EQ(t.getNodeChild(root, 5), c);
  const Array array = root->children_array();
  t.createNodeChild(root, 2);
  EXPECT_EQ(root->children_array(), array);  // later children go into the same array
}

TEST(ChildArrays, DeletingEveryChildKeepsAnEmptyArray) {
  OccupancyTree t(0.1);
  OccupancyNode* root = new_root(t);
  t.createNodeChild(root, 1);
  t.deleteNodeChild(root, 1);
  EXPECT_NE(root->children_array(), nullptr);
  EXPECT_FALSE(t.nodeHasChildren(root));  // a leaf all the same
}

TEST(ChildArrays, ExpandingGivesEightChildrenTheNodesData) {
  OccupancyTree t(0.1);
  OccupancyNode* root = new_root(t);
  root->setLogOdds(0.75f);
  root->set_carried_loss(0.25f);
  t.expandNode(root);
  EXPECT_FALSE(root->carries_loss());  // its children carry it now
  for (unsigned i = 0; i < 8; ++i) {
    ASSERT_TRUE(t.nodeChildExists(root, i));
    EXPECT_EQ(t.getNodeChild(root, i)->getLogOdds(), 0.75f);
    EXPECT_EQ(t.getNodeChild(root, i)->carried_loss(), 0.25f);
  }
  EXPECT_EQ(t.size(), 9u);
}

TEST(ChildArrays, PruningFreesTheArrayForTheNextOneOnTheThread) {
  std::thread([] {  // a thread of its own: its free lists hold only what this test frees
    OccupancyTree t(0.1);
    OccupancyNode* root = new_root(t);
    t.expandNode(root);
    const Array array = root->children_array();
    ASSERT_TRUE(t.pruneNode(root));
    EXPECT_EQ(root->children_array(), nullptr);
    EXPECT_EQ(t.size(), 1u);
    t.expandNode(root);
    EXPECT_EQ(root->children_array(), array);  // a freed block is the next one taken
  })
      .join();
}

TEST(ChildArrays, CopiesHaveArraysOfTheirOwn) {
  OccupancyTree t(0.1);
  OccupancyNode* root = new_root(t);
  t.createNodeChild(root, 3);
  t.createNodeChild(t.getNodeChild(root, 3), 7)->setLogOdds(1.0f);
  const OccupancyTree copy(t);
  const OccupancyNode* croot = copy.getRoot();
  EXPECT_NE(const_cast<OccupancyNode*>(croot)->children_array(), root->children_array());
  for (unsigned i = 0; i < 8; ++i) EXPECT_EQ(copy.nodeChildExists(croot, i), i == 3) << i;
  const OccupancyNode* c = copy.getNodeChild(croot, 3);
  EXPECT_EQ(copy.getNodeChild(c, 7)->getLogOdds(), 1.0f);
  EXPECT_NE(c, t.getNodeChild(root, 3));
}

TEST(ChildArrays, AnArenaTreesArraysAreItsArenas) {
  OccupancyTree t(0.1);
  t.start_arena();
  OccupancyNode* root = t.create_root();
  OccupancyNode* c = t.create_child(root, 6);
  EXPECT_EQ(detail::arena_of(root->children_array()), t.arena());
  EXPECT_EQ(detail::arena_of(c), t.arena());
  for (unsigned i = 0; i < 8; ++i) EXPECT_EQ(t.nodeChildExists(root, i), i == 6) << i;
  t.clear();  // the arena goes with its slabs
  EXPECT_EQ(t.arena(), nullptr);
  EXPECT_EQ(t.size(), 0u);
}
