// octofuse: real-time scan insertion ("fast" mode): free space cleared a cell at a time where
// a scan's rays are dense (see insert_fast.hpp).
#include "octofuse/insert_fast.hpp"

#include "octofuse/detail/key_codes.hpp"
#include "octofuse/detail/parallel_for.hpp"
#include "octofuse/detail/ray_codes.hpp"
#include "octofuse/scan_check.hpp"

#include "fast_applier.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <utility>

namespace octofuse {

namespace {

using detail::kHit;
using detail::kNoCode;
using detail::morton;

using detail::kCell;
using detail::kCodeOnly;
constexpr long kKeyOffset = 32768;  // OctoMap's tree_max_val at depth 16

// The size of a cache line: per-thread state that is written often is kept on lines of
// its own, so that the threads do not take the lines from each other.
constexpr std::size_t kLine = 64;

// Rays crossing each cell of a scan, and the cells holding one of its end points: an
// open-addressing map from cell code to a count whose top bit marks an end point.
class alignas(kLine) CellTally {
 public:
  static constexpr std::uint32_t kHasEnd = 1u << 31;

  explicit CellTally(std::size_t expected) {
    std::size_t cap = 1024;
    while (cap < 2 * expected) cap *= 2;
    resize(cap);
  }
  /// Adds `what` to a cell: a count of rays, or kHasEnd (marks the cell).
  void add(std::uint64_t cell, std::uint32_t what) {
    Slot* s = &find(cell);
    if (s->cell == kNoCode) {
      s->cell = cell;
      if (++size_ * 2 > slots_.size()) {
        grow();
        s = &find(cell);
      }
    }
    s->value = (what & kHasEnd) ? (s->value | what) : s->value + what;
  }
  /// Adds a ray to a cell through a small direct-mapped cache: a ray's neighbours cross
  /// mostly the same cells, whose counts then add up there (call flush() before reading).
  void add_ray(std::uint64_t cell) {
    Recent& r = recent_[(cell ^ (cell >> 9)) & (kRecent - 1)];
    if (r.cell == cell) {
      ++r.count;
      return;
    }
    if (r.count != 0) add(r.cell, r.count);
    r = {cell, 1};
  }
  void flush() {
    for (Recent& r : recent_) {
      if (r.count != 0) add(r.cell, r.count);
      r = Recent{};
    }
  }
  /// Adds every cell of `other` (its rays and its mark).
  void absorb(const CellTally& other) {
    for (const Slot& s : other.slots_) {
      if (s.cell == kNoCode) continue;
      add(s.cell, s.value & ~kHasEnd);
      if (s.value & kHasEnd) add(s.cell, kHasEnd);
    }
  }
  /// Calls f(cell, value) for every cell.
  template <class F>
  void each(F&& f) const {
    for (const Slot& s : slots_)
      if (s.cell != kNoCode) f(s.cell, s.value);
  }
  std::uint32_t get(std::uint64_t cell) const {
    for (std::size_t i = slot(cell);; i = (i + 1) & mask_) {
      const Slot& s = slots_[i];
      if (s.cell == cell) return s.value;
      if (s.cell == kNoCode) return 0;
    }
  }

