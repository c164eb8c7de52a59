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

// Walks the reference and several maps at once: each map follows the walk it would have
// alone (down to where both it and the reference are leaves or unknown), so its sums are
// added in the same order; the reference is read once for all of them.
struct Comparer {
  double tol, thr;
  std::vector<Comparison> out;
  // the maps still being walked below the current node, per depth: (index, walk node)
  std::vector<std::vector<std::pair<std::size_t, W>>> active;
  // KL of a voxel from its two stored values (the absent map's as +0): exact, memoized
  detail::PairMemo<double> kl{detail::kl_logodds(0.0, 0.0)};
  static void kl_of(float lr, float lm, double& out) { out = detail::kl_logodds(lr, lm); }

  Comparer(double tol_, double thr_, std::size_t n)
      : tol(tol_), thr(thr_), out(n), active(18) {
    for (auto& level : active) level.reserve(n);
  }

  int cls(const W& n) const {
    if (!n.present()) return kUnknown;
    return n.node->getLogOdds() > thr ? kOccupied : kFree;
  }

  void count(Comparison& c, const W& r, const W& m, double weight) {
    c.confusion[cls(r)][cls(m)] += weight;
    if (!r.present()) return;
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

  // `active[depth]` holds the maps to walk at reference node `r`.
  void walk(const W& r, unsigned depth, double weight) {
    auto& here = active[depth];
    const bool r_done = !r.present() || r.leaf;
    std::size_t left = 0;  // maps that go on below, moved to the front
    for (const auto& [i, m] : here) {
      if (r_done && (!m.present() || m.leaf)) {
        count(out[i], r, m, weight);
      } else {
        here[left++] = {i, m};
      }
    }
    here.resize(left);
    if (left == 0) return;
    auto& below = active[depth + 1];
    for (unsigned c = 0; c < 8; ++c) {
      const W cr = r.child(c);
      below.clear();
      for (const auto& [i, m] : here) {
        const W cm = m.child(c);
        if (cr.present() || cm.present()) below.push_back({i, cm});
      }
      if (!below.empty()) walk(cr, depth + 1, weight / 8.0);
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

std::vector<Comparison> compare_maps(const OccupancyMap& ref,
                                     const std::vector<const OccupancyMap*>& maps, double tol,
                                     double occ_threshold) {
  Comparer cmp(tol, occ_threshold, maps.size());
  const W r = W::root(ref.tree());
  for (std::size_t i = 0; i < maps.size(); ++i) {
    const W m = W::root(maps[i]->tree());
    if (r.present() || m.present()) cmp.active[0].push_back({i, m});
  }
  // weight 8^16: the root stands for all finest voxels
  if (!cmp.active[0].empty()) cmp.walk(r, 0, std::pow(8.0, 16));
  return std::move(cmp.out);
}

Comparison compare_maps(const OccupancyMap& ref, const OccupancyMap& map, double tol,
                        double occ_threshold) {
  return compare_maps(ref, {&map}, tol, occ_threshold)[0];
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
