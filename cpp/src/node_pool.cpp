// octofuse: BlockPool, the shared side (slabs with free-block bitmaps).
#include "octofuse/node_pool.hpp"

#include <cstdint>
#include <cstdlib>
#include <mutex>
#include <new>
#include <vector>

namespace octofuse::detail {

namespace {

// The start of every slab of a pool: its free blocks (bit set = free) and where to look
// first. The header occupies the slab's first blocks, which are never free.
template <std::size_t kSize>
struct SlabHeader {
  static constexpr std::size_t kBlocks = kSlabBytes / kSize;
  static constexpr std::size_t kWords = kBlocks / 64;
  TreeArena* arena;        // always null (arena_of())
  std::size_t index;       // in Shared::slabs
  std::size_t free;        // free blocks
  std::size_t first_word;  // no free block before this bitmap word
  std::uint64_t bits[kWords];

  static constexpr std::size_t kHeaderBlocks =
      (sizeof(TreeArena*) + sizeof(std::size_t) * 3 + 8 * kWords + kSize - 1) / kSize;
  static constexpr std::size_t kUsable = kBlocks - kHeaderBlocks;

  static SlabHeader* of(const void* p) {
    return reinterpret_cast<SlabHeader*>(reinterpret_cast<std::uintptr_t>(p) & ~(kSlabBytes - 1));
  }
};

template <std::size_t kSize>
struct Shared {
  std::mutex mutex;
  std::vector<SlabHeader<kSize>*> slabs;
  std::size_t cursor = 0;  // no free block in slabs before this one
  std::size_t free_blocks = 0;
};

// Never destroyed: threads return their lists at exit, the main thread's after static
// destructors may have run.
template <std::size_t kSize>
Shared<kSize>& shared() {
  static Shared<kSize>* s = new Shared<kSize>;
  return *s;
}

template <std::size_t kSize>
void new_slab(Shared<kSize>& s) {
  using H = SlabHeader<kSize>;
  s.slabs.reserve(s.slabs.size() + 1);  // may throw before anything changes
  auto* h = static_cast<H*>(take_slab());
  h->arena = nullptr;
  h->index = s.slabs.size();
  h->free = H::kUsable;
  h->first_word = 0;
  for (std::size_t w = 0; w < H::kWords; ++w) h->bits[w] = ~std::uint64_t{0};
  for (std::size_t b = 0; b < H::kHeaderBlocks; ++b)
    h->bits[b / 64] &= ~(std::uint64_t{1} << (b % 64));
  s.slabs.push_back(h);
  s.free_blocks += H::kUsable;
}

struct SpareSlabs {
  std::mutex mutex;
  std::vector<void*> slabs;
};

SpareSlabs& spare() {  // never destroyed, like the pools
  static SpareSlabs* s = new SpareSlabs;
  return *s;
}

}  // namespace

void* take_slab() {
  {
    SpareSlabs& s = spare();
    std::lock_guard<std::mutex> lock(s.mutex);
    if (!s.slabs.empty()) {
      void* slab = s.slabs.back();
      s.slabs.pop_back();
      return slab;
    }
  }
  void* mem = std::aligned_alloc(kSlabBytes, kSlabBytes);
  if (mem == nullptr) throw std::bad_alloc();
  return mem;
}

void give_slab(void* slab) noexcept {
  SpareSlabs& s = spare();
  std::lock_guard<std::mutex> lock(s.mutex);
  try {
    s.slabs.push_back(slab);
  } catch (...) {  // no room to keep it: give it back now
    std::free(slab);
  }
}

std::size_t trim_spare_slabs() {
  SpareSlabs& s = spare();
  std::lock_guard<std::mutex> lock(s.mutex);
  for (void* slab : s.slabs) std::free(slab);
  const std::size_t freed = s.slabs.size() * kSlabBytes;
  s.slabs.clear();
  s.slabs.shrink_to_fit();
  return freed;
}

std::size_t spare_slab_bytes() {
  SpareSlabs& s = spare();
  std::lock_guard<std::mutex> lock(s.mutex);
  return s.slabs.size() * kSlabBytes;
}

template <std::size_t kSize>
void BlockPool<kSize>::Cache::refill() {
  using H = SlabHeader<kSize>;
  Shared<kSize>& s = shared<kSize>();
  std::lock_guard<std::mutex> lock(s.mutex);
  // the lowest free blocks, stacked so that the lowest address is taken first
  std::size_t got = 0;
  while (got < kBatch) {
    while (s.cursor < s.slabs.size() && s.slabs[s.cursor]->free == 0) ++s.cursor;
    if (s.cursor == s.slabs.size()) {
      if (got > 0) break;
      new_slab(s);
      continue;
    }
    H* h = s.slabs[s.cursor];
    char* base = reinterpret_cast<char*>(h);
    std::size_t w = h->first_word;
    for (; w < H::kWords && got < kBatch; ++w) {
      std::uint64_t bits = h->bits[w];
      while (bits != 0 && got < kBatch) {
        const unsigned b = static_cast<unsigned>(__builtin_ctzll(bits));
        bits &= bits - 1;
        blocks[kBatch - 1 - got++] = base + (w * 64 + b) * kSize;
        --h->free;
      }
      h->bits[w] = bits;
      if (bits != 0) break;
    }
    h->first_word = w;
  }
  if (got < kBatch) {  // a short batch: move it to the bottom of the stack
    for (std::size_t i = 0; i < got; ++i) blocks[i] = blocks[kBatch - got + i];
  }
  s.free_blocks -= got;
  count = got;
}

template <std::size_t kSize>
void BlockPool<kSize>::Cache::spill(std::size_t n) noexcept {
  using H = SlabHeader<kSize>;
  Shared<kSize>& s = shared<kSize>();
  std::lock_guard<std::mutex> lock(s.mutex);
  for (; n > 0 && count > 0; --n) {  // the most recently freed first
    void* f = blocks[--count];
    H* h = H::of(f);
    const std::size_t b =
        static_cast<std::size_t>(static_cast<char*>(f) - reinterpret_cast<char*>(h)) / kSize;
    h->bits[b / 64] |= std::uint64_t{1} << (b % 64);
    if (b / 64 < h->first_word) h->first_word = b / 64;
    ++h->free;
    if (h->index < s.cursor) s.cursor = h->index;
    ++s.free_blocks;
  }
}

template <std::size_t kSize>
BlockPool<kSize>::Cache::~Cache() {
  spill(count);
}

namespace {

// Owns a thread's cache: returns its blocks to the slabs and deletes it when the thread exits.
template <std::size_t kSize, class Cache>
struct CacheOwner {
  Cache* cache = nullptr;
  ~CacheOwner() {
    pool_cache<kSize> = nullptr;
    delete cache;
  }
};

}  // namespace

template <std::size_t kSize>
typename BlockPool<kSize>::Cache* BlockPool<kSize>::new_cache() {
  thread_local CacheOwner<kSize, Cache> owner;
  owner.cache = new Cache;
  pool_cache<kSize> = owner.cache;
  return owner.cache;
}

template <std::size_t kSize>
typename BlockPool<kSize>::Stats BlockPool<kSize>::stats() {
  Shared<kSize>& s = shared<kSize>();
  std::lock_guard<std::mutex> lock(s.mutex);
  return {s.slabs.size() * kSlabBytes, s.free_blocks,
          s.slabs.size() * SlabHeader<kSize>::kUsable - s.free_blocks};
}

template <std::size_t kSize>
std::size_t BlockPool<kSize>::trim() {
  using H = SlabHeader<kSize>;
  Shared<kSize>& s = shared<kSize>();
  std::lock_guard<std::mutex> lock(s.mutex);
  std::size_t freed = 0, kept = 0;
  for (H* h : s.slabs) {
    if (h->free == H::kUsable) {
      s.free_blocks -= H::kUsable;
      std::free(h);
      freed += kSlabBytes;
    } else {
      h->index = kept;
      s.slabs[kept++] = h;
    }
  }
  s.slabs.resize(kept);
  s.cursor = 0;
  return freed;
}

template class BlockPool<16>;
template class BlockPool<64>;

}  // namespace octofuse::detail
