// Storage for big arrays (the BVH build's references and nodes, the wide tree's triangle
// blocks): 2 MiB aligned and advised as transparent huge pages on Linux, as Embree does, so a
// 32 MB array takes 16 page faults instead of 8192 and random accesses miss the TLB less.
// Small arrays come from malloc. Free with big_free (std::free).
#pragma once
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>
#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace pl {

// `align`: a power of two up to 2 MiB (over-aligned types: the wide BVH's nodes).
inline void* big_alloc(size_t bytes, size_t align = alignof(std::max_align_t)) {
  constexpr size_t kHuge = size_t(1) << 21;
  const bool over_aligned = align > alignof(std::max_align_t);
  const auto plain = [&] {  // malloc, or aligned_alloc where malloc's alignment is not enough
    const size_t n = std::max<size_t>(bytes, 1);
    return over_aligned ? std::aligned_alloc(align, (n + align - 1) & ~(align - 1)) : std::malloc(n);
  };
  if (bytes >= 2 * kHuge) {
    const size_t size = (bytes + kHuge - 1) & ~(kHuge - 1);
    if (void* p = std::aligned_alloc(kHuge, size)) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
      madvise(p, size, MADV_HUGEPAGE);  // advice only: without huge pages it is ordinary memory
#endif
      return p;
    }
  }
  return plain();  // also when the huge-page-aligned block was refused: never under-aligned
}

inline void big_free(void* p) { std::free(p); }

// Advises the whole 2 MiB pages inside [p, p + bytes) as transparent huge pages: for a big
// std::vector right after reserve(), before its pages are first touched.
inline void advise_huge_pages(const void* p, size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr uintptr_t kHuge = uintptr_t(1) << 21;
  const uintptr_t b = (reinterpret_cast<uintptr_t>(p) + kHuge - 1) & ~(kHuge - 1);
  const uintptr_t e = (reinterpret_cast<uintptr_t>(p) + bytes) & ~(kHuge - 1);
  if (p != nullptr && e > b) madvise(reinterpret_cast<void*>(b), e - b, MADV_HUGEPAGE);
#else
  (void)p;
  (void)bytes;
#endif
}

// An allocator whose resize() leaves new elements uninitialised (default-initialised), for big
// arrays their code writes in full: no serial pass zeroes them first, and their pages are first
// touched by the (parallel) code that fills them. Memory from big_alloc (huge pages when big).
template <class T>
struct NoInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = NoInitAllocator<U>;
  };
  NoInitAllocator() = default;
  template <class U>
  NoInitAllocator(const NoInitAllocator<U>&) noexcept {}
  T* allocate(size_t n) {
    static_assert(alignof(T) <= (size_t(1) << 21), "big_alloc aligns to at most 2 MiB");
    if (n > size_t(-1) / sizeof(T)) throw std::bad_alloc();
    if (void* p = big_alloc(n * sizeof(T), std::max(alignof(T), alignof(std::max_align_t)))) return static_cast<T*>(p);
    throw std::bad_alloc();
  }
  void deallocate(T* p, size_t) noexcept { big_free(p); }
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    // `new U` would still zero a type with member initialisers (Vec3's): a trivially copyable
    // element is left as allocated, for the code that fills it.
    if constexpr (!std::is_trivially_copyable_v<U>) ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
template <class T>
using RawVector = std::vector<T, NoInitAllocator<T>>;

}  // namespace pl
