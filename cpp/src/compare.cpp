// octofuse: map comparison and delta extraction by simultaneous tree walks.
#include "octofuse/compare.hpp"

#include "octofuse/detail/pair_memo.hpp"
#include "octofuse/rules.hpp"

#include "prune_or_max.hpp"
#include "walk.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <utility>
#include <vector>

namespace octofuse {

namespace {

using W = detail::WalkNode<OccupancyTree>;
using OcNode = OccupancyNode;

// The bits set in each 8-bit child mask (a look-up: without -mpopcnt, __builtin_popcount is a
// call into libgcc).
constexpr std::array<std::uint8_t, 256> kSetBits = [] {
  std::array<std::uint8_t, 256> t{};
  for (unsigned m = 1; m < 256; ++m) t[m] = static_cast<std::uint8_t>(t[m >> 1] + (m & 1u));
  return t;
}();

// Walks the reference and one map at once, down to where both are leaves or unknown (a
// coarse leaf stands for the voxels below it): only the children that either tree has are
// visited, found from a mask of each node's children.
struct Comparer {
  // a node of the reference in the walk (null when unknown) and the mask of its children
  // (none: a leaf, which stands for all 8)
  struct RefSide {
    const ReferenceMap::Node* node;
    unsigned kids;
  };

  const std::vector<ReferenceMap::Node>& ref;
  const OccupancyTree& mt;
  double tol, thr;
  Comparison out{};
  // KL of a voxel from its two stored values (the absent map's as +0): exact, memoized
  detail::PairMemo<double> kl{detail::kl_logodds(0.0, 0.0)};
  static void kl_of(float lr, float lm, double& out) { out = detail::kl_logodds(lr, lm); }

  static float value(const ReferenceMap::Node* n) { return n->value; }
  static float value(const OcNode* n) { return n->getLogOdds(); }

  template <class Side>
  int cls(const Side& n) const {
    if (n.node == nullptr) return kUnknown;
    return value(n.node) > thr ? kOccupied : kFree;
  }

  void count(const RefSide& r, const W& m, double weight) {
    out.confusion[cls(r)][cls(m)] += weight;
    if (r.node == nullptr) return;
    const float stored_r = r.node->value;
    const float stored_m = m.node != nullptr ? m.node->getLogOdds() : 0.0f;
    out.kl_sum += weight * kl.get(stored_r, stored_m, kl_of);
    const double lr = stored_r, lm = stored_m;
    if (m.node != nullptr) {
      out.both_known += weight;
      out.abs_diff_sum += weight * std::fabs(lm - lr);
      if (std::fabs(lm) > std::fabs(lr) + tol) out.overconfident += weight;
    }
  }

  // The children the reference has in the walk: all 8 for a leaf, none when unknown.
  static unsigned mask(const RefSide& s) {
    if (s.node == nullptr) return 0;
    return s.kids == 0 ? 0xFFu : s.kids;
  }

  RefSide child(const RefSide& s, unsigned i) const {
    if (s.kids == 0) return s;  // unknown, or a leaf standing for its child
    if (!((s.kids >> i) & 1u)) return {nullptr, 0};
    const ReferenceMap::Node& c = ref[s.node->first + kSetBits[s.kids & ((1u << i) - 1)]];
    return {&c, c.kids};
  }

  void walk(const RefSide& r, const W& m, double weight) {
    if (r.kids == 0 && m.leaf_or_unknown()) {
      count(r, m, weight);
      return;
    }
    const double w = weight / 8.0;
    for (unsigned both = mask(r) | m.children_mask(); both != 0; both &= both - 1) {
      const unsigned i = static_cast<unsigned>(__builtin_ctz(both));
      walk(child(r, i), m.child(i), w);
    }
  }

