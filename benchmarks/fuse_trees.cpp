// octofuse benchmark: fusing two large overlapping occupancy trees with every rule, beside
// the merge that OctoMap map mergers do today (copy a, expand b, then a.updateNode(key,
// log-odds) for every leaf of b).
//
//   octofuse_bench_fuse_trees [--repeats N] [--scale S] [--layout file|scattered]
//                             [--values sensor|continuous] [--json FILE]
//                             [--map-a FILE --map-b FILE] [--threads N]
//
// With --map-a/--map-b the two maps are read from .ot/.bt files (maps built from bags) instead
// of being generated. Besides the rows below, the program times fuse_into (naive-bayes and
// min-info-loss, on 1 thread and on --threads) against the in-place merge, and every rule's
// fuse_maps together with the freeing of its result (timed separately) against the merge.
//
// Both maps are built deterministically (fixed seeds) by setting node values over two
// overlapping boxes of finest-level voxels: most voxels get a log-odds value that OctoMap's
// sensor model produces after a few hits and misses (spread over the clamping range), and
// some 8^3 and 4^3 blocks are saturated (clamped) free or occupied space, which OctoMap prunes
// to coarse leaves. With "--values continuous" every finest-level voxel instead gets a value
// drawn uniformly from the clamping range (as in maps that were fused before), so that no
// pair of values repeats. Every method runs single-threaded on the same two trees; each is run once
// untimed, then timed `repeats` times (in rounds over all methods), and the median is reported.
//
// Node layout: a tree read from a map file (or a deep copy) has its nodes allocated in
// depth-first order, which a tree walk reads almost sequentially; a tree built in memory by
// insertion has them scattered over the heap. Map mergers merge maps read from files, so the
// default ("file") deep-copies both built maps before timing; "scattered" uses them as built.
//
// Heap: freed memory is kept by the process (glibc M_TRIM_THRESHOLD) and the allocator's free
// lists are consolidated between timed runs, outside the timed region, so every timed run of
// every method allocates from the same warm heap (no page faults, no deferred consolidation
// work from the previous run's frees).
//
// Trees: octofuse's maps keep their nodes in its node pool (octofuse/node_pool.hpp), and
// fuse_maps builds its two trees from these inputs in arenas of their own (octofuse/
// tree_arena.hpp: freeing them gives back slabs); the updateNode merge runs on plain
// octomap::OcTree copies of the same maps (glibc's heap), as map mergers hold them.
//
// Throughput unit ("voxels"): the leaf pairs of the two trees walked together, i.e. the
// leaves of the union of both maps at the finer of the two trees' resolutions at each place
// (a coarse leaf of one map facing finer leaves of the other counts once per finer leaf).
// This count depends on the inputs only and is the same for every method.
#include "octofuse/fuse.hpp"
#include "octofuse/fuse_into.hpp"
#include "octofuse/map_file.hpp"

#include "walk.hpp"

#include <octomap/OcTree.h>

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <malloc.h>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

using namespace octofuse;

