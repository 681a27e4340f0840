// Counts every heap allocation of the test executable that includes it (include it in one
// translation unit only): operator new in all its forms, and the C allocator (malloc, calloc,
// realloc, memalign, posix_memalign, aligned_alloc), which is Eigen's path in every build.
//  - Dynamic builds replace the C allocator and forward to glibc's __libc_* entry points.
//  - Static builds (RVD_STATIC_LINK, the cross builds run under QEMU): static glibc defines malloc
//    and __libc_malloc in one object, so the test links with -Wl,--wrap=malloc,... instead
//    (tests/cpp/CMakeLists.txt): every reference to malloc in the link reaches __wrap_malloc.
//  - AddressSanitizer builds: the sanitizer owns the allocator and cannot be replaced; its
//    allocator hooks (__sanitizer_install_malloc_and_free_hooks) see every allocation, new included.
// rvd::testing::allocations() is the running count; kAllocationCounting names the mechanism.
#pragma once

#include <Eigen/Core>  // its allocator declarations (mm_malloc.h) come before the definitions below

#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <new>

#ifndef RVD_STATIC_LINK
#define RVD_STATIC_LINK 0
#endif

namespace rvd::testing {
inline std::atomic<long> g_allocations{0};
inline long allocations() { return g_allocations.load(); }
}  // namespace rvd::testing

#if defined(__SANITIZE_ADDRESS__)
// libasan's allocator hook API (sanitizer/allocator_interface.h, not installed with every GCC).
extern "C" int __sanitizer_install_malloc_and_free_hooks(void (*malloc_hook)(const volatile void*, size_t),
                                                         void (*free_hook)(const volatile void*));
namespace rvd::testing {
inline void count_malloc(const volatile void*, size_t) { ++g_allocations; }
inline void ignore_free(const volatile void*) {}
inline const int kHooksInstalled = __sanitizer_install_malloc_and_free_hooks(count_malloc, ignore_free);
constexpr const char* kAllocationCounting = "AddressSanitizer allocator hooks";
}  // namespace rvd::testing
#elif defined(__SANITIZE_THREAD__)
#error "allocation counting needs replaceable allocators or ASan hooks; ThreadSanitizer has neither here"
#else
#if RVD_STATIC_LINK
#define RVD_C_ALLOC(name) __wrap_##name
#define RVD_REAL(name) __real_##name
#else
#define RVD_C_ALLOC(name) name
#define RVD_REAL(name) __libc_##name
#endif
namespace rvd::testing {
constexpr const char* kAllocationCounting = RVD_STATIC_LINK ? "link-time wrapped C allocator and operator new"
                                                            : "replaced C allocator and operator new";
}
extern "C" {
void* RVD_REAL(malloc)(size_t);
void* RVD_REAL(calloc)(size_t, size_t);
void* RVD_REAL(realloc)(void*, size_t);
void* RVD_REAL(memalign)(size_t, size_t);
void RVD_REAL(free)(void*);

void* RVD_C_ALLOC(malloc)(size_t n) {
  ++rvd::testing::g_allocations;
  return RVD_REAL(malloc)(n);
}
void* RVD_C_ALLOC(calloc)(size_t n, size_t m) {
  ++rvd::testing::g_allocations;
  return RVD_REAL(calloc)(n, m);
}
void* RVD_C_ALLOC(realloc)(void* p, size_t n) {
  ++rvd::testing::g_allocations;
  return RVD_REAL(realloc)(p, n);
}
void RVD_C_ALLOC(free)(void* p) { RVD_REAL(free)(p); }
int RVD_C_ALLOC(posix_memalign)(void** out, size_t align, size_t n) {
  ++rvd::testing::g_allocations;
  *out = RVD_REAL(memalign)(align, n);
  return *out ? 0 : 12;  // ENOMEM
}
void* RVD_C_ALLOC(aligned_alloc)(size_t align, size_t n) {
  ++rvd::testing::g_allocations;
  return RVD_REAL(memalign)(align, n);
}
void* RVD_C_ALLOC(memalign)(size_t align, size_t n) {
  ++rvd::testing::g_allocations;
  return RVD_REAL(memalign)(align, n);
}
}

void* operator new(size_t n) {
  ++rvd::testing::g_allocations;
  if (void* p = RVD_REAL(malloc)(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](size_t n) { return operator new(n); }
void* operator new(size_t n, const std::nothrow_t&) noexcept {
  ++rvd::testing::g_allocations;
  return RVD_REAL(malloc)(n ? n : 1);
}
void* operator new[](size_t n, const std::nothrow_t&) noexcept { return operator new(n, std::nothrow); }
void* operator new(size_t n, std::align_val_t a) {
  ++rvd::testing::g_allocations;
  if (void* p = RVD_REAL(memalign)(static_cast<size_t>(a), n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](size_t n, std::align_val_t a) { return operator new(n, a); }
void operator delete(void* p) noexcept { RVD_REAL(free)(p); }
void operator delete[](void* p) noexcept { RVD_REAL(free)(p); }
void operator delete(void* p, size_t) noexcept { RVD_REAL(free)(p); }
void operator delete[](void* p, size_t) noexcept { RVD_REAL(free)(p); }
void operator delete(void* p, std::align_val_t) noexcept { RVD_REAL(free)(p); }
void operator delete[](void* p, std::align_val_t) noexcept { RVD_REAL(free)(p); }
void operator delete(void* p, size_t, std::align_val_t) noexcept { RVD_REAL(free)(p); }
void operator delete[](void* p, size_t, std::align_val_t) noexcept { RVD_REAL(free)(p); }
#endif

namespace rvd::testing {
// Heap allocations made while running f.
template <class F>
long allocations_during(F&& f) {
  const long before = allocations();
  f();
  return allocations() - before;
}
}  // namespace rvd::testing
