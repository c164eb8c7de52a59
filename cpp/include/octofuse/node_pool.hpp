// octofuse: the allocator of tree nodes and their child arrays (fixed-size blocks from slabs,
// thread-local free lists).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>

namespace octofuse::detail {

/// Blocks come from slabs of this size, aligned to it. A slab's first word names the
/// TreeArena (tree_arena.hpp) it belongs to, or is null for the pools' own slabs.
inline constexpr std::size_t kSlabBytes = std::size_t(1) << 20;

class TreeArena;

/// The arena whose slab holds block `p`, or null if a pool's slab does.
inline TreeArena* arena_of(const void* p) {
  return *reinterpret_cast<TreeArena* const*>(reinterpret_cast<std::uintptr_t>(p) &
                                              ~(kSlabBytes - 1));
}

/// Arenas alive in the process: while there are none, freeing a block reads nothing but the
/// freeing thread's list (not its slab's first word). On a cache line of its own.
struct alignas(64) LiveArenas {
  std::atomic<std::size_t> count{0};
};
inline LiveArenas live_arenas;

/// Counts a node of an arena as freed (its block stays with the arena until it goes).
void arena_node_freed(TreeArena* arena) noexcept;

/// A slab of kSlabBytes, aligned to its size: a spare one if any, else from the system.
void* take_slab();
/// Keeps a slab no longer used as a spare, for take_slab().
void give_slab(void* slab) noexcept;
/// Gives the spare slabs back to the system; returns the bytes freed.
std::size_t trim_spare_slabs();
/// Bytes of the spare slabs.
std::size_t spare_slab_bytes();

/// The thread's cache of BlockPool<kSize> (null until its first use). Only a pointer is
/// thread-local, in the initial-exec model: one load, not a call into the dynamic linker for
/// every block (a module loaded at run time has room for a few such bytes). A variable
/// template, not a static member: its constant initializer is seen wherever it is read.
template <std::size_t kSize>
inline thread_local void* pool_cache __attribute__((tls_model("initial-exec"))) = nullptr;

/// Blocks of `kSize` bytes for octofuse's trees (outside arenas): nodes (16 bytes, which
/// glibc stores in 32 and frees one by one with coalescing) and arrays of 8 child pointers (64
/// bytes, 80 in glibc). Blocks come from 1 MiB slabs, each with a bitmap of its free blocks. A
/// thread takes blocks in batches, lowest address first (a tree built in depth-first order
/// gets its nodes side by side, however scattered the blocks freed before were), and frees
/// onto a stack of its own that goes back to the bitmaps in batches; a block may be freed on
/// any thread. trim() gives empty slabs back to the system.
template <std::size_t kSize>
class BlockPool {
 public:
  static constexpr std::size_t kBlock = kSize;

  static void* allocate() {
    Cache& c = cache();
    if (c.count == 0) c.refill();
    return c.blocks[--c.count];
  }

  /// Frees a block; an arena's block is only counted (its arena frees it).
  static void release(void* p) noexcept {
    if (__builtin_expect(live_arenas.count.load(std::memory_order_relaxed) != 0, 0)) {
      if (TreeArena* a = arena_of(p)) {
        if constexpr (kSize == 16) arena_node_freed(a);  // NodePool: a node
        return;
      }
    }
    release_to_pool(p);
  }

  /// Frees a block known not to be an arena's (a block of a tree that has no arena).
  static void release_to_pool(void* p) noexcept {
    Cache& c = cache();
    if (c.count == 2 * kBatch) c.spill(kBatch);
    c.blocks[c.count++] = p;
  }

  struct Stats {
    std::size_t slab_bytes;     ///< bytes taken from the system
    std::size_t free_blocks;    ///< free blocks in the slabs (not counting threads' lists)
    std::size_t blocks_in_use;  ///< not free in the slabs (blocks on threads' lists included)
  };
  static Stats stats();

  /// Gives the slabs with no block in use back to the system; returns the bytes freed.
  static std::size_t trim();

 private:
  static constexpr std::size_t kBatch = 1024;  ///< blocks a thread takes or gives at once
  // A thread's free blocks: a stack of addresses (the blocks themselves are not touched, so
  // taking and giving batches under the pool's lock reads no block).
  struct Cache {
    void* blocks[2 * kBatch];
    std::size_t count = 0;
    void refill();
    void spill(std::size_t n) noexcept;
    ~Cache();
  };
  // The thread's cache, created on its first use and destroyed at its exit.
  static Cache& cache() {
    void* c = pool_cache<kSize>;
    if (__builtin_expect(c == nullptr, 0)) c = new_cache();
    return *static_cast<Cache*>(c);
  }
  static Cache* new_cache();
};

using NodePool = BlockPool<16>;      ///< tree nodes
using ChildrenPool = BlockPool<64>;  ///< arrays of 8 child pointers

extern template class BlockPool<16>;
extern template class BlockPool<64>;

}  // namespace octofuse::detail
