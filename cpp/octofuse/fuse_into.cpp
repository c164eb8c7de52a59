// octofuse: in-place fusion by a walk of the message tree down the destination tree.
#include "octofuse/fuse_into.hpp"

#include "octofuse/loss_tree.hpp"
#include "octofuse/walk.hpp"

namespace octofuse {

namespace {

using OcNode = octomap::OcTreeNode;
using MsgNode = detail::WalkNode<octomap::OcTree>;
using ScalarWalk = detail::WalkNode<ScalarTree>;
using detail::LossCursor;

struct IntoWalker {
  Rule rule;
  UnknownPolicy unknown;
  double lmin, lmax;
  octomap::OcTree& dst;
  detail::LossAdder loss;
  FuseIntoStats st;

  float clamp(double l) const {
    return static_cast<float>(l < lmin ? lmin : (l > lmax ? lmax : l));
  }

  void finish_occ(OcNode* n) {
    if (dst.nodeHasChildren(n) && !dst.pruneNode(n)) n->setLogOdds(n->getMaxChildLogOdds());
  }

  void apply(OcNode* d, double la, double lb, const LossCursor& lc) {
    const Fused f = fuse_logodds(rule, la, lb, 0.0);
    d->setLogOdds(clamp(f.l));
    loss.add(lc, static_cast<float>(f.info_loss));
    ++st.fused;
  }

  // A dst subtree the message does not know, under UnknownPolicy::Prior.
  void prior_only(OcNode* d, const LossCursor& lc) {
    if (!dst.nodeHasChildren(d)) {
      apply(d, d->getLogOdds(), 0.0, lc);
      return;
    }
    for (unsigned i = 0; i < 8; ++i)
      if (dst.nodeChildExists(d, i)) prior_only(dst.getNodeChild(d, i), loss.child(lc, i));
    finish_occ(d);
    loss.finish(lc);
  }

  // A message subtree dst does not know, written into the new dst node d.
  void msg_only(const MsgNode& m, OcNode* d, const LossCursor& lc) {
    if (m.leaf) {
      if (unknown == UnknownPolicy::Copy) {
        d->setLogOdds(m.node->getLogOdds());
        ++st.copied;
      } else {
        apply(d, 0.0, m.node->getLogOdds(), lc);
      }
      return;
    }
    const bool track = unknown == UnknownPolicy::Prior;
    for (unsigned i = 0; i < 8; ++i) {
      const MsgNode c = m.child(i);
      if (c.present()) msg_only(c, dst.createNodeChild(d, i), track ? loss.child(lc, i) : LossCursor{});
    }
    finish_occ(d);
    if (track) loss.finish(lc);
  }

  void walk(OcNode* d, const MsgNode& m, const LossCursor& lc) {
    const bool d_leaf = !dst.nodeHasChildren(d);
    if (d_leaf && m.leaf) {
      apply(d, d->getLogOdds(), m.node->getLogOdds(), lc);
      return;
    }
    if (d_leaf) dst.expandNode(d);  // the message is finer here
    for (unsigned i = 0; i < 8; ++i) {
      const MsgNode mc = m.child(i);
      if (!dst.nodeChildExists(d, i)) {
        if (mc.present()) {
          msg_only(mc, dst.createNodeChild(d, i),
                   unknown == UnknownPolicy::Prior ? loss.child(lc, i) : LossCursor{});
        }
        continue;
      }
      OcNode* dc = dst.getNodeChild(d, i);
      if (mc.present()) {
        walk(dc, mc, loss.child(lc, i));
      } else if (unknown == UnknownPolicy::Prior) {
        prior_only(dc, loss.child(lc, i));
      }
    }
    finish_occ(d);
    loss.finish(lc);
  }
};

// Both maps fused with each other at once, in place: a bidirectional simultaneous exchange.
struct MutualWalker {
  IntoWalker& a;  // dst = map a
  IntoWalker& b;  // dst = map b

