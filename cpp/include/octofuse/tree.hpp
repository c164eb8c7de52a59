// octofuse: the tree types of octofuse's maps: OctoMap's occupancy and scalar trees with
// their nodes and child arrays in octofuse's pools (node_pool.hpp). Same nodes, same
// algorithms, same .ot/.bt streams as octomap::OcTree; only where the nodes live differs.
//
// A node is 16 bytes and has no vtable: bytes 0-7 the pointer to its array of children
// (null for a leaf), 8-11 its float value (log-odds, or a scalar such as a loss), 12-15
// OctoMap's padding, where an OccupancyNode keeps its carried loss (kNoLoss: none). An array
// of children is 64 bytes: 8 pointers, null where a child does not exist; a node with an
// array and no child is a leaf too. A pruned leaf stands for all the voxels below it.
#pragma once

#include "octofuse/node_pool.hpp"
#include "octofuse/tree_arena.hpp"

#include <octomap/OcTreeBase.h>
#include <octomap/OcTreeDataNode.h>
#include <octomap/OcTreeNode.h>
#include <octomap/OccupancyOcTreeBase.h>

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <type_traits>

namespace octofuse {

/// An OctoMap node type `Base` (value and children) whose nodes and arrays of children live
/// in octofuse's pools (or in their tree's arena: ArenaTree); `Derived` is the node type
/// itself.
template <class Base, class Derived>
class PooledTreeNode : public Base {
 public:
  static void* operator new(std::size_t) { return detail::NodePool::allocate(); }
  static void operator delete(void* p) noexcept {
    if (p != nullptr) detail::NodePool::release(p);
  }

  PooledTreeNode() = default;
  /// Deep copy; the children are pooled too (OctoMap's copy would make plain nodes).
  PooledTreeNode(const PooledTreeNode& rhs) : Base() {
    this->value = rhs.value;
    if (rhs.children == nullptr) return;
    this->children = static_cast<octomap::AbstractOcTreeNode**>(detail::ChildrenPool::allocate());
    for (unsigned i = 0; i < 8; ++i) {
      this->children[i] = rhs.children[i] == nullptr
                              ? nullptr
                              : new Derived(*static_cast<const Derived*>(rhs.children[i]));
    }
  }

  /// The array of child pointers, for trees that make and free nodes themselves (ArenaTree).
  octomap::AbstractOcTreeNode**& children_array() { return this->children; }
};

/// octomap::OcTreeNode (log-odds and children), pooled. In the 4 bytes OctoMap's node leaves
/// as padding it may carry the accumulated information loss of its voxels, for a map that
/// carries its loss map (carried_loss.hpp); a node carries nothing by default.
class OccupancyNode : public PooledTreeNode<octomap::OcTreeNode, OccupancyNode> {
 public:
  /// The bits of "carries no loss": a NaN that no loss is stored as (see carried_loss.hpp).
  static constexpr std::uint32_t kNoLoss = 0xFFFFFFFFu;

  OccupancyNode() = default;
  /// A copy carries no loss: a copied map (a message, a snapshot) has no loss map.
  OccupancyNode(const OccupancyNode& other) : PooledTreeNode(other) {}
  OccupancyNode& operator=(const OccupancyNode&) = delete;

  /// OctoMap's expandNode gives the children their parent's data and pruneNode the parent its
  /// children's: the carried loss goes with the log-odds.
  void copyData(const OccupancyNode& from) {
    value = from.value;
    carried_ = from.carried_;
  }
  /// Equal log-odds and the same carried loss, bit for bit (OctoMap's isNodeCollapsible).
  bool operator==(const OccupancyNode& rhs) const {
    return value == rhs.value && carried_ == rhs.carried_;
  }

  bool carries_loss() const { return carried_ != kNoLoss; }
  std::uint32_t carried_bits() const { return carried_; }
  float carried_loss() const {
    float v;
    std::memcpy(&v, &carried_, sizeof v);
    return v;
  }
  void set_carried_loss(float v) { std::memcpy(&carried_, &v, sizeof v); }
  void drop_carried_loss() { carried_ = kNoLoss; }