namespace {

// ---------------------------------------------------------------------------------------
// Deterministic scene generation

/// splitmix64: small, fast and identical on every platform (unlike std:: distributions).
struct Rng {
  std::uint64_t s;
  std::uint64_t next() {
    std::uint64_t z = (s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double uniform() { return (next() >> 11) * 0x1.0p-53; }
  unsigned below(unsigned n) { return static_cast<unsigned>(uniform() * n); }
};

/// A box of finest-level voxels (keys relative to the tree centre 32768), in 8^3 blocks.
struct Box {
  unsigned x0, x1, y0, y1, z0, z1;  // multiples of 8
  std::uint64_t seed;
};

constexpr unsigned kCentre = 32768;

/// Log-odds after `hits` hits and `misses` misses, accumulated in float with clamping after
/// every update as OctoMap does (hits first, then misses).
float sensor_value(const OccupancyTree& t, unsigned hits, unsigned misses) {
  const float lh = t.getProbHitLog(), lm = t.getProbMissLog();
  const float lo = t.getClampingThresMinLog(), hi = t.getClampingThresMaxLog();
  float v = 0.0f;
  for (unsigned i = 0; i < hits; ++i) v = std::min(hi, v + lh);
  for (unsigned i = 0; i < misses; ++i) v = std::max(lo, v + lm);
  return v;
}

/// One robot's map over `box`: per 8^3 block, 20% are saturated free space (one depth-13
/// leaf after pruning), 10% hold 4^3 sub-blocks that are saturated with probability 1/2
/// (depth-14 leaves; a quarter of them occupied), the rest are finest-level voxels with
/// values from the sensor model: 15% occupied (1-6 hits, 0-2 misses), 85% free
/// (0-1 hits, 1-8 misses).
std::unique_ptr<OccupancyMap> make_map(const Box& box, bool continuous) {
  auto m = std::make_unique<OccupancyMap>(MapParams{});
  OccupancyTree& t = m->settled_tree();
  Rng rng{box.seed};
  const float sat_free = t.getClampingThresMinLog(), sat_occ = t.getClampingThresMaxLog();
  auto fine = [&](unsigned x, unsigned y, unsigned z) {
    float v;
    if (continuous) {
      v = static_cast<float>(sat_free + (sat_occ - sat_free) * rng.uniform());
    } else if (rng.uniform() < 0.15) {
      v = sensor_value(t, 1 + rng.below(6), rng.below(3));
    } else {
      v = sensor_value(t, rng.below(2), 1 + rng.below(8));
    }
    t.setNodeValue(octomap::OcTreeKey(kCentre + x, kCentre + y, kCentre + z), v, true);
  };
  auto uniform = [&](unsigned x, unsigned y, unsigned z, unsigned n, float v) {
    for (unsigned i = 0; i < n; ++i)
      for (unsigned j = 0; j < n; ++j)
        for (unsigned k = 0; k < n; ++k)
          t.setNodeValue(octomap::OcTreeKey(kCentre + x + i, kCentre + y + j, kCentre + z + k),
                         v, true);
  };
  for (unsigned bx = box.x0; bx < box.x1; bx += 8)
    for (unsigned by = box.y0; by < box.y1; by += 8)
      for (unsigned bz = box.z0; bz < box.z1; bz += 8) {
        const double kind = rng.uniform();
        if (kind < 0.2) {
          uniform(bx, by, bz, 8, sat_free);
          continue;
        }
        const bool mixed = kind < 0.3;
        for (unsigned s = 0; s < 8; ++s) {
          const unsigned sx = bx + 4 * (s & 1), sy = by + 2 * (s & 2), sz = bz + (s & 4);
          if (mixed && rng.uniform() < 0.5) {
            uniform(sx, sy, sz, 4, rng.uniform() < 0.25 ? sat_occ : sat_free);
            continue;
          }
          for (unsigned i = 0; i < 4; ++i)
            for (unsigned j = 0; j < 4; ++j)
              for (unsigned k = 0; k < 4; ++k) fine(sx + i, sy + j, sz + k);
        }
      }
  t.updateInnerOccupancy();
  t.prune();
  return m;
}

// ---------------------------------------------------------------------------------------
// Result comparison: every finest-level voxel with its value, sorted by key

using Voxels = std::vector<std::pair<std::uint64_t, float>>;

template <class Tree>
[[maybe_unused]] Voxels expand(const Tree& t) {
  Voxels out;
  for (auto it = t.begin_leafs(), end = t.end_leafs(); it != end; ++it) {
    const unsigned span = 1u << (16 - it.getDepth());
    const octomap::OcTreeKey k = it.getKey();
    const std::uint64_t k0 = k[0] & ~(span - 1), k1 = k[1] & ~(span - 1), k2 = k[2] & ~(span - 1);
    const float v = it->getLogOdds();
    for (unsigned x = 0; x < span; ++x)
      for (unsigned y = 0; y < span; ++y)
        for (unsigned z = 0; z < span; ++z)
          out.emplace_back(((k0 + x) << 32) | ((k1 + y) << 16) | (k2 + z), v);
  }
  std::sort(out.begin(), out.end());
  return out;
}

/// Walks two trees together (a leaf stands for the voxels below it): counts the leaf pairs
/// (`pairs`) and those whose values differ or that only one tree knows (returned).
template <class TreeX, class TreeY>
std::size_t walk_differences(const detail::WalkNode<TreeX>& x, const detail::WalkNode<TreeY>& y,
                             std::size_t& pairs) {
  if (!x.present() && !y.present()) return 0;
  if ((x.leaf || !x.present()) && (y.leaf || !y.present())) {
    ++pairs;
    return !x.present() || !y.present() || x.node->getLogOdds() != y.node->getLogOdds();
  }
  std::size_t d = 0;
  for (unsigned i = 0; i < 8; ++i) d += walk_differences(x.child(i), y.child(i), pairs);
  return d;
}

/// Leaf pairs of two trees walked together (`pairs`) and those known to both (returned).
std::size_t walk_pairs(const detail::WalkNode<OccupancyTree>& x,
                       const detail::WalkNode<OccupancyTree>& y, std::size_t& pairs) {
  if (!x.present() && !y.present()) return 0;
  if ((x.leaf || !x.present()) && (y.leaf || !y.present())) {
    ++pairs;
    return x.present() && y.present();
  }
  std::size_t both = 0;
  for (unsigned i = 0; i < 8; ++i) both += walk_pairs(x.child(i), y.child(i), pairs);
  return both;
}

/// Leaf pairs of two trees that differ (every voxel compared, without expanding the trees).
template <class TreeX, class TreeY>
std::size_t tree_differences(const TreeX& x, const TreeY& y, std::size_t* pairs = nullptr) {
  std::size_t n = 0;
  const std::size_t d = walk_differences(detail::WalkNode<TreeX>::root(x),
                                         detail::WalkNode<TreeY>::root(y), n);
  if (pairs) *pairs = n;
  return d;
}

/// Number of voxels whose values differ (or that only one side has); 0 = same map.
[[maybe_unused]] std::size_t count_differences(const Voxels& x, const Voxels& y) {
  std::size_t i = 0, j = 0, diff = 0;
  while (i < x.size() && j < y.size()) {
    if (x[i].first == y[j].first) {
      if (x[i].second != y[j].second) ++diff;
      ++i, ++j;
    } else if (x[i].first < y[j].first) {
      ++diff, ++i;
    } else {
      ++diff, ++j;
    }
  }
  return diff + (x.size() - i) + (y.size() - j);
}

std::size_t finest_leaves(const OccupancyTree& t) {
  std::size_t n = 0;
  for (auto it = t.begin_leafs(), end = t.end_leafs(); it != end; ++it) n += it.getDepth() == 16;
  return n;
}

// ---------------------------------------------------------------------------------------
// Timing

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// CPU time of the whole process (every thread), seconds.
double cpu_seconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

/// Consolidates glibc's free lists (a large request does) outside the timed region.
void settle_heap() {
  void* p = std::malloc(1 << 16);
  std::free(p);
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// `t` as a plain octomap::OcTree (OctoMap's own nodes, as map mergers hold their maps),
/// through OctoMap's full stream: nodes in depth-first order, as read from a map file.
std::unique_ptr<octomap::OcTree> plain_copy(const OccupancyTree& t) {
  std::stringstream s;
  t.writeData(s);
  auto out = std::make_unique<octomap::OcTree>(t.getResolution());
  out->setProbHit(t.getProbHit());
  out->setProbMiss(t.getProbMiss());
  out->setClampingThresMin(t.getClampingThresMin());
  out->setClampingThresMax(t.getClampingThresMax());
  out->readData(s);
  return out;
}

/// The updateNode merge of OctoMap map mergers, timed in its three steps.
struct MergeTimes {
  double copy_a = 0, expand_b = 0, update = 0, inner = 0;
  double total() const { return copy_a + expand_b + update + inner; }
};

MergeTimes updatenode_merge(const octomap::OcTree& a, const octomap::OcTree& b, bool lazy,
                            std::unique_ptr<octomap::OcTree>* keep) {
  MergeTimes t;
  octomap::OcTree bb(b);  // the merger owns (loads) b; copying it here is not timed
  settle_heap();
  auto t0 = Clock::now();
  auto merged = std::make_unique<octomap::OcTree>(a);
  t.copy_a = seconds_since(t0);
  t0 = Clock::now();
  bb.expand();
  t.expand_b = seconds_since(t0);
  t0 = Clock::now();
  for (auto it = bb.begin_leafs(), end = bb.end_leafs(); it != end; ++it)
    merged->updateNode(it.getKey(), it->getLogOdds(), lazy);
  t.update = seconds_since(t0);
  if (lazy) {
    t0 = Clock::now();
    merged->updateInnerOccupancy();
    t.inner = seconds_since(t0);
  }
  if (keep) *keep = std::move(merged);
  return t;
}

std::string machine_memory() {
  std::ifstream f("/proc/meminfo");
  std::string key;
  double kib = 0;
  while (f >> key) {
    if (key == "MemTotal:") {
      f >> kib;
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.1f GiB", kib / (1024.0 * 1024.0));
      return buf;
    }
    std::string rest;
    std::getline(f, rest);
  }
  return "unknown memory";
}

std::string with_commas(std::size_t n) {
  std::string s = std::to_string(n);
  for (int i = static_cast<int>(s.size()) - 3; i > 0; i -= 3) s.insert(static_cast<std::size_t>(i), ",");
  return s;
}

struct Row {
  std::string name;
  double median_s;
  double voxels_per_s;
  double vs_naive_bayes;  // time / octofuse naive-bayes time
};

}  // namespace

int main(int argc, char** argv) {
  int repeats = 5;
  double scale = 1.0;
  bool file_layout = true, continuous = false;
  unsigned threads = 2;
  std::string json_path, map_a_path, map_b_path;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--repeats" && i + 1 < argc) {
      repeats = std::max(1, std::atoi(argv[++i]));
    } else if (arg == "--scale" && i + 1 < argc) {
      scale = std::atof(argv[++i]);
    } else if (arg == "--layout" && i + 1 < argc && (std::strcmp(argv[i + 1], "file") == 0 ||
                                                      std::strcmp(argv[i + 1], "scattered") == 0)) {
      file_layout = std::strcmp(argv[++i], "file") == 0;
    } else if (arg == "--values" && i + 1 < argc && (std::strcmp(argv[i + 1], "sensor") == 0 ||
                                                      std::strcmp(argv[i + 1], "continuous") == 0)) {
      continuous = std::strcmp(argv[++i], "continuous") == 0;
    } else if (arg == "--json" && i + 1 < argc) {
      json_path = argv[++i];
    } else if (arg == "--map-a" && i + 1 < argc) {
      map_a_path = argv[++i];
    } else if (arg == "--map-b" && i + 1 < argc) {
      map_b_path = argv[++i];
    } else if (arg == "--threads" && i + 1 < argc) {
      threads = static_cast<unsigned>(std::max(1, std::atoi(argv[++i])));
    } else {
      std::fprintf(stderr,
                   "usage: %s [--repeats N] [--scale S] [--layout file|scattered] [--values sensor|continuous]\n"
                   "          [--json FILE] [--map-a FILE --map-b FILE] [--threads N]\n"
                   "  --map-a, --map-b  fuse these .ot/.bt maps instead of the generated ones\n"
                   "  --threads N  threads of the parallel in-place rows (default 2)\n"
                   "  --scale S  multiplies the x extent of both maps (1 = ~1.2 million leaves each)\n",
                   argv[0]);
      return 2;
    }
  }