  void walk(OcNode* da, OcNode* db, const LossCursor& la, const LossCursor& lb) {
    octomap::OcTree &ta = a.dst, &tb = b.dst;
    const bool a_leaf = !ta.nodeHasChildren(da), b_leaf = !tb.nodeHasChildren(db);
    if (a_leaf && b_leaf) {
      const double va = da->getLogOdds(), vb = db->getLogOdds();
      a.apply(da, va, vb, la);
      b.apply(db, vb, va, lb);
      return;
    }
    if (a_leaf) ta.expandNode(da);
    if (b_leaf) tb.expandNode(db);
    const bool prior = a.unknown == UnknownPolicy::Prior;
    for (unsigned i = 0; i < 8; ++i) {
      const bool ea = ta.nodeChildExists(da, i), eb = tb.nodeChildExists(db, i);
      if (ea && eb) {
        walk(ta.getNodeChild(da, i), tb.getNodeChild(db, i), a.loss.child(la, i),
             b.loss.child(lb, i));
      } else if (ea) {  // only a knows this part: b receives it, a meets b's unknown
        OcNode* ca = ta.getNodeChild(da, i);
        b.msg_only(MsgNode{&ta, ca, !ta.nodeHasChildren(ca)}, tb.createNodeChild(db, i),
                   prior ? b.loss.child(lb, i) : LossCursor{});
        if (prior) a.prior_only(ca, a.loss.child(la, i));
      } else if (eb) {
        OcNode* cb = tb.getNodeChild(db, i);
        a.msg_only(MsgNode{&tb, cb, !tb.nodeHasChildren(cb)}, ta.createNodeChild(da, i),
                   prior ? a.loss.child(la, i) : LossCursor{});
        if (prior) b.prior_only(cb, b.loss.child(lb, i));
      }
    }
    a.finish_occ(da);
    b.finish_occ(db);
    a.loss.finish(la);
    b.loss.finish(lb);
  }
};

void add_tree(detail::LossAdder& adder, const ScalarWalk& b, const LossCursor& c) {
  if (b.leaf) {
    adder.add(c, b.node->getValue());
    return;
  }
  for (unsigned i = 0; i < 8; ++i) {
    const ScalarWalk bc = b.child(i);
    if (bc.present()) add_tree(adder, bc, adder.child(c, i));
  }
  adder.finish(c);
}

}  // namespace

FuseIntoStats fuse_into(OccupancyMap& dst, const OccupancyMap& msg, Rule rule,
                        UnknownPolicy unknown, ScalarTree* loss) {
  check_compatible(dst, msg);
  IntoWalker w{rule, unknown, dst.clamp_min_logodds(), dst.clamp_max_logodds(), dst.tree(),
               detail::LossAdder(loss), {}};
  const MsgNode m = MsgNode::root(msg.tree());
  OcNode* root = dst.tree().getRoot();
  const bool visit_dst_only = unknown == UnknownPolicy::Prior && root != nullptr;
  if (m.present() || visit_dst_only) {
    const LossCursor lc = w.loss.root();
    if (!m.present()) {
      w.prior_only(root, lc);
    } else if (root == nullptr) {
      w.msg_only(m, detail::TreeAccess<octomap::OcTree>::ensure_root(dst.tree()), lc);
    } else {
      w.walk(root, m, lc);
    }
    w.loss.done();
  }
  detail::TreeAccess<octomap::OcTree>::mark_changed(dst.tree());
  return w.st;
}

std::pair<FuseIntoStats, FuseIntoStats> fuse_mutual(OccupancyMap& a, OccupancyMap& b, Rule rule,
                                                    UnknownPolicy unknown, ScalarTree* loss_a,
                                                    ScalarTree* loss_b) {
  check_compatible(a, b);
  OcNode *ra = a.tree().getRoot(), *rb = b.tree().getRoot();
  if (ra == nullptr || rb == nullptr) {
    // one map is empty: the other one's content is all the exchange carries
    const std::unique_ptr<OccupancyMap> a0 = ra == nullptr ? nullptr : std::make_unique<OccupancyMap>(a);
    const FuseIntoStats sa = fuse_into(a, b, rule, unknown, loss_a);
    const FuseIntoStats sb = a0 ? fuse_into(b, *a0, rule, unknown, loss_b) : FuseIntoStats{};
    return {sa, sb};
  }
  IntoWalker wa{rule, unknown, a.clamp_min_logodds(), a.clamp_max_logodds(), a.tree(),
                detail::LossAdder(loss_a), {}};
  IntoWalker wb{rule, unknown, b.clamp_min_logodds(), b.clamp_max_logodds(), b.tree(),
                detail::LossAdder(loss_b), {}};
  MutualWalker m{wa, wb};
  const LossCursor la = wa.loss.root(), lb = wb.loss.root();
  m.walk(ra, rb, la, lb);
  wa.loss.done();
  wb.loss.done();
  detail::TreeAccess<octomap::OcTree>::mark_changed(a.tree());
  detail::TreeAccess<octomap::OcTree>::mark_changed(b.tree());
  return {wa.st, wb.st};
}

void accumulate_loss(ScalarTree& acc, const ScalarTree& b) {
  const ScalarWalk rb = ScalarWalk::root(b);
  if (!rb.present()) return;
  detail::LossAdder adder(&acc);
  add_tree(adder, rb, adder.root());
  adder.done();
}

}  // namespace octofuse
