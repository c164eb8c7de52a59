// octofuse: map comparison and delta extraction by simultaneous tree walks.
#include "octofuse/compare.hpp"

#include "octofuse/detail/pair_memo.hpp"
#include "octofuse/detail/prune_or_max.hpp"
#include "octofuse/rules.hpp"
#include "octofuse/walk.hpp"

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace octofuse {

namespace {

using W = detail::WalkNode<OccupancyTree>;
using OcNode = OccupancyNode;

// Walks the reference and one map at once, down to where both are leaves or unknown (a
// coarse leaf stands for the voxels below it): only the children that either tree has are
// visited, found from a mask of each node's children.
struct Comparer {
  // a node of one tree in the walk (null when unknown) and the mask of its children (none:
  // a leaf, which stands for all 8)
  struct Side {
    const OcNode* node;
    unsigned kids;
  };

  const OccupancyTree &rt, &mt;
  double tol, thr;
  Comparison out{};
  // KL of a voxel from its two stored values (the absent map's as +0): exact, memoized
  detail::PairMemo<double> kl{detail::kl_logodds(0.0, 0.0)};
  static void kl_of(float lr, float lm, double& out) { out = detail::kl_logodds(lr, lm); }

  int cls(const Side& n) const {
    if (n.node == nullptr) return kUnknown;
    return n.node->getLogOdds() > thr ? kOccupied : kFree;
  }

  void count(const Side& r, const Side& m, double weight) {
    out.confusion[cls(r)][cls(m)] += weight;
    if (r.node == nullptr) return;
    const float stored_r = r.node->getLogOdds();
    const float stored_m = m.node != nullptr ? m.node->getLogOdds() : 0.0f;
    out.kl_sum += weight * kl.get(stored_r, stored_m, kl_of);
    const double lr = stored_r, lm = stored_m;
    if (m.node != nullptr) {
      out.both_known += weight;
      out.abs_diff_sum += weight * std::fabs(lm - lr);
      if (std::fabs(lm) > std::fabs(lr) + tol) out.overconfident += weight;
    }
  }

  static Side side(const OccupancyTree& t, const OcNode* n) {
    unsigned kids = 0;
    if (t.nodeHasChildren(n))
      for (unsigned i = 0; i < 8; ++i) kids |= unsigned{t.nodeChildExists(n, i)} << i;
    return {n, kids};
  }

  // The children a side has in the walk: all 8 for a leaf, none when unknown.
  static unsigned mask(const Side& s) {
    if (s.node == nullptr) return 0;
    return s.kids == 0 ? 0xFFu : s.kids;
  }

  static Side child(const OccupancyTree& t, const Side& s, unsigned i) {
    if (s.kids == 0) return s;  // unknown, or a leaf standing for its child
    if (!((s.kids >> i) & 1u)) return {nullptr, 0};
    return side(t, t.getNodeChild(s.node, i));
  }

  void walk(const Side& r, const Side& m, double weight) {
    if (r.kids == 0 && m.kids == 0) {
      count(r, m, weight);
      return;
    }
    const double w = weight / 8.0;
    for (unsigned both = mask(r) | mask(m); both != 0; both &= both - 1) {
      const unsigned i = static_cast<unsigned>(__builtin_ctz(both));
      walk(child(rt, r, i), child(mt, m, i), w);
    }
  }

  static Side root(const OccupancyTree& t) {
    return t.getRoot() == nullptr ? Side{nullptr, 0} : side(t, t.getRoot());
  }
};

struct LeafRec {
  std::uint16_t k[3];  // lower corner key of the leaf
  std::uint8_t depth;
  float value;
};

// Collects the leaves of `cur` whose value is new or differs from `prev`.
struct Differ {
  std::vector<LeafRec> out;

  void walk(const W& cur, const W& prev, const std::uint16_t k0[3], unsigned depth) {
    if (!cur.present()) return;
    if (cur.leaf && (!prev.present() || prev.leaf)) {
      if (!prev.present() || prev.node->getLogOdds() != cur.node->getLogOdds()) {
        out.push_back({{k0[0], k0[1], k0[2]}, static_cast<std::uint8_t>(depth),
                       cur.node->getLogOdds()});
      }
      return;
    }
    const unsigned half = 1u << (15 - depth);
    for (unsigned i = 0; i < 8; ++i) {
      const W cc = cur.child(i);
      if (!cc.present()) continue;
      const std::uint16_t kc[3] = {static_cast<std::uint16_t>(k0[0] + ((i & 1) ? half : 0)),
                                   static_cast<std::uint16_t>(k0[1] + ((i & 2) ? half : 0)),
                                   static_cast<std::uint16_t>(k0[2] + ((i & 4) ? half : 0))};
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

// Builds a tree from disjoint leaves given by lower-corner key and depth.
void build_from_leaves(OccupancyTree& t, const std::vector<LeafRec>& leaves) {
  if (leaves.empty()) return;
  OccupancyNode* root = detail::TreeAccess<OccupancyTree>::ensure_root(t);
  for (const LeafRec& l : leaves) {
    OccupancyNode* n = root;
    for (unsigned d = 0; d < l.depth; ++d) {
      const unsigned bit = 15 - d;
      const unsigned i = ((l.k[0] >> bit) & 1u) | (((l.k[1] >> bit) & 1u) << 1) |
                         (((l.k[2] >> bit) & 1u) << 2);
      n = t.nodeChildExists(n, i) ? t.getNodeChild(n, i) : t.createNodeChild(n, i);
    }
    n->setLogOdds(l.value);
  }
  finish_inner(t, root);
  detail::TreeAccess<OccupancyTree>::mark_changed(t);
}

}  // namespace

Comparison compare_maps(const OccupancyMap& ref, const OccupancyMap& map, double tol,
                        double occ_threshold) {
  Comparer cmp{ref.tree(), map.tree(), tol, occ_threshold};
  const Comparer::Side r = Comparer::root(ref.tree()), m = Comparer::root(map.tree());
  // weight 8^16: the root stands for all finest voxels
  if (r.node != nullptr || m.node != nullptr) cmp.walk(r, m, std::pow(8.0, 16));
  return cmp.out;
}

std::unique_ptr<OccupancyMap> changed_voxels(const OccupancyMap& current,
                                             const OccupancyMap& previous) {
  auto out = std::make_unique<OccupancyMap>(current.params());
  Differ d;
  const std::uint16_t k0[3] = {0, 0, 0};
  d.walk(W::root(current.tree()), W::root(previous.tree()), k0, 0);
  build_from_leaves(out->tree(), d.out);
  return out;
}

}  // namespace octofuse