  // Two robots' maps: boxes of 192 x 128 x 64 finest voxels (9.6 x 6.4 x 3.2 m at 5 cm)
  // overlapping in half of their x extent.
  const unsigned w = std::max(16u, static_cast<unsigned>(std::lround(192 * scale / 16.0)) * 16);
  const Box box_a{0, w, 0, 128, 0, 64, 0x0C70F05Eull};
  const Box box_b{w / 2, w + w / 2, 0, 128, 0, 64, 0xB0B5EEDull};

  mallopt(M_TRIM_THRESHOLD, 1 << 30);  // keep freed memory (see the heap note above)
  std::printf("octofuse tree fusion benchmark\n");
  std::printf("machine: %u hardware threads, %s memory (the benchmarked code is single-threaded)\n",
              std::thread::hardware_concurrency(), machine_memory().c_str());
  std::printf("building the two maps (deterministic)...\n");
  std::fflush(stdout);
  auto t0 = Clock::now();
  const bool from_files = !map_a_path.empty() && !map_b_path.empty();
  std::unique_ptr<OccupancyMap> a, b;
  if (from_files) {
    a = read_map_file(map_a_path);
    b = read_map_file(map_b_path);
  } else {
    a = make_map(box_a, continuous);
    b = make_map(box_b, continuous);
  }
  if (file_layout && !from_files) {  // depth-first node layout, as read from a map file
    a = std::make_unique<OccupancyMap>(*a);
    b = std::make_unique<OccupancyMap>(*b);
  }
  if (from_files)
    std::printf("  read %s and %s in %.1f s\n", map_a_path.c_str(), map_b_path.c_str(), seconds_since(t0));
  else
    std::printf("  built in %.1f s; node layout: %s; values: %s\n", seconds_since(t0),
                file_layout ? "depth-first, as read from a map file" : "scattered, as built by insertion",
                continuous ? "continuous (uniform over the clamping range)"
                           : "sensor model (sums of hit/miss log-odds, clamped)");

