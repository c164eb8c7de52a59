// octofuse: simultaneous walk of two octrees producing the fused tree and its loss tree.
#include "octofuse/fuse.hpp"

#include "lazy_tree.hpp"
#include "walk.hpp"

#include <memory>
#include <type_traits>

namespace octofuse {

namespace {

using OcNode = OccupancyNode;
using W = detail::WalkNode<OccupancyTree>;
using detail::Kids;
using detail::Lazy;

void set_logodds(OcNode* n, float v) { n->setLogOdds(v); }
void set_scalar(ScalarNode* n, float v) { n->setValue(v); }

/// The simultaneous walk; the per-voxel policy (rule, unknown voxels) is fixed at compile time.
template <class Fusion>
struct Walker {
  const OccupancyTree& ta;
  const OccupancyTree& tb;
  Fusion& fusion;
  OccupancyTree& out;
  ScalarTree& loss;
  FusionCounts counts;

  /// Values of a voxel (or a block of voxels at `depth`) given the input nodes covering it
  /// (null = unknown; not both null).
  void leaf(const OcNode* a, const OcNode* b, unsigned depth, float& value, float& info_loss) {
    const VoxelValue v = a == nullptr   ? fusion.only_b(b->getLogOdds())
                         : b == nullptr ? fusion.only_a(a->getLogOdds())
                                        : fusion.both(a->getLogOdds(), b->getLogOdds());
    value = v.value;
    info_loss = v.loss;
    counts.add(v, depth);
  }

  /// Walks the node pair (a, b) at `depth`, not both leaves or unknown. Returns for each
  /// output tree whether the subtree collapsed to one leaf, whose value is then in vm / vl.
  void walk(const W& a, const W& b, unsigned depth, Lazy<OccupancyTree>& om, Lazy<ScalarTree>& ol,
            bool& leaf_m, float& vm, bool& leaf_l, float& vl) {
    Kids km, kl;
    for (unsigned i = 0; i < 8; ++i) {
      const W ca = a.child(i), cb = b.child(i);
      if (!ca.present() && !cb.present()) continue;
      if (ca.leaf_or_unknown() && cb.leaf_or_unknown()) {
        km.mark(i);
        kl.mark(i);
        leaf(ca.node, cb.node, depth + 1, km.value[i], kl.value[i]);
        continue;
      }
      Lazy<OccupancyTree> cm{&om, i, nullptr};
      Lazy<ScalarTree> cl{&ol, i, nullptr};
      bool lm, ll;
      walk(ca, cb, depth + 1, cm, cl, lm, km.value[i], ll, kl.value[i]);
      km.mark(i, !lm);
      kl.mark(i, !ll);
    }
    leaf_m = km.finish(out, om, set_logodds);
    vm = km.value[0];
    leaf_l = kl.finish(loss, ol, set_scalar);
    vl = kl.value[0];
  }

  void run() {
    const W ra = W::root(ta), rb = W::root(tb);
    Lazy<OccupancyTree> om{nullptr, 0, nullptr};
    Lazy<ScalarTree> ol{nullptr, 0, nullptr};
    float vm, vl;
    if (ra.leaf_or_unknown() && rb.leaf_or_unknown()) {
      leaf(ra.node, rb.node, 0, vm, vl);
      om.get(out)->setLogOdds(vm);
      ol.get(loss)->setValue(vl);
      return;
    }
    bool leaf_m, leaf_l;
    walk(ra, rb, 0, om, ol, leaf_m, vm, leaf_l, vl);
    if (leaf_m) om.get(out)->setLogOdds(vm);
    if (leaf_l) ol.get(loss)->setValue(vl);
  }
};

}  // namespace

FusionResult fuse_maps(const OccupancyMap& a, const OccupancyMap& b, Rule rule,
                       UnknownPolicy unknown, std::size_t arena_min_nodes) {
  check_compatible(a, b);
  FusionResult res;
  res.map = std::make_unique<OccupancyMap>(a.params());
  res.info_loss = std::make_unique<ScalarTree>(a.params().resolution);
  if (a.tree().getRoot() != nullptr || b.tree().getRoot() != nullptr) {
    // the new trees have at most the nodes of both inputs: large ones get arenas of their own
    if (a.num_nodes() + b.num_nodes() >= arena_min_nodes) {
      res.map->settled_tree().start_arena();
      res.info_loss->start_arena();
    }
    with_voxel_fusion(
        rule, unknown, a.clamp_min_logodds(), a.clamp_max_logodds(), [&](auto& fusion) {
          Walker<std::decay_t<decltype(fusion)>> w{
              a.tree(), b.tree(), fusion, res.map->settled_tree(), *res.info_loss, {}};
          w.run();
          res.counts = w.counts;
        });
  }
  return res;
}

}  // namespace octofuse
