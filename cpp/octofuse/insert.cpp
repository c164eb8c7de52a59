// octofuse: batched scan insertion (ray keys once per scan, applied to several maps).
#include "octofuse/insert.hpp"

#include "octofuse/detail/key_codes.hpp"
#include "octofuse/detail/parallel_for.hpp"
#include "octofuse/detail/prune_or_max.hpp"
#include "octofuse/scan_check.hpp"
#include "octofuse/tree_access.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <map>
#include <stdexcept>
#include <string>
#include <thread>

namespace octofuse {

namespace {

using detail::CodeSet;
using detail::kCode;
using detail::kHit;
using detail::morton;
using detail::sort_unique;
using detail::unmorton;

// The update of one scan as items in ascending code order (free and occupied merged;
// occupied wins over free), with computeUpdate()'s semantics. Every ray is checked first
// (std::invalid_argument prefixed by `where`).
std::vector<std::uint64_t> compute_items(const OccupancyTree& grid, const float* xyz,
                                         std::size_t n, const float origin[3],
                                         double max_range, const std::string& where) {
  const octomap::point3d o(origin[0], origin[1], origin[2]);
  const ScanCheck check(grid, o, max_range, where);
  for (std::size_t i = 0; i < n; ++i) {
    check.check(i, octomap::point3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]));
  }
  octomap::KeyRay ray;
  CodeSet free(n * 4);
  std::vector<std::uint64_t> occ;
  occ.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const octomap::point3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    if (max_range < 0.0 || (p - o).norm() <= max_range) {
      if (grid.computeRayKeys(o, p, ray)) {
        for (const auto& k : ray) free.insert(morton(k));
      }
      octomap::OcTreeKey key;
      if (grid.coordToKeyChecked(p, key)) occ.push_back(morton(key));
    } else {
      const octomap::point3d end = o + (p - o).normalized() * static_cast<float>(max_range);
      if (grid.computeRayKeys(o, end, ray)) {
        for (const auto& k : ray) free.insert(morton(k));
      }
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

// Applies items (ascending codes, each voxel once) to a tree in one depth-first pass. The
// result is the tree that OctoMap's updateNode(key, hit, lazy_eval = false) gives when
// called for every item in turn: each voxel receives exactly one update, so its value does
// not depend on the order; a voxel whose leaf is already at the clamping threshold in the
// update's direction is skipped without touching the tree (updateNode's early abort);
// pruned leaves are expanded and missing children created as updateNodeRecurs() does; and
// every node on the path of an applied update is pruned if collapsible, or else gets the
// maximum of its children, once its subtree is final - which is the state updateNode leaves
// it in after the last update below it. Nodes are walked once per batch of keys instead of
// twice (search + update) per key from the root.
class BatchApplier {
 public:
  explicit BatchApplier(OccupancyTree& tree)
      : t_(tree),
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
    visit(root, created, 0, b, e);
  }

 private:
  float update_of(std::uint64_t item) const { return (item & kHit) ? hit_ : miss_; }
  bool at_threshold(float value, float u) const {
    return (u >= 0 && value >= cmax_) || (u <= 0 && value <= cmin_);
  }

  // Returns whether any item below `node` was applied.
  bool visit(OccupancyNode* node, bool just_created, unsigned depth,
             const std::uint64_t* b, const std::uint64_t* e) {
    std::vector<std::uint64_t> kept;
    if (!just_created && !t_.nodeHasChildren(node)) {
      // an existing leaf (pruned or finest) holds these voxels: updateNode's early abort
      const float v = node->getLogOdds();
      std::size_t skip = 0;
      for (const std::uint64_t* p = b; p != e; ++p) skip += at_threshold(v, update_of(*p));
      if (skip == static_cast<std::size_t>(e - b)) return false;
      if (skip > 0) {
        kept.reserve(static_cast<std::size_t>(e - b) - skip);
        for (const std::uint64_t* p = b; p != e; ++p)
          if (!at_threshold(v, update_of(*p))) kept.push_back(*p);
        b = kept.data();
        e = b + kept.size();
      }
    }
    if (depth == depth_) {  // one voxel: e == b + 1
      t_.updateNodeLogOdds(node, update_of(*b));
      return true;
    }
    const unsigned shift = 3 * (depth_ - 1 - depth);
    bool any = false;
    while (b != e) {
      const unsigned pos = static_cast<unsigned>(((*b & kCode) >> shift) & 7);
      const std::uint64_t* g = b + 1;
      if (static_cast<unsigned>(((*(e - 1) & kCode) >> shift) & 7) == pos) {
        g = e;  // the whole range lies under one child
      } else {
        while (g != e && static_cast<unsigned>(((*g & kCode) >> shift) & 7) == pos) ++g;
      }
      bool created = false;
      if (!t_.nodeChildExists(node, pos)) {
        if (!t_.nodeHasChildren(node) && !just_created) {
          t_.expandNode(node);  // a pruned leaf
        } else {
          t_.createNodeChild(node, pos);
          created = true;
        }
      }
      any |= visit(t_.getNodeChild(node, pos), created, depth + 1, b, g);
      b = g;
    }
    if (any) detail::prune_or_max(t_, node);
    return any;
  }

  OccupancyTree& t_;
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

void apply_items(OccupancyTree& tree, const std::vector<std::uint64_t>& items) {
  if (tree.isChangeDetectionEnabled()) {
    apply_each(tree, items);
  } else {
    BatchApplier(tree).apply(items.data(), items.data() + items.size());
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
    const Eigen::Vector3d q =
        R * Eigen::Vector3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]) + t;
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

RayItems trace_rays(const std::vector<ScanInput>& scans, const OccupancyMap& grid,
                    unsigned threads, bool targeted_only) {
  check_threads(threads);
  RayItems out;
  out.resolution = grid.params().resolution;
  out.per_scan.resize(scans.size());
  detail::parallel_for(scans.size(), threads, [&](std::size_t i) {
    const ScanInput& s = scans[i];
    if (targeted_only && s.targets.empty()) return;
    const std::vector<float> pts =
        s.map_frame ? (s.is_double ? as_float(static_cast<const double*>(s.xyz), s.n)
                                   : as_float(static_cast<const float*>(s.xyz), s.n))
        : s.is_double ? to_map_frame(static_cast<const double*>(s.xyz), s.n, s.pose)
                      : to_map_frame(static_cast<const float*>(s.xyz), s.n, s.pose);
    const float origin[3] = {static_cast<float>(s.pose[3]), static_cast<float>(s.pose[7]),
                             static_cast<float>(s.pose[11])};
    out.per_scan[i] = compute_items(grid.tree(), pts.data(), s.n, origin, s.max_range,
                                    "scan " + std::to_string(i) + ": ");
  });
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
    for (std::size_t i : per_map[maps[k]]) apply_items(maps[k]->tree(), items.per_scan[i]);
  });
}

void insert_batch(const std::vector<ScanInput>& scans, unsigned threads) {
  std::vector<std::vector<OccupancyMap*>> targets;
  const OccupancyMap* grid = nullptr;
  for (const ScanInput& s : scans) {
    targets.push_back(s.targets);
    if (grid == nullptr && !s.targets.empty()) grid = s.targets.front();
  }
  if (grid == nullptr) return check_threads(threads);
  apply_rays(trace_rays(scans, *grid, threads, true), targets, threads);
}

template <class Real>
void insert_scan_batched(OccupancyMap& map, const Real* xyz, std::size_t n,
                         const double origin[3], double max_range) {
  const std::vector<float> pts = as_float(xyz, n);
  const float o[3] = {static_cast<float>(origin[0]), static_cast<float>(origin[1]),
                      static_cast<float>(origin[2])};
  apply_items(map.tree(), compute_items(map.tree(), pts.data(), n, o, max_range, ""));
}

template void insert_scan_batched<float>(OccupancyMap&, const float*, std::size_t, const double*,
                                         double);
template void insert_scan_batched<double>(OccupancyMap&, const double*, std::size_t,
                                          const double*, double);

}  // namespace octofuse