  const std::size_t leaves_a = a->num_leaves(), leaves_b = b->num_leaves();
  const std::size_t fine_a = finest_leaves(a->tree()), fine_b = finest_leaves(b->tree());
  std::printf("map a: %s leaves (%.1f%% at the finest level), %s nodes\n",
              with_commas(leaves_a).c_str(), 100.0 * fine_a / leaves_a,
              with_commas(a->num_nodes()).c_str());
  std::printf("map b: %s leaves (%.1f%% at the finest level), %s nodes\n",
              with_commas(leaves_b).c_str(), 100.0 * fine_b / leaves_b,
              with_commas(b->num_nodes()).c_str());

  // the merge runs on OctoMap's own trees, as map mergers hold them
  const std::unique_ptr<octomap::OcTree> plain_a = plain_copy(a->tree()), plain_b = plain_copy(b->tree());

  // --- timing: rounds over all methods (every method once per round, so that a change in
  // the machine's other load during the run affects all methods alike); round -1 is a
  // warm-up and is not timed.
  std::vector<std::vector<double>> rule_times(kNumRules), free_times(kNumRules), whole_cpu(kNumRules);
  // in place: naive-bayes and min-info-loss, on 1 thread and on `threads`
  struct IntoRun {
    Rule rule;
    unsigned threads;
    std::vector<double> times, cpu;
  };
  std::vector<IntoRun> into_runs;
  for (Rule r : {Rule::NaiveBayes, Rule::MinInfoLoss})
    for (unsigned t : {1u, threads}) {
      into_runs.push_back({r, t, {}, {}});
      if (threads == 1) break;
    }
  std::vector<MergeTimes> eager_runs, lazy_runs;
  std::size_t pairs = 0;
  const std::size_t pairs_both = walk_pairs(detail::WalkNode<OccupancyTree>::root(a->tree()),
                                            detail::WalkNode<OccupancyTree>::root(b->tree()), pairs);
  for (int k = -1; k < repeats; ++k) {
    for (int r = 0; r < kNumRules; ++r) {
      settle_heap();
      const double c0 = cpu_seconds();
      t0 = Clock::now();
      FusionResult res = fuse_maps(*a, *b, static_cast<Rule>(r), UnknownPolicy::Copy);
      const double dt = seconds_since(t0);
      t0 = Clock::now();
      res.map.reset();  // freeing the result: part of the cost of every fuse_maps call
      res.info_loss.reset();
      const double df = seconds_since(t0);
      const double dc = cpu_seconds() - c0;
      if (k >= 0) {
        rule_times[r].push_back(dt);
        free_times[r].push_back(df);
        whole_cpu[r].push_back(dc);
      }
    }
    for (IntoRun& run : into_runs) {  // in place, as an agent fuses a received map into its own
      OccupancyMap dst(*a);  // (the copy of a is not timed)
      settle_heap();
      const double c0 = cpu_seconds();
      t0 = Clock::now();
      fuse_into(dst, *b, run.rule, UnknownPolicy::Copy, nullptr, run.threads);
      if (k >= 0) {
        run.times.push_back(seconds_since(t0));
        run.cpu.push_back(cpu_seconds() - c0);
      }
    }
    const MergeTimes eager = updatenode_merge(*plain_a, *plain_b, false, nullptr);
    const MergeTimes lazy = updatenode_merge(*plain_a, *plain_b, true, nullptr);
    if (k >= 0) {
      eager_runs.push_back(eager);
      lazy_runs.push_back(lazy);
    }
    std::printf("  %s %d of %d done (node pool: %.0f MB)\n", k < 0 ? "warm-up round" : "round",
                k + 1, repeats, detail::NodePool::stats().slab_bytes / 1e6);
    std::fflush(stdout);
  }
  std::vector<double> rule_median(kNumRules);
  for (int r = 0; r < kNumRules; ++r) rule_median[r] = median(rule_times[r]);
  auto merge_medians = [](const std::vector<MergeTimes>& runs) {
    auto med = [&](double MergeTimes::*f) {
      std::vector<double> v;
      for (auto& m : runs) v.push_back(m.*f);
      return median(v);
    };
    std::vector<double> tot;
    for (auto& m : runs) tot.push_back(m.total());
    MergeTimes out{med(&MergeTimes::copy_a), med(&MergeTimes::expand_b), med(&MergeTimes::update),
                   med(&MergeTimes::inner)};
    return std::make_pair(median(tot), out);
  };
  const auto [eager_s, eager_parts] = merge_medians(eager_runs);
  const auto [lazy_s, lazy_parts] = merge_medians(lazy_runs);

