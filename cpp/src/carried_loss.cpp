// octofuse: the losses a map carries, settled into its loss map's tree or read as if they were.
#include "octofuse/carried_loss.hpp"

#include "loss_tree.hpp"
#include "prune_or_max.hpp"
#include "walk.hpp"

namespace octofuse {

namespace {

void settle(OccupancyTree& t, OccupancyNode* n, detail::LossAdder& loss,
            const detail::LossCursor& lc) {
  if (!t.nodeHasChildren(n)) {
    if (n->carries_loss()) {
      loss.add(lc, n->carried_loss());
      n->drop_carried_loss();
    }
    return;
  }
  for (unsigned i = 0; i < 8; ++i)
    if (t.nodeChildExists(n, i)) settle(t, t.getNodeChild(n, i), loss, loss.child(lc, i));
  loss.finish(lc);
}

// The losses under one node of the loss tree that settling would build, without building it:
// none, one value for every voxel (the node would be a leaf, or merge into one), or leaves
// already written out.
struct Part {
  enum Kind : std::uint8_t { Empty, Uniform, Written } kind;
  float value;
};

class LeavesOfSettled {
 public:
  LeavesOfSettled(const OccupancyTree& t, const ScalarTree& side, std::vector<float>& values,
                  std::vector<std::uint8_t>& depths)
      : t_(t), s_(side), values_(values), depths_(depths) {}

  void run() {
    const Part p = visit(MapWalk::root(t_), SideWalk::root(s_), 0);
    if (p.kind == Part::Uniform) put(values_.size(), p.value, 0);
  }

 private:
  using MapWalk = detail::WalkNode<OccupancyTree>;
  using SideWalk = detail::WalkNode<ScalarTree>;

  // The node of the map (none: none there, or a leaf above that carries nothing) and of the
  // side tree at one position of `depth`. A voxel's loss is its leaf's carried loss, else the
  // side tree's (never both).
  Part visit(MapWalk o, const SideWalk& s, unsigned depth) {
    if (s.present() && s.leaf) return {Part::Uniform, s.node->getValue()};
    if (o.present() && o.leaf) {
      if (o.node->carries_loss()) return {Part::Uniform, o.node->carried_loss()};
      o = MapWalk{};  // the side tree's below it, if any
    }
    if (!o.present() && !s.present()) return {Part::Empty, 0.0f};
    // the children, merged by the prune rule: 8 equal values, the first one's kept
    Part kids[8];
    detail::PruneRule rule(kMaxOfNoChildren<ScalarNode>);
    for (unsigned i = 0; i < 8; ++i) {
      const std::size_t before = values_.size();
      kids[i] = visit(o.child(i), s.child(i), depth + 1);
      const bool was_mergeable = rule.may_merge();
      if (kids[i].kind == Part::Empty) {
        rule.absent();
      } else {
        rule.child(kids[i].value, kids[i].kind == Part::Uniform);
      }
      const bool still = rule.may_merge();
      if (was_mergeable && !still) {  // the earlier children, equal so far, are leaves after all
        std::size_t at = kids[i].kind == Part::Written ? before : values_.size();
        for (unsigned k = 0; k < i; ++k) put(at++, kids[k].value, depth + 1);
      }
      if (!still && kids[i].kind == Part::Uniform) put(values_.size(), kids[i].value, depth + 1);
    }
    return rule.merges() ? kids[0] : Part{Part::Written, 0.0f};
  }

  void put(std::size_t at, float value, unsigned depth) {
    values_.insert(values_.begin() + static_cast<std::ptrdiff_t>(at), value);
    depths_.insert(depths_.begin() + static_cast<std::ptrdiff_t>(at),
                   static_cast<std::uint8_t>(depth));
  }

  const OccupancyTree& t_;
  const ScalarTree& s_;
  std::vector<float>& values_;
  std::vector<std::uint8_t>& depths_;
};

}  // namespace

void move_carried_loss(OccupancyTree& tree, ScalarTree& side) {
  OccupancyNode* root = tree.getRoot();
  if (root == nullptr) return;
  detail::LossAdder loss(&side);
  settle(tree, root, loss, loss.root());
  loss.done();
}

void settled_loss_leaves(const OccupancyTree& tree, const ScalarTree& side,
                         std::vector<float>& values, std::vector<std::uint8_t>& depths) {
  values.clear();
  depths.clear();
  LeavesOfSettled(tree, side, values, depths).run();
}

}  // namespace octofuse
