// octofuse: simultaneous walk of two octrees producing the fused tree and its loss tree.
#include "octofuse/fuse.hpp"

#include "octofuse/tree_access.hpp"
#include "octofuse/walk.hpp"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>

namespace octofuse {

namespace {

using OcNode = octomap::OcTreeNode;
using ScalarNode = octomap::OcTreeDataNode<float>;

template <class Tree>
using Src = detail::WalkNode<Tree>;

/// A node of an output tree that is only allocated once it is known to stay (lazily).
/// The walk builds each subtree bottom-up: a subtree whose voxels turn out to be 8 equal
/// leaves is returned as one value and never allocated, instead of being allocated and then
/// pruned (OctoMap's pruneNode). A node is allocated (with all its missing ancestors) as soon
/// as one of its children is an inner node, because then it can no longer be pruned.
template <class Tree>
struct Lazy {
  using Node = typename detail::TreeAccess<Tree>::Node;
  Lazy* parent;
  unsigned index;
  Node* node;  // null until allocated

  Node* get(Tree& t) {
    if (node == nullptr) {
      node = parent == nullptr ? detail::TreeAccess<Tree>::ensure_root(t)
                               : t.createNodeChild(parent->get(t), index);
    }
    return node;
  }
};

/// Up to 8 children of an output node: values of leaves not allocated yet, or of finished
/// inner nodes (already allocated).
struct Kids {
  float value[8];
  std::uint8_t present = 0;  // bit i: child i exists
  std::uint8_t inner = 0;    // bit i: child i is an allocated inner node

  /// Ends a node: true if the 8 children collapse to one leaf (OctoMap's isNodeCollapsible),
  /// else allocates the node and its leaf children and sets its value to the max of its
  /// children (OctoMap's updateOccupancyChildren). Either way `value[0]` is then the node's
  /// value, which its parent takes as the value of this child.
  template <class Tree, class SetValue>
  bool finish(Tree& t, Lazy<Tree>& self, SetValue set) {
    if (present == 0xFF && inner == 0) {
      const float v = value[0];
      bool equal = true;
      for (unsigned i = 1; i < 8; ++i) equal &= value[i] == v;
      if (equal) return true;
    }
    auto* n = self.get(t);
    float mx = -std::numeric_limits<float>::infinity();
    for (unsigned i = 0; i < 8; ++i) {
      if (!(present & (1u << i))) continue;
      if (!(inner & (1u << i))) set(t.createNodeChild(n, i), value[i]);
      if (value[i] > mx) mx = value[i];
    }
    set(n, mx);
    value[0] = mx;
    return false;
  }
};

void set_logodds(OcNode* n, float v) { n->setLogOdds(v); }
void set_scalar(ScalarNode* n, float v) { n->setValue(v); }

/// The last results of the rule for a few thousand pairs of stored values (direct mapped).
/// The values of a map built from scans are sums of a few sensor-model increments, clamped,
/// so the same pairs come back again and again; a hit costs a few ns where the rule costs
/// 30-300 ns. The entries are exact results of the rule for their key (the pair of float
/// bit patterns), so a hit returns exactly what computing would.
struct Memo {
  static constexpr unsigned kBits = 12;
  struct Entry {
    std::uint64_t key;
    float value, loss;
  };
  std::unique_ptr<Entry[]> entries;

  static std::uint64_t key_of(float a, float b) {
    std::uint32_t ua, ub;
    std::memcpy(&ua, &a, sizeof ua);
    std::memcpy(&ub, &b, sizeof ub);
    return (std::uint64_t{ua} << 32) | ub;
  }
  Entry& slot(float a, float b) {
    return entries[(key_of(a, b) * 0x9E3779B97F4A7C15ull) >> (64 - kBits)];
  }
  /// Fills every entry with the (exact) result for the pair whose key is 0: (+0, +0).
  void init(float value, float loss) {
    entries.reset(new Entry[1u << kBits]);
    for (unsigned i = 0; i < (1u << kBits); ++i) entries[i] = {key_of(0.0f, 0.0f), value, loss};
  }
};

/// The simultaneous walk, with the rule and the unknown-voxel policy fixed at compile time.
template <Rule R, UnknownPolicy U>
struct Walker {
  const octomap::OcTree& ta;
  const octomap::OcTree& tb;
  double lmin, lmax;  // clamping in log-odds
  octomap::OcTree& out;
  ScalarTree& loss;
  std::size_t fused = 0, copied = 0;

