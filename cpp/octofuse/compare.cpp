// octofuse: map comparison and delta extraction by simultaneous tree walks.
#include "octofuse/compare.hpp"

#include "octofuse/detail/pair_memo.hpp"
#include "octofuse/rules.hpp"
#include "octofuse/walk.hpp"

#include <cmath>
#include <cstdint>
#include <vector>

namespace octofuse {

namespace {

using W = detail::WalkNode<OccupancyTree>;

struct Comparer {
  double tol, thr;
  Comparison c;
  // KL of a voxel from its two stored values (the absent map's as +0): exact, memoized
  detail::PairMemo<double> kl{detail::kl_logodds(0.0, 0.0)};
  static void kl_of(float lr, float lm, double& out) { out = detail::kl_logodds(lr, lm); }

  int cls(const W& n) const {
    if (!n.present()) return kUnknown;
    return n.node->getLogOdds() > thr ? kOccupied : kFree;
  }

  void walk(const W& r, const W& m, double weight) {
    const bool r_done = !r.present() || r.leaf, m_done = !m.present() || m.leaf;
    if (r_done && m_done) {
      c.confusion[cls(r)][cls(m)] += weight;
      if (r.present()) {
        const float stored_r = r.node->getLogOdds();
        const float stored_m = m.present() ? m.node->getLogOdds() : 0.0f;
        c.kl_sum += weight * kl.get(stored_r, stored_m, kl_of);
        const double lr = stored_r, lm = stored_m;
        if (m.present()) {
          c.both_known += weight;
          c.abs_diff_sum += weight * std::fabs(lm - lr);
          if (std::fabs(lm) > std::fabs(lr) + tol) c.overconfident += weight;
        }
      }
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      const W cr = r.child(i), cm = m.child(i);
      if (cr.present() || cm.present()) walk(cr, cm, weight / 8.0);
    }
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
  if (!t.pruneNode(n)) n->setLogOdds(n->getMaxChildLogOdds());
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
  Comparer cmp{tol, occ_threshold, {}};
  const W r = W::root(ref.tree()), m = W::root(map.tree());
  // weight 8^16: the root stands for all finest voxels
  if (r.present() || m.present()) cmp.walk(r, m, std::pow(8.0, 16));
  return cmp.c;
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
