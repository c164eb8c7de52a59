// octofuse: a node of an input tree as seen by a simultaneous walk of several trees (the one
// place where a coarse leaf stands for its children), and a walk of one tree's leaves.
#pragma once

#include "octofuse/detail/tree_access.hpp"

#include <octomap/OcTreeKey.h>

namespace octofuse::detail {

/// A real node, or a pruned leaf standing for the child it would have (a "virtual" node
/// with the leaf's value), or nothing (unknown space). A coarse leaf thus behaves as if it
/// were expanded, without modifying the tree.
template <class Tree>
struct WalkNode {
  using Node = typename TreeAccess<Tree>::Node;
  const Tree* tree = nullptr;
  const Node* node = nullptr;  ///< null when unknown
  bool leaf = false;

  bool present() const { return node != nullptr; }
  /// Whether the walk ends here: a leaf, or unknown space.
  bool leaf_or_unknown() const { return node == nullptr || leaf; }

  /// The children the walk visits, bit i for child i: all 8 below a leaf, none below unknown.
  unsigned children_mask() const {
    if (node == nullptr) return 0;
    if (leaf) return 0xFFu;
    unsigned mask = 0;
    for (unsigned i = 0; i < 8; ++i) mask |= unsigned{tree->nodeChildExists(node, i)} << i;
    return mask;
  }

  /// The walk node of child i.
  WalkNode child(unsigned i) const {
    if (node == nullptr || leaf) return *this;  // unknown stays unknown, leaves expand
    if (!tree->nodeChildExists(node, i)) return WalkNode{tree, nullptr, false};
    const Node* c = tree->getNodeChild(node, i);
    return WalkNode{tree, c, !tree->nodeHasChildren(c)};
  }

  /// The root of a tree (not present for an empty tree).
  static WalkNode root(const Tree& t) {
    const Node* r = t.getRoot();
    return WalkNode{&t, r, r != nullptr && !t.nodeHasChildren(r)};
  }
};

namespace leaf_walk {
// The leaves under n, whose key is `key` at `depth` (see for_each_leaf).
template <class Tree, class Node, class F>
void visit(const Tree& t, const Node* n, const octomap::OcTreeKey& key, unsigned depth, F& f) {
  if (depth == t.getTreeDepth() || !t.nodeHasChildren(n)) {
    f(*n, key, depth);
    return;
  }
  // the iterator's child keys: the parent's key -/+ half the child's extent
  const auto offset = static_cast<octomap::key_type>((1u << (t.getTreeDepth() - 1)) >> (depth + 1));
  octomap::OcTreeKey child;
  for (unsigned i = 0; i < 8; ++i) {
    if (!t.nodeChildExists(n, i)) continue;
    octomap::computeChildKey(i, offset, key, child);
    visit(t, t.getNodeChild(n, i), child, depth + 1, f);
  }
}
}  // namespace leaf_walk

/// Calls f(node, key, depth) for every leaf of `t`, in the order and with the keys of
/// OctoMap's leaf iterator (depth first, child 0 first), without its stack of copies.
template <class Tree, class F>
void for_each_leaf(const Tree& t, F&& f) {
  const auto* root = t.getRoot();
  if (root == nullptr) return;
  const auto mid = static_cast<octomap::key_type>(1u << (t.getTreeDepth() - 1));
  leaf_walk::visit(t, root, octomap::OcTreeKey(mid, mid, mid), 0, f);
}

}  // namespace octofuse::detail