  // --- same result? (untimed runs) -------------------------------------------------------
  const FusionResult nb_res = fuse_maps(*a, *b, Rule::NaiveBayes, UnknownPolicy::Copy);
  const std::size_t result_leaves_nb = nb_res.map->num_leaves();
  std::unique_ptr<octomap::OcTree> merged_eager, merged_lazy;
  updatenode_merge(*plain_a, *plain_b, false, &merged_eager);
  updatenode_merge(*plain_a, *plain_b, true, &merged_lazy);
  std::size_t result_pairs = 0;
  tree_differences(nb_res.map->tree(), nb_res.map->tree(), &result_pairs);
  // in place on every thread count = the new tree of the same rule, node for node in count
  std::size_t diff_into = 0;
  for (const IntoRun& run : into_runs) {
    OccupancyMap into_res(*a);
    fuse_into(into_res, *b, run.rule, UnknownPolicy::Copy, nullptr, run.threads);
    const FusionResult ref = fuse_maps(*a, *b, run.rule, UnknownPolicy::Copy);
    const std::size_t d = tree_differences(ref.map->tree(), into_res.tree());
    const bool same_size = into_res.num_nodes() == into_res.tree().calcNumNodes();
    std::printf("check: %s in place on %u thread(s) vs fuse_maps: %zu leaf pairs differ; node count %s\n",
                kRuleNames[static_cast<int>(run.rule)], run.threads, d, same_size ? "right" : "WRONG");
    diff_into += d + (same_size ? 0 : 1);
  }
  // The floor of any method that builds a new OctoMap tree of the result's size: OctoMap's own
  // deep copy of the result (one heap allocation per node, as every OcTree has).
  const std::unique_ptr<octomap::OcTree> plain_result = plain_copy(nb_res.map->tree());
  std::vector<double> copy_times;
  for (int k = -1; k < repeats; ++k) {
    settle_heap();
    t0 = Clock::now();
    octomap::OcTree copy(*plain_result);
    const double dt = seconds_since(t0);
    if (k >= 0) copy_times.push_back(dt);
  }
  const double copy_result_s = median(copy_times);
  const std::size_t diff_eager = tree_differences(nb_res.map->tree(), *merged_eager);
  const std::size_t diff_lazy = tree_differences(nb_res.map->tree(), *merged_lazy);

