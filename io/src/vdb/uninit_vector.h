#pragma once
// Vectors whose resize leaves the new elements default-initialized: uninitialized for plain
// numbers and structs of them.
#include <memory>
#include <new>
#include <utility>
#include <vector>

namespace slurry::io::detail {

/// An allocator that leaves the elements of a resized vector default-initialized (not zeroed),
/// for buffers whose every element is written before it is read: a serial memset of tens of MB
/// otherwise precedes their parallel filling.
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
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
template <class T>
using UninitVector = std::vector<T, DefaultInitAllocator<T>>;

}  // namespace slurry::io::detail
