// octofuse: adding values into a scalar tree (accumulated information loss) along a walk.
#pragma once

#include "octofuse/detail/tree_access.hpp"
#include "octofuse/tree.hpp"

#include "prune_or_max.hpp"

#include <cstring>
#include <mutex>

namespace octofuse::detail {

/// A position in a scalar tree during a walk. Nodes are created lazily, only when a value
/// is added below them, so a walk that adds nothing leaves no trace. A "fresh" node was
/// created by this walk (its region was not in the tree); a non-fresh childless node is a
/// leaf that stands for all voxels below it, expanded only when an add below it changes a
/// value. Children keep a pointer to their parent cursor, which lives in the caller's frame
/// for the whole visit.
struct LossCursor {
  mutable ScalarNode* node = nullptr;
  mutable bool fresh = false;
  const LossCursor* parent = nullptr;
  const ScalarNode* within = nullptr;  ///< the leaf a cursor without a node lies in, if any
  unsigned idx = 0;
  bool active = false;
  bool shared = false;  ///< visited by the serial top of a parallel walk (see LossAdder)
};

/// Adds values into a ScalarTree while walking down it.
///
/// In a parallel walk each worker has its own adder: node operations go through `ops`, a
/// scratch tree of the worker that counts the nodes it creates and deletes (OctoMap keeps the
/// count in the tree object; the caller adds the workers' counts to `tree` afterwards), and
/// nodes under the cursors of the serial top of the walk (`shared`) are created under `lock`.
class LossAdder {
 public:
  using Node = ScalarNode;

  explicit LossAdder(ScalarTree* tree, ScalarTree* ops = nullptr, std::mutex* lock = nullptr)
      : t_(tree), ops_(ops != nullptr ? ops : tree), lock_(lock) {}

  /// The root cursor (inactive if there is no tree).
  LossCursor root() const {
    LossCursor c;
    c.active = t_ != nullptr;
    if (c.active) c.node = t_->getRoot();
    return c;
  }

  /// The cursor of child i (creates no node yet).
  LossCursor child(const LossCursor& c, unsigned i) {
    LossCursor k;
    if (!c.active) return k;
    k.active = true;
    k.parent = &c;
    k.idx = i;
    if (c.node == nullptr) {
      k.within = c.within;
    } else if (!c.fresh && !ops_->nodeHasChildren(c.node)) {
      // a coarse leaf: expanded when an add below it changes a value. A NaN leaf is expanded
      // now, as finishing it then makes it the max of its children (NaN children never prune)
      if (c.node->getValue() == c.node->getValue()) {
        k.within = c.node;
      } else {
        ops_->expandNode(c.node);
        k.node = ops_->getNodeChild(c.node, i);
      }
    } else if (ops_->nodeChildExists(c.node, i)) {
      k.node = ops_->getNodeChild(c.node, i);
      k.fresh = c.fresh;
    }
    return k;
  }

  /// Adds v to every voxel under the cursor.
  void add(const LossCursor& c, float v) {
    if (!c.active) return;
    if (c.node == nullptr && c.within != nullptr && keeps(c.within->getValue(), v)) {
      return;  // expanding the leaf would give every child its value, pruned back at the end
    }
    materialize(c);
    if (c.fresh || !ops_->nodeHasChildren(c.node)) {
      c.node->setValue(c.node->getValue() + v);
      return;
    }
    add_all(c.node, v);
  }

  /// After the children of a cursor were visited: prune, or hold the max of the children.
  void finish(const LossCursor& c) {
    if (c.node != nullptr) prune_or_max(*ops_, c.node);
  }

  /// Marks the tree's metric size stale (call once when done).
  void done() {
    if (t_ != nullptr) TreeAccess<ScalarTree>::mark_changed(*t_);
  }

 private:
  void materialize(const LossCursor& c) {
    if (c.node != nullptr) return;
    if (lock_ != nullptr && (c.shared || (c.parent != nullptr && c.parent->shared))) {
      const std::lock_guard<std::mutex> guard(*lock_);  // a node under the shared top
      materialize_here(c, true);
      return;
    }
    materialize_here(c, false);
  }

  // `held`: the caller holds the lock (then every ancestor is materialized under it too).
  void materialize_here(const LossCursor& c, bool held) {
    if (c.node != nullptr) return;
    if (c.parent == nullptr) {  // the root of an empty tree
      c.node = TreeAccess<ScalarTree>::ensure_root(*t_);
      c.node->setValue(0.0f);
      c.fresh = true;
      return;
    }
    if (held) {
      materialize_here(*c.parent, true);
    } else {
      materialize(*c.parent);
    }
    Node* p = c.parent->node;
    if (!c.parent->fresh && !ops_->nodeHasChildren(p)) {
      ops_->expandNode(p);  // a coarse leaf: its children inherit its value
    }
    if (ops_->nodeChildExists(p, c.idx)) {
      c.node = ops_->getNodeChild(p, c.idx);
      c.fresh = c.parent->fresh;
    } else {
      c.node = ops_->createNodeChild(p, c.idx);
      c.node->setValue(0.0f);
      c.fresh = true;
    }
  }

  // Every voxel under n gets v: existing leaves add it, voxels without a value yet (children
  // no fusion reached before) start from it.
  void add_all(Node* n, float v) {
    if (!ops_->nodeHasChildren(n)) {
      n->setValue(n->getValue() + v);
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      if (ops_->nodeChildExists(n, i)) {
        add_all(ops_->getNodeChild(n, i), v);
      } else {
        ops_->createNodeChild(n, i)->setValue(v);
      }
    }
    LossCursor c;
    c.node = n;
    finish(c);
  }

  // Whether x + v is x, bit for bit.
  static bool keeps(float x, float v) {
    const float s = x + v;
    return std::memcmp(&s, &x, sizeof s) == 0;
  }

  ScalarTree* t_;
  ScalarTree* ops_;
  std::mutex* lock_;
};

}  // namespace octofuse::detail