  void run() {
    const RefSide r = ref.empty() ? RefSide{nullptr, 0} : RefSide{&ref[0], ref[0].kids};
    const W m = W::root(mt);
    // weight 8^16: the root stands for all finest voxels
    if (r.node != nullptr || m.present()) walk(r, m, std::pow(8.0, 16));
  }
};

// Appends the children of `n` (the node at `at`) to `out`, side by side, then theirs.
void read_children(const OccupancyTree& t, const OcNode* n, std::size_t at,
                   std::vector<ReferenceMap::Node>& out) {
  if (!t.nodeHasChildren(n)) return;
  unsigned kids = 0;
  for (unsigned i = 0; i < 8; ++i) kids |= unsigned{t.nodeChildExists(n, i)} << i;
  const std::size_t first = out.size();
  out[at].first = static_cast<std::uint32_t>(first);
  out[at].kids = kids;
  for (unsigned b = kids; b != 0; b &= b - 1)
    out.push_back({t.getNodeChild(n, static_cast<unsigned>(__builtin_ctz(b)))->getLogOdds(), 0, 0});
  std::size_t k = first;
  for (unsigned b = kids; b != 0; b &= b - 1, ++k)
    read_children(t, t.getNodeChild(n, static_cast<unsigned>(__builtin_ctz(b))), k, out);
}

struct LeafRec {
  std::uint16_t k[3];  // lower corner key of the leaf
  std::uint8_t depth;
  float value;
};

// The child of a node at `depth` on the way to leaf `l`.
unsigned child_index(const LeafRec& l, unsigned depth) {
  const unsigned bit = 15 - depth;
  return ((l.k[0] >> bit) & 1u) | (((l.k[1] >> bit) & 1u) << 1) | (((l.k[2] >> bit) & 1u) << 2);
}

// The lower corner key of child i of the node at `depth` whose lower corner key is k0.
void child_key(const std::uint16_t k0[3], unsigned depth, unsigned i, std::uint16_t kc[3]) {
  const unsigned half = 1u << (15 - depth);
  kc[0] = static_cast<std::uint16_t>(k0[0] + ((i & 1) ? half : 0));
  kc[1] = static_cast<std::uint16_t>(k0[1] + ((i & 2) ? half : 0));
  kc[2] = static_cast<std::uint16_t>(k0[2] + ((i & 4) ? half : 0));
}

// Collects the leaves of `cur` whose value is new or differs from `prev`.
struct Differ {
  std::vector<LeafRec> out;

  void walk(const W& cur, const W& prev, const std::uint16_t k0[3], unsigned depth) {
    if (!cur.present()) return;
    if (cur.leaf && (!prev.present() || prev.leaf)) {
      if (!prev.present() || prev.node->getLogOdds() != cur.node->getLogOdds()) {
        out.push_back(
            {{k0[0], k0[1], k0[2]}, static_cast<std::uint8_t>(depth), cur.node->getLogOdds()});
      }
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      const W cc = cur.child(i);
      if (!cc.present()) continue;
      std::uint16_t kc[3];
      child_key(k0, depth, i, kc);
      walk(cc, prev.child(i), kc, depth + 1);
    }
  }
};

// Sets inner nodes to the max of their children and prunes, bottom up.
void finish_inner(OccupancyTree& t, OccupancyNode* n) {
  if (!t.nodeHasChildren(n)) return;
  for (unsigned i = 0; i < 8; ++i)
    if (t.nodeChildExists(n, i)) finish_inner(t, t.getNodeChild(n, i));
  detail::prune_or_max(t, n);
}

// Builds a tree from disjoint leaves given by lower-corner key and depth, in their order,
// up to the first that would make it more than `max_nodes` nodes; returns how many it took.
std::size_t build_from_leaves(OccupancyTree& t, const std::vector<LeafRec>& leaves,
                              std::size_t max_nodes = std::numeric_limits<std::size_t>::max()) {
  // a root without leaves would be one leaf over all space: no tree unless a leaf fits
  if (leaves.empty() || 1u + leaves.front().depth > max_nodes) return 0;
  OccupancyNode* root = detail::TreeAccess<OccupancyTree>::ensure_root(t);
  std::size_t nodes = 1, taken = 0;
  for (const LeafRec& l : leaves) {
    // the nodes this leaf adds: those below the deepest one its path already has
    OccupancyNode* n = root;
    unsigned d = 0;
    for (; d < l.depth; ++d) {
      const unsigned i = child_index(l, d);
      if (!t.nodeChildExists(n, i)) break;
      n = t.getNodeChild(n, i);
    }
    if (nodes + (l.depth - d) > max_nodes) break;
    nodes += l.depth - d;
    for (; d < l.depth; ++d) n = t.createNodeChild(n, child_index(l, d));
    n->setLogOdds(l.value);
    ++taken;
  }
  finish_inner(t, root);
  detail::TreeAccess<OccupancyTree>::mark_changed(t);
  return taken;
}

// The leaves of `delta` with the log-odds of `held` at each (0 where it has no node).
struct HeldValues {
  std::vector<LeafRec> leaves;
  std::vector<float> held;

