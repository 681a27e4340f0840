// solve() must not touch the heap: every allocation path of this executable (operator new/delete
// and the C allocator) is replaced by counting wrappers, and the count must not move across
// solve() calls in both modes, warm and cold, feasible and infeasible, and with bad input.
#include <doctest/doctest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>

#include "flight_sw/solver/fast_mpc.hpp"
#include "test_solver_problems.hpp"

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define RVD_COUNT_ALLOCATIONS 0  // the sanitizer runtime owns the allocator
#else
#define RVD_COUNT_ALLOCATIONS 1
#endif

namespace {
std::atomic<long> g_allocations{0};
}

#if RVD_COUNT_ALLOCATIONS
// Dynamic builds replace the C allocator and forward to glibc's __libc_* entry points. Static
// glibc defines malloc and __libc_malloc in one object, so static builds (RVD_STATIC_LINK, the
// cross builds run under QEMU) link with -Wl,--wrap=malloc,... instead: every reference to malloc
// in the link, libstdc++'s included, reaches __wrap_malloc, which forwards to __real_malloc.
#if RVD_STATIC_LINK
#define RVD_C_ALLOC(name) __wrap_##name
#define RVD_REAL(name) __real_##name
#else
#define RVD_C_ALLOC(name) name
#define RVD_REAL(name) __libc_##name
#endif
extern "C" {
void* RVD_REAL(malloc)(size_t);
void* RVD_REAL(calloc)(size_t, size_t);
void* RVD_REAL(realloc)(void*, size_t);
void* RVD_REAL(memalign)(size_t, size_t);
void RVD_REAL(free)(void*);

void* RVD_C_ALLOC(malloc)(size_t n) {
  ++g_allocations;
  return RVD_REAL(malloc)(n);
}
void* RVD_C_ALLOC(calloc)(size_t n, size_t m) {
  ++g_allocations;
  return RVD_REAL(calloc)(n, m);
}
void* RVD_C_ALLOC(realloc)(void* p, size_t n) {
  ++g_allocations;
  return RVD_REAL(realloc)(p, n);
}
void RVD_C_ALLOC(free)(void* p) { RVD_REAL(free)(p); }
int RVD_C_ALLOC(posix_memalign)(void** out, size_t align, size_t n) {
  ++g_allocations;
  *out = RVD_REAL(memalign)(align, n);
  return *out ? 0 : 12;  // ENOMEM
}
void* RVD_C_ALLOC(aligned_alloc)(size_t align, size_t n) {
  ++g_allocations;
  return RVD_REAL(memalign)(align, n);
}
void* RVD_C_ALLOC(memalign)(size_t align, size_t n) {
  ++g_allocations;
  return RVD_REAL(memalign)(align, n);
}
}

void* operator new(size_t n) {
  ++g_allocations;
  if (void* p = RVD_REAL(malloc)(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](size_t n) { return operator new(n); }
void* operator new(size_t n, const std::nothrow_t&) noexcept {
  ++g_allocations;
  return RVD_REAL(malloc)(n ? n : 1);
}
void* operator new[](size_t n, const std::nothrow_t&) noexcept { return operator new(n, std::nothrow); }
void* operator new(size_t n, std::align_val_t a) {
  ++g_allocations;
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

using namespace rvd::solver;
using namespace rvd::solver::testing;

namespace {
// Heap allocations made while running f.
template <class F>
long allocations_during(F&& f) {
  const long before = g_allocations.load();
  f();
  return g_allocations.load() - before;
}
}  // namespace

TEST_CASE("the counters see allocations") {
  if (!RVD_COUNT_ALLOCATIONS) return;
  const long n = allocations_during([] {
    Vector v = Vector::Ones(100);
    void* volatile p = std::malloc(16);  // volatile: the compiler may not elide the pair
    std::free(p);
    CHECK(v.sum() == 100.0);
  });
  CHECK(n == 2);
}

TEST_CASE("solve() allocates nothing, in every mode and outcome") {
  if (!RVD_COUNT_ALLOCATIONS) {
    MESSAGE("allocation counting is off under a sanitizer");
    return;
  }
  for (int N : {5, 30}) {
    OcpQp qp = docking_like(N, 0.0);
    OcpQp bad = qp;
    bad.q[2](1) = std::nan("");
    OcpQp infeasible = qp;
    infeasible.d[N](0) = -1e3;  // the cone's first facet pushed far out of reach: no plan exists
    Vector x0 = docking_x0();

    Vector x1 = x0;  // the next period's initial state: the plan's x1 (sized before counting)
    FastMpcSolver converged(qp.dims);
    FastMpcSolver barrier(qp.dims, fixed_barrier_settings(1e-3, 30));
    Status s1 = Status::InvalidInput, s2 = s1, s3 = s1, s4 = s1, s5 = s1, s6 = s1;
    const long n = allocations_during([&] {
      s1 = converged.solve(qp, x0);  // cold
      x1 = converged.x()[1];
      converged.shift_warm_start();
      s2 = converged.solve(qp, x1);  // warm
      s3 = barrier.solve(qp, x0);    // cold: primal-dual start, then Newton
      x1 = barrier.x()[1];
      barrier.shift_warm_start();
      s4 = barrier.solve(qp, x1);  // warm
      s5 = converged.solve(infeasible, x0);
      s6 = converged.solve(bad, x0);
      converged.settings().time_limit_us = 1e-3;
      converged.solve(qp, x0);
      converged.settings().time_limit_us = 0;
    });
    CHECK(n == 0);
    CHECK(s1 == Status::Solved);
    CHECK(s2 == Status::Solved);
    CHECK(s3 == Status::Solved);
    CHECK(s4 == Status::Solved);
    CHECK(s5 == Status::Infeasible);
    CHECK(s6 == Status::InvalidInput);
  }
  // The generic-size path (nx != 6).
  Vector x0;
  const OcpQp planar = planar_like(15, x0);
  FastMpcSolver converged(planar.dims), barrier(planar.dims, fixed_barrier_settings(1e-4, 40));
  Status a = Status::InvalidInput, b = a, c = a;
  const long n = allocations_during([&] {
    a = converged.solve(planar, x0);
    b = barrier.solve(planar, x0);
    barrier.shift_warm_start();
    c = barrier.solve(planar, x0);
  });
  CHECK(n == 0);
  CHECK(a == Status::Solved);
  CHECK(b == Status::Solved);
  CHECK((c == Status::Solved || c == Status::MaxIter));
}
