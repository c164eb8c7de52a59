// octofuse: slabs of one tree's own, freed all at once with the tree (TreeArena), and the
// trees that can own one (ArenaTree).
#pragma once

#include "octofuse/detail/tree_access.hpp"
#include "octofuse/node_pool.hpp"

#include <octomap/OcTreeDataNode.h>

#include <atomic>
#include <cstddef>
#include <memory>
#include <new>
#include <vector>

namespace octofuse::detail {

/// Nodes and child arrays of one tree, side by side in slabs of its own (each slab's first
/// word names the arena, so the pools know its blocks). A tree whose nodes are all its
/// arena's is freed by giving the slabs back, not node by node. Blocks are handed out to one
/// thread at a time; a node freed before the arena goes (on any thread) is counted, and its
/// block kept until then.
class TreeArena {
 public:
  TreeArena();
  TreeArena(const TreeArena&) = delete;
  TreeArena& operator=(const TreeArena&) = delete;
  ~TreeArena();

  void* take_node() {
    ++nodes_taken_;
    return take(nodes_, NodePool::kBlock);
  }
  void* take_children() { return take(children_, ChildrenPool::kBlock); }

  /// Nodes handed out and not freed.
  std::size_t live_nodes() const {
    return nodes_taken_ - freed_nodes_.load(std::memory_order_acquire);
  }
  /// Bytes of the slabs held.
  std::size_t bytes() const { return slabs_.size() * kSlabBytes; }

  void node_freed() noexcept { freed_nodes_.fetch_add(1, std::memory_order_release); }

 private:
  struct Bump {  // blocks of one size, handed out from the newest slab
    char* next = nullptr;
    char* end = nullptr;
  };
  void* take(Bump& b, std::size_t size) {
    if (b.next == b.end) new_slab(b, size);
    void* p = b.next;
    b.next += size;
    return p;
  }
  void new_slab(Bump& b, std::size_t size);

  std::vector<void*> slabs_;
  Bump nodes_, children_;
  std::size_t nodes_taken_ = 0;
  std::atomic<std::size_t> freed_nodes_{0};
};

/// Total bytes of all arenas' slabs.
std::size_t arena_bytes();

}  // namespace octofuse::detail

namespace octofuse {

/// An OctoMap tree type that may own a TreeArena for its nodes (`Base::NodeType` must give
/// access to its array of children: PooledTreeNode). A tree whose nodes are all its arena's
/// (none added from the pools since, as the node counts show) is cleared and destroyed
/// without a walk; a tree with no arena frees its nodes (clear, prune) without asking each
/// block's slab. Nodes of an arena never move to another tree: OctoMap's swap() is hidden, and
/// copies get nodes of their own.
template <class Base>
class ArenaTree : public Base {
 public:
  using Node = typename Base::NodeType;
  using Base::Base;
  ArenaTree(const ArenaTree& other) : Base(other) {}  // the copy's nodes are the pools'
  ~ArenaTree() override { clear(); }

  /// Gives the (empty) tree an arena: the nodes that create_root() and create_child() make
  /// from now on come from it (other ways of adding nodes still take them from the pools).
  void start_arena() { arena_ = std::make_unique<detail::TreeArena>(); }
  detail::TreeArena* arena() const { return arena_.get(); }

  /// The root, made if the tree is empty.
  Node* create_root() {
    if (arena_ == nullptr) return detail::TreeAccess<Base>::ensure_root(*this);
    if (this->root == nullptr) {
      this->root = ::new (arena_->take_node()) Node();
      ++this->tree_size;
      this->size_changed = true;
    }
    return this->root;
  }

  /// OctoMap's createNodeChild(), with the node (and the array of children, if `parent` has
  /// none) from the arena if the tree has one.
  Node* create_child(Node* parent, unsigned i) {
    if (arena_ == nullptr) return this->createNodeChild(parent, i);
    octomap::AbstractOcTreeNode**& kids = parent->children_array();
    if (kids == nullptr) {
      kids = static_cast<octomap::AbstractOcTreeNode**>(arena_->take_children());
      for (unsigned k = 0; k < 8; ++k) kids[k] = nullptr;
    }
    Node* n = ::new (arena_->take_node()) Node();
    kids[i] = n;
    ++this->tree_size;
    this->size_changed = true;
    return n;
  }

  /// Removes every node, and the arena with them.
  void clear() {
    if (arena_ == nullptr) {
      if (this->root != nullptr) free_pool_nodes(this->root);
    } else if (arena_->live_nodes() != this->tree_size) {
      Base::clear();  // the pools' nodes go back one by one; the arena's are only counted
    }                 // else every node is the arena's: its slabs go at once
    this->root = nullptr;
    this->tree_size = 0;
    this->size_changed = true;
    arena_.reset();
  }

  /// OctoMap's pruneNode(); in a tree with no arena, the children go back to the pools
  /// without asking their slabs (none can be an arena's).
  bool pruneNode(Node* node) final {
    if (arena_ != nullptr) return Base::pruneNode(node);
    if (!this->isNodeCollapsible(node)) return false;
    node->copyData(*this->getNodeChild(node, 0));
    octomap::AbstractOcTreeNode**& kids = node->children_array();
    // a leaf child may still have an array, emptied by OctoMap's deleteNodeChild
    for (unsigned i = 0; i < 8; ++i) free_pool_nodes(static_cast<Node*>(kids[i]));
    detail::ChildrenPool::release_to_pool(kids);
    kids = nullptr;
    this->tree_size -= 8;
    this->size_changed = true;
    return true;
  }

  void swap(ArenaTree&) = delete;

 private:
  static void free_pool_nodes(Node* n) {
    octomap::AbstractOcTreeNode**& kids = n->children_array();
    if (kids != nullptr) {
      for (unsigned i = 0; i < 8; ++i)
        if (kids[i] != nullptr) free_pool_nodes(static_cast<Node*>(kids[i]));
      detail::ChildrenPool::release_to_pool(kids);
      kids = nullptr;
    }
    n->~Node();
    detail::NodePool::release_to_pool(n);
  }

  std::unique_ptr<detail::TreeArena> arena_;
};

}  // namespace octofuse
