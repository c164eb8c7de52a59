// octofuse: in-place fusion by a walk of the message tree down the destination tree.
#include "octofuse/fuse_into.hpp"

#include "octofuse/detail/parallel_for.hpp"

#include "carried_loss_walk.hpp"
#include "loss_tree.hpp"
#include "map_access.hpp"
#include "prune_or_max.hpp"
#include "walk.hpp"

#include <atomic>
#include <deque>
#include <memory>
#include <mutex>
#include <type_traits>
#include <vector>

namespace octofuse {

namespace {

using OcNode = OccupancyNode;
using MsgNode = detail::WalkNode<OccupancyTree>;
using ScalarWalk = detail::WalkNode<ScalarTree>;
using detail::LossCursor;

/// Whether child `c` of message node `m` is one of the message's own leaves (not a part of a
/// coarse leaf the walk expands): each is reached once, from its parent.
bool own_leaf(const MsgNode& m, const MsgNode& c) { return !m.leaf && c.present() && c.leaf; }

/// Fuses a message into dst in place; the per-voxel policy is fixed at compile time. `dst` is
/// the tree whose node operations are called: the destination itself, or in a parallel walk a
/// worker's scratch tree (which then counts the nodes the worker created and deleted).
/// `carry`: the destination carries the loss map `loss` adds into (carried_loss.hpp).
template <class Fusion>
struct IntoWalker {
  static constexpr bool kPrior = Fusion::kUnknown == UnknownPolicy::Prior;
  Fusion& fusion;
  OccupancyTree& dst;
  detail::LossAdder loss;
  FuseIntoStats st;
  bool carry = false;

  // The inner node n (the loss cursor lc at it) once its children are done.
  void finish_occ(OcNode* n, const LossCursor& lc) {
    if (carry) {
      detail::prune_or_max(dst, n, detail::MoveLossesAside{loss, lc});
    } else {
      detail::prune_or_max(dst, n);
    }
  }

  void count_msg_leaf(const MsgNode& m, const MsgNode& c) { st.msg_leaves += own_leaf(m, c); }

  // The leaf d at `depth` gets v.
  void set(OcNode* d, const VoxelValue& v, const LossCursor& lc, unsigned depth) {
    d->setLogOdds(v.value);
    if (v.fused) {
      if (carry) {
        detail::add_carried_loss(d, v.loss, loss, lc);
      } else {
        loss.add(lc, v.loss);
      }
    }
    st.add(v, depth);
  }

  // A dst subtree the message does not know, under UnknownPolicy::Prior.
  void prior_only(OcNode* d, const LossCursor& lc, unsigned depth) {
    if (!dst.nodeHasChildren(d)) {
      set(d, fusion.only_a(d->getLogOdds()), lc, depth);
      return;
    }
    for (unsigned i = 0; i < 8; ++i)
      if (dst.nodeChildExists(d, i))
        prior_only(dst.getNodeChild(d, i), loss.child(lc, i), depth + 1);
    finish_occ(d, lc);
    loss.finish(lc);
  }

  // A message subtree dst does not know, written into the new dst node d.
  void msg_only(const MsgNode& m, OcNode* d, const LossCursor& lc, unsigned depth) {
    if (m.leaf) {
      set(d, fusion.only_b(m.node->getLogOdds()), lc, depth);
      return;
    }
    for (unsigned i = 0; i < 8; ++i) {
      const MsgNode c = m.child(i);
      if (!c.present()) continue;
      count_msg_leaf(m, c);
      msg_only(c, dst.createNodeChild(d, i), kPrior ? loss.child(lc, i) : LossCursor{}, depth + 1);
    }
    finish_occ(d, lc);
    if (kPrior) loss.finish(lc);
  }

  void walk(OcNode* d, const MsgNode& m, const LossCursor& lc, unsigned depth) {
    const bool d_leaf = !dst.nodeHasChildren(d);
    if (d_leaf && m.leaf) {
      set(d, fusion.both(d->getLogOdds(), m.node->getLogOdds()), lc, depth);
      return;
    }
    if (d_leaf) dst.expandNode(d);  // the message is finer here
    for (unsigned i = 0; i < 8; ++i) {
      const MsgNode mc = m.child(i);
      count_msg_leaf(m, mc);
      if (!dst.nodeChildExists(d, i)) {
        if (mc.present()) {
          msg_only(mc, dst.createNodeChild(d, i), kPrior ? loss.child(lc, i) : LossCursor{},
                   depth + 1);
        }
        continue;
      }
      OcNode* dc = dst.getNodeChild(d, i);
      if (mc.present()) {
        walk(dc, mc, loss.child(lc, i), depth + 1);
      } else if constexpr (kPrior) {
        prior_only(dc, loss.child(lc, i), depth + 1);
      }
    }
    finish_occ(d, lc);
    loss.finish(lc);
  }

