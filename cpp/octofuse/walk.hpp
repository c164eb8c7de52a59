// octofuse: a node of an input tree as seen by a simultaneous walk of several trees.
#pragma once

#include "octofuse/tree_access.hpp"

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

}  // namespace octofuse::detail
