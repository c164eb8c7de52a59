// octofuse: the per-voxel policy of every tree fusion (new tree, in place, mutual): the rule,
// what a voxel only one map knows becomes, clamping of the stored value and the loss.
#pragma once

#include "octofuse/detail/pair_memo.hpp"
#include "octofuse/rules.hpp"

#include <cmath>
#include <cstdint>
#include <memory>
#include <utility>

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
  /// leaves of the message (the map fused in) as it was: its size as a list of voxels,
  /// counted by the walk that reads it anyway (in-place fusions only; 0 otherwise)
  std::uint64_t msg_leaves = 0;

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
    msg_leaves += o.msg_leaves;
    return *this;
  }
};

/// The fusion of one voxel of map a with the same voxel of map b, rule R and policy U fixed
/// at compile time. Fused values are clamped to the maps' thresholds; the loss is taken
/// against the unclamped naive-Bayes value.
template <Rule R, UnknownPolicy U>
class VoxelFusion {
 public:
  static constexpr Rule kRule = R;
  static constexpr UnknownPolicy kUnknown = U;
  /// both(a, b) and both(b, a) give the same bits (see detail::is_order_free).
  static constexpr bool kOrderFree = detail::is_order_free(R);

  /// `clamp_min`, `clamp_max`: the maps' clamping thresholds in log-odds.
  VoxelFusion(float clamp_min, float clamp_max) : lmin_(clamp_min), lmax_(clamp_max) {
    if constexpr (detail::is_weighted_chernoff(R)) {
      factors_ = std::make_unique<detail::ValueMemo<double>>(detail::chernoff_factor<R>(0.0, 0.0));
    }
    if constexpr (R != Rule::NaiveBayes) memo_ = detail::PairMemo<Stored>(stored(0.0f, 0.0f));
  }

  /// Both maps know the voxel.
  VoxelValue both(float a, float b) {
    if constexpr (R == Rule::NaiveBayes) {
      return compute(a, b);  // cheaper than a look-up
    } else {
      const Stored& s =
          memo_.get(a, b, [this](float x, float y, Stored& out) { out = stored(x, y); });
      return {s.value, s.loss, true};
    }
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
  VoxelValue compute(float a, float b) {
    const Fused f = fuse(a, b);
    const double l = f.l < lmin_ ? lmin_ : (f.l > lmax_ ? lmax_ : f.l);
    return {static_cast<float>(l), static_cast<float>(f.info_loss), true};
  }

  // fuse_logodds<R>(a, b, 0); the weighted Chernoff rules take each map's factor from a memo
  Fused fuse(float a, float b) {
    if constexpr (detail::is_weighted_chernoff(R)) {
      if (std::isfinite(a) && std::isfinite(b) && a != b) {
        if (a > b) std::swap(a, b);  // lower first, as fuse_logodds fuses a pair
        const auto factor = [](float x) { return detail::chernoff_factor<R>(x, 0.0); };
        const double ca = factors_->get(a, factor), cb = factors_->get(b, factor);
        return detail::wep_fuse(a, b, 0.0, detail::weighted_chernoff_weight<R>(a, b, ca, cb));
      }
    }
    return fuse_logodds<R>(a, b, 0.0);
  }

  struct Stored {  // a memo entry: 16 bytes with its key
    float value, loss;
  };
  Stored stored(float a, float b) {
    const VoxelValue v = compute(a, b);
    return {v.value, v.loss};
  }
  double lmin_, lmax_;
  detail::PairMemo<Stored> memo_;                       // not used by naive-bayes
  std::unique_ptr<detail::ValueMemo<double>> factors_;  // the weighted Chernoff rules only
};

/// Calls f(VoxelFusion<R, U>&) for the run-time rule and policy: the one dispatch of every
/// tree walk, made once per walk, outside the voxel loop.
template <class F>
decltype(auto) with_voxel_fusion(Rule rule, UnknownPolicy unknown, float clamp_min, float clamp_max,
                                 F&& f) {
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