  void walk(const W& cur, const W& prev, const std::uint16_t k0[3], unsigned depth) {
    if (!cur.present()) return;
    if (cur.leaf) {
      leaves.push_back(
          {{k0[0], k0[1], k0[2]}, static_cast<std::uint8_t>(depth), cur.node->getLogOdds()});
      held.push_back(prev.present() ? prev.node->getLogOdds() : 0.0f);
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      std::uint16_t kc[3];
      child_key(k0, depth, i, kc);
      walk(cur.child(i), prev.child(i), kc, depth + 1);
    }
  }
};

// The leaves of `held` with those of `delta` over them, disjoint.
struct Overlay {
  std::vector<LeafRec> out;

  void walk(const W& base, const W& top, const std::uint16_t k0[3], unsigned depth) {
    const W& from = top.present() ? top : base;
    if (!from.present()) return;
    if (from.leaf) {  // a leaf of delta, or of held where delta has nothing
      out.push_back(
          {{k0[0], k0[1], k0[2]}, static_cast<std::uint8_t>(depth), from.node->getLogOdds()});
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      std::uint16_t kc[3];
      child_key(k0, depth, i, kc);
      walk(base.child(i), top.child(i), kc, depth + 1);
    }
  }
};

}  // namespace

ReferenceMap::ReferenceMap(const OccupancyMap& ref) : grid_(ref.params()) {
  const OccupancyTree& t = ref.tree();
  if (t.getRoot() == nullptr) return;
  nodes_.reserve(t.size());
  nodes_.push_back({t.getRoot()->getLogOdds(), 0, 0});
  read_children(t, t.getRoot(), 0, nodes_);
  if (nodes_.size() > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error("a reference map of more than 2^32 nodes");
}

Comparison compare_maps(const ReferenceMap& ref, const OccupancyMap& map, double tol,
                        double occ_threshold) {
  Comparer cmp{ref.nodes(), map.tree(), tol, occ_threshold};
  cmp.run();
  return cmp.out;
}

std::unique_ptr<OccupancyMap> changed_voxels(const OccupancyMap& current,
                                             const OccupancyMap& previous) {
  auto out = std::make_unique<OccupancyMap>(current.params());
  Differ d;
  const std::uint16_t k0[3] = {0, 0, 0};
  d.walk(W::root(current.tree()), W::root(previous.tree()), k0, 0);
  build_from_leaves(out->settled_tree(), d.out);
  return out;
}

std::unique_ptr<OccupancyMap> most_informative_voxels(const OccupancyMap& delta,
                                                      const OccupancyMap& held,
                                                      std::size_t max_nodes, std::size_t& taken) {
  HeldValues h;
  const std::uint16_t k0[3] = {0, 0, 0};
  h.walk(W::root(delta.tree()), W::root(held.tree()), k0, 0);
  std::vector<std::size_t> order(h.leaves.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return std::fabs(h.leaves[a].value - h.held[a]) > std::fabs(h.leaves[b].value - h.held[b]);
  });
  std::vector<LeafRec> ranked;
  ranked.reserve(order.size());
  for (std::size_t i : order) ranked.push_back(h.leaves[i]);
  auto out = std::make_unique<OccupancyMap>(delta.params());
  taken = build_from_leaves(out->settled_tree(), ranked, max_nodes);
  return out;
}

std::unique_ptr<OccupancyMap> overlaid(const OccupancyMap& held, const OccupancyMap& delta) {
  Overlay o;
  const std::uint16_t k0[3] = {0, 0, 0};
  o.walk(W::root(held.tree()), W::root(delta.tree()), k0, 0);
  auto out = std::make_unique<OccupancyMap>(held.params());
  build_from_leaves(out->settled_tree(), o.out);
  return out;
}

}  // namespace octofuse