  // --- report --------------------------------------------------------------------------
  const double nb = rule_median[static_cast<int>(Rule::NaiveBayes)];
  const double eager_inplace = eager_parts.expand_b + eager_parts.update;
  std::vector<Row> rows;
  rows.push_back({"OctoMap updateNode merge (lazy_eval=false)", eager_s, pairs / eager_s, eager_s / nb});
  const double into_s = median(into_runs.front().times);
  rows.push_back({"octofuse naive-bayes in place (fuse_into)", into_s, pairs / into_s, into_s / nb});
  rows.push_back({"  same, in place (no copy of a)", eager_inplace, pairs / eager_inplace,
                  eager_inplace / nb});
  rows.push_back({"OctoMap updateNode merge (lazy_eval=true)", lazy_s, pairs / lazy_s, lazy_s / nb});
  for (int r = 0; r < kNumRules; ++r)
    rows.push_back({std::string("octofuse ") + kRuleNames[r], rule_median[r],
                    pairs / rule_median[r], rule_median[r] / nb});

  std::printf("\nvoxels = leaf pairs walked = %s (%s known to both maps, %s to one); "
              "naive-bayes result: %s leaves, %s leaf pairs against itself\n",
              with_commas(pairs).c_str(), with_commas(pairs_both).c_str(),
              with_commas(pairs - pairs_both).c_str(), with_commas(result_leaves_nb).c_str(),
              with_commas(result_pairs).c_str());
  std::printf("median of %d runs each\n\n", repeats);
  std::printf("%-46s %10s %14s %16s\n", "method", "median s", "voxels/s", "time / octofuse NB");
  for (const Row& r : rows)
    std::printf("%-46s %10.3f %14s %16.2f\n", r.name.c_str(), r.median_s,
                with_commas(static_cast<std::size_t>(r.voxels_per_s)).c_str(), r.vs_naive_bayes);
  std::printf("\nupdateNode merge (lazy_eval=false) steps: copy a %.3f s, expand b %.3f s, "
              "updateNode %.3f s\n",
              eager_parts.copy_a, eager_parts.expand_b, eager_parts.update);
  std::printf("updateNode merge (lazy_eval=true) steps: copy a %.3f s, expand b %.3f s, "
              "updateNode %.3f s, updateInnerOccupancy %.3f s\n",
              lazy_parts.copy_a, lazy_parts.expand_b, lazy_parts.update, lazy_parts.inner);
  std::printf("octofuse naive-bayes vs updateNode merge (lazy_eval=false): %.1fx the throughput "
              "(%.1fx against the in-place merge)\n",
              eager_s / nb, eager_inplace / nb);
  std::printf("octofuse naive-bayes vs updateNode merge (lazy_eval=true):  %.1fx the throughput\n",
              lazy_s / nb);
  std::printf("allocation floor: OctoMap's deep copy of the naive-bayes result (%s nodes) takes "
              "%.3f s = %.2f x octofuse naive-bayes; the updateNode merge takes %.1f x that copy\n",
              with_commas(nb_res.map->num_nodes()).c_str(), copy_result_s, copy_result_s / nb,
              eager_s / copy_result_s);
  std::printf("same map as octofuse naive-bayes (every voxel compared, %s leaf pairs): "
              "updateNode merge %s, lazy merge %s\n",
              with_commas(result_pairs).c_str(),
              diff_eager == 0 ? "yes" : ("NO, " + std::to_string(diff_eager) + " differ").c_str(),
              diff_lazy == 0 ? "yes" : ("NO, " + std::to_string(diff_lazy) + " differ").c_str());

