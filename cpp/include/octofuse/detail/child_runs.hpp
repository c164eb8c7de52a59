// octofuse: a depth-first update walk's step from a node to its children, over sorted codes.
#pragma once

#include <cstdint>

namespace octofuse::detail {

/// For the ascending codes b..e (b != e) below one node: the end of the run that starts at b
/// and lies under one child, whose index (the three code bits at `shift`, of `code & mask`)
/// goes to `pos`.
inline const std::uint64_t* child_run_end(const std::uint64_t* b, const std::uint64_t* e,
                                          unsigned shift, std::uint64_t mask, unsigned& pos) {
  const auto child = [shift, mask](std::uint64_t c) {
    return static_cast<unsigned>(((c & mask) >> shift) & 7);
  };
  pos = child(*b);
  if (child(*(e - 1)) == pos) return e;  // the whole range lies under one child
  const std::uint64_t* g = b + 1;
  while (g != e && child(*g) == pos) ++g;
  return g;
}

/// Child `pos` of `node` for an update below it, as updateNodeRecurs() makes it: a pruned
/// leaf (a node without children that was not `just_created`) is expanded, a missing child
/// created (then `created` is set).
template <class Tree, class Node>
Node* child_to_update(Tree& t, Node* node, bool just_created, unsigned pos, bool& created) {
  created = false;
  if (!t.nodeChildExists(node, pos)) {
    if (!t.nodeHasChildren(node) && !just_created) {
      t.expandNode(node);
    } else {
      t.createNodeChild(node, pos);
      created = true;
    }
  }
  return t.getNodeChild(node, pos);
}

}  // namespace octofuse::detail
