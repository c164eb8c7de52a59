// octofuse: OctoMap's rule for ending an inner node once its children are final (PruneRule),
// and ending one in a tree that way, in one pass (prune_or_max). Every walk that builds or
// changes a tree (fusions, insertion, comparison, the carried loss) ends its nodes by it.
#pragma once

#include "octofuse/detail/tree_access.hpp"
#include "octofuse/tree.hpp"

namespace octofuse::detail {

/// OctoMap's rule for an inner node whose children are final: the eight children merge into
/// it when all eight exist and are leaves of one value (isNodeCollapsible, pruneNode: the
/// first child's data is kept); otherwise it holds the max of its children's values
/// (getMaxChildLogOdds). A NaN equals nothing, so children holding one never merge, and it is
/// never the max. Children are shown in child order, absent ones included.
class PruneRule {
 public:
  /// `max_of_none`: the max of no children (kMaxOfNoChildren<Node>).
  explicit PruneRule(float max_of_none) : max_(max_of_none) {}

  void absent() { mergeable_ = false; }
  void child(float value, bool leaf) {
    if (value > max_) max_ = value;
    mergeable_ = mergeable_ && leaf && (count_ == 0 || value == first_);
    if (count_ == 0) first_ = value;
    ++count_;
  }

  /// Whether the children shown so far may still merge (all present leaves of one value).
  bool may_merge() const { return mergeable_; }
  /// Whether the eight children merge.
  bool merges() const { return mergeable_ && count_ == 8; }
  bool no_children() const { return count_ == 0; }
  float max() const { return max_; }

 private:
  float max_;
  float first_ = 0.0f;
  unsigned count_ = 0;
  bool mergeable_ = true;
};

/// The children pointer of a node, which OctoMap keeps protected.
template <class Node>
struct ChildrenAccess : Node {
  static bool has_array(const Node* n) { return n->*(&ChildrenAccess::children) != nullptr; }
};

/// Whether two leaves carry different losses (OccupancyNode::operator== compares them too).
inline bool losses_differ(const OccupancyNode* a, const OccupancyNode* b) {
  return a->carried_bits() != b->carried_bits();
}
inline bool losses_differ(const ScalarNode*, const ScalarNode*) { return false; }

/// For prune_or_max: children that would merge but for their carried losses stay apart.
struct KeepLossesApart {
  template <class Node>
  bool operator()(Node* const*) const {
    return false;
  }
};

/// What a walk does to an inner node `n` once its children are done, as OctoMap does it (`if
/// (!pruneNode(n)) n->setLogOdds(n->getMaxChildLogOdds())`), by PruneRule in one pass over the
/// children. A node without children is left as it is. `t` is the tree whose methods count
/// the nodes (see LossAdder). Leaves of one value that carry different losses
/// (carried_loss.hpp) are passed to `move_aside(children)`, which may move their losses out
/// of the nodes and return true: they then merge. Returns whether it pruned.
template <class Tree, class MoveAside = KeepLossesApart>
bool prune_or_max(Tree& t, typename TreeAccess<Tree>::Node* n, MoveAside&& move_aside = {}) {
  using Node = typename TreeAccess<Tree>::Node;
  if (!ChildrenAccess<Node>::has_array(n)) return false;
  PruneRule rule(kMaxOfNoChildren<Node>);
  Node* kids[8];
  for (unsigned i = 0; i < 8; ++i) {
    if (!t.nodeChildExists(n, i)) {
      rule.absent();
      continue;
    }
    Node* c = kids[i] = t.getNodeChild(n, i);
    // a child with an array of children is a leaf only if the array is empty
    rule.child(c->getValue(), !ChildrenAccess<Node>::has_array(c) || !t.nodeHasChildren(c));
  }
  if (rule.no_children()) return false;
  bool merge = rule.merges();
  if (merge) {
    bool differ = false;
    for (unsigned i = 1; i < 8; ++i) differ = differ || losses_differ(kids[i], kids[0]);
    if (differ) merge = move_aside(kids);
  }
  if (merge && t.pruneNode(n)) return true;
  n->setValue(rule.max());
  return false;
}

}  // namespace octofuse::detail
