// octofuse: adding values into a scalar tree (accumulated information loss) along a walk.
#pragma once

#include "octofuse/occupancy_map.hpp"
#include "octofuse/tree_access.hpp"

#include <algorithm>
#include <limits>

namespace octofuse::detail {

/// A position in a scalar tree during a walk. Nodes are created lazily, only when a value
/// is added below them, so a walk that adds nothing leaves no trace. A "fresh" node was
/// created by this walk (its region was not in the tree); a non-fresh childless node is a
/// leaf that stands for all voxels below it. Children keep a pointer to their parent cursor,
/// which lives in the caller's frame for the whole visit.
struct LossCursor {
  mutable octomap::OcTreeDataNode<float>* node = nullptr;
  mutable bool fresh = false;
  const LossCursor* parent = nullptr;
  unsigned idx = 0;
  bool active = false;
};

/// Adds values into a ScalarTree while walking down it.
class LossAdder {
 public:
  using Node = octomap::OcTreeDataNode<float>;

  explicit LossAdder(ScalarTree* tree) : t_(tree) {}

  /// The root cursor (inactive if there is no tree).
  LossCursor root() const {
    LossCursor c;
    c.active = t_ != nullptr;
    if (c.active) c.node = t_->getRoot();
    return c;
  }

  /// The cursor of child i (expands a coarse leaf; does not create nodes yet).
  LossCursor child(const LossCursor& c, unsigned i) {
    LossCursor k;
    if (!c.active) return k;
    k.active = true;
    if (c.node != nullptr) {
      if (!c.fresh && !t_->nodeHasChildren(c.node)) {
        t_->expandNode(c.node);  // a coarse leaf: its children inherit its value
        k.node = t_->getNodeChild(c.node, i);
        return k;
      }
      if (t_->nodeChildExists(c.node, i)) {
        k.node = t_->getNodeChild(c.node, i);
        k.fresh = c.fresh;
        return k;
      }
    }
    k.parent = &c;
    k.idx = i;
    return k;
  }

  /// Adds v to every voxel under the cursor.
  void add(const LossCursor& c, float v) {
    if (!c.active) return;
    materialize(c);
    if (c.fresh || !t_->nodeHasChildren(c.node)) {
      c.node->setValue(c.node->getValue() + v);
      return;
    }
    add_all(c.node, v);
  }

  /// After the children of a cursor were visited: prune, or hold the max of the children.
  void finish(const LossCursor& c) {
    if (c.node == nullptr || !t_->nodeHasChildren(c.node)) return;
    if (t_->pruneNode(c.node)) return;
    float mx = -std::numeric_limits<float>::infinity();
    for (unsigned i = 0; i < 8; ++i)
      if (t_->nodeChildExists(c.node, i)) mx = std::max(mx, t_->getNodeChild(c.node, i)->getValue());
    c.node->setValue(mx);
  }

  /// Marks the tree's metric size stale (call once when done).
  void done() {
    if (t_ != nullptr) TreeAccess<ScalarTree>::mark_changed(*t_);
  }

 private:
  void materialize(const LossCursor& c) {
    if (c.node != nullptr) return;
    if (c.parent == nullptr) {  // the root of an empty tree
      c.node = TreeAccess<ScalarTree>::ensure_root(*t_);
      c.node->setValue(0.0f);
      c.fresh = true;
      return;
    }
    materialize(*c.parent);
    Node* p = c.parent->node;
    if (t_->nodeChildExists(p, c.idx)) {
      c.node = t_->getNodeChild(p, c.idx);
      c.fresh = c.parent->fresh;
    } else {
      c.node = t_->createNodeChild(p, c.idx);
      c.node->setValue(0.0f);
      c.fresh = true;
    }
  }

  void add_all(Node* n, float v) {
    if (!t_->nodeHasChildren(n)) {
      n->setValue(n->getValue() + v);
      return;
    }
    for (unsigned i = 0; i < 8; ++i)
      if (t_->nodeChildExists(n, i)) add_all(t_->getNodeChild(n, i), v);
    LossCursor c;
    c.node = n;
    finish(c);
  }

  ScalarTree* t_;
};

}  // namespace octofuse::detail
