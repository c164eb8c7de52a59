// octofuse: scan insertion into OccupancyMaps.
#include "octofuse/insert.hpp"

#include <octomap/Pointcloud.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <atomic>
#include <map>
#include <thread>

namespace octofuse {

namespace {

// Spreads the 16 bits of v to every third bit (Morton encoding).
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
  return spread3(k[0]) << 2 | spread3(k[1]) << 1 | spread3(k[2]);
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
  return octomap::OcTreeKey(compact(m >> 2), compact(m >> 1), compact(m));
}

void sort_unique(std::vector<std::uint64_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
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

ScanUpdate compute_update(const octomap::OcTree& grid, const float* xyz, std::size_t n,
                          const float origin[3], double max_range) {
  const octomap::point3d o(origin[0], origin[1], origin[2]);
  octomap::KeyRay ray;
  std::vector<std::uint64_t> free, occ;
  free.reserve(n * 16);
  occ.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const octomap::point3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    if (max_range < 0.0 || (p - o).norm() <= max_range) {
      if (grid.computeRayKeys(o, p, ray)) {
        for (const auto& k : ray) free.push_back(morton(k));
      }
      octomap::OcTreeKey key;
      if (grid.coordToKeyChecked(p, key)) occ.push_back(morton(key));
    } else {
      const octomap::point3d end = o + (p - o).normalized() * static_cast<float>(max_range);
      if (grid.computeRayKeys(o, end, ray)) {
        for (const auto& k : ray) free.push_back(morton(k));
      }
    }
  }
  sort_unique(free);
  sort_unique(occ);
  ScanUpdate u;
  u.occupied.reserve(occ.size());
  for (auto m : occ) u.occupied.push_back(unmorton(m));
  u.free.reserve(free.size());
  auto it = occ.begin();
  for (auto m : free) {  // occupied wins over free
    while (it != occ.end() && *it < m) ++it;
    if (it != occ.end() && *it == m) continue;
    u.free.push_back(unmorton(m));
  }
  return u;
}

void apply_update(octomap::OcTree& tree, const ScanUpdate& u) {
  for (const auto& k : u.free) tree.updateNode(k, false, /*lazy_eval=*/false);
  for (const auto& k : u.occupied) tree.updateNode(k, true, /*lazy_eval=*/false);
}

void insert_batch(const std::vector<ScanInput>& scans, unsigned threads) {
  std::vector<ScanUpdate> updates(scans.size());
  parallel_for(scans.size(), threads, [&](std::size_t i) {
    const ScanInput& s = scans[i];
    if (s.targets.empty()) return;
    const std::vector<float> pts =
        s.is_double ? to_map_frame(static_cast<const double*>(s.xyz), s.n, s.pose)
                    : to_map_frame(static_cast<const float*>(s.xyz), s.n, s.pose);
    const float origin[3] = {static_cast<float>(s.pose[3]), static_cast<float>(s.pose[7]),
                             static_cast<float>(s.pose[11])};
    updates[i] = compute_update(s.targets.front()->tree(), pts.data(), s.n, origin, s.max_range);
  });
  // every map gets its scans in order; distinct maps go to threads by amount of work
  std::map<OccupancyMap*, std::vector<std::size_t>> per_map;
  std::map<OccupancyMap*, std::size_t> work;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    for (OccupancyMap* m : scans[i].targets) {
      per_map[m].push_back(i);
      work[m] += updates[i].free.size() + updates[i].occupied.size();
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
      for (std::size_t i : per_map[m]) apply_update(m->tree(), updates[i]);
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
