// Storage for big arrays (the BVH build's references and nodes, the wide tree's triangle
// blocks): 2 MiB aligned and advised as transparent huge pages on Linux, as Embree does, so a
// 32 MB array takes 16 page faults instead of 8192 and random accesses miss the TLB less.
// Small arrays come from malloc. Free with big_free (std::free).
#pragma once
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace pl {

inline void* big_alloc(size_t bytes) {
  constexpr size_t kHuge = size_t(1) << 21;
  if (bytes >= 2 * kHuge) {
    const size_t size = (bytes + kHuge - 1) & ~(kHuge - 1);
    if (void* p = std::aligned_alloc(kHuge, size)) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
      madvise(p, size, MADV_HUGEPAGE);  // advice only: without huge pages it is ordinary memory
#endif
      return p;
    }
  }
  return std::malloc(std::max<size_t>(bytes, 1));
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

}  // namespace pl
