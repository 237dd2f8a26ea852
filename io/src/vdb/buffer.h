#pragma once
// The surfacing's large temporary buffers (tens of MB each, freed when a frame is surfaced):
// vectors whose large allocations are kept for reuse, and optionally whose resize leaves new
// elements default-initialized (not zeroed).
//
// Why: the first touch of each fresh 4 KiB page is a page fault, which costs the kernel's
// zeroing of the page plus the trap itself, and under virtualization the trap can cost many
// microseconds (15 us per page measured on the project's 2-core VM). The buffers of one frame of
// the 3D dam break (875 k particles) span about 300 MB, 75 k pages, and whether malloc hands a
// frame fresh pages or the previous frame's depends on its heuristics (mappings above its
// threshold are returned to the system when freed, the heap's top is trimmed): in one process
// the faults took longer than the surfacing's arithmetic. So an allocation of kLargeBytes or
// more is served from a pool of mappings that the earlier frames freed (the smallest that fits;
// its pages are already present) or else mapped fresh, aligned to 2 MiB and marked
// MADV_HUGEPAGE (a fault per 2 MiB where the kernel's transparent_hugepage setting allows it).
// The pool keeps at most kPoolBytes of freed mappings (the largest first); release_buffer_pool()
// returns them to the system. Smaller buffers use operator new.
#include <cstddef>
#include <cstdint>
#include <new>
#include <utility>
#include <vector>

namespace slurry::io::detail {

/// Allocations of at least this many bytes come from the pool.
inline constexpr std::size_t kLargeBytes = std::size_t(4) << 20;
/// The most bytes of freed mappings the pool keeps for reuse.
inline constexpr std::size_t kPoolBytes = std::size_t(2) << 30;

/// At least `bytes` (>= kLargeBytes) of memory aligned to 2 MiB: a pooled mapping or a fresh
/// one. Thread-safe. Throws std::bad_alloc.
void* pool_allocate(std::size_t bytes);
/// Returns a pointer from pool_allocate to the pool (which unmaps what exceeds kPoolBytes).
void pool_free(void* p) noexcept;
/// Unmaps every freed mapping the pool keeps; returns the bytes released.
std::size_t release_buffer_pool() noexcept;
/// Bytes of freed mappings the pool keeps (for tests).
std::size_t buffer_pool_bytes() noexcept;

/// A stateless allocator: kLargeBytes or more from the pool, less from operator new.
template <class T>
struct LargeAllocator {
  using value_type = T;
  LargeAllocator() = default;
  template <class U>
  LargeAllocator(const LargeAllocator<U>&) noexcept {}
  T* allocate(std::size_t n) {
    if (n > std::size_t(-1) / sizeof(T)) throw std::bad_array_new_length();
    const std::size_t bytes = n * sizeof(T);
    if (bytes >= kLargeBytes) return static_cast<T*>(pool_allocate(bytes));
    return static_cast<T*>(::operator new(bytes, std::align_val_t(alignof(T))));
  }
  void deallocate(T* p, std::size_t n) noexcept {
    const std::size_t bytes = n * sizeof(T);
    if (bytes >= kLargeBytes)
      pool_free(p);
    else
      ::operator delete(p, bytes, std::align_val_t(alignof(T)));
  }
  template <class U>
  bool operator==(const LargeAllocator<U>&) const noexcept { return true; }
  template <class U>
  bool operator!=(const LargeAllocator<U>&) const noexcept { return false; }
};

/// LargeAllocator that leaves the elements of a resized vector default-initialized (not
/// zeroed), for buffers whose every element is written before it is read: a serial memset of
/// tens of MB otherwise precedes their parallel filling.
template <class T>
struct DefaultInitAllocator : LargeAllocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

/// A vector on LargeAllocator (elements value-initialized, as std::vector's).
template <class T>
using Buffer = std::vector<T, LargeAllocator<T>>;
/// A vector on DefaultInitAllocator.
template <class T>
using UninitVector = std::vector<T, DefaultInitAllocator<T>>;

}  // namespace slurry::io::detail
