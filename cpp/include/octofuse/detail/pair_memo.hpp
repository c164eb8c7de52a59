// octofuse: memos of a function of one or two stored float values (direct mapped, exact).
#pragma once

#include <cstdint>
#include <cstring>
#include <memory>

namespace octofuse::detail {

/// The last results of a function of two stored values for a few thousand pairs (direct
/// mapped). The values of a map built from scans are sums of a few sensor-model increments,
/// clamped, so the same pairs come back again and again; a hit costs a few ns where a rule or
/// a KL divergence costs 30-300 ns. The entries are exact results for their key (the pair of
/// float bit patterns), so a hit returns exactly what computing would.
template <class T>
class PairMemo {
 public:
  static constexpr unsigned kBits = 12;

  /// No table: for a function that is cheaper than a look-up (get() must not be called).
  PairMemo() = default;

  /// Every entry starts as the result `at_zero` for the pair (+0, +0).
  explicit PairMemo(const T& at_zero) : entries_(new Entry[1u << kBits]) {
    for (unsigned i = 0; i < (1u << kBits); ++i) entries_[i] = {key_of(0.0f, 0.0f), at_zero};
  }

  /// f(a, b), computed by `compute(a, b, T&)` unless the pair's slot holds it.
  template <class Compute>
  const T& get(float a, float b, Compute&& compute) {
    const std::uint64_t key = key_of(a, b);
    Entry& e = entries_[(key * 0x9E3779B97F4A7C15ull) >> (64 - kBits)];
    if (e.key != key) {
      e.key = key;
      compute(a, b, e.value);
    }
    return e.value;
  }

 private:
  struct Entry {
    std::uint64_t key;
    T value;
  };
  static std::uint64_t key_of(float a, float b) {
    std::uint32_t ua, ub;
    std::memcpy(&ua, &a, sizeof ua);
    std::memcpy(&ub, &b, sizeof ub);
    return (std::uint64_t{ua} << 32) | ub;
  }
  std::unique_ptr<Entry[]> entries_;
};

/// The same for a function of one stored value (e.g. a rule's factor of one map's value,
/// which repeats far more often than the pairs).
template <class T>
class ValueMemo {
 public:
  static constexpr unsigned kBits = 12;

  /// Every entry starts as the result `at_zero` for +0.
  explicit ValueMemo(const T& at_zero) : entries_(new Entry[1u << kBits]) {
    for (unsigned i = 0; i < (1u << kBits); ++i) entries_[i] = {0u, at_zero};
  }

  /// f(a), computed by `compute(a)` unless a's slot holds it.
  template <class Compute>
  const T& get(float a, Compute&& compute) {
    std::uint32_t key;
    std::memcpy(&key, &a, sizeof key);
    Entry& e = entries_[(key * 0x9E3779B1u) >> (32 - kBits)];
    if (e.key != key) {
      e.key = key;
      e.value = compute(a);
    }
    return e.value;
  }

 private:
  struct Entry {
    std::uint32_t key;
    T value;
  };
  std::unique_ptr<Entry[]> entries_;
};

}  // namespace octofuse::detail