  void run(const OccupancyTree& msg) {
    const MsgNode m = MsgNode::root(msg);
    if (m.leaf) st.msg_leaves = 1;
    OcNode* root = dst.getRoot();
    if (!m.present() && !(kPrior && root != nullptr)) return;
    const LossCursor lc = loss.root();
    if (!m.present()) {
      if constexpr (kPrior) prior_only(root, lc, 0);  // dst meets an empty message
    } else if (root == nullptr) {
      msg_only(m, detail::TreeAccess<OccupancyTree>::ensure_root(dst), lc, 0);
    } else {
      walk(root, m, lc, 0);
    }
    loss.done();
  }
};

/// fuse_into on several threads: the top of both trees is walked serially, breadth first,
/// until it has split into enough independent subtree pairs (disjoint regions of space); those
/// are fused in parallel, each by its own walker with its own VoxelFusion and scratch trees;
/// then the top nodes are finished serially, children before parents. Every voxel gets what
/// the serial walk gives it and every node ends as the serial walk leaves it.
template <class Fusion>
struct ParallelInto {
  static constexpr bool kPrior = Fusion::kUnknown == UnknownPolicy::Prior;
  enum class Kind { Walk, MsgOnly, PriorOnly };
  struct Part {
    Kind kind;
    OcNode* d;
    MsgNode m;
    const LossCursor* lc;
    unsigned depth;
  };

  OccupancyTree& dst;
  ScalarTree* loss_tree;
  float clamp_min, clamp_max;
  unsigned threads;
  bool carry;  // dst carries loss_tree

  std::deque<LossCursor> cursors;  // stable addresses: cursors point to their parents
  std::vector<Part> frames;        // top nodes split serially, to finish afterwards

  const LossCursor* keep(LossCursor c) {
    c.shared = true;
    cursors.push_back(c);
    return &cursors.back();
  }

  FuseIntoStats run(const OccupancyTree& msg) {
    detail::LossAdder top(loss_tree);
    std::vector<Part> level{{Kind::Walk, dst.getRoot(), MsgNode::root(msg), keep(top.root()), 0}};
    FuseIntoStats st;  // the message's leaves in the top; the parts' counts are added below
    if (level[0].m.leaf) st.msg_leaves = 1;
    const std::size_t target = 16 * std::size_t{threads};
    for (unsigned depth = 0; depth < 14 && level.size() < target; ++depth) {
      std::vector<Part> next;
      bool split = false;
      for (const Part& t : level) {
        const bool d_leaf = !dst.nodeHasChildren(t.d);
        if (t.kind != Kind::Walk || (d_leaf && t.m.leaf)) {
          next.push_back(t);
          continue;
        }
        split = true;
        frames.push_back(t);
        if (d_leaf) dst.expandNode(t.d);
        for (unsigned i = 0; i < 8; ++i) {
          const MsgNode mc = t.m.child(i);
          st.msg_leaves += own_leaf(t.m, mc);
          if (!dst.nodeChildExists(t.d, i)) {
            if (mc.present())
              next.push_back({Kind::MsgOnly, dst.createNodeChild(t.d, i), mc,
                              keep(kPrior ? top.child(*t.lc, i) : LossCursor{}), t.depth + 1});
            continue;
          }
          OcNode* dc = dst.getNodeChild(t.d, i);
          if (mc.present()) {
            next.push_back({Kind::Walk, dc, mc, keep(top.child(*t.lc, i)), t.depth + 1});
          } else if constexpr (kPrior) {
            next.push_back({Kind::PriorOnly, dc, mc, keep(top.child(*t.lc, i)), t.depth + 1});
          }
        }
      }
      level.swap(next);
      if (!split) break;
    }

    // the subtrees, in parallel: each worker has its own scratch trees (OctoMap's tree objects
    // count nodes and own a ray buffer, so they are made once per worker) and VoxelFusion. The
    // workers are threads of their own and the caller waits: each allocates and frees nodes
    // through its own lists of the node pools
    std::mutex loss_lock;
    std::atomic<std::size_t> next{0};
    // counts per part, added in part order afterwards: the loss sum does not depend on which
    // worker took which part
    std::vector<FuseIntoStats> stats(level.size());
    std::vector<std::size_t> sizes(threads, 0), loss_sizes(threads, 0);
    const double res = dst.getResolution();
    detail::run_on_workers(threads, [&](std::size_t worker) {
      OccupancyTree scratch(res);
      std::unique_ptr<ScalarTree> scratch_loss;
      if (loss_tree != nullptr) scratch_loss = std::make_unique<ScalarTree>(res);
      Fusion fusion(clamp_min, clamp_max);
      IntoWalker<Fusion> w{
          fusion, scratch, detail::LossAdder(loss_tree, scratch_loss.get(), &loss_lock), {}, carry};
      struct Settle {  // the scratch trees' counts go to the real trees, also on an exception
        std::size_t &n, &nl;
        OccupancyTree& t;
        ScalarTree* l;
        ~Settle() {
          n = detail::TreeAccess<OccupancyTree>::size_of(t);
          detail::TreeAccess<OccupancyTree>::size_of(t) = 0;  // its nodes are not its own
          if (l != nullptr) {
            nl = detail::TreeAccess<ScalarTree>::size_of(*l);
            detail::TreeAccess<ScalarTree>::size_of(*l) = 0;
          }
        }
      } settle{sizes[worker], loss_sizes[worker], scratch, scratch_loss.get()};
      for (std::size_t k = next++; k < level.size(); k = next++) {
        const Part& t = level[k];
        w.st = {};
        switch (t.kind) {
          case Kind::Walk:
            w.walk(t.d, t.m, *t.lc, t.depth);
            break;
          case Kind::MsgOnly:
            w.msg_only(t.m, t.d, *t.lc, t.depth);
            break;
          case Kind::PriorOnly:
            w.prior_only(t.d, *t.lc, t.depth);
            break;
        }
        stats[k] = w.st;
      }
    });

    for (const FuseIntoStats& part : stats) st += part;
    for (std::size_t k = 0; k < threads; ++k) {
      detail::TreeAccess<OccupancyTree>::size_of(dst) += sizes[k];  // modulo 2^64: deletions too
      if (loss_tree != nullptr)
        detail::TreeAccess<ScalarTree>::size_of(*loss_tree) += loss_sizes[k];
    }
    Fusion unused(clamp_min, clamp_max);
    IntoWalker<Fusion> fin{unused, dst, detail::LossAdder(loss_tree), {}, carry};
    for (auto it = frames.rbegin(); it != frames.rend(); ++it) {
      fin.finish_occ(it->d, *it->lc);
      fin.loss.finish(*it->lc);
    }
    fin.loss.done();
    return st;
  }
};

// Both maps fused with each other at once, in place: a bidirectional simultaneous exchange.
template <class Fusion>
struct MutualWalker {
  static constexpr bool kPrior = IntoWalker<Fusion>::kPrior;
  IntoWalker<Fusion>& a;  // dst = map a
  IntoWalker<Fusion>& b;  // dst = map b