 private:
  std::uint32_t carried_ = kNoLoss;
};

/// octomap::OcTreeDataNode<float>, pooled: one float per voxel (e.g. information loss).
class ScalarNode : public PooledTreeNode<octomap::OcTreeDataNode<float>, ScalarNode> {};

/// Where the max of a node's children starts (OctoMap's getMaxChildLogOdds starts from
/// -FLT_MAX; octofuse's scalar trees from -inf).
template <class Node>
inline constexpr float kMaxOfNoChildren = std::is_same_v<Node, OccupancyNode>
                                              ? -std::numeric_limits<float>::max()
                                              : -std::numeric_limits<float>::infinity();

static_assert(sizeof(OccupancyNode) == detail::NodePool::kBlock &&
                  sizeof(ScalarNode) == detail::NodePool::kBlock,
              "pooled nodes are the size of the pool's blocks");

}  // namespace octofuse

// The three places OctoMap allocates and frees the arrays of child pointers, for octofuse's
// trees: the same code with the arrays in ChildrenPool.
#define OCTOFUSE_POOLED_CHILDREN(NODE, BASE)                                                       \
  template <>                                                                                      \
  inline void octomap::OcTreeBaseImpl<NODE, BASE>::allocNodeChildren(NODE* node) {                 \
    node->children =                                                                               \
        static_cast<AbstractOcTreeNode**>(octofuse::detail::ChildrenPool::allocate());             \
    for (unsigned i = 0; i < 8; ++i) node->children[i] = nullptr;                                  \
  }                                                                                                \
  template <>                                                                                      \
  inline bool octomap::OcTreeBaseImpl<NODE, BASE>::pruneNode(NODE* node) {                         \
    if (!isNodeCollapsible(node)) return false;                                                    \
    node->copyData(*(getNodeChild(node, 0)));                                                      \
    for (unsigned i = 0; i < 8; ++i) deleteNodeChild(node, i);                                     \
    octofuse::detail::ChildrenPool::release(node->children);                                       \
    node->children = nullptr;                                                                      \
    return true;                                                                                   \
  }                                                                                                \
  template <>                                                                                      \
  inline void octomap::OcTreeBaseImpl<NODE, BASE>::deleteNodeRecurs(NODE* node) {                  \
    if (node->children != nullptr) {                                                               \
      for (unsigned i = 0; i < 8; ++i)                                                             \
        if (node->children[i] != nullptr) deleteNodeRecurs(static_cast<NODE*>(node->children[i])); \
      octofuse::detail::ChildrenPool::release(node->children);                                     \
      node->children = nullptr;                                                                    \
    }                                                                                              \
    delete node;                                                                                   \
  }

OCTOFUSE_POOLED_CHILDREN(octofuse::OccupancyNode, octomap::AbstractOccupancyOcTree)
OCTOFUSE_POOLED_CHILDREN(octofuse::ScalarNode, octomap::AbstractOcTree)
#undef OCTOFUSE_POOLED_CHILDREN

namespace octofuse {

/// An occupancy tree as octomap::OcTree, with pooled nodes (or an arena's); it calls itself
/// "OcTree" in file headers, which OctoMap's tools read as theirs.
class OccupancyTree : public ArenaTree<octomap::OccupancyOcTreeBase<OccupancyNode>> {
 public:
  explicit OccupancyTree(double resolution) : ArenaTree(resolution) {}
  OccupancyTree(const OccupancyTree&) = default;
  OccupancyTree* create() const override { return new OccupancyTree(resolution); }
  /// OctoMap's expandNode: the children take the node's data; the node, now inner, carries no
  /// loss (its children carry it).
  void expandNode(OccupancyNode* node) override {
    ArenaTree::expandNode(node);
    node->drop_carried_loss();
  }
  std::string getTreeType() const override { return "OcTree"; }
};

/// Per-voxel scalar tree (e.g. the information loss of a fusion), same key grid as the maps.
class ScalarTree : public ArenaTree<octomap::OcTreeBase<ScalarNode>> {
 public:
  explicit ScalarTree(double resolution) : ArenaTree(resolution) {}
};

}  // namespace octofuse