  Memo memo;

  /// The clamped fused value and the loss of one pair of stored log-odds.
  void compute(float fa, float fb, float& value, float& info_loss) const {
    const Fused f = fuse_logodds<R>(fa, fb, 0.0);
    const double l = f.l < lmin ? lmin : (f.l > lmax ? lmax : f.l);
    value = static_cast<float>(l);
    info_loss = static_cast<float>(f.info_loss);
  }

  /// Values of a voxel (or a block of voxels) given the input nodes covering it (null =
  /// unknown; not both null).
  void leaf(const OcNode* a, const OcNode* b, float& value, float& info_loss) {
    float fa, fb;
    if (a != nullptr && b != nullptr) {
      fa = a->getLogOdds();
      fb = b->getLogOdds();
    } else if (U == UnknownPolicy::Copy) {
      value = (a != nullptr ? a : b)->getLogOdds();
      info_loss = 0.0f;
      ++copied;
      return;
    } else {
      fa = a != nullptr ? a->getLogOdds() : 0.0f;
      fb = b != nullptr ? b->getLogOdds() : 0.0f;
    }
    ++fused;
    if constexpr (R == Rule::NaiveBayes) {
      compute(fa, fb, value, info_loss);  // cheaper than a look-up
    } else {
      Memo::Entry& e = memo.slot(fa, fb);
      if (e.key != Memo::key_of(fa, fb)) {
        e.key = Memo::key_of(fa, fb);
        compute(fa, fb, e.value, e.loss);
      }
      value = e.value;
      info_loss = e.loss;
    }
  }

  /// Child i of an input node of tree t as seen by the walk: a leaf stands for all its
  /// children, unknown stays unknown (null).
  static const OcNode* child(const octomap::OcTree& t, const OcNode* n, bool leaf, unsigned i,
                             bool& child_leaf) {
    if (n == nullptr || leaf) {
      child_leaf = true;
      return n;
    }
    if (!t.nodeChildExists(n, i)) {
      child_leaf = true;
      return nullptr;
    }
    const OcNode* c = t.getNodeChild(n, i);
    child_leaf = !t.nodeHasChildren(c);
    return c;
  }

  /// Walks the node pair (a, b), not both leaves or unknown. Returns for each output tree
  /// whether the subtree collapsed to one leaf, whose value is then in vm / vl.
  void walk(const OcNode* a, bool a_leaf, const OcNode* b, bool b_leaf, Lazy<octomap::OcTree>& om,
            Lazy<ScalarTree>& ol, bool& leaf_m, float& vm, bool& leaf_l, float& vl) {
    Kids km, kl;
    for (unsigned i = 0; i < 8; ++i) {
      bool ca_leaf, cb_leaf;
      const OcNode* ca = child(ta, a, a_leaf, i, ca_leaf);
      const OcNode* cb = child(tb, b, b_leaf, i, cb_leaf);
      if (ca == nullptr && cb == nullptr) continue;
      km.present |= static_cast<std::uint8_t>(1u << i);
      kl.present |= static_cast<std::uint8_t>(1u << i);
      if (ca_leaf && cb_leaf) {
        leaf(ca, cb, km.value[i], kl.value[i]);
        continue;
      }
      Lazy<octomap::OcTree> cm{&om, i, nullptr};
      Lazy<ScalarTree> cl{&ol, i, nullptr};
      bool lm, ll;
      walk(ca, ca_leaf, cb, cb_leaf, cm, cl, lm, km.value[i], ll, kl.value[i]);
      if (!lm) km.inner |= static_cast<std::uint8_t>(1u << i);
      if (!ll) kl.inner |= static_cast<std::uint8_t>(1u << i);
    }
    leaf_m = km.finish(out, om, set_logodds);
    vm = km.value[0];
    leaf_l = kl.finish(loss, ol, set_scalar);
    vl = kl.value[0];
  }

