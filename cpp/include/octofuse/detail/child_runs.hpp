// octofuse: a depth-first update walk's step from a node to its children, over sorted codes.
#pragma once

#include <cstddef>
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
  // the children's indices ascend: the run ends in (lo, hi], found by steps that double
  // (runs are long near the root and a code or two near the voxels), then halving
  const std::uint64_t* lo = b;
  const std::uint64_t* hi = b + 1;
  for (std::ptrdiff_t step = 1; child(*hi) == pos; step *= 2) {
    lo = hi;
    hi = (e - 1) - hi > 2 * step ? hi + 2 * step : e - 1;
  }
  while (hi - lo > 1) {
    const std::uint64_t* mid = lo + (hi - lo) / 2;
    (child(*mid) == pos ? lo : hi) = mid;
  }
  return hi;
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
