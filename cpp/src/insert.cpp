// octofuse: batched scan insertion (ray keys once per scan, applied to several maps).
#include "octofuse/insert.hpp"

#include "octofuse/detail/child_runs.hpp"
#include "octofuse/detail/key_codes.hpp"
#include "octofuse/detail/parallel_for.hpp"
#include "octofuse/detail/ray_codes.hpp"
#include "octofuse/detail/tree_access.hpp"
#include "octofuse/insert_fast.hpp"
#include "octofuse/scan_check.hpp"

#include "carried_loss_walk.hpp"
#include "map_access.hpp"
#include "prune_or_max.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cstddef>
#include <map>
#include <stdexcept>
#include <string>
#include <thread>

namespace octofuse {

namespace {

using detail::CodeSet;
using detail::kCode;
using detail::kHit;
using detail::kNoCode;
using detail::morton;
using detail::sort_unique;
using detail::trace_ray_codes;
using detail::unmorton;

// The update of one scan as items in ascending code order (free and occupied merged;
// occupied wins over free), with computeUpdate()'s semantics. Every ray is checked first
// (std::invalid_argument prefixed by `where`).
std::vector<std::uint64_t> compute_items(const OccupancyTree& grid, const float* xyz, std::size_t n,
                                         const float origin[3], double max_range,
                                         const std::string& where) {
  const octomap::point3d o(origin[0], origin[1], origin[2]);
  const ScanCheck check(grid, o, max_range, where);
  for (std::size_t i = 0; i < n; ++i) {
    check.check(i, octomap::point3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]));
  }
  CodeSet free(n * 4);
  const auto add_free = [&free](std::uint64_t code) { free.insert(code); };
  std::vector<std::uint64_t> occ;
  occ.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const octomap::point3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    if (max_range < 0.0 || (p - o).norm() <= max_range) {
      std::uint64_t hit;
      trace_ray_codes(grid, o, p, add_free, &hit);
      if (hit != kNoCode) occ.push_back(hit);
    } else {
      const octomap::point3d end = o + (p - o).normalized() * static_cast<float>(max_range);
      trace_ray_codes(grid, o, end, add_free);
    }
  }
  sort_unique(occ);
  const std::vector<std::uint64_t> fr = free.sorted();
  std::vector<std::uint64_t> items;
  items.reserve(fr.size() + occ.size());
  auto it = occ.begin();
  for (std::uint64_t m : fr) {
    while (it != occ.end() && *it < m) items.push_back(*it++ | kHit);
    if (it != occ.end() && *it == m) continue;  // occupied wins over free
    items.push_back(m);
  }
  while (it != occ.end()) items.push_back(*it++ | kHit);
  return items;
}

// Applies items (ascending codes; a voxel's updates, one per scan, in scan order) to a tree
// in one depth-first pass. The result is the tree that OctoMap's updateNode(key, hit,
// lazy_eval = false) gives when called for every item of each scan in turn, scan after scan:
// within a scan each voxel receives one update, so its value does not depend on the order,
// and across scans a voxel's updates come in scan order; a voxel whose leaf is already at the
// clamping threshold in an update's direction skips that update without touching the tree
// (updateNode's early abort); pruned leaves are expanded and missing children created as
// updateNodeRecurs() does; and every node on the path of an applied update is pruned if
// collapsible, or else gets the maximum of its children, once its subtree is final - which
// is the state updateNode leaves it in after the last update below it (a node pruned by one
// scan and expanded by the next ends as if never pruned). Nodes are walked once per batch of
// keys instead of twice (search + update) per key from the root.
class BatchApplier {
 public:
  /// `carried`: the loss tree the map carries, if any (carried_loss.hpp).
  explicit BatchApplier(OccupancyTree& tree, ScalarTree* carried = nullptr)
      : t_(tree),
        loss_(carried),
        hit_(tree.getProbHitLog()),
        miss_(tree.getProbMissLog()),
        cmin_(tree.getClampingThresMinLog()),
        cmax_(tree.getClampingThresMaxLog()),
        depth_(tree.getTreeDepth()) {}

  void apply(const std::uint64_t* b, const std::uint64_t* e) {
    if (b == e) return;
    OccupancyNode* root = t_.getRoot();
    bool created = false;
    if (root == nullptr) {
      root = detail::TreeAccess<OccupancyTree>::ensure_root(t_);
      created = true;
    }
    visit(root, created, 0, b, e, loss_.root());
    loss_.done();
  }

