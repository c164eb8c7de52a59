// octofuse: applying a fast-mode scan's items to a tree, on one or more threads.
#include "fast_applier.hpp"

#include "octofuse/detail/child_runs.hpp"
#include "octofuse/detail/key_codes.hpp"
#include "octofuse/detail/parallel_for.hpp"
#include "octofuse/detail/tree_access.hpp"

#include "prune_or_max.hpp"

#include <algorithm>
#include <atomic>
#include <deque>
#include <iterator>
#include <limits>

namespace octofuse::detail {

namespace {

// Applies items (ascending codes, one per voxel or cell) below a node in one depth-first
// pass, as BatchApplier (insert.cpp) applies exact items: a voxel already at the clamping
// threshold in an update's direction is skipped without touching the tree, pruned leaves are
// expanded and missing children created as updateNodeRecurs() does, and every node on the
// path of an applied update ends pruned if collapsible or else holding the maximum of its
// children. A cell item gives every voxel under its node one miss: leaves (and missing
// children: unknown space) get it as they are, without being split, and occupied leaves are
// left as they are (the cell is then a conflict). Nodes are made and deleted through the
// methods of `methods`: the tree itself, or a worker's scratch tree that counts them.
class CellApplier {
 public:
  CellApplier(const OccupancyTree& tree, OccupancyTree& methods, unsigned level)
      : t_(methods),
        hit_(tree.getProbHitLog()),
        miss_(tree.getProbMissLog()),
        cmin_(tree.getClampingThresMinLog()),
        cmax_(tree.getClampingThresMaxLog()),
        depth_(tree.getTreeDepth()),
        cell_depth_(tree.getTreeDepth() - level),
        shift_(3 * level) {}

  /// Applies the items b..e to `node` at `depth` (`just_created`: made for this update);
  /// returns whether anything changed.
  bool visit(OccupancyNode* node, bool just_created, unsigned depth, const std::uint64_t* b,
             const std::uint64_t* e) {
    std::vector<std::uint64_t> kept;
    if (!narrow(node, just_created, b, e, kept)) return false;
    if (depth == depth_) {  // one voxel
      add(node, (*b & kHit) ? hit_ : miss_);
      return true;
    }
    if (depth == cell_depth_ && (*b & kCell)) {
      if (!just_created && node->getLogOdds() > 0) {  // an inner node: its children's maximum
        conflicts_.push_back((*b & kCodeOnly) >> shift_);
        return false;
      }
      return clear(node, just_created);
    }
    bool any = false;
    for_children(node, just_created, depth, b, e,
                 [&](OccupancyNode* child, bool created, const std::uint64_t* cb,
                     const std::uint64_t* ce) { any |= visit(child, created, depth + 1, cb, ce); });
    if (any) prune_or_max(t_, node);
    return any;
  }

  /// For the items b..e of `node`: if it is an existing leaf, only those that change it
  /// (copied to `kept` unless all do). False if none is left.
  bool narrow(const OccupancyNode* node, bool just_created, const std::uint64_t*& b,
              const std::uint64_t*& e, std::vector<std::uint64_t>& kept) {
    if (just_created || t_.nodeHasChildren(node)) return true;
    const float v = node->getLogOdds();
    const std::uint64_t* p = b;
    while (p != e && changes(v, *p)) ++p;
    if (p == e) return true;
    kept.assign(b, p);
    for (++p; p != e; ++p)
      if (changes(v, *p)) kept.push_back(*p);
    if (kept.empty()) return false;
    b = kept.data();
    e = b + kept.size();
    return true;
  }

  /// Calls f(child, created, b', e') for each run of the items b..e (of an inner node at
  /// `depth` above the voxels) under one child, the child made as updateNodeRecurs() does.
  template <class F>
  void for_children(OccupancyNode* node, bool just_created, unsigned depth, const std::uint64_t* b,
                    const std::uint64_t* e, F&& f) {
    const unsigned shift = 3 * (depth_ - 1 - depth);
    while (b != e) {
      unsigned pos;
      const std::uint64_t* g = child_run_end(b, e, shift, kCodeOnly, pos);
      bool created;
      OccupancyNode* child = child_to_update(t_, node, just_created, pos, created);
      f(child, created, b, g);
      b = g;
    }
  }

  unsigned cell_depth() const { return cell_depth_; }
  std::vector<std::uint64_t>& conflicts() { return conflicts_; }

 private:
  // Whether an item changes a leaf of value v; a cell over an occupied leaf is a conflict.
  bool changes(float v, std::uint64_t item) {
    if (item & kHit) return v < cmax_;
    if ((item & kCell) && v > 0) {
      conflicts_.push_back((item & kCodeOnly) >> shift_);
      return false;
    }
    return v > cmin_;
  }

  // OctoMap's updateNodeLogOdds() with the tree's clamping (not the scratch tree's).
  void add(OccupancyNode* node, float update) const {
    node->addValue(update);
    if (node->getLogOdds() < cmin_) {
      node->setLogOdds(cmin_);
    } else if (node->getLogOdds() > cmax_) {
      node->setLogOdds(cmax_);
    }
  }

