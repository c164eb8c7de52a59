// octofuse: building a tree bottom-up with the pruning built in: a node is only allocated
// once it is known to stay (new-tree fusion, clamped copies).
#pragma once

#include "octofuse/detail/tree_access.hpp"
#include "octofuse/tree.hpp"

#include "prune_or_max.hpp"

#include <cstdint>
#include <limits>

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

  /// The children under the prune rule, the max from `max_of_none` up.
  PruneRule judged(float max_of_none) const {
    PruneRule rule(max_of_none);
    for (unsigned i = 0; i < 8; ++i) {
      if (present & (1u << i)) {
        rule.child(value[i], !(inner & (1u << i)));
      } else {
        rule.absent();
      }
    }
    return rule;
  }

  /// Whether the children are 8 equal leaves (OctoMap's isNodeCollapsible).
  bool collapsible() const { return judged(-std::numeric_limits<float>::infinity()).merges(); }

  /// Ends a node: true if the children collapse to one leaf (the prune rule, and
  /// `may_collapse`), else allocates the node and its leaf children and sets its value to the
  /// max of its children (OctoMap's updateOccupancyChildren). Either way `value[0]` is then
  /// the node's value, which its parent takes as the value of this child.
  template <class Tree, class SetValue>
  bool finish(Tree& t, Lazy<Tree>& self, SetValue set, bool may_collapse = true) {
    const PruneRule rule = judged(kMaxOfNoChildren<typename Lazy<Tree>::Node>);
    if (may_collapse && rule.merges()) return true;
    auto* n = self.get(t);
    for (unsigned i = 0; i < 8; ++i)
      if ((present & ~inner) & (1u << i)) set(t.create_child(n, i), value[i]);
    set(n, rule.max());
    value[0] = rule.max();
    return false;
  }
};

}  // namespace octofuse::detail