 private:
  float update_of(std::uint64_t item) const { return (item & kHit) ? hit_ : miss_; }
  bool at_threshold(float value, float u) const {
    return (u >= 0 && value >= cmax_) || (u <= 0 && value <= cmin_);
  }

  // Whether a voxel has had an update that changes it, item by item in code order: the
  // voxel's (the item's code's) earlier items and this one, given which of them are no-ops.
  struct Moved {
    std::uint64_t code = kNoCode;
    bool moved = false;
    bool operator()(std::uint64_t item, bool no_op) {
      if ((item & kCode) != code) {
        code = item & kCode;
        moved = false;
      }
      moved = moved || !no_op;
      return moved;
    }
  };

  // Returns whether any item below `node` was applied.
  // `lc`: the carried loss tree's cursor at node (inactive if the map carries none).
  bool visit(OccupancyNode* node, bool just_created, unsigned depth, const std::uint64_t* b,
             const std::uint64_t* e, const detail::LossCursor& lc) {
    std::vector<std::uint64_t> kept;
    if (!just_created && !t_.nodeHasChildren(node)) {
      // an existing leaf (pruned or finest) holds these voxels: a voxel's first updates that
      // find it at the clamping threshold in their direction change nothing (updateNode's
      // early abort); from its first update that does, all of its updates apply
      const float v = node->getLogOdds();
      std::size_t live = 0;
      Moved moved;
      for (const std::uint64_t* p = b; p != e; ++p)
        live += moved(*p, at_threshold(v, update_of(*p)));
      if (live == 0) return false;
      if (live < static_cast<std::size_t>(e - b)) {
        kept.reserve(live);
        moved = Moved{};
        for (const std::uint64_t* p = b; p != e; ++p)
          if (moved(*p, at_threshold(v, update_of(*p)))) kept.push_back(*p);
        b = kept.data();
        e = b + kept.size();
      }
    }
    if (depth == depth_) {  // one voxel: its updates in scan order
      for (const std::uint64_t* p = b; p != e; ++p) t_.updateNodeLogOdds(node, update_of(*p));
      return true;
    }
    const unsigned shift = 3 * (depth_ - 1 - depth);
    bool any = false;
    while (b != e) {
      unsigned pos;
      const std::uint64_t* g = detail::child_run_end(b, e, shift, kCode, pos);
      bool created;
      OccupancyNode* child = detail::child_to_update(t_, node, just_created, pos, created);
      any |= visit(child, created, depth + 1, b, g, loss_.child(lc, pos));
      b = g;
    }
    if (any) {
      if (lc.active) {
        detail::prune_or_max(t_, node, detail::MoveLossesAside{loss_, lc});
        loss_.finish(lc);
      } else {
        detail::prune_or_max(t_, node);
      }
    }
    return any;
  }

  OccupancyTree& t_;
  detail::LossAdder loss_;
  const float hit_, miss_, cmin_, cmax_;
  const unsigned depth_;
};

// Applies items with OctoMap's per-key updateNode() (change detection needs it).
void apply_each(OccupancyTree& tree, const std::vector<std::uint64_t>& items) {
  for (std::uint64_t m : items)
    if (!(m & kHit)) tree.updateNode(unmorton(m), false, /*lazy_eval=*/false);
  for (std::uint64_t m : items)
    if (m & kHit) tree.updateNode(unmorton(m & kCode), true, /*lazy_eval=*/false);
}

void apply_items(OccupancyMap& map, const std::vector<std::uint64_t>& items) {
  if (map.tree().isChangeDetectionEnabled()) {
    // OctoMap's updateNode merges nodes without moving carried losses aside
    apply_each(map.settled_tree(), items);
  } else {
    BatchApplier(detail::CarryingAccess::tree(map), map.carried_loss())
        .apply(items.data(), items.data() + items.size());
  }
}

// Scans applied in one walk at most (their items merged): consecutive scans of a robot
// mostly update the same voxels, which one walk then visits once.
constexpr std::size_t kScansPerWalk = 8;

// The buffers of merged_items(): each thread keeps its own between walks (a run applies batch
// after batch), as long as they hold at most kKeptMergeItems items each.
constexpr std::size_t kKeptMergeItems = std::size_t{4} << 20;