  // One miss for every voxel under `node` (which holds no occupied voxel).
  bool clear(OccupancyNode* node, bool just_created) {
    if (just_created || !t_.nodeHasChildren(node)) {
      if (!just_created && node->getLogOdds() <= cmin_) return false;
      add(node, miss_);
      return true;
    }
    bool any = false;
    for (unsigned pos = 0; pos < 8; ++pos) {
      const bool exists = t_.nodeChildExists(node, pos);
      if (!exists) t_.createNodeChild(node, pos);
      any |= clear(t_.getNodeChild(node, pos), !exists);
    }
    if (any) prune_or_max(t_, node);
    return any;
  }

  OccupancyTree& t_;
  const float hit_, miss_, cmin_, cmax_;
  const unsigned depth_, cell_depth_, shift_;
  std::vector<std::uint64_t> conflicts_;
};

// Items per thread below which a scan is applied on one thread.
constexpr std::size_t kItemsPerThread = 16384;

// The items on `threads` threads: the top of the tree is split serially, depth first, into
// the subtrees of nodes holding at most 1/(8 threads) of the items (or down to the cells),
// those are walked in parallel, largest first, each worker with a scratch tree that counts
// its nodes; then the nodes split are finished serially, children before parents.
std::vector<std::uint64_t> apply_split(OccupancyTree& tree, unsigned level, OccupancyNode* root,
                                       bool root_created, const std::uint64_t* b,
                                       const std::uint64_t* e, unsigned threads) {
  constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
  struct Part {
    OccupancyNode* node;
    bool created;
    unsigned depth;
    const std::uint64_t *b, *e;
    std::size_t frame;  // the node split above it (kNone: none)
  };
  struct Frame {
    OccupancyNode* node;
    std::size_t parent;
    bool changed;
  };
  CellApplier top(tree, tree, level);
  const std::size_t most = static_cast<std::size_t>(e - b) / (8 * std::size_t{threads});
  std::deque<std::vector<std::uint64_t>> kept;  // items narrowed at split nodes (stable)
  std::vector<Part> open{{root, root_created, 0, b, e, kNone}}, parts;
  std::vector<Frame> frames;
  while (!open.empty()) {
    Part p = open.back();
    open.pop_back();
    if (static_cast<std::size_t>(p.e - p.b) <= most || p.depth >= top.cell_depth()) {
      parts.push_back(p);
      continue;
    }
    kept.emplace_back();
    if (!top.narrow(p.node, p.created, p.b, p.e, kept.back())) continue;
    frames.push_back({p.node, p.frame, false});
    const std::size_t f = frames.size() - 1;
    top.for_children(
        p.node, p.created, p.depth, p.b, p.e,
        [&](OccupancyNode* child, bool created, const std::uint64_t* cb, const std::uint64_t* ce) {
          open.push_back({child, created, p.depth + 1, cb, ce, f});
        });
  }
  std::sort(parts.begin(), parts.end(),
            [](const Part& x, const Part& y) { return x.e - x.b > y.e - y.b; });

  std::vector<char> changed(parts.size(), 0);
  std::vector<std::vector<std::uint64_t>> conflicts(threads);
  std::vector<std::size_t> sizes(threads, 0);
  std::atomic<std::size_t> next{0};
  run_on_workers(threads, [&](std::size_t worker) {
    OccupancyTree scratch(tree.getResolution());
    if (tree.arena() != nullptr) scratch.start_arena();  // so that it prunes the tree's way
    struct Settle {  // the scratch tree's count goes to the tree, also on an exception
      std::size_t& n;
      OccupancyTree& t;
      ~Settle() {
        n = TreeAccess<OccupancyTree>::size_of(t);
        TreeAccess<OccupancyTree>::size_of(t) = 0;  // its nodes are not its own
      }
    } settle{sizes[worker], scratch};
    CellApplier walk(tree, scratch, level);
    for (std::size_t k = next++; k < parts.size(); k = next++) {
      const Part& p = parts[k];
      changed[k] = walk.visit(p.node, p.created, p.depth, p.b, p.e);
    }
    conflicts[worker].swap(walk.conflicts());
  });
  for (std::size_t s : sizes) TreeAccess<OccupancyTree>::size_of(tree) += s;  // modulo 2^64

  for (std::size_t k = 0; k < parts.size(); ++k)
    if (changed[k] && parts[k].frame != kNone) frames[parts[k].frame].changed = true;
  for (auto f = frames.rbegin(); f != frames.rend(); ++f) {
    if (!f->changed) continue;
    prune_or_max(tree, f->node);
    if (f->parent != kNone) frames[f->parent].changed = true;
  }
  std::vector<std::uint64_t> all = std::move(top.conflicts());
  for (const auto& c : conflicts) all.insert(all.end(), c.begin(), c.end());
  return all;
}

}  // namespace

std::vector<std::uint64_t> apply_fast_items(OccupancyTree& tree, unsigned level,
                                            const std::uint64_t* b, const std::uint64_t* e,
                                            unsigned threads) {
  if (b == e) return {};
  OccupancyNode* root = tree.getRoot();
  const bool created = root == nullptr;
  if (created) root = TreeAccess<OccupancyTree>::ensure_root(tree);
  std::vector<std::uint64_t> conflicts;
  if (threads > 1 && static_cast<std::size_t>(e - b) >= 2 * kItemsPerThread) {
    conflicts = apply_split(tree, level, root, created, b, e, threads);
  } else {
    CellApplier walk(tree, tree, level);
    walk.visit(root, created, 0, b, e);
    conflicts.swap(walk.conflicts());
  }
  sort_unique(conflicts);
  return conflicts;
}

}  // namespace octofuse::detail