  if (!json_path.empty()) {
    std::ofstream j(json_path);
    j << "{\n  \"layout\": \"" << (file_layout ? "file" : "scattered") << "\",\n  \"values\": \""
      << (continuous ? "continuous" : "sensor") << "\",\n  \"hardware_threads\": " << std::thread::hardware_concurrency()
      << ",\n  \"memory\": \"" << machine_memory() << "\",\n  \"repeats\": " << repeats
      << ",\n  \"leaves_a\": " << leaves_a << ",\n  \"leaves_b\": " << leaves_b
      << ",\n  \"finest_leaves_a\": " << fine_a << ",\n  \"finest_leaves_b\": " << fine_b
      << ",\n  \"voxels\": " << pairs << ",\n  \"voxels_both\": " << pairs_both
      << ",\n  \"result_leaf_pairs\": " << result_pairs
      << ",\n  \"same_result_eager\": " << (diff_eager == 0 ? "true" : "false")
      << ",\n  \"same_result_lazy\": " << (diff_lazy == 0 ? "true" : "false")
      << ",\n  \"copy_result_s\": " << copy_result_s << ",\n  \"result_nodes\": " << nb_res.map->num_nodes()
      << ",\n  \"merge_steps_eager\": {\"copy_a\": " << eager_parts.copy_a
      << ", \"expand_b\": " << eager_parts.expand_b << ", \"update\": " << eager_parts.update
      << "},\n  \"merge_in_place_s\": " << eager_inplace << ",\n  \"in_place\": [";
    for (std::size_t i = 0; i < into_runs.size(); ++i)
      j << (i ? ", " : "") << "{\"rule\": \"" << kRuleNames[static_cast<int>(into_runs[i].rule)]
        << "\", \"threads\": " << into_runs[i].threads << ", \"median_s\": " << median(into_runs[i].times)
        << ", \"cpu_s\": " << median(into_runs[i].cpu) << "}";
    j << "],\n  \"whole_cost\": [";
    for (int r = 0; r < kNumRules; ++r)
      j << (r ? ", " : "") << "{\"rule\": \"" << kRuleNames[r] << "\", \"fuse_s\": " << rule_median[r]
        << ", \"free_s\": " << median(free_times[r]) << ", \"cpu_s\": " << median(whole_cpu[r]) << "}";
    j << "],\n  \"rows\": [\n";
    for (std::size_t i = 0; i < rows.size(); ++i)
      j << "    {\"name\": \"" << rows[i].name << "\", \"median_s\": " << rows[i].median_s
        << ", \"voxels_per_s\": " << rows[i].voxels_per_s
        << ", \"vs_naive_bayes\": " << rows[i].vs_naive_bayes << "}"
        << (i + 1 < rows.size() ? ",\n" : "\n");
    j << "  ]\n}\n";
  }
  std::printf("octofuse naive-bayes in place (fuse_into) vs updateNode merge in place: %.1fx the "
              "throughput; same result: %s\n", eager_inplace / into_s,
              diff_into == 0 ? "yes" : ("NO, " + std::to_string(diff_into) + " differ").c_str());
  std::printf("\nin place against the in-place updateNode merge (expand b + updateNode: %.3f s)\n",
              eager_inplace);
  for (const IntoRun& run : into_runs) {
    const double t = median(run.times);
    std::printf("  octofuse %-22s fuse_into, %u thread(s): %.3f s (CPU %.3f s)  %5.1fx\n",
                kRuleNames[static_cast<int>(run.rule)], run.threads, t, median(run.cpu),
                eager_inplace / t);
  }
  std::printf("\nnew tree with its whole cost (fuse_maps, then freeing the result) against the "
              "updateNode merge (copy a + expand b + updateNode: %.3f s), all on the caller's "
              "thread (CPU time of the process in brackets)\n", eager_s);
  for (int r = 0; r < kNumRules; ++r) {
    const double f = median(free_times[r]);
    std::printf("  octofuse %-28s fuse %.3f s + free %.3f s = %.3f s (CPU %.3f s)  %5.1fx\n",
                kRuleNames[r], rule_median[r], f, rule_median[r] + f, median(whole_cpu[r]),
                eager_s / (rule_median[r] + f));
  }

  return diff_eager == 0 && diff_lazy == 0 && diff_into == 0 ? 0 : 1;
}
