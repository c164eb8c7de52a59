// octofuse: log-odds arithmetic on whole maps (see arith.hpp).
#include "octofuse/arith.hpp"

#include "lazy_tree.hpp"
#include "map_access.hpp"

#include <algorithm>
#include <array>
#include <stdexcept>

namespace octofuse {

namespace {

using OcNode = OccupancyNode;

/// copy + clamp_values in one walk of the source tree, twice: first without allocating, to
/// find the levels OctoMap's prune() reaches (from the finest up, until a level prunes
/// nothing), then building the copy bottom-up with those levels' collapses built in.
class ClampedCopier {
 public:
  ClampedCopier(const OccupancyTree& src, OccupancyTree& dst)
      : src_(src),
        dst_(dst),
        lo_(dst.getClampingThresMinLog()),
        hi_(dst.getClampingThresMaxLog()) {}

  void run() {
    const OcNode* root = src_.getRoot();
    if (root == nullptr) return;
    detail::Lazy<OccupancyTree> top{nullptr, 0, nullptr};
    if (!src_.nodeHasChildren(root)) {
      top.get(dst_)->setLogOdds(clamp(root->getLogOdds()));
      return;
    }
    float v;
    visit<false>(root, 0, top, v);
    for (unsigned d = src_.getTreeDepth() - 1; d > 0; --d) {
      if (collapsible_[d] == 0) {
        lowest_pruned_ = d + 1;
        break;
      }
    }
    visit<true>(root, 0, top, v);
  }

 private:
  float clamp(float v) const { return std::min(std::max(v, lo_), hi_); }

  // The inner node s at `depth`: true if its subtree collapses to one leaf of value v. The
  // first walk counts, per depth, the nodes that collapse once every finer level has; the
  // second builds, collapsing only at the levels prune() reaches (never the root).
  template <bool kBuild>
  bool visit(const OcNode* s, unsigned depth, detail::Lazy<OccupancyTree>& self, float& v) {
    detail::Kids k;
    for (unsigned i = 0; i < 8; ++i) {
      if (!src_.nodeChildExists(s, i)) continue;
      const OcNode* c = src_.getNodeChild(s, i);
      if (!src_.nodeHasChildren(c)) {
        k.mark(i);
        k.value[i] = clamp(c->getLogOdds());
        continue;
      }
      detail::Lazy<OccupancyTree> child{&self, i, nullptr};
      k.mark(i, !visit<kBuild>(c, depth + 1, child, k.value[i]));
    }
    if constexpr (!kBuild) {
      const bool collapses = depth > 0 && k.collapsible();
      collapsible_[depth] += collapses;
      if (collapses) v = k.value[0];  // an inner node's value is not needed
      return collapses;
    } else {
      const bool leaf = k.finish(
          dst_, self, [](OcNode* n, float x) { n->setLogOdds(x); },
          depth > 0 && depth >= lowest_pruned_);
      v = k.value[0];
      return leaf;
    }
  }

  const OccupancyTree& src_;
  OccupancyTree& dst_;
  const float lo_, hi_;
  std::array<std::size_t, 17> collapsible_{};  // per depth, in the first walk
  unsigned lowest_pruned_ = 1;                 // the coarsest depth prune() collapses nodes at
};

}  // namespace

void open_clamping(OccupancyMap& map) {
  // OctoMap stores logodds(p) as float: p = 0 and p = 1 give -inf and +inf. No node changes.
  OccupancyTree& t = detail::CarryingAccess::tree(map);
  t.setClampingThresMin(0.0);
  t.setClampingThresMax(1.0);
}

void negate_values(OccupancyMap& map) {
  // values only: nothing merges, so the losses the leaves carry stay with them
  OccupancyTree& t = detail::CarryingAccess::tree(map);
  for (auto it = t.begin_tree(), end = t.end_tree(); it != end; ++it) {
    it->setLogOdds(-it->getLogOdds());
  }
  t.updateInnerOccupancy();
}

void clamp_values(OccupancyMap& map) {
  OccupancyTree& t = map.settled_tree();  // prune() merges nodes without moving losses aside
  const float lo = t.getClampingThresMinLog();
  const float hi = t.getClampingThresMaxLog();
  for (auto it = t.begin_leafs(), end = t.end_leafs(); it != end; ++it) {
    const float v = it->getLogOdds();
    it->setLogOdds(std::min(std::max(v, lo), hi));
  }
  t.updateInnerOccupancy();
  t.prune();
}

std::unique_ptr<OccupancyMap> clamped_copy(const OccupancyMap& map) {
  auto out = std::make_unique<OccupancyMap>(map.params());
  ClampedCopier(map.tree(), out->settled_tree()).run();
  return out;
}

std::size_t assign_values(OccupancyMap& map, OccupancyMap& channel, const OccupancyMap& msg) {
  check_compatible(map, msg);
  check_compatible(channel, msg);
  if (&map == &channel || &map == &msg || &channel == &msg) {
    throw std::invalid_argument("assign_values needs three different maps");
  }
  OccupancyTree& tm = map.settled_tree();
  OccupancyTree& tc = channel.settled_tree();
  const auto& src = msg.tree();
  const unsigned depth = src.getTreeDepth();
  std::size_t n = 0;
  auto one = [&](const octomap::OcTreeKey& k, float v) {
    const OccupancyNode* c = tc.search(k);
    const float old = c != nullptr ? c->getLogOdds() : 0.0f;
    tm.updateNode(k, v - old, true);
    tc.setNodeValue(k, v, true);
    ++n;
  };
  for (auto it = src.begin_leafs(), end = src.end_leafs(); it != end; ++it) {
    const float v = it->getLogOdds();
    const unsigned d = it.getDepth();
    if (d == depth) {
      one(it.getKey(), v);
      continue;
    }
    const octomap::OcTreeKey base = it.getIndexKey();
    const unsigned side = 1u << (depth - d);
    octomap::OcTreeKey k;
    for (unsigned x = 0; x < side; ++x) {
      for (unsigned y = 0; y < side; ++y) {
        for (unsigned z = 0; z < side; ++z) {
          k[0] = static_cast<octomap::key_type>(base[0] + x);
          k[1] = static_cast<octomap::key_type>(base[1] + y);
          k[2] = static_cast<octomap::key_type>(base[2] + z);
          one(k, v);
        }
      }
    }
  }
  tm.updateInnerOccupancy();
  tm.prune();
  tc.updateInnerOccupancy();
  tc.prune();
  return n;
}

}  // namespace octofuse