  void walk(OcNode* da, OcNode* db, const LossCursor& la, const LossCursor& lb, unsigned depth) {
    OccupancyTree &ta = a.dst, &tb = b.dst;
    const bool a_leaf = !ta.nodeHasChildren(da), b_leaf = !tb.nodeHasChildren(db);
    // each map's own leaves, as messages to the other: the children of a node that was
    // inner on arrival (a node made by expandNode arrives as a leaf)
    const MsgNode ma{&ta, da, a_leaf}, mb{&tb, db, b_leaf};
    if (a_leaf && b_leaf) {
      const float va = da->getLogOdds(), vb = db->getLogOdds();
      const VoxelValue fa = a.fusion.both(va, vb);
      a.set(da, fa, la, depth);
      b.set(db, Fusion::kOrderFree ? fa : b.fusion.both(vb, va), lb, depth);  // one fusion
      return;
    }
    if (a_leaf) ta.expandNode(da);
    if (b_leaf) tb.expandNode(db);
    for (unsigned i = 0; i < 8; ++i) {
      const bool ea = ta.nodeChildExists(da, i), eb = tb.nodeChildExists(db, i);
      b.count_msg_leaf(ma, ma.child(i));  // a's leaves, sent to b
      a.count_msg_leaf(mb, mb.child(i));
      if (ea && eb) {
        walk(ta.getNodeChild(da, i), tb.getNodeChild(db, i), a.loss.child(la, i),
             b.loss.child(lb, i), depth + 1);
      } else if (ea) {  // only a knows this part: b receives it, a meets b's unknown
        OcNode* ca = ta.getNodeChild(da, i);
        b.msg_only(MsgNode{&ta, ca, !ta.nodeHasChildren(ca)}, tb.createNodeChild(db, i),
                   kPrior ? b.loss.child(lb, i) : LossCursor{}, depth + 1);
        if constexpr (kPrior) a.prior_only(ca, a.loss.child(la, i), depth + 1);
      } else if (eb) {
        OcNode* cb = tb.getNodeChild(db, i);
        a.msg_only(MsgNode{&tb, cb, !tb.nodeHasChildren(cb)}, ta.createNodeChild(da, i),
                   kPrior ? a.loss.child(la, i) : LossCursor{}, depth + 1);
        if constexpr (kPrior) b.prior_only(cb, b.loss.child(lb, i), depth + 1);
      }
    }
    a.finish_occ(da, la);
    b.finish_occ(db, lb);
    a.loss.finish(la);
    b.loss.finish(lb);
  }

