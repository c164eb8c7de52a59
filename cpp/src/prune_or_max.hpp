// octofuse: ending an inner node of a tree after its children changed, in one pass.
#pragma once

#include "octofuse/detail/tree_access.hpp"
#include "octofuse/tree.hpp"

namespace octofuse::detail {

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
  bool operator()(Node* const*) const { return false; }
};

/// What a walk does to an inner node once its children are done, as OctoMap does it (`if
/// (!pruneNode(n)) n->setLogOdds(n->getMaxChildLogOdds())`), in one pass over the children:
/// the 8 children collapse into `n` if they are equal leaves (isNodeCollapsible, pruneNode);
/// otherwise `n` holds the max of its children's values (from kMaxOfNoChildren). A node
/// without children is left as it is. `t` is the tree whose methods count the nodes (see
/// LossAdder). Leaves of one value that carry different losses (carried_loss.hpp) are passed
/// to `move_aside(children)`, which may move their losses out of the nodes and return true:
/// they then collapse. Returns whether it pruned.
template <class Tree, class MoveAside = KeepLossesApart>
bool prune_or_max(Tree& t, typename TreeAccess<Tree>::Node* n, MoveAside&& move_aside = {}) {
  using Node = typename TreeAccess<Tree>::Node;
  if (!ChildrenAccess<Node>::has_array(n)) return false;
  float mx = kMaxOfNoChildren<Node>;
  bool any = false;
  bool collapsible = t.nodeChildExists(n, 0);  // by value: 8 leaves of one value
  bool differ = false;                         // and their carried losses differ
  Node* kids[8];
  kids[0] = collapsible ? t.getNodeChild(n, 0) : nullptr;
  const float first = collapsible ? kids[0]->getValue() : 0.0f;
  for (unsigned i = 0; i < 8; ++i) {
    if (!t.nodeChildExists(n, i)) {
      collapsible = false;
      continue;
    }
    Node* c = kids[i] = t.getNodeChild(n, i);
    const float v = c->getValue();
    any = true;
    if (v > mx) mx = v;
    // a child with an array of children is a leaf only if the array is empty
    collapsible = collapsible && (i == 0 || v == first) &&
                  (!ChildrenAccess<Node>::has_array(c) || !t.nodeHasChildren(c));
    differ = differ || (i > 0 && collapsible && losses_differ(c, kids[0]));
  }
  if (!any) return false;
  if (collapsible && differ) collapsible = move_aside(kids);
  if (collapsible && t.pruneNode(n)) return true;
  n->setValue(mx);
  return false;
}

}  // namespace octofuse::detail