struct MergeBuffers {
  std::vector<std::uint64_t> a, b;
  void trim() {
    if (a.capacity() > kKeptMergeItems) std::vector<std::uint64_t>().swap(a);
    if (b.capacity() > kKeptMergeItems) std::vector<std::uint64_t>().swap(b);
  }
};

// The items of `scans` (indices into `per_scan`, in order) as one batch for BatchApplier:
// ascending codes, a voxel's updates in scan order (a stable merge of the sorted scans), in
// `buf.a` (`buf.b` is the merge's other buffer).
const std::vector<std::uint64_t>& merged_items(
    const std::vector<std::vector<std::uint64_t>>& per_scan, const std::size_t* scans,
    std::size_t count, MergeBuffers& buf) {
  std::vector<std::uint64_t>& a = buf.a;
  std::vector<std::uint64_t>& b = buf.b;
  a.clear();
  std::vector<std::size_t> bounds{0};
  for (std::size_t k = 0; k < count; ++k) {
    a.insert(a.end(), per_scan[scans[k]].begin(), per_scan[scans[k]].end());
    bounds.push_back(a.size());
  }
  b.resize(a.size());
  const auto by_code = [](std::uint64_t x, std::uint64_t y) { return (x & kCode) < (y & kCode); };
  while (bounds.size() > 2) {          // neighbouring runs merged pairwise; std::merge keeps the
    std::vector<std::size_t> next{0};  // first run's items first among equal codes
    for (std::size_t k = 0; k + 1 < bounds.size(); k += 2) {
      const auto lo = a.begin() + static_cast<std::ptrdiff_t>(bounds[k]);
      const auto mid = a.begin() + static_cast<std::ptrdiff_t>(bounds[k + 1]);
      const auto out = b.begin() + static_cast<std::ptrdiff_t>(bounds[k]);
      if (k + 2 < bounds.size()) {
        std::merge(lo, mid, mid, a.begin() + static_cast<std::ptrdiff_t>(bounds[k + 2]), out,
                   by_code);
        next.push_back(bounds[k + 2]);
      } else {
        std::copy(lo, mid, out);
        next.push_back(bounds[k + 1]);
      }
    }
    a.swap(b);
    bounds.swap(next);
  }
  return a;
}

// Applies the scans `scans` (indices into `per_scan`) to a tree in order: up to
// kScansPerWalk of them per walk (one at a time with change detection, which needs OctoMap's
// per-key updates).
void apply_scans(OccupancyMap& map, const std::vector<std::vector<std::uint64_t>>& per_scan,
                 const std::vector<std::size_t>& scans) {
  const std::size_t step = map.tree().isChangeDetectionEnabled() ? 1 : kScansPerWalk;
  for (std::size_t k = 0; k < scans.size(); k += step) {
    const std::size_t count = std::min(step, scans.size() - k);
    if (count == 1) {
      apply_items(map, per_scan[scans[k]]);
    } else {
      thread_local MergeBuffers buf;
      const std::vector<std::uint64_t>& items = merged_items(per_scan, &scans[k], count, buf);
      BatchApplier(detail::CarryingAccess::tree(map), map.carried_loss())
          .apply(items.data(), items.data() + items.size());
      buf.trim();
    }
  }
}

template <class Real>
std::vector<float> as_float(const Real* xyz, std::size_t n) {
  std::vector<float> out(3 * n);
  for (std::size_t i = 0; i < 3 * n; ++i) out[i] = static_cast<float>(xyz[i]);
  return out;
}

template <class Real>
std::vector<float> to_map_frame(const Real* xyz, std::size_t n, const double pose[16]) {
  const Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(pose);
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const Eigen::Vector3d t = T.topRightCorner<3, 1>();
  std::vector<float> out(3 * n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d q = R * Eigen::Vector3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]) + t;
    out[3 * i] = static_cast<float>(q.x());
    out[3 * i + 1] = static_cast<float>(q.y());
    out[3 * i + 2] = static_cast<float>(q.z());
  }
  return out;
}

}  // namespace

unsigned default_threads() {
  const unsigned hw = std::thread::hardware_concurrency();
  return std::min(kMaxThreads, std::max(1u, hw));
}

namespace {

void check_threads(unsigned threads) {
  if (threads < 1 || threads > kMaxThreads) {
    throw std::invalid_argument("threads = " + std::to_string(threads) + ": expected 1 to " +
                                std::to_string(kMaxThreads));
  }
}

}  // namespace

