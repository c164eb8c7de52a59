// octofuse: ending an inner node of a tree after its children changed, in one pass.
#pragma once

#include "octofuse/tree.hpp"
#include "octofuse/tree_access.hpp"

namespace octofuse::detail {

/// The children pointer of a node, which OctoMap keeps protected.
template <class Node>
struct ChildrenAccess : Node {
  static bool has_array(const Node* n) { return n->*(&ChildrenAccess::children) != nullptr; }
};

/// Whether two leaves may merge besides their values: an occupancy node's carried loss must
/// be the same too (OccupancyNode::operator==).
inline bool same_besides_value(const OccupancyNode* a, const OccupancyNode* b) {
  return a->carried_bits() == b->carried_bits();
}
inline bool same_besides_value(const ScalarNode*, const ScalarNode*) { return true; }

/// What a walk does to an inner node once its children are done, as OctoMap does it (`if
/// (!pruneNode(n)) n->setLogOdds(n->getMaxChildLogOdds())`), in one pass over the children:
/// the 8 children collapse into `n` if they are equal leaves (isNodeCollapsible, pruneNode;
/// a walk of a map that carries its loss first moves differing carried losses aside);
/// otherwise `n` holds the max of its children's values (from kMaxOfNoChildren). A node
/// without children is left as it is. `t` is the tree whose methods count the nodes (see
/// LossAdder). Returns whether it pruned.
template <class Tree>
bool prune_or_max(Tree& t, typename TreeAccess<Tree>::Node* n) {
  using Node = typename TreeAccess<Tree>::Node;
  if (!ChildrenAccess<Node>::has_array(n)) return false;
  float mx = kMaxOfNoChildren<Node>;
  bool any = false;
  bool collapsible = t.nodeChildExists(n, 0);
  const Node* c0 = collapsible ? t.getNodeChild(n, 0) : nullptr;
  const float first = collapsible ? c0->getValue() : 0.0f;
  for (unsigned i = 0; i < 8; ++i) {
    if (!t.nodeChildExists(n, i)) {
      collapsible = false;
      continue;
    }
    const Node* c = t.getNodeChild(n, i);
    const float v = c->getValue();
    any = true;
    if (v > mx) mx = v;
    // a child with an array of children is a leaf only if the array is empty
    collapsible = collapsible && (i == 0 || (v == first && same_besides_value(c, c0))) &&
                  (!ChildrenAccess<Node>::has_array(c) || !t.nodeHasChildren(c));
  }
  if (!any) return false;
  if (collapsible && t.pruneNode(n)) return true;
  n->setValue(mx);
  return false;
}

}  // namespace octofuse::detail
