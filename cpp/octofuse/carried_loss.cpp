// octofuse: settling the losses a map carries into its loss map's tree.
#include "octofuse/carried_loss.hpp"

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

}  // namespace

void move_carried_loss(OccupancyTree& tree, ScalarTree& side) {
  OccupancyNode* root = tree.getRoot();
  if (root == nullptr) return;
  detail::LossAdder loss(&side);
  settle(tree, root, loss, loss.root());
  loss.done();
}

}  // namespace octofuse
