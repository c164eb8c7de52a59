// octofuse: the allocator of tree nodes (16-byte blocks from slabs, thread-local free lists).
#pragma once

#include <cstddef>

namespace octofuse::detail {

/// 16-byte blocks for the nodes of octofuse's trees. An OctoMap node is 16 bytes, which glibc
/// stores in a 32-byte chunk and frees one by one with coalescing; here blocks are carved from
/// 1 MiB slabs and freed onto a free list, so a node costs 16 bytes and freeing a tree is a
/// walk that pushes its nodes. Each thread allocates from and frees to its own list and trades
/// batches with a shared one, so a node may be freed on any thread. Freed blocks are reused by
/// later trees; the slabs are not given back to the system.
class NodePool {
 public:
  static constexpr std::size_t kBlock = 16;

  static void* allocate() {
    Cache& c = cache();
    if (c.head != nullptr) {
      Free* b = c.head;
      c.head = b->next;
      --c.count;
      return b;
    }
    if (c.bump == c.bump_end) c.refill();
    if (c.head != nullptr) return allocate();
    void* b = c.bump;
    c.bump += kBlock;
    return b;
  }

  static void release(void* p) noexcept {
    Cache& c = cache();
    Free* b = static_cast<Free*>(p);
    b->next = c.head;
    c.head = b;
    if (++c.count >= 2 * kBatch) c.spill();
  }

  struct Stats {
    std::size_t slab_bytes;  ///< bytes taken from the system
    std::size_t shared_free_blocks;  ///< free blocks on the shared list (not in thread caches)
  };
  static Stats stats();

 private:
  struct Free {
    Free* next;
  };
  static constexpr std::size_t kBatch = 1024;  ///< blocks a thread takes or gives at once
  struct Cache {
    Free* head = nullptr;
    std::size_t count = 0;
    char* bump = nullptr;  ///< blocks never used, carved in order
    char* bump_end = nullptr;
    void refill();
    void spill() noexcept;
    ~Cache();
  };
  static Cache& cache() {
    thread_local Cache c;
    return c;
  }
};

/// Node types derive from this to live in the pool (the type must be 16 bytes).
template <class Derived>
struct PooledNode {
  static void* operator new(std::size_t n) {
    static_assert(sizeof(Derived) == NodePool::kBlock, "pooled nodes are 16 bytes");
    (void)n;
    return NodePool::allocate();
  }
  static void operator delete(void* p) noexcept {
    if (p != nullptr) NodePool::release(p);
  }
};

}  // namespace octofuse::detail