 private:
  struct Slot {
    std::uint64_t cell = kNoCode;
    std::uint32_t value = 0;
  };
  struct Recent {
    std::uint64_t cell = kNoCode;
    std::uint32_t count = 0;
  };
  static constexpr std::size_t kRecent = 4096;
  std::vector<Recent> recent_ = std::vector<Recent>(kRecent);
  std::size_t slot(std::uint64_t c) const {
    return static_cast<std::size_t>((c * 0x9E3779B97F4A7C15ULL) >> shift_);
  }
  Slot& find(std::uint64_t c) {
    std::size_t i = slot(c);
    while (slots_[i].cell != c && slots_[i].cell != kNoCode) i = (i + 1) & mask_;
    return slots_[i];
  }
  void resize(std::size_t cap) {
    slots_.assign(cap, Slot{});
    mask_ = cap - 1;
    shift_ = 64;
    for (std::size_t c = cap; c > 1; c >>= 1) --shift_;
  }
  void grow() {
    std::vector<Slot> old;
    old.swap(slots_);
    resize(old.size() * 2);
    for (const Slot& s : old)
      if (s.cell != kNoCode) find(s.cell) = s;
  }
  std::vector<Slot> slots_;
  std::size_t mask_ = 0;
  unsigned shift_ = 64;
  std::size_t size_ = 0;
};

// One ray of a scan: where it ends (cut to the maximum range) and whether its end is a hit.
struct Ray {
  octomap::point3d end;
  bool hit;
};

// The lower edge (metres) of cell `c` of size 2^level voxels along one axis.
inline double cell_edge(long c, unsigned level, double res) {
  return static_cast<double>((c << level) - kKeyOffset) * res;
}

// Calls f(cell code) for each cell of 2^level voxels per edge that the segment o->e crosses
// (a voxel walk on the coarser grid; o and e inside the tree's extent).
template <class F>
void walk_cells(const OccupancyTree& t, const octomap::point3d& o, const octomap::point3d& e,
                unsigned level, F&& f) {
  const octomap::OcTreeKey ko = t.coordToKey(o), ke = t.coordToKey(e);
  long cell[3], last[3];
  int step[3];
  double t_max[3], t_delta[3];
  const double res = t.getResolution(), size = res * static_cast<double>(1u << level);
  const double dx = e.x() - o.x(), dy = e.y() - o.y(), dz = e.z() - o.z();
  const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
  const double dir[3] = {dx / len, dy / len, dz / len};
  long steps_left = 4;
  for (unsigned i = 0; i < 3; ++i) {
    cell[i] = ko[i] >> level;
    last[i] = ke[i] >> level;
    steps_left += std::labs(last[i] - cell[i]);
    step[i] = dir[i] > 0 ? 1 : dir[i] < 0 ? -1 : 0;
    if (step[i] != 0 && len > 0) {
      t_max[i] = (cell_edge(cell[i] + (step[i] > 0), level, res) - o(i)) / dir[i];
      t_delta[i] = size / std::fabs(dir[i]);
    } else {
      t_max[i] = t_delta[i] = std::numeric_limits<double>::max();
    }
  }
  std::uint64_t code = morton(octomap::OcTreeKey(static_cast<octomap::key_type>(cell[0]),
                                                 static_cast<octomap::key_type>(cell[1]),
                                                 static_cast<octomap::key_type>(cell[2])));
  f(code);
  while (--steps_left > 0 && (cell[0] != last[0] || cell[1] != last[1] || cell[2] != last[2])) {
    const unsigned a =
        t_max[0] < t_max[1] ? (t_max[0] < t_max[2] ? 0 : 2) : (t_max[1] < t_max[2] ? 1 : 2);
    if (t_max[a] > len) break;
    cell[a] += step[a];
    t_max[a] += t_delta[a];
    code = detail::morton_step(code, detail::axis_mask(a), step[a]);
    f(code);
  }
}

// The voxel walk of detail::trace_ray_codes() (OctoMap's computeRayKeys, statement for
// statement, so that a ray that crosses no cleared cell gives its voxels bit for bit), which
// crosses the cells that `cleared(cell code)` says are cleared whole a cell at a time (a walk
// on the grid of cells) and passes the other voxels before the end's to `on_voxel`.
template <class Cleared, class OnVoxel>
void trace_ray_cells(const OccupancyTree& tree, const octomap::point3d& origin,
                     const octomap::point3d& end, unsigned level, Cleared&& cleared,
                     OnVoxel&& on_voxel) {
  octomap::OcTreeKey key_origin, key_end;
  if (!tree.coordToKeyChecked(origin, key_origin) || !tree.coordToKeyChecked(end, key_end)) return;
  if (key_origin == key_end) return;
  const std::uint64_t code_end = morton(key_end);
  octomap::point3d direction = (end - origin);
  const float length = static_cast<float>(direction.norm());
  direction /= length;
  const double resolution = tree.getResolution();
  const double size = resolution * static_cast<double>(1u << level);
  int step[3];
  double t[3], t_delta[3];    // the voxel walk's
  double ct[3], ct_delta[3];  // the cell walk's
  long key[3], cell[3];
  long steps_left = 16;
  const auto t_leave = [&](unsigned i) {  // where the ray leaves voxel key[i] along axis i
    double voxel_border = tree.keyToCoord(static_cast<octomap::key_type>(key[i]));
    voxel_border += static_cast<float>(step[i] * resolution * 0.5);
    return (voxel_border - origin(i)) / direction(i);
  };
  const auto ct_leave = [&](unsigned i) {  // where it leaves cell[i] along axis i
    return (cell_edge(cell[i] + (step[i] > 0), level, resolution) - origin(i)) / direction(i);
  };
  for (unsigned i = 0; i < 3; ++i) {
    key[i] = key_origin[i];
    cell[i] = key[i] >> level;
    steps_left += 2 * std::labs(static_cast<long>(key_end[i]) - key[i]);
    step[i] = direction(i) > 0.0 ? 1 : direction(i) < 0.0 ? -1 : 0;
    if (step[i] != 0) {
      t[i] = t_leave(i);
      t_delta[i] = resolution / std::fabs(direction(i));
      ct[i] = ct_leave(i);
      ct_delta[i] = size / std::fabs(direction(i));
    } else {
      t[i] = t_delta[i] = ct[i] = ct_delta[i] = std::numeric_limits<double>::max();
    }
  }
  const auto code_of = [](const long* k) {
    return morton(octomap::OcTreeKey(static_cast<octomap::key_type>(k[0]),
                                     static_cast<octomap::key_type>(k[1]),
                                     static_cast<octomap::key_type>(k[2])));
  };
  const long top = (1L << (16 - level)) - 1;
  const unsigned shift = 3 * level;
  std::uint64_t code = morton(key_origin);
  bool new_cell = true;  // whether the walk is in a cell not yet asked about
  while (--steps_left > 0) {
    std::uint64_t cell_code = code >> shift;
    if (new_cell && cleared(cell_code)) {
      // on to the next cell not cleared, then into its voxel at the entry point
      unsigned a;
      do {
        a = ct[0] < ct[1] ? (ct[0] < ct[2] ? 0 : 2) : (ct[1] < ct[2] ? 1 : 2);
        if (ct[a] > length) return;  // the ray ends in a cleared cell
        cell[a] += step[a];
        if (cell[a] < 0 || cell[a] > top) return;
        ct[a] += ct_delta[a];
        cell_code = detail::morton_step(cell_code, detail::axis_mask(a), step[a]);
      } while (cleared(cell_code) && --steps_left > 0);
      const double t_in = ct[a] - ct_delta[a];
      for (unsigned i = 0; i < 3; ++i) {
        if (step[i] == 0) continue;
        if (i == a) {
          key[i] = step[i] > 0 ? cell[i] << level : ((cell[i] + 1) << level) - 1;
        } else {
          const double x = origin(i) + direction(i) * t_in;
          const long k = static_cast<long>(std::floor(x / resolution)) + kKeyOffset;
          key[i] = std::clamp(k, cell[i] << level, ((cell[i] + 1) << level) - 1);
        }
        t[i] = t_leave(i);
      }
      code = code_of(key);
    }
    new_cell = false;
    if (code == code_end) return;
    on_voxel(code);
    unsigned a;
    if (t[0] < t[1]) {
      a = t[0] < t[2] ? 0 : 2;
    } else {
      a = t[1] < t[2] ? 1 : 2;
    }
    key[a] += step[a];
    t[a] += t_delta[a];
    code = detail::morton_step(code, detail::axis_mask(a), step[a]);
    if ((key[a] >> level) != cell[a]) {  // into the next cell
      cell[a] = key[a] >> level;
      ct[a] = ct_leave(a);
      new_cell = true;
    }
    // past the ray's length: rounding made the walk miss the end's voxel
    if (code != code_end && std::min(std::min(t[0], t[1]), t[2]) > length) return;
  }
}

// Merges two ascending item lists whose codes differ (std::merge by code).
std::vector<std::uint64_t> merged(const std::vector<std::uint64_t>& a,
                                  const std::vector<std::uint64_t>& b) {
  std::vector<std::uint64_t> out(a.size() + b.size());
  std::merge(a.begin(), a.end(), b.begin(), b.end(), out.begin(),
             [](std::uint64_t x, std::uint64_t y) { return (x & kCodeOnly) < (y & kCodeOnly); });
  return out;
}

}  // namespace

InsertMode parse_insert_mode(const std::string& name) {
  if (name == "exact") return InsertMode::Exact;
  if (name == "fast") return InsertMode::Fast;
  throw std::invalid_argument("insert mode '" + name + "': expected 'exact' or 'fast'");
}

void FastInsert::validate() const {
  if (coarse_levels < 1 || coarse_levels > 8) {
    throw std::invalid_argument("coarse_levels = " + std::to_string(coarse_levels) +
                                ": expected 1 to 8");
  }
  if (min_rays < 1) throw std::invalid_argument("min_rays = 0: expected 1 or more");
  if (threads < 1 || threads > kMaxThreads) {
    throw std::invalid_argument("threads = " + std::to_string(threads) + ": expected 1 to " +
                                std::to_string(kMaxThreads));
  }
}

namespace {

// Calls f(worker, b, e) for runs b..e of the rays [0, n) on `threads` workers (0 to
// threads - 1, the caller's thread among them), each taking the next run when done with one:
// the rays of a scan differ in length. Neighbouring rays share their voxels, so the runs are
// long (a voxel then seldom goes to two workers): each a share of the rays left, down to
// 256 rays at the end, so that the workers end together. Then each worker calls
// done(worker).
template <class F, class Done>
void ray_runs(std::size_t n, unsigned threads, F&& f, Done&& done) {
  std::atomic<std::size_t> next{0};
  const std::size_t parts = 4 * std::size_t{threads};
  detail::parallel_for(threads, threads, [&](std::size_t worker) {
    std::size_t b = next.load();
    while (b < n) {
      const std::size_t e = std::min(n, b + std::max<std::size_t>(256, (n - b) / parts));
      if (!next.compare_exchange_weak(b, e)) continue;  // b: where the runs are now
      f(worker, b, e);
      b = next.load();
    }
    done(worker);
  });
}

// The free voxels of a scan's rays outside the cells that `jump(cell code)` says the walk
// crosses a cell at a time (ascending, each once), traced on `threads` threads, each with a
// direct-mapped cache of jump()'s recent answers.
template <class Jump>
std::vector<std::uint64_t> free_voxels(const OccupancyTree& grid, const FastScan& scan,
                                       unsigned threads, const Jump& jump) {
  const std::size_t n = scan.ends.size() / 3;
  const octomap::point3d o(scan.origin[0], scan.origin[1], scan.origin[2]);
  constexpr std::size_t kCache = 4096;
  struct alignas(kLine) Worker {
    std::vector<std::uint64_t> cache;  // the cell, its top bit: jumped
    detail::CodeSet voxels;
  };
  std::vector<Worker> workers;
  workers.reserve(threads);
  // a ray crosses some voxels no other ray does: room for 16 a ray, so that the sets of a
  // real scan's rays to 40 m are not made again as they grow
  for (unsigned k = 0; k < threads; ++k)
    workers.push_back(
        {std::vector<std::uint64_t>(kCache, kNoCode), detail::CodeSet(16 * n / threads)});
  std::vector<std::vector<std::uint64_t>> parts(threads);
  const auto trace = [&](std::size_t k, std::size_t b, std::size_t e) {
    Worker& w = workers[k];
    const auto jumped = [&](std::uint64_t cell) {
      std::uint64_t& c = w.cache[(cell ^ (cell >> 9)) & (kCache - 1)];
      if ((c & ~kHit) != cell) c = cell | (jump(cell) ? kHit : 0);
      return (c & kHit) != 0;
    };
    for (std::size_t i = b; i < e; ++i) {
      const float* p = &scan.ends[3 * i];
      trace_ray_cells(grid, o, octomap::point3d(p[0], p[1], p[2]), scan.levels, jumped,
                      [&w](std::uint64_t c) { w.voxels.insert(c); });
    }
  };
  ray_runs(n, threads, trace, [&](std::size_t k) { parts[k] = workers[k].voxels.sorted(); });
  std::vector<std::uint64_t> fr = std::move(parts[0]);
  for (std::size_t k = 1; k < threads; ++k) {
    fr = merged(fr, parts[k]);
    fr.erase(std::unique(fr.begin(), fr.end()), fr.end());
  }
  return fr;
}

// Calls mark(i) for the cells cells[i] (ascending codes, b to e; cells of `cell_depth`) under
// `node` (at `depth`) that hold an occupied voxel of the tree (inner nodes hold the maximum
// of their children, as updateNode() leaves them).
template <class Mark>
void occupied_cells(const OccupancyTree& t, const OccupancyNode* node, unsigned depth,
                    unsigned cell_depth, const std::uint64_t* b, const std::uint64_t* e,
                    Mark& mark) {
  if (node->getLogOdds() <= 0) return;
  if (depth == cell_depth || !t.nodeHasChildren(node)) {
    for (const std::uint64_t* p = b; p != e; ++p) mark(*p);
    return;
  }
  const unsigned shift = 3 * (cell_depth - 1 - depth);
  while (b != e) {
    const unsigned pos = static_cast<unsigned>((*b >> shift) & 7);
    const std::uint64_t* g = b + 1;
    while (g != e && static_cast<unsigned>((*g >> shift) & 7) == pos) ++g;
    if (t.nodeChildExists(node, pos))
      occupied_cells(t, t.getNodeChild(node, pos), depth + 1, cell_depth, b, g, mark);
    b = g;
  }
}

// The rays of a scan to trace (x y z ends; `cut`: whether a ray was cut at the maximum
// range): every ray to an end point, and of the cut rays one per end voxel (the returns of a
// beam past the range end there together, and neighbouring beams may), the one to the least
// end (by x, then y, then z), so that neither the order nor repeats of the points change the
// map. In the order of the end voxels' codes (which go to `codes`), so that neighbouring
// rays follow each other. Sorted in `threads` parts at once, then merged (rays of one end
// voxel and end point are alike).
std::vector<float> rays_to_trace(const OccupancyTree& grid, const std::vector<float>& ends,
                                 const std::vector<char>& cut, std::vector<std::uint64_t>& codes,
                                 unsigned threads) {
  const std::size_t n = ends.size() / 3;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(n);
  const auto less = [&ends](const auto& a, const auto& b) {
    if (a.first != b.first) return a.first < b.first;
    const float* p = &ends[3 * a.second];
    const float* q = &ends[3 * b.second];
    return std::lexicographical_compare(p, p + 3, q, q + 3);
  };
  const auto part = [&](std::size_t k) { return keyed.begin() + k * n / threads; };
  detail::parallel_for(threads, threads, [&](std::size_t k) {
    for (std::size_t i = k * n / threads; i < (k + 1) * n / threads; ++i) {
      const float* e = &ends[3 * i];
      keyed[i] = {morton(grid.coordToKey(octomap::point3d(e[0], e[1], e[2]))),
                  static_cast<std::uint32_t>(i)};
    }
    std::sort(part(k), part(k + 1), less);
  });
  for (unsigned k = 1; k < threads; ++k) std::inplace_merge(part(0), part(k), part(k + 1), less);
  std::vector<float> out;
  out.reserve(ends.size());
  codes.clear();
  std::uint64_t last_cut = kNoCode;  // the end voxel of the last cut ray taken
  for (const auto& [code, i] : keyed) {
    if (cut[i]) {
      if (code == last_cut) continue;
      last_cut = code;
    }
    out.insert(out.end(), &ends[3 * i], &ends[3 * i + 3]);
    codes.push_back(code);
  }
  return out;
}

// Threads for a scan of n rays: at most `threads`, one per 1024 rays.
unsigned threads_for(std::size_t n, unsigned threads) {
  return static_cast<unsigned>(std::min<std::size_t>(threads, std::max<std::size_t>(n / 1024, 1)));
}

}  // namespace

FastScan trace_fast(const OccupancyTree& grid, const float* xyz, std::size_t n,
                    const float origin[3], double max_range, const FastInsert& opt,
                    const std::string& where, const OccupancyTree* map,
                    const std::function<bool(std::uint64_t)>& blocked) {
  opt.validate();
  const octomap::point3d o(origin[0], origin[1], origin[2]);
  const ScanCheck check(grid, o, max_range, where);
  const unsigned level = opt.coarse_levels;
  FastScan scan;
  scan.levels = level;
  scan.threads = opt.threads;
  std::copy(origin, origin + 3, scan.origin);
  scan.ends.resize(3 * n);
  std::vector<std::uint64_t> occ;
  occ.reserve(n);
  std::vector<char> cut(n);
  for (std::size_t i = 0; i < n; ++i) {
    const octomap::point3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
    check.check(i, p);
    const bool hit = max_range < 0.0 || (p - o).norm() <= max_range;
    const octomap::point3d e = hit ? p : o + (p - o).normalized() * static_cast<float>(max_range);
    for (unsigned a = 0; a < 3; ++a) scan.ends[3 * i + a] = e(a);
    cut[i] = !hit;
    if (hit) occ.push_back(morton(grid.coordToKey(p)));
  }
  detail::sort_unique(occ);
  std::vector<std::uint64_t> end_codes;
  scan.ends = rays_to_trace(grid, scan.ends, cut, end_codes, threads_for(n, opt.threads));
  const std::size_t rays = scan.ends.size() / 3;

  // the rays crossing each cell, a ray per end voxel (a point given twice is one ray), counted
  // on each thread's share of the rays, then summed; and the cells of the end points
  const unsigned nt = threads_for(rays, opt.threads);
  std::vector<CellTally> tallies(nt, CellTally(n / 4 + 1024));
  const auto count = [&](std::size_t k, std::size_t b, std::size_t e) {
    for (std::size_t j = b; j < e; ++j) {
      if (j > 0 && end_codes[j] == end_codes[j - 1]) continue;  // the first of its end voxel
      const float* p = &scan.ends[3 * j];
      walk_cells(grid, o, octomap::point3d(p[0], p[1], p[2]), level,
                 [&](std::uint64_t c) { tallies[k].add_ray(c); });
    }
  };
  ray_runs(rays, nt, count, [&](std::size_t k) { tallies[k].flush(); });
  CellTally& tally = tallies[0];
  for (std::size_t k = 1; k < nt; ++k) tally.absorb(tallies[k]);
  for (std::uint64_t c : occ) tally.add(c >> (3 * level), CellTally::kHasEnd);
  const std::uint32_t min_rays = opt.min_rays;
  const auto is_cleared = [min_rays](std::uint32_t v) {
    return !(v & CellTally::kHasEnd) && v >= min_rays;
  };
  std::vector<std::uint64_t>& cells = scan.cells;
  tally.each([&](std::uint64_t c, std::uint32_t v) {
    if (is_cleared(v)) cells.push_back(c);
  });
  detail::sort_codes(cells);
  if (map != nullptr && map->getRoot() != nullptr && !cells.empty()) {
    // cells where the map holds occupied voxels are not cleared whole (marked as end cells)
    std::vector<std::uint64_t> kept;
    kept.reserve(cells.size());
    auto next = cells.begin();
    const auto mark = [&](std::uint64_t c) {
      while (*next != c) kept.push_back(*next++);
      ++next;
      tally.add(c, CellTally::kHasEnd);
    };
    occupied_cells(*map, map->getRoot(), 0, map->getTreeDepth() - level, cells.data(),
                   cells.data() + cells.size(), mark);
    kept.insert(kept.end(), next, cells.end());
    cells.swap(kept);
  }
  if (blocked) {
    cells.erase(std::remove_if(cells.begin(), cells.end(),
                               [&](std::uint64_t c) {
                                 if (!blocked(c)) return false;
                                 tally.add(c, CellTally::kHasEnd);
                                 return true;
                               }),
                cells.end());
  }
  const std::vector<std::uint64_t> fr =
      free_voxels(grid, scan, nt, [&](std::uint64_t c) { return is_cleared(tally.get(c)); });

  // free voxels less the end points' (occupied wins), the end points, the cleared cells
  std::vector<std::uint64_t> items;
  items.reserve(fr.size() + occ.size());
  auto it = occ.begin();
  for (std::uint64_t m : fr) {
    while (it != occ.end() && *it < m) items.push_back(*it++ | kHit);
    if (it != occ.end() && *it == m) continue;
    items.push_back(m);
  }
  while (it != occ.end()) items.push_back(*it++ | kHit);
  std::vector<std::uint64_t> cell_items(cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i) cell_items[i] = (cells[i] << (3 * level)) | kCell;
  scan.items = merged(items, cell_items);
  return scan;
}

std::vector<std::shared_ptr<const FastScan>> trace_fast_batch(const OccupancyTree& grid,
                                                              const std::vector<FastInput>& in,
                                                              const FastInsert& opt,
                                                              unsigned threads) {
  opt.validate();
  const unsigned shift = 3 * opt.coarse_levels;
  // the cells of each scan's end points (its points checked first)
  std::vector<std::vector<std::uint64_t>> ends(in.size());
  detail::parallel_for(in.size(), threads, [&](std::size_t i) {
    const FastInput& s = in[i];
    if (s.skip) return;
    const octomap::point3d o(s.origin[0], s.origin[1], s.origin[2]);
    const ScanCheck check(grid, o, s.max_range, s.where);
    for (std::size_t j = 0; 3 * j < s.pts.size(); ++j) {
      const octomap::point3d p(s.pts[3 * j], s.pts[3 * j + 1], s.pts[3 * j + 2]);
      check.check(j, p);
      if (s.max_range < 0.0 || (p - o).norm() <= s.max_range)
        ends[i].push_back(morton(grid.coordToKey(p)) >> shift);
    }
    detail::sort_unique(ends[i]);
  });
  // the first scan (1-based) with an end point in each cell
  std::size_t total = 0;
  for (const auto& e : ends) total += e.size();
  CellTally first(total);
  for (std::size_t i = 0; i < in.size(); ++i)
    for (std::uint64_t c : ends[i])
      if (first.get(c) == 0) first.add(c, static_cast<std::uint32_t>(i + 1));
  FastInsert each = opt;  // a lone scan takes the threads, else each scan one
  each.threads = in.size() == 1 ? threads : 1;
  std::vector<std::shared_ptr<const FastScan>> out(in.size());
  detail::parallel_for(in.size(), threads, [&](std::size_t i) {
    const FastInput& s = in[i];
    if (s.skip) return;
    const auto earlier = [&first, i](std::uint64_t c) {
      const std::uint32_t k = first.get(c);
      return k != 0 && k <= i;
    };
    out[i] =
        std::make_shared<const FastScan>(trace_fast(grid, s.pts.data(), s.pts.size() / 3, s.origin,
                                                    s.max_range, each, s.where, s.map, earlier));
  });
  return out;
}

void apply_fast(OccupancyMap& map, const FastScan& scan) {
  if (map.tree().isChangeDetectionEnabled()) {
    throw std::invalid_argument("the fast insert mode does not track changed voxels");
  }
  // the walk merges nodes without moving carried losses aside: settled first
  OccupancyTree& tree = map.settled_tree();
  const unsigned threads = threads_for(scan.ends.size() / 3, scan.threads);
  const std::vector<std::uint64_t> conflicts = detail::apply_fast_items(
      tree, scan.levels, scan.items.data(), scan.items.data() + scan.items.size(), threads);
  if (conflicts.empty()) return;
  // the cells where the map holds occupied voxels get the exact mode's voxels instead
  const std::vector<std::uint64_t> fr =
      free_voxels(tree, scan, threads, [&conflicts](std::uint64_t c) {
        return !std::binary_search(conflicts.begin(), conflicts.end(), c);
      });
  detail::apply_fast_items(tree, scan.levels, fr.data(), fr.data() + fr.size(), threads);
}

template <class Real>
void insert_scan_fast(OccupancyMap& map, const Real* xyz, std::size_t n, const double origin[3],
                      double max_range, const FastInsert& opt) {
  std::vector<float> pts(3 * n);
  for (std::size_t i = 0; i < 3 * n; ++i) pts[i] = static_cast<float>(xyz[i]);
  const float o[3] = {static_cast<float>(origin[0]), static_cast<float>(origin[1]),
                      static_cast<float>(origin[2])};
  apply_fast(map, trace_fast(map.tree(), pts.data(), n, o, max_range, opt, "", &map.tree()));
}

template void insert_scan_fast<float>(OccupancyMap&, const float*, std::size_t, const double*,
                                      double, const FastInsert&);
template void insert_scan_fast<double>(OccupancyMap&, const double*, std::size_t, const double*,
                                       double, const FastInsert&);

void insert_ray_loop(OccupancyMap& map, const float* xyz, std::size_t n, const double origin[3],
                     double max_range) {
  const octomap::point3d o(static_cast<float>(origin[0]), static_cast<float>(origin[1]),
                           static_cast<float>(origin[2]));
  const ScanCheck check(map.tree(), o, max_range);
  for (std::size_t i = 0; i < n; ++i)
    check.check(i, octomap::point3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]));
  OccupancyTree& tree = map.settled_tree();
  for (std::size_t i = 0; i < n; ++i) {
    tree.insertRay(o, octomap::point3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]), max_range,
                   /*lazy_eval=*/false);
  }
}

}  // namespace octofuse
