// octofuse: internal access to OctoMap tree internals needed to build trees node by node.
#pragma once

#include <octomap/OcTreeBaseImpl.h>

namespace octofuse::detail {

/// Gives the tree builders access to the root pointer and the node count of any
/// octomap::OcTreeBaseImpl, which OctoMap keeps protected. Only used to create a root node
/// in an empty tree (children are created with the public createNodeChild()).
template <class Tree>
struct TreeAccess : Tree {
  using Node = typename std::remove_pointer<decltype(std::declval<Tree&>().getRoot())>::type;

  /// Returns the root of `t`, creating it if the tree is empty.
  static Node* ensure_root(Tree& t) {
    Node*& root = t.*(&TreeAccess::root);
    if (root == nullptr) {
      root = new Node();
      t.*(&TreeAccess::tree_size) += 1;
      t.*(&TreeAccess::size_changed) = true;
    }
    return root;
  }

  /// The node count `t` keeps (OctoMap counts nodes in the tree object whose methods created
  /// or deleted them: a walk that used a scratch tree's methods adds that tree's count here).
  static std::size_t& size_of(Tree& t) { return t.*(&TreeAccess::tree_size); }

  /// Marks the metric bounding box as stale after nodes were added or removed directly.
  static void mark_changed(Tree& t) { t.*(&TreeAccess::size_changed) = true; }
};

}  // namespace octofuse::detail
