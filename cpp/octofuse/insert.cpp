// octofuse: scan insertion into OccupancyMaps.
#include "octofuse/insert.hpp"

#include "octofuse/tree_access.hpp"

#include <octomap/Pointcloud.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <atomic>
#include <map>
#include <thread>

namespace octofuse {

namespace {

// Morton code of a key: bit i of key[0] (x) goes to bit 3i, of key[1] (y) to 3i+1, of key[2]
// (z) to 3i+2. At every level the three bits are OctoMap's child index (computeChildIdx), so
// ascending codes are the tree's depth-first order and the keys under one node are contiguous.
inline std::uint64_t spread3(std::uint64_t v) {
  v &= 0xffff;
  v = (v | (v << 32)) & 0x001f00000000ffffULL;
  v = (v | (v << 16)) & 0x001f0000ff0000ffULL;
  v = (v | (v << 8)) & 0x100f00f00f00f00fULL;
  v = (v | (v << 4)) & 0x10c30c30c30c30c3ULL;
  v = (v | (v << 2)) & 0x1249249249249249ULL;
  return v;
}

inline std::uint64_t morton(const octomap::OcTreeKey& k) {
  return spread3(k[0]) | spread3(k[1]) << 1 | spread3(k[2]) << 2;
}

inline octomap::OcTreeKey unmorton(std::uint64_t m) {
  auto compact = [](std::uint64_t v) {
    v &= 0x1249249249249249ULL;
    v = (v | (v >> 2)) & 0x10c30c30c30c30c3ULL;
    v = (v | (v >> 4)) & 0x100f00f00f00f00fULL;
    v = (v | (v >> 8)) & 0x001f0000ff0000ffULL;
    v = (v | (v >> 16)) & 0x001f00000000ffffULL;
    v = (v | (v >> 32)) & 0xffffULL;
    return static_cast<octomap::key_type>(v);
  };
  return octomap::OcTreeKey(compact(m), compact(m >> 1), compact(m >> 2));
}

// An update item: the Morton code of a voxel, bit 63 set for a hit (occupied), clear for a
// miss (free). Codes use 48 bits, so the flag never collides with them.
constexpr std::uint64_t kHit = 1ULL << 63;
constexpr std::uint64_t kCode = kHit - 1;

void sort_unique(std::vector<std::uint64_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

// Set of Morton codes (open addressing, linear probing). A ray passes through voxels that the
// neighbouring rays of the scan also pass through, so most keys repeat; the set keeps each
// once, and only the distinct ones are sorted afterwards.
class CodeSet {
 public:
  explicit CodeSet(std::size_t expected) {
    std::fill(std::begin(recent_), std::end(recent_), kEmpty);
    std::size_t cap = 1024;
    while (cap < 2 * expected) cap *= 2;
    rehash(cap);
  }
  void insert(std::uint64_t c) {
    std::uint64_t& recent = recent_[c & (kRecent - 1)];
    if (recent == c) return;
    recent = c;
    if (put(c) && ++size_ * 2 > table_.size()) rehash(table_.size() * 2);
  }
  /// The codes in ascending order.
  std::vector<std::uint64_t> sorted() const {
    std::vector<std::uint64_t> out;
    out.reserve(size_);
    for (std::uint64_t s : table_)
      if (s != kEmpty) out.push_back(s);
    std::sort(out.begin(), out.end());
    return out;
  }

 private:
  static constexpr std::uint64_t kEmpty = ~0ULL;  // never a code (codes use 48 bits)
  // Adds c to the table; false if it was there.
  bool put(std::uint64_t c) {
    std::size_t i = slot(c);
    while (true) {
      const std::uint64_t s = table_[i];
      if (s == c) return false;
      if (s == kEmpty) break;
      i = (i + 1) & mask_;
    }
    table_[i] = c;
    return true;
  }
  std::size_t slot(std::uint64_t c) const {
    return static_cast<std::size_t>((c * 0x9E3779B97F4A7C15ULL) >> shift_);
  }
  void rehash(std::size_t cap) {
    std::vector<std::uint64_t> old(cap, kEmpty);
    old.swap(table_);
    mask_ = cap - 1;
    shift_ = 64;
    for (std::size_t c = cap; c > 1; c >>= 1) --shift_;
    for (std::uint64_t s : old)
      if (s != kEmpty) put(s);
  }
  // direct-mapped by the low code bits (a few voxels' neighbourhood): the keys of the
  // previous rays, tested before the table
  static constexpr std::size_t kRecent = 1024;
  std::uint64_t recent_[kRecent];
  std::vector<std::uint64_t> table_;
  std::size_t mask_ = 0;
  unsigned shift_ = 64;
  std::size_t size_ = 0;
};

// The update of one scan as items in ascending code order (free and occupied merged;
// occupied wins over free), with computeUpdate()'s semantics.
std::vector<std::uint64_t> compute_items(const octomap::OcTree& grid, const float* xyz,
                                         std::size_t n, const float origin[3],
                                         double max_range) {
  const octomap::point3d o(origin[0], origin[1], origin[2]);
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
  explicit BatchApplier(octomap::OcTree& tree)
      : t_(tree),
        hit_(tree.getProbHitLog()),
        miss_(tree.getProbMissLog()),
        cmin_(tree.getClampingThresMinLog()),
        cmax_(tree.getClampingThresMaxLog()),
        depth_(tree.getTreeDepth()) {}

  void apply(const std::uint64_t* b, const std::uint64_t* e) {
    if (b == e) return;
    octomap::OcTreeNode* root = t_.getRoot();
    bool created = false;
    if (root == nullptr) {
      root = detail::TreeAccess<octomap::OcTree>::ensure_root(t_);
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
  bool visit(octomap::OcTreeNode* node, bool just_created, unsigned depth,
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
    if (any && !t_.pruneNode(node)) node->updateOccupancyChildren();
    return any;
  }

  octomap::OcTree& t_;
  const float hit_, miss_, cmin_, cmax_;
  const unsigned depth_;
};

// Applies items with OctoMap's per-key updateNode() (change detection needs it).
void apply_each(octomap::OcTree& tree, const std::vector<std::uint64_t>& items) {
  for (std::uint64_t m : items)
    if (!(m & kHit)) tree.updateNode(unmorton(m), false, /*lazy_eval=*/false);
  for (std::uint64_t m : items)
    if (m & kHit) tree.updateNode(unmorton(m & kCode), true, /*lazy_eval=*/false);
}

void apply_items(octomap::OcTree& tree, const std::vector<std::uint64_t>& items) {
  if (tree.isChangeDetectionEnabled()) {
    apply_each(tree, items);
  } else {
    BatchApplier(tree).apply(items.data(), items.data() + items.size());
  }
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

// Runs f(i) for i in [0, n) on `threads` threads (dynamic scheduling).
template <class F>
void parallel_for(std::size_t n, unsigned threads, F f) {
  threads = std::max(1u, std::min<unsigned>(threads, static_cast<unsigned>(n)));
  if (threads <= 1) {
    for (std::size_t i = 0; i < n; ++i) f(i);
    return;
  }
  std::atomic<std::size_t> next{0};
  auto work = [&] {
    for (std::size_t i = next++; i < n; i = next++) f(i);
  };
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
}

}  // namespace

void insert_batch(const std::vector<ScanInput>& scans, unsigned threads) {
  std::vector<std::vector<std::uint64_t>> updates(scans.size());
  parallel_for(scans.size(), threads, [&](std::size_t i) {
    const ScanInput& s = scans[i];
    if (s.targets.empty()) return;
    const std::vector<float> pts =
        s.is_double ? to_map_frame(static_cast<const double*>(s.xyz), s.n, s.pose)
                    : to_map_frame(static_cast<const float*>(s.xyz), s.n, s.pose);
    const float origin[3] = {static_cast<float>(s.pose[3]), static_cast<float>(s.pose[7]),
                             static_cast<float>(s.pose[11])};
    updates[i] = compute_items(s.targets.front()->tree(), pts.data(), s.n, origin, s.max_range);
  });
  // every map gets its scans in order; distinct maps go to threads by amount of work
  std::map<OccupancyMap*, std::vector<std::size_t>> per_map;
  std::map<OccupancyMap*, std::size_t> work;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    for (OccupancyMap* m : scans[i].targets) {
      per_map[m].push_back(i);
      work[m] += updates[i].size();
    }
  }
  std::vector<OccupancyMap*> maps;
  for (auto& kv : per_map) maps.push_back(kv.first);
  std::sort(maps.begin(), maps.end(), [&](auto* a, auto* b) { return work[a] > work[b]; });
  const unsigned nt = std::max(1u, threads);
  std::vector<std::vector<OccupancyMap*>> lanes(nt);
  std::vector<std::size_t> load(nt, 0);
  for (OccupancyMap* m : maps) {
    const auto t = std::min_element(load.begin(), load.end()) - load.begin();
    lanes[t].push_back(m);
    load[t] += work[m];
  }
  parallel_for(nt, nt, [&](std::size_t t) {
    for (OccupancyMap* m : lanes[t])
      for (std::size_t i : per_map[m]) apply_items(m->tree(), updates[i]);
  });
}

// Single scans through OctoMap's own insertPointCloud().
template <class Real>
void OccupancyMap::insert_scan(const Real* xyz, std::size_t n, const double origin[3],
                               double max_range) {
  octomap::Pointcloud cloud;
  cloud.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    cloud.push_back(static_cast<float>(xyz[3 * i]), static_cast<float>(xyz[3 * i + 1]),
                    static_cast<float>(xyz[3 * i + 2]));
  }
  const octomap::point3d o(static_cast<float>(origin[0]), static_cast<float>(origin[1]),
                           static_cast<float>(origin[2]));
  tree_->insertPointCloud(cloud, o, max_range, /*lazy_eval=*/false, /*discretize=*/false);
}

template <class Real>
void OccupancyMap::insert_scan_from_sensor(const Real* xyz, std::size_t n, const double pose[16],
                                           double max_range) {
  const Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(pose);
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const Eigen::Vector3d t = T.topRightCorner<3, 1>();
  octomap::Pointcloud cloud;
  cloud.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    const Eigen::Vector3d q = R * p + t;
    cloud.push_back(static_cast<float>(q.x()), static_cast<float>(q.y()),
                    static_cast<float>(q.z()));
  }
  const octomap::point3d o(static_cast<float>(t.x()), static_cast<float>(t.y()),
                           static_cast<float>(t.z()));
  tree_->insertPointCloud(cloud, o, max_range, /*lazy_eval=*/false, /*discretize=*/false);
}

template void OccupancyMap::insert_scan<float>(const float*, std::size_t, const double*, double);
template void OccupancyMap::insert_scan<double>(const double*, std::size_t, const double*, double);
template void OccupancyMap::insert_scan_from_sensor<float>(const float*, std::size_t,
                                                           const double*, double);
template void OccupancyMap::insert_scan_from_sensor<double>(const double*, std::size_t,
                                                            const double*, double);

}  // namespace octofuse