  void run(OcNode* ra, OcNode* rb) {
    if (!a.dst.nodeHasChildren(ra)) b.st.msg_leaves = 1;  // a root leaf
    if (!b.dst.nodeHasChildren(rb)) a.st.msg_leaves = 1;
    const LossCursor la = a.loss.root(), lb = b.loss.root();
    walk(ra, rb, la, lb, 0);
    a.loss.done();
    b.loss.done();
  }
};

// Naive Bayes with the message's values negated as they are read (exact: negation is).
struct Difference {
  static constexpr Rule kRule = Rule::NaiveBayes;
  static constexpr UnknownPolicy kUnknown = UnknownPolicy::Copy;
  VoxelFusion<Rule::NaiveBayes, UnknownPolicy::Copy> nb;
  VoxelValue both(float a, float b) { return nb.both(a, -b); }
  VoxelValue only_a(float a) { return nb.only_a(a); }
  VoxelValue only_b(float b) { return nb.only_b(-b); }
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
                        UnknownPolicy unknown, ScalarTree* loss, unsigned threads) {
  check_compatible(dst, msg);
  const bool carry = detail::CarryingAccess::start_fusion(dst, loss);
  OccupancyTree& tree = detail::CarryingAccess::tree(dst);
  FuseIntoStats st;
  const bool parallel = threads > 1 && tree.getRoot() != nullptr && msg.tree().getRoot() != nullptr;
  with_voxel_fusion(
      rule, unknown, dst.clamp_min_logodds(), dst.clamp_max_logodds(), [&](auto& fusion) {
        using Fusion = std::decay_t<decltype(fusion)>;
        if (parallel) {
          st =
              ParallelInto<Fusion>{
                  tree, loss, dst.clamp_min_logodds(), dst.clamp_max_logodds(), threads, carry,
                  {},   {}}
                  .run(msg.tree());
          return;
        }
        IntoWalker<Fusion> w{fusion, tree, detail::LossAdder(loss), {}, carry};
        w.run(msg.tree());
        st = w.st;
      });
  detail::TreeAccess<OccupancyTree>::mark_changed(tree);
  return st;
}

std::pair<FuseIntoStats, FuseIntoStats> fuse_mutual(OccupancyMap& a, OccupancyMap& b, Rule rule,
                                                    UnknownPolicy unknown, ScalarTree* loss_a,
                                                    ScalarTree* loss_b) {
  check_compatible(a, b);
  OccupancyTree &ta = detail::CarryingAccess::tree(a), &tb = detail::CarryingAccess::tree(b);
  OcNode *ra = ta.getRoot(), *rb = tb.getRoot();
  if (ra == nullptr || rb == nullptr) {
    // one map is empty: the other one's content is all the exchange carries
    const std::unique_ptr<OccupancyMap> a0 =
        ra == nullptr ? nullptr : std::make_unique<OccupancyMap>(a);
    const FuseIntoStats sa = fuse_into(a, b, rule, unknown, loss_a);
    const FuseIntoStats sb = a0 ? fuse_into(b, *a0, rule, unknown, loss_b) : FuseIntoStats{};
    return {sa, sb};
  }
  std::pair<FuseIntoStats, FuseIntoStats> st;
  with_voxel_fusion(rule, unknown, a.clamp_min_logodds(), a.clamp_max_logodds(), [&](auto& fusion) {
    using Fusion = std::decay_t<decltype(fusion)>;
    IntoWalker<Fusion> wa{
        fusion, ta, detail::LossAdder(loss_a), {}, detail::CarryingAccess::start_fusion(a, loss_a)};
    IntoWalker<Fusion> wb{
        fusion, tb, detail::LossAdder(loss_b), {}, detail::CarryingAccess::start_fusion(b, loss_b)};
    MutualWalker<Fusion>{wa, wb}.run(ra, rb);
    st = {wa.st, wb.st};
  });
  detail::TreeAccess<OccupancyTree>::mark_changed(ta);
  detail::TreeAccess<OccupancyTree>::mark_changed(tb);
  return st;
}

void subtract_into(OccupancyMap& dst, const OccupancyMap& msg) {
  check_compatible(dst, msg);
  OccupancyTree& tree = dst.settled_tree();
  Difference fusion{{dst.clamp_min_logodds(), dst.clamp_max_logodds()}};
  IntoWalker<Difference>{fusion, tree, detail::LossAdder(nullptr), {}}.run(msg.tree());
  detail::TreeAccess<OccupancyTree>::mark_changed(tree);
}

void accumulate_loss(ScalarTree& acc, const ScalarTree& b) {
  const ScalarWalk rb = ScalarWalk::root(b);
  if (!rb.present()) return;
  detail::LossAdder adder(&acc);
  add_tree(adder, rb, adder.root());
  adder.done();
}

}  // namespace octofuse
