// octofuse: TreeArena's slabs.
#include "octofuse/tree_arena.hpp"

namespace octofuse::detail {

namespace {
std::atomic<std::size_t> all_arena_bytes{0};
}  // namespace

TreeArena::TreeArena() { live_arenas.count.fetch_add(1, std::memory_order_relaxed); }

TreeArena::~TreeArena() {
  for (void* slab : slabs_) give_slab(slab);
  all_arena_bytes.fetch_sub(bytes(), std::memory_order_relaxed);
  live_arenas.count.fetch_sub(1, std::memory_order_relaxed);
}

void TreeArena::new_slab(Bump& b, std::size_t size) {
  slabs_.reserve(slabs_.size() + 1);  // may throw before anything changes
  auto* slab = static_cast<char*>(take_slab());
  *reinterpret_cast<TreeArena**>(slab) = this;  // arena_of()
  slabs_.push_back(slab);
  all_arena_bytes.fetch_add(kSlabBytes, std::memory_order_relaxed);
  b.next = slab + 64;  // past the first word's cache line: blocks stay aligned to their size
  b.end = b.next + (kSlabBytes - 64) / size * size;
}

std::size_t arena_bytes() { return all_arena_bytes.load(std::memory_order_relaxed); }

void arena_node_freed(TreeArena* arena) noexcept { arena->node_freed(); }

}  // namespace octofuse::detail
