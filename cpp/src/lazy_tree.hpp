// octofuse: building a tree bottom-up with the pruning built in: a node is only allocated
// once it is known to stay (new-tree fusion, clamped copies).
#pragma once

#include "octofuse/detail/tree_access.hpp"
#include "octofuse/tree.hpp"

#include <cstdint>

namespace octofuse::detail {

/// A node of an output tree that is only allocated once it is known to stay (lazily).
/// The walk builds each subtree bottom-up: a subtree whose voxels turn out to be 8 equal
/// leaves is returned as one value and never allocated, instead of being allocated and then
/// pruned (OctoMap's pruneNode). A node is allocated (with all its missing ancestors) as soon
/// as one of its children is an inner node, because then it can no longer be pruned.
template <class Tree>
struct Lazy {
  using Node = typename TreeAccess<Tree>::Node;
  Lazy* parent;
  unsigned index;
  Node* node;  // null until allocated

  Node* get(Tree& t) {
    if (node == nullptr) {
      node = parent == nullptr ? t.create_root() : t.create_child(parent->get(t), index);
    }
    return node;
  }
};

/// Up to 8 children of an output node: values of leaves not allocated yet, or of finished
/// inner nodes (already allocated).
struct Kids {
  float value[8];
  std::uint8_t present = 0;  // bit i: child i exists
  std::uint8_t inner = 0;    // bit i: child i is an allocated inner node

  /// Child i exists; it is an allocated inner node too with `inner`.
  void mark(unsigned i, bool is_inner = false) {
    present |= static_cast<std::uint8_t>(1u << i);
    if (is_inner) inner |= static_cast<std::uint8_t>(1u << i);
  }

  /// Whether the children are 8 equal leaves (OctoMap's isNodeCollapsible).
  bool collapsible() const {
    if (present != 0xFF || inner != 0) return false;
    bool equal = true;
    for (unsigned i = 1; i < 8; ++i) equal &= value[i] == value[0];
    return equal;
  }

  /// Ends a node: true if the children collapse to one leaf (collapsible() and
  /// `may_collapse`), else allocates the node and its leaf children and sets its value to the
  /// max of its children (OctoMap's updateOccupancyChildren). Either way `value[0]` is then
  /// the node's value, which its parent takes as the value of this child.
  template <class Tree, class SetValue>
  bool finish(Tree& t, Lazy<Tree>& self, SetValue set, bool may_collapse = true) {
    if (may_collapse && collapsible()) return true;
    auto* n = self.get(t);
    float mx = kMaxOfNoChildren<typename Lazy<Tree>::Node>;
    for (unsigned i = 0; i < 8; ++i) {
      if (!(present & (1u << i))) continue;
      if (!(inner & (1u << i))) set(t.create_child(n, i), value[i]);
      if (value[i] > mx) mx = value[i];
    }
    set(n, mx);
    value[0] = mx;
    return false;
  }
};

}  // namespace octofuse::detail