RayItems trace_rays(const std::vector<ScanInput>& scans, const OccupancyMap& grid, unsigned threads,
                    bool targeted_only, const FastInsert* fast) {
  check_threads(threads);
  RayItems out;
  out.resolution = grid.params().resolution;
  std::vector<FastInput> fast_in(fast != nullptr ? scans.size() : 0);
  out.per_scan.resize(scans.size());
  detail::parallel_for(scans.size(), threads, [&](std::size_t i) {
    const ScanInput& s = scans[i];
    if (targeted_only && s.targets.empty()) return;
    std::vector<float> pts =
        s.map_frame   ? (s.is_double ? as_float(static_cast<const double*>(s.xyz), s.n)
                                     : as_float(static_cast<const float*>(s.xyz), s.n))
        : s.is_double ? to_map_frame(static_cast<const double*>(s.xyz), s.n, s.pose)
                      : to_map_frame(static_cast<const float*>(s.xyz), s.n, s.pose);
    const float origin[3] = {static_cast<float>(s.pose[3]), static_cast<float>(s.pose[7]),
                             static_cast<float>(s.pose[11])};
    const std::string where = "scan " + std::to_string(i) + ": ";
    if (fast != nullptr) {  // traced below, with the end points of the scans before
      FastInput& f = fast_in[i];
      f.pts = std::move(pts);
      std::copy(origin, origin + 3, f.origin);
      f.max_range = s.max_range;
      f.map = targeted_only ? &s.targets.front()->tree() : nullptr;
      f.where = where;
      f.skip = false;
    } else {
      out.per_scan[i] = compute_items(grid.tree(), pts.data(), s.n, origin, s.max_range, where);
    }
  });
  if (fast != nullptr) out.fast = trace_fast_batch(grid.tree(), fast_in, *fast, threads);
  return out;
}

void apply_rays(const RayItems& items, const std::vector<std::vector<OccupancyMap*>>& targets,
                unsigned threads) {
  check_threads(threads);
  if (targets.size() != items.per_scan.size()) {
    throw std::invalid_argument("apply_rays: " + std::to_string(targets.size()) +
                                " target lists for " + std::to_string(items.per_scan.size()) +
                                " scans");
  }
  // every map gets its scans in order; distinct maps go to whichever thread is free, the
  // most work first
  std::map<OccupancyMap*, std::vector<std::size_t>> per_map;
  std::map<OccupancyMap*, std::size_t> work;
  for (std::size_t i = 0; i < targets.size(); ++i) {
    for (OccupancyMap* m : targets[i]) {
      per_map[m].push_back(i);
      work[m] += items.per_scan[i].size();
    }
  }
  std::vector<OccupancyMap*> maps;
  for (auto& kv : per_map) maps.push_back(kv.first);
  std::sort(maps.begin(), maps.end(), [&](auto* a, auto* b) { return work[a] > work[b]; });
  detail::parallel_for(maps.size(), threads, [&](std::size_t k) {
    if (items.fast.empty()) return apply_scans(*maps[k], items.per_scan, per_map[maps[k]]);
    for (std::size_t i : per_map[maps[k]]) apply_fast(*maps[k], *items.fast[i]);
  });
}

void insert_batch(const std::vector<ScanInput>& scans, unsigned threads, const FastInsert* fast) {
  std::vector<std::vector<OccupancyMap*>> targets;
  const OccupancyMap* grid = nullptr;
  for (const ScanInput& s : scans) {
    targets.push_back(s.targets);
    if (grid == nullptr && !s.targets.empty()) grid = s.targets.front();
  }
  if (grid == nullptr) return check_threads(threads);
  apply_rays(trace_rays(scans, *grid, threads, true, fast), targets, threads);
}

template <class Real>
void insert_scan_batched(OccupancyMap& map, const Real* xyz, std::size_t n, const double origin[3],
                         double max_range) {
  const std::vector<float> pts = as_float(xyz, n);
  const float o[3] = {static_cast<float>(origin[0]), static_cast<float>(origin[1]),
                      static_cast<float>(origin[2])};
  apply_items(map, compute_items(map.tree(), pts.data(), n, o, max_range, ""));
}

template void insert_scan_batched<float>(OccupancyMap&, const float*, std::size_t, const double*,
                                         double);
template void insert_scan_batched<double>(OccupancyMap&, const double*, std::size_t, const double*,
                                          double);

}  // namespace octofuse
