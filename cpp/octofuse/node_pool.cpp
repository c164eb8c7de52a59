// octofuse: NodePool, the shared side (slabs and batches of free blocks).
#include "octofuse/node_pool.hpp"

#include <cstdlib>
#include <mutex>
#include <new>
#include <utility>
#include <vector>

namespace octofuse::detail {

namespace {

constexpr std::size_t kSlabBytes = std::size_t(1) << 20;

struct Shared {
  std::mutex mutex;
  std::vector<std::pair<void*, std::size_t>> batches;  // (list head, blocks)
  std::size_t free_blocks = 0;
  char* slab = nullptr;  // the slab being carved
  char* slab_end = nullptr;
  std::size_t slab_bytes = 0;
};

// Never destroyed: threads return their caches at exit, the main thread's after static
// destructors may have run.
Shared& shared() {
  static Shared* s = new Shared;
  return *s;
}

}  // namespace

void NodePool::Cache::refill() {
  Shared& s = shared();
  std::lock_guard<std::mutex> lock(s.mutex);
  if (!s.batches.empty()) {
    auto [list, n] = s.batches.back();
    s.batches.pop_back();
    s.free_blocks -= n;
    head = static_cast<Free*>(list);
    count = n;
    return;
  }
  const std::size_t want = kBatch * kBlock;
  if (static_cast<std::size_t>(s.slab_end - s.slab) < want) {
    void* slab = std::aligned_alloc(kBlock, kSlabBytes);
    if (slab == nullptr) throw std::bad_alloc();
    s.slab = static_cast<char*>(slab);
    s.slab_end = s.slab + kSlabBytes;
    s.slab_bytes += kSlabBytes;
  }
  bump = s.slab;
  bump_end = s.slab + want;
  s.slab += want;
}

void NodePool::Cache::spill() noexcept {
  // the first kBatch blocks of the list go to the shared list as one batch
  Free* first = head;
  Free* last = head;
  for (std::size_t i = 1; i < kBatch; ++i) last = last->next;
  head = last->next;
  last->next = nullptr;
  count -= kBatch;
  Shared& s = shared();
  std::lock_guard<std::mutex> lock(s.mutex);
  try {
    s.batches.emplace_back(first, kBatch);
    s.free_blocks += kBatch;
  } catch (...) {  // no room to record the batch: keep it in this thread
    last->next = head;
    head = first;
    count += kBatch;
  }
}

NodePool::Cache::~Cache() {
  while (bump != bump_end) {  // unused blocks join the free list
    Free* b = reinterpret_cast<Free*>(bump);
    b->next = head;
    head = b;
    ++count;
    bump += kBlock;
  }
  if (head == nullptr) return;
  Shared& s = shared();
  std::lock_guard<std::mutex> lock(s.mutex);
  try {
    s.batches.emplace_back(head, count);
    s.free_blocks += count;
  } catch (...) {  // lost to the pool, not to the process
  }
  head = nullptr;
  count = 0;
}

NodePool::Stats NodePool::stats() {
  Shared& s = shared();
  std::lock_guard<std::mutex> lock(s.mutex);
  return {s.slab_bytes, s.free_blocks};
}

}  // namespace octofuse::detail
