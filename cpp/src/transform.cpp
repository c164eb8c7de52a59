// octofuse: rigid transforms and resampling of occupancy maps (forward splatting).
#include "octofuse/transform.hpp"

#include "octofuse/detail/text.hpp"
#include "octofuse/detail/tree_access.hpp"

#include "prune_or_max.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace octofuse {

namespace {

/// Votes of one target voxel.
struct Cell {
  std::uint64_t key = kEmpty;  ///< packed key (k0 | k1 << 16 | k2 << 32), kEmpty if unused
  double sum = 0.0;            ///< sum of votes
  float max = 0.0f;            ///< largest vote
  std::uint32_t n = 0;         ///< number of votes
  float nearest = 0.0f;        ///< the vote of the cell nearest to the voxel's centre
  double nearest_d2 = 0.0;     ///< that distance, in half cell edges (Chebyshev, source axes)
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};
};

/// Open-addressing hash table of target voxels (linear probing, power-of-two capacity).
class VoteTable {
 public:
  explicit VoteTable(std::size_t expected) {
    std::size_t cap = 1024;
    while (cap < 2 * expected) cap *= 2;
    cells_.resize(cap);
    mask_ = cap - 1;
  }

  void vote(std::uint64_t key, float v, std::uint32_t count, double d2) {
    Cell* c = &find(key);
    if (c->key == Cell::kEmpty) {
      c->key = key;
      c->max = c->nearest = v;
      c->nearest_d2 = d2;
      if (2 * ++used_ > cells_.size()) {
        grow();
        c = &find(key);
      }
    } else {
      if (v > c->max) c->max = v;
      if (d2 < c->nearest_d2) {
        c->nearest = v;
        c->nearest_d2 = d2;
      }
    }
    c->sum += static_cast<double>(v) * count;
    c->n += count;
  }

  std::vector<Cell>& cells() { return cells_; }
  std::size_t size() const { return used_; }

 private:
  static std::uint64_t mix(std::uint64_t k) {
    k ^= k >> 33;  // MurmurHash3's 64-bit finaliser
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    k *= 0xc4ceb9fe1a85ec53ULL;
    k ^= k >> 33;
    return k;
  }

  Cell& find(std::uint64_t key) {
    std::size_t i = mix(key) & mask_;
    while (cells_[i].key != Cell::kEmpty && cells_[i].key != key) i = (i + 1) & mask_;
    return cells_[i];
  }

  void grow() {
    std::vector<Cell> old;
    old.swap(cells_);
    cells_.resize(old.size() * 2);
    mask_ = cells_.size() - 1;
    for (const Cell& c : old) {
      if (c.key == Cell::kEmpty) continue;
      find(c.key) = c;
    }
  }

  std::vector<Cell> cells_;
  std::size_t mask_ = 0;
  std::size_t used_ = 0;
};

/// True if T maps the grid of voxel size `res` onto itself (a signed permutation of the axes and
/// a translation by whole voxels), for source and target of the same resolution.
/// Most samples one resampling may take (about a minute of work).
constexpr double kMaxSamples = 2e9;

bool grid_preserving(const double T[16], double res) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const double a = std::fabs(T[4 * r + c]);
      if (a > 1e-9 && std::fabs(a - 1.0) > 1e-9) return false;
    }
    const double t = T[4 * r + 3] / res;
    if (std::fabs(t - std::round(t)) > 1e-6) return false;
  }
  return true;
}

/// Votes of one source leaf, merged per target voxel before they go to the table (the cells
/// of a leaf land in few target voxels).
class LeafVotes {
 public:
  explicit LeafVotes(VoteTable& table) : table_(table) {}
  /// A vote in voxel `key` from a cell at distance `d2` of the voxel's centre (see Cell).
  void add(std::uint64_t key, double d2) {
    for (unsigned i = 0; i < n_; ++i) {
      if (keys_[i] == key) {
        ++counts_[i];
        d2_[i] = std::min(d2_[i], d2);
        return;
      }
    }
    if (n_ == kSize) flush();
    keys_[n_] = key;
    d2_[n_] = d2;
    counts_[n_++] = 1;
  }
  void flush() {
    for (unsigned i = 0; i < n_; ++i) table_.vote(keys_[i], value_, counts_[i], d2_[i]);
    n_ = 0;
  }
  void start(float value) {
    flush();
    value_ = value;
  }

