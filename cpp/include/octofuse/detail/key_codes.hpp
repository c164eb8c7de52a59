// octofuse: voxel keys as Morton codes, and a set of them, for the batched scan update.
#pragma once

// the standard headers first: OcTreeKey.h uses uint16_t, size_t and std::vector without
// including them
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <iterator>
#include <vector>

#include <octomap/OcTreeKey.h>

namespace octofuse::detail {

// Morton code of a key: bit i of key[0] (x) goes to bit 3i, of key[1] (y) to 3i+1, of key[2]
// (z) to 3i+2. At every level the three bits are OctoMap's child index (computeChildIdx), so
// ascending codes are the tree's depth-first order and the keys under one node are contiguous.
constexpr std::uint64_t spread3(std::uint64_t v) {
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
// No voxel: all 64 bits set, which no 48-bit code is.
constexpr std::uint64_t kNoCode = ~std::uint64_t{0};

// Sorts Morton codes (at most 48 bits): a counting pass per byte, least significant first,
// skipping the bytes that every code shares. For the thousands of distinct codes of a scan
// this is faster than std::sort's comparisons, which a branch predictor cannot guess.
inline void sort_codes(std::vector<std::uint64_t>& v) {
  const std::size_t n = v.size();
  if (n < 256) {
    std::sort(v.begin(), v.end());
    return;
  }
  constexpr unsigned kBytes = 6;
  std::vector<std::size_t> count(kBytes * 256, 0);
  for (std::uint64_t c : v)
    for (unsigned d = 0; d < kBytes; ++d) ++count[256 * d + ((c >> (8 * d)) & 255)];
  std::vector<std::uint64_t> other(n);
  std::uint64_t* src = v.data();
  std::uint64_t* dst = other.data();
  for (unsigned d = 0; d < kBytes; ++d) {
    std::size_t* slot = &count[256 * d];
    if (slot[(src[0] >> (8 * d)) & 255] == n) continue;  // every code has this byte
    std::size_t start = 0;
    for (unsigned b = 0; b < 256; ++b) {
      const std::size_t k = slot[b];
      slot[b] = start;
      start += k;
    }
    for (std::size_t i = 0; i < n; ++i) dst[slot[(src[i] >> (8 * d)) & 255]++] = src[i];
    std::swap(src, dst);
  }
  if (src != v.data()) std::copy(src, src + n, v.data());
}

inline void sort_unique(std::vector<std::uint64_t>& v) {
  sort_codes(v);
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
    sort_codes(out);
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

}  // namespace octofuse::detail
