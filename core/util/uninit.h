#pragma once
// Stack storage for N values of T left unconstructed. The small vector types zero themselves
// (default member initialisers), and hot paths that declare arrays of them but fill only the
// entries a shader uses paid for zeroing all of them on every hit.
#include <cstddef>
#include <new>
#include <type_traits>

namespace pl {

template <class T, std::size_t N>
struct UninitArray {
  static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                "UninitArray holds plain values only");
  alignas(T) unsigned char bytes[sizeof(T) * N];
  T* data() { return std::launder(reinterpret_cast<T*>(bytes)); }
  const T* data() const { return std::launder(reinterpret_cast<const T*>(bytes)); }
  T& operator[](std::size_t i) { return data()[i]; }
  const T& operator[](std::size_t i) const { return data()[i]; }
};

}  // namespace pl