  void run() {
    const OcNode* ra = ta.getRoot();
    const OcNode* rb = tb.getRoot();
    const bool a_leaf = ra == nullptr || !ta.nodeHasChildren(ra);
    const bool b_leaf = rb == nullptr || !tb.nodeHasChildren(rb);
    Lazy<octomap::OcTree> om{nullptr, 0, nullptr};
    Lazy<ScalarTree> ol{nullptr, 0, nullptr};
    float vm, vl;
    if (a_leaf && b_leaf) {
      leaf(ra, rb, vm, vl);
      om.get(out)->setLogOdds(vm);
      ol.get(loss)->setValue(vl);
      return;
    }
    bool leaf_m, leaf_l;
    walk(ra, a_leaf, rb, b_leaf, om, ol, leaf_m, vm, leaf_l, vl);
    if (leaf_m) om.get(out)->setLogOdds(vm);
    if (leaf_l) ol.get(loss)->setValue(vl);
  }
};

template <Rule R, UnknownPolicy U>
void run_walk(const octomap::OcTree& a, const octomap::OcTree& b, double lmin, double lmax,
              FusionResult& res) {
  Walker<R, U> w{a, b, lmin, lmax, res.map->tree(), *res.info_loss, 0, 0, Memo{}};
  if constexpr (R != Rule::NaiveBayes) {
    float v, l;
    w.compute(0.0f, 0.0f, v, l);
    w.memo.init(v, l);
  }
  w.run();
  res.voxels_fused = w.fused;
  res.voxels_copied = w.copied;
}

template <Rule R>
void run_walk(const octomap::OcTree& a, const octomap::OcTree& b, UnknownPolicy unknown,
              double lmin, double lmax, FusionResult& res) {
  if (unknown == UnknownPolicy::Copy) {
    run_walk<R, UnknownPolicy::Copy>(a, b, lmin, lmax, res);
  } else {
    run_walk<R, UnknownPolicy::Prior>(a, b, lmin, lmax, res);
  }
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
  if (a.tree().getRoot() != nullptr || b.tree().getRoot() != nullptr) {
    const octomap::OcTree &ta = a.tree(), &tb = b.tree();
    const double lmin = a.clamp_min_logodds(), lmax = a.clamp_max_logodds();
    switch (rule) {
      case Rule::NaiveBayes:
        run_walk<Rule::NaiveBayes>(ta, tb, unknown, lmin, lmax, res);
        break;
      case Rule::Bhattacharyya:
        run_walk<Rule::Bhattacharyya>(ta, tb, unknown, lmin, lmax, res);
        break;
      case Rule::MinEntropy:
        run_walk<Rule::MinEntropy>(ta, tb, unknown, lmin, lmax, res);
        break;
      case Rule::Chernoff:
        run_walk<Rule::Chernoff>(ta, tb, unknown, lmin, lmax, res);
        break;
      case Rule::EntropyWeightedChernoff:
        run_walk<Rule::EntropyWeightedChernoff>(ta, tb, unknown, lmin, lmax, res);
        break;
      case Rule::KldWeightedChernoff:
        run_walk<Rule::KldWeightedChernoff>(ta, tb, unknown, lmin, lmax, res);
        break;
      case Rule::MinInfoLoss:
        run_walk<Rule::MinInfoLoss>(ta, tb, unknown, lmin, lmax, res);
        break;
    }
  }
  return res;
}


}  // namespace octofuse
