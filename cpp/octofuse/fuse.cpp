// octofuse: simultaneous walk of two octrees producing the fused tree and its loss tree.
#include "octofuse/fuse.hpp"

#include "octofuse/tree_access.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace octofuse {

namespace {

using OcNode = octomap::OcTreeNode;
using ScalarNode = octomap::OcTreeDataNode<float>;

/// A node of an input tree as seen by the walk: a real node, or a pruned leaf standing for
/// the child it would have (a "virtual" node with the leaf's value), or nothing (unknown).
template <class Tree>
struct Src {
  using Node = typename detail::TreeAccess<Tree>::Node;
  const Tree* tree = nullptr;
  const Node* node = nullptr;  // null when unknown
  bool leaf = false;

  bool present() const { return node != nullptr; }
  Src child(unsigned i) const {
    if (node == nullptr || leaf) return *this;  // unknown stays unknown, leaves expand
    if (!tree->nodeChildExists(node, i)) return Src{tree, nullptr, false};
    const Node* c = tree->getNodeChild(node, i);
    return Src{tree, c, !tree->nodeHasChildren(c)};
  }
  static Src root(const Tree& t) {
    const Node* r = t.getRoot();
    return Src{&t, r, r != nullptr && !t.nodeHasChildren(r)};
  }
};

struct Walker {
  Rule rule;
  UnknownPolicy unknown;
  double lmin, lmax;  // clamping in log-odds
  octomap::OcTree& out;
  ScalarTree& loss;
  std::size_t fused = 0, copied = 0;

  void leaf(const Src<octomap::OcTree>& a, const Src<octomap::OcTree>& b, OcNode* o,
            ScalarNode* lo) {
    double la, lb;
    if (a.present() && b.present()) {
      la = a.node->getLogOdds();
      lb = b.node->getLogOdds();
    } else if (unknown == UnknownPolicy::Copy) {
      o->setLogOdds((a.present() ? a.node : b.node)->getLogOdds());
      lo->setValue(0.0f);
      ++copied;
      return;
    } else {
      la = a.present() ? a.node->getLogOdds() : 0.0;
      lb = b.present() ? b.node->getLogOdds() : 0.0;
    }
    const Fused f = fuse_logodds(rule, la, lb, 0.0);
    const double l = f.l < lmin ? lmin : (f.l > lmax ? lmax : f.l);
    o->setLogOdds(static_cast<float>(l));
    lo->setValue(static_cast<float>(f.info_loss));
    ++fused;
  }

  // Prunes a node whose 8 children are leaves of equal value (OctoMap's pruneNode);
  // otherwise sets the inner node to the max of its children, as OctoMap does.
  template <class Tree, class Node, class Get, class Set>
  static void finish(Tree& t, Node* n, Get get, Set set) {
    if (t.pruneNode(n)) return;
    float mx = -std::numeric_limits<float>::infinity();
    for (unsigned i = 0; i < 8; ++i) {
      if (!t.nodeChildExists(n, i)) continue;
      const float v = get(t.getNodeChild(n, i));
      if (v > mx) mx = v;
    }
    set(n, mx);
  }

  void walk(const Src<octomap::OcTree>& a, const Src<octomap::OcTree>& b, OcNode* o,
            ScalarNode* lo) {
    const bool a_done = !a.present() || a.leaf, b_done = !b.present() || b.leaf;
    if (a_done && b_done) {
      leaf(a, b, o, lo);
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      const Src<octomap::OcTree> ca = a.child(i), cb = b.child(i);
      if (!ca.present() && !cb.present()) continue;
      walk(ca, cb, out.createNodeChild(o, i), loss.createNodeChild(lo, i));
    }
    finish(out, o, [](const OcNode* c) { return c->getLogOdds(); },
           [](OcNode* n, float v) { n->setLogOdds(v); });
    finish(loss, lo, [](const ScalarNode* c) { return c->getValue(); },
           [](ScalarNode* n, float v) { n->setValue(v); });
  }
};

void add_walk(ScalarTree& acc, ScalarNode* n, const Src<ScalarTree>& b, bool n_leaf) {
  // n is a node of acc (n_leaf: it has no children); b the matching node of the addend.
  if (!b.present()) return;
  if (n_leaf && b.leaf) {
    n->setValue(n->getValue() + b.node->getValue());
    return;
  }
  if (n_leaf) acc.expandNode(n);  // the addend is finer here: split the accumulated leaf
  for (unsigned i = 0; i < 8; ++i) {
    const Src<ScalarTree> cb = b.child(i);
    if (!cb.present()) continue;
    if (acc.nodeChildExists(n, i)) {
      ScalarNode* c = acc.getNodeChild(n, i);
      add_walk(acc, c, cb, !acc.nodeHasChildren(c));
    } else {
      ScalarNode* c = acc.createNodeChild(n, i);
      c->setValue(0.0f);
      add_walk(acc, c, cb, true);
    }
  }
  Walker::finish(acc, n, [](const ScalarNode* c) { return c->getValue(); },
                 [](ScalarNode* m, float v) { m->setValue(v); });
}

}  // namespace

void check_compatible(const OccupancyMap& a, const OccupancyMap& b) {
  const MapParams &pa = a.params(), &pb = b.params();
  if (std::fabs(pa.resolution - pb.resolution) > 1e-9 * pa.resolution) {
    throw std::invalid_argument("maps have different resolutions (" + std::to_string(pa.resolution) +
                                " m and " + std::to_string(pb.resolution) +
                                " m); fuse maps built at the same resolution");
  }
  if (a.clamp_min_logodds() != b.clamp_min_logodds() ||
      a.clamp_max_logodds() != b.clamp_max_logodds()) {
    throw std::invalid_argument(
        "maps have different clamping thresholds ([" + std::to_string(pa.clamp_min) + ", " +
        std::to_string(pa.clamp_max) + "] and [" + std::to_string(pb.clamp_min) + ", " +
        std::to_string(pb.clamp_max) + "]); fuse maps built with the same clamping");
  }
}

FusionResult fuse_maps(const OccupancyMap& a, const OccupancyMap& b, Rule rule,
                       UnknownPolicy unknown) {
  check_compatible(a, b);
  FusionResult res;
  res.map = std::make_unique<OccupancyMap>(a.params());
  res.info_loss = std::make_unique<ScalarTree>(a.params().resolution);
  const auto ra = Src<octomap::OcTree>::root(a.tree());
  const auto rb = Src<octomap::OcTree>::root(b.tree());
  if (ra.present() || rb.present()) {
    Walker w{rule, unknown, a.clamp_min_logodds(), a.clamp_max_logodds(), res.map->tree(),
             *res.info_loss};
    OcNode* o = detail::TreeAccess<octomap::OcTree>::ensure_root(res.map->tree());
    ScalarNode* lo = detail::TreeAccess<ScalarTree>::ensure_root(*res.info_loss);
    w.walk(ra, rb, o, lo);
    res.voxels_fused = w.fused;
    res.voxels_copied = w.copied;
  }
  return res;
}

void accumulate(ScalarTree& acc, const ScalarTree& b) {
  const auto rb = Src<ScalarTree>::root(b);
  if (!rb.present()) return;
  const bool was_empty = acc.getRoot() == nullptr;
  ScalarNode* r = detail::TreeAccess<ScalarTree>::ensure_root(acc);
  if (was_empty) r->setValue(0.0f);
  add_walk(acc, r, rb, !acc.nodeHasChildren(r));
  detail::TreeAccess<ScalarTree>::mark_changed(acc);
}

}  // namespace octofuse
