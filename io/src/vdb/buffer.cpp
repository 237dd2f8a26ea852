// The pool of large buffers' mappings (buffer.h).
#include "vdb/buffer.h"

#include "slurry/io/surface.h"

#include <algorithm>
#include <map>
#include <mutex>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace slurry::io::detail {

namespace {

constexpr std::size_t kHugePage = std::size_t(2) << 20;

/// A fresh mapping of `size` bytes (a multiple of kHugePage) aligned to kHugePage.
void* map_fresh(std::size_t size) {
#if defined(__linux__)
  // Over-map by one huge page, then unmap the unaligned head and the tail.
  void* raw = ::mmap(nullptr, size + kHugePage, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (raw == MAP_FAILED) throw std::bad_alloc();
  const std::uintptr_t begin = std::uintptr_t(raw), end = begin + size + kHugePage;
  const std::uintptr_t at = (begin + kHugePage - 1) & ~std::uintptr_t(kHugePage - 1);
  if (at > begin) ::munmap(raw, at - begin);
  if (end > at + size) ::munmap(reinterpret_cast<void*>(at + size), end - (at + size));
  ::madvise(reinterpret_cast<void*>(at), size, MADV_HUGEPAGE);  // advice: refused, 4 KiB pages
  return reinterpret_cast<void*>(at);
#else
  return ::operator new(size, std::align_val_t(kHugePage));
#endif
}

void unmap(void* p, std::size_t size) noexcept {
#if defined(__linux__)
  ::munmap(p, size);
#else
  ::operator delete(p, std::align_val_t(kHugePage));
#endif
}

struct Pool {
  std::mutex mutex;
  std::map<void*, std::size_t> live;           ///< handed out: address -> mapping size
  std::multimap<std::size_t, void*> freed;     ///< kept for reuse: size -> address
  std::size_t freed_bytes = 0;
};

Pool& pool() {
  static Pool* p = new Pool;  // never destroyed: buffers may be freed during static destruction
  return *p;
}

}  // namespace

void* pool_allocate(std::size_t bytes) {
  const std::size_t size = (bytes + kHugePage - 1) & ~(kHugePage - 1);
  Pool& P = pool();
  {
    const std::lock_guard<std::mutex> lock(P.mutex);
    // The smallest freed mapping that holds `size`, unless it is more than twice as large (a
    // small buffer does not pin a large mapping).
    const auto it = P.freed.lower_bound(size);
    if (it != P.freed.end() && it->first <= 2 * size) {
      void* p = it->second;
      P.live.emplace(p, it->first);
      P.freed_bytes -= it->first;
      P.freed.erase(it);
      return p;
    }
  }
  void* p = map_fresh(size);
  const std::lock_guard<std::mutex> lock(P.mutex);
  P.live.emplace(p, size);
  return p;
}

void pool_free(void* p) noexcept {
  Pool& P = pool();
  std::vector<std::pair<void*, std::size_t>> drop;
  {
    const std::lock_guard<std::mutex> lock(P.mutex);
    const auto it = P.live.find(p);
    if (it == P.live.end()) return;  // not ours: never happens with LargeAllocator
    const std::size_t size = it->second;
    P.live.erase(it);
    P.freed.emplace(size, p);
    P.freed_bytes += size;
    // Over the limit: unmap the largest kept mappings.
    while (P.freed_bytes > kPoolBytes) {
      const auto last = std::prev(P.freed.end());
      drop.emplace_back(last->second, last->first);
      P.freed_bytes -= last->first;
      P.freed.erase(last);
    }
  }
  for (const auto& [q, size] : drop) unmap(q, size);
}

std::size_t release_buffer_pool() noexcept {
  Pool& P = pool();
  std::multimap<std::size_t, void*> drop;
  {
    const std::lock_guard<std::mutex> lock(P.mutex);
    drop.swap(P.freed);
    P.freed_bytes = 0;
  }
  std::size_t released = 0;
  for (const auto& [size, q] : drop) unmap(q, size), released += size;
  return released;
}

std::size_t buffer_pool_bytes() noexcept {
  Pool& P = pool();
  const std::lock_guard<std::mutex> lock(P.mutex);
  return P.freed_bytes;
}

}  // namespace slurry::io::detail

namespace slurry::io {

std::size_t release_surfacing_memory() {
  return detail::release_buffer_pool();
}

}  // namespace slurry::io