 private:
  static constexpr unsigned kSize = 16;
  VoteTable& table_;
  std::uint64_t keys_[kSize];
  std::uint32_t counts_[kSize];
  double d2_[kSize];
  unsigned n_ = 0;
  float value_ = 0.0f;
};

/// Spreads the 16 bits of x to every third bit.
std::uint64_t spread3(std::uint64_t x) {
  x &= 0xffff;
  x = (x | (x << 16)) & 0x0000ff0000ffULL;
  x = (x | (x << 8)) & 0x00f00f00f00fULL;
  x = (x | (x << 4)) & 0x0c30c30c30c3ULL;
  x = (x | (x << 2)) & 0x249249249249ULL;
  return x;
}

/// Morton code of a packed key in OctoMap's child order (bit 0: k0, bit 1: k1, bit 2: k2 at
/// each level, the root's level highest): sorted codes list the voxels depth first.
std::uint64_t morton(std::uint64_t packed) {
  return spread3(packed) | (spread3(packed >> 16) << 1) | (spread3(packed >> 32) << 2);
}

/// Child index (0..7) of a Morton code at tree depth d (0 = root's children).
unsigned child_at(std::uint64_t code, unsigned depth) {
  return static_cast<unsigned>((code >> (3 * (15 - depth))) & 7u);
}

struct Voxel {
  std::uint64_t code;
  float value;
};

/// Builds the subtree of `node` (at `depth`) from the voxels [lo, hi) sorted by Morton code;
/// inner nodes get the largest child value (OctoMap's rule) and eight equal leaf children are
/// pruned. Returns true if the node ended as a leaf.
bool build(OccupancyTree& tree, OccupancyNode* node, unsigned depth, const Voxel* lo,
           const Voxel* hi) {
  if (depth == 16) {
    node->setLogOdds(lo->value);
    return true;
  }
  const Voxel* p = lo;
  while (p != hi) {
    const unsigned c = child_at(p->code, depth);
    const Voxel* q = p;
    while (q != hi && child_at(q->code, depth) == c) ++q;
    build(tree, tree.createNodeChild(node, c), depth + 1, p, q);
    p = q;
  }
  return detail::prune_or_max(tree, node);
}

}  // namespace

