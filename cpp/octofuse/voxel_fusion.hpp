// octofuse: the per-voxel policy of every tree fusion (new tree, in place, mutual): the rule,
// what a voxel only one map knows becomes, clamping of the stored value and the loss.
#pragma once

#include "octofuse/rules.hpp"

#include <cstdint>
#include <cstring>
#include <memory>

namespace octofuse {

/// What to do with a voxel that only one of the two maps knows.
enum class UnknownPolicy : std::uint8_t {
  Copy = 0,   ///< keep the known value (no common information; exact fusion)
  Prior = 1,  ///< treat the missing value as the prior (p = 0.5, log-odds 0) and apply the rule
};

/// Number of values of `UnknownPolicy`.
inline constexpr int kNumUnknownPolicies = 2;

/// Names of the unknown-voxel policies, indexed by `UnknownPolicy`.
inline constexpr const char* kUnknownPolicyNames[kNumUnknownPolicies] = {"copy", "prior"};

/// One voxel of a fused map.
struct VoxelValue {
  float value;  ///< stored log-odds: clamped when fused, as it was when copied
  float loss;   ///< information loss KL(p_NB || p_fused) (0 when copied)
  bool fused;   ///< false when copied from the only map that knows the voxel
};

/// Finest voxels under a node at `depth` of an OctoMap tree (depth 16 = one finest voxel).
inline constexpr std::uint64_t voxels_at_depth(unsigned depth) {
  return std::uint64_t{1} << (3 * (16 - depth));
}

/// What a tree fusion did, in finest voxels: a leaf at depth d counts for the 8^(16-d)
/// voxels it stands for.
struct FusionCounts {
  std::uint64_t fused = 0;   ///< voxels the rule was applied to
  std::uint64_t copied = 0;  ///< voxels known to one map only and copied (policy Copy)
  double loss_sum = 0.0;     ///< information loss summed over the fused voxels (nats)

  /// Counts the voxels of one leaf at `depth` that got `v`.
  void add(const VoxelValue& v, unsigned depth) {
    const std::uint64_t n = voxels_at_depth(depth);
    if (v.fused) {
      fused += n;
      loss_sum += static_cast<double>(v.loss) * static_cast<double>(n);
    } else {
      copied += n;
    }
  }

  FusionCounts& operator+=(const FusionCounts& o) {
    fused += o.fused;
    copied += o.copied;
    loss_sum += o.loss_sum;
    return *this;
  }
};

namespace detail {

/// The last results of the rule for a few thousand pairs of stored values (direct mapped).
/// The values of a map built from scans are sums of a few sensor-model increments, clamped,
/// so the same pairs come back again and again; a hit costs a few ns where the rule costs
/// 30-300 ns. The entries are exact results of the rule for their key (the pair of float
/// bit patterns), so a hit returns exactly what computing would.
struct RuleMemo {
  static constexpr unsigned kBits = 12;
  struct Entry {
    std::uint64_t key;
    float value, loss;
  };
  std::unique_ptr<Entry[]> entries;

  static std::uint64_t key_of(float a, float b) {
    std::uint32_t ua, ub;
    std::memcpy(&ua, &a, sizeof ua);
    std::memcpy(&ub, &b, sizeof ub);
    return (std::uint64_t{ua} << 32) | ub;
  }
  Entry& slot(float a, float b) {
    return entries[(key_of(a, b) * 0x9E3779B97F4A7C15ull) >> (64 - kBits)];
  }
  /// Fills every entry with the (exact) result for the pair whose key is 0: (+0, +0).
  void init(float value, float loss) {
    entries.reset(new Entry[1u << kBits]);
    for (unsigned i = 0; i < (1u << kBits); ++i) entries[i] = {key_of(0.0f, 0.0f), value, loss};
  }
};

}  // namespace detail

/// The fusion of one voxel of map a with the same voxel of map b, rule R and policy U fixed
/// at compile time. Fused values are clamped to the maps' thresholds; the loss is taken
/// against the unclamped naive-Bayes value.
template <Rule R, UnknownPolicy U>
class VoxelFusion {
 public:
  static constexpr Rule kRule = R;
  static constexpr UnknownPolicy kUnknown = U;

  /// `clamp_min`, `clamp_max`: the maps' clamping thresholds in log-odds.
  VoxelFusion(float clamp_min, float clamp_max) : lmin_(clamp_min), lmax_(clamp_max) {
    if constexpr (R != Rule::NaiveBayes) {
      float v, l;
      compute(0.0f, 0.0f, v, l);
      memo_.init(v, l);
    }
  }

  /// Both maps know the voxel.
  VoxelValue both(float a, float b) {
    VoxelValue out{0.0f, 0.0f, true};
    if constexpr (R == Rule::NaiveBayes) {
      compute(a, b, out.value, out.loss);  // cheaper than a look-up
    } else {
      detail::RuleMemo::Entry& e = memo_.slot(a, b);
      const std::uint64_t key = detail::RuleMemo::key_of(a, b);
      if (e.key != key) {
        e.key = key;
        compute(a, b, e.value, e.loss);
      }
      out.value = e.value;
      out.loss = e.loss;
    }
    return out;
  }

  /// Only map a knows the voxel.
  VoxelValue only_a(float a) {
    if constexpr (U == UnknownPolicy::Copy) {
      return {a, 0.0f, false};
    } else {
      return both(a, 0.0f);
    }
  }

  /// Only map b knows the voxel.
  VoxelValue only_b(float b) {
    if constexpr (U == UnknownPolicy::Copy) {
      return {b, 0.0f, false};
    } else {
      return both(0.0f, b);
    }
  }

 private:
  void compute(float a, float b, float& value, float& loss) const {
    const Fused f = fuse_logodds<R>(a, b, 0.0);
    const double l = f.l < lmin_ ? lmin_ : (f.l > lmax_ ? lmax_ : f.l);
    value = static_cast<float>(l);
    loss = static_cast<float>(f.info_loss);
  }

  double lmin_, lmax_;
  detail::RuleMemo memo_;
};

/// Calls f(VoxelFusion<R, U>&) for the run-time rule and policy: the one dispatch of every
/// tree walk, made once per walk, outside the voxel loop.
template <class F>
decltype(auto) with_voxel_fusion(Rule rule, UnknownPolicy unknown, float clamp_min,
                                 float clamp_max, F&& f) {
  return with_rule(rule, [&](auto r) -> decltype(auto) {
    constexpr Rule R = decltype(r)::value;
    if (unknown == UnknownPolicy::Prior) {
      VoxelFusion<R, UnknownPolicy::Prior> vf(clamp_min, clamp_max);
      return f(vf);
    }
    VoxelFusion<R, UnknownPolicy::Copy> vf(clamp_min, clamp_max);
    return f(vf);
  });
}

}  // namespace octofuse