std::unique_ptr<OccupancyMap> transform_map(const OccupancyMap& src, const double T[16],
                                            double resolution, Resampling resampling,
                                            TransformStats* stats) {
  MapParams params = src.params();
  const double src_res = params.resolution;
  params.resolution = resolution;
  params.validate();
  auto out = std::make_unique<OccupancyMap>(params);
  OccupancyTree& dst = out->settled_tree();
  const OccupancyTree& tree = src.tree();
  TransformStats st;
  st.source_leaves = tree.getNumLeafNodes();
  if (st.source_leaves == 0) {
    if (stats) *stats = st;
    return out;
  }

  const bool same_res = std::fabs(src_res - resolution) <= 1e-9 * resolution;
  const double h0 = (same_res && grid_preserving(T, resolution))
                        ? resolution
                        : std::min(src_res, resolution) / 2.0;
  const double inv = 1.0 / resolution;
  const double lim = 32768.0;  // keys are 16-bit, centred on 32768

  // refuse work that cannot finish: every sample is a hash-table update
  double planned = 0.0;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double n = std::max(1.0, std::ceil(it.getSize() / h0 - 1e-9));
    planned += n * n * n;
  }
  if (planned > kMaxSamples) {
    throw std::invalid_argument("resampling to " + detail::shortest(resolution) + " m needs " +
                                detail::shortest(std::round(planned / 1e8) / 10) +
                                " billion samples (at most " + detail::shortest(kMaxSamples / 1e9) +
                                " billion): choose a coarser resolution");
  }

  // expected target voxels: about the source's finest voxels, rescaled
  VoteTable votes(st.source_leaves);
  LeafVotes leaf(votes);
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double s = it.getSize();
    const float v = it->getLogOdds();
    const octomap::point3d c = it.getCoordinate();
    leaf.start(v);
    const long n = std::max(1L, static_cast<long>(std::ceil(s / h0 - 1e-9)));
    const double h = s / static_cast<double>(n);
    const double half = h / 2;
    const double x0 = c.x() - s / 2 + h / 2, y0 = c.y() - s / 2 + h / 2, z0 = c.z() - s / 2 + h / 2;
    for (long i = 0; i < n; ++i) {
      const double x = x0 + static_cast<double>(i) * h;
      for (long j = 0; j < n; ++j) {
        const double y = y0 + static_cast<double>(j) * h;
        // the row of cells along z: p = base + k h (T's third column)
        const double bx = T[0] * x + T[1] * y + T[3], by = T[4] * x + T[5] * y + T[7],
                     bz = T[8] * x + T[9] * y + T[11];
        for (long k = 0; k < n; ++k) {
          const double z = z0 + static_cast<double>(k) * h;
          const double p[3] = {bx + T[2] * z, by + T[6] * z, bz + T[10] * z};
          std::uint64_t packed = 0;
          double off[3];  // from the target voxel's centre to the sample
          for (int a = 0; a < 3; ++a) {
            const double f = std::floor(p[a] * inv);
            off[a] = p[a] - (f + 0.5) * resolution;
            if (!(f >= -lim && f < lim)) {
              throw std::invalid_argument(
                  "the transformed map reaches " + std::string(1, "xyz"[a]) + " = " +
                  detail::shortest(p[a]) + " m, outside the octree's range of +-" +
                  detail::shortest(lim * resolution) + " m at resolution " +
                  detail::shortest(resolution) + " m");
            }
            packed |= static_cast<std::uint64_t>(static_cast<long>(f) + 32768) << (16 * a);
          }
          // where the voxel's centre lies in the sample's cell (source axes, in half edges):
          // at most 1 if the cell contains the pre-image of the centre
          double cell = 0.0;
          for (int a = 0; a < 3; ++a) {
            const double o = T[a] * off[0] + T[4 + a] * off[1] + T[8 + a] * off[2];
            cell = std::max(cell, std::fabs(o));
          }
          leaf.add(packed, cell / half);
        }
      }
    }
    st.samples += static_cast<std::size_t>(n * n * n);
  }

  leaf.flush();

  // the target tree, built depth first from the voxels in Morton order
  std::vector<Voxel> voxels;
  voxels.reserve(votes.size());
  for (const Cell& c : votes.cells()) {
    if (c.key == Cell::kEmpty) continue;
    // point sampling: a voxel whose centre's pre-image is in unknown space stays unknown
    if (resampling == Resampling::Nearest && c.nearest_d2 > 1.0 + 1e-9) continue;
    const float v = resampling == Resampling::Nearest ? c.nearest
                    : c.max > 0.0f                    ? c.max
                                                      : static_cast<float>(c.sum / c.n);
    voxels.push_back({morton(c.key), v});
  }
  std::vector<Cell>().swap(votes.cells());
  std::sort(voxels.begin(), voxels.end(),
            [](const Voxel& a, const Voxel& b) { return a.code < b.code; });
  st.target_voxels = voxels.size();
  OccupancyNode* root = detail::TreeAccess<OccupancyTree>::ensure_root(dst);
  build(dst, root, 0, voxels.data(), voxels.data() + voxels.size());
  detail::TreeAccess<OccupancyTree>::mark_changed(dst);
  if (stats) *stats = st;
  return out;
}

}  // namespace octofuse
