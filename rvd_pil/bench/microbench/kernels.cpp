// Microbenchmarks with known answers for the cycle model (rvd_pil/bench/microbench/README.md): each kernel
// is a loop of hand-written instructions whose cost per iteration follows from published
// latencies and throughputs, run inside one solve marker so that the block-profile plugin counts
// it exactly as it counts the flight software's solves.
//
//   kernels KERNEL ITERATIONS [KERNEL ITERATIONS ...]
//
// Kernels (OPS_PER_ITERATION of the measured instruction, plus the loop's own subs/b.ne):
//   fma_chain   8 dependent FP64 multiply-adds, each accumulating into the previous result
//               (A64 FMADD d0 = d0 + d1*d2; A32 VMLA.F64 d0 += d1*d2)
//   fma_stream  8 independent FP64 multiply-adds (8 accumulators): throughput
//   load_chain  8 dependent loads, each address the previous load's result (pointer chasing a
//               pointer that points to itself: always an L1 hit)
//   div_chain   8 dependent FP64 divides
//   call_loop   4 calls of a function that returns at once (BL + RET; A32: BL + BX LR)
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "flight_sw/app/solve_marker.hpp"

namespace {

extern "C" void rvd_micro_leaf();

#if defined(__aarch64__)
asm(".text\n.global rvd_micro_leaf\n.type rvd_micro_leaf, %function\nrvd_micro_leaf:\n\tret\n");

#define REP8(x) x x x x x x x x

void fma_chain(std::uint64_t n) {
  asm volatile("fmov d0, #1.0\n\tfmov d1, #1.0\n\tfmov d2, #0.5\n"
               "1:\n\t" REP8("fmadd d0, d1, d2, d0\n\t") "subs %0, %0, #1\n\tb.ne 1b"
               : "+r"(n) : : "cc", "v0", "v1", "v2");
}

void fma_stream(std::uint64_t n) {
  asm volatile("fmov d1, #1.0\n\tfmov d2, #0.5\n"
               "1:\n\t"
               "fmadd d0, d1, d2, d0\n\tfmadd d3, d1, d2, d3\n\tfmadd d4, d1, d2, d4\n\tfmadd d5, d1, d2, d5\n\t"
               "fmadd d6, d1, d2, d6\n\tfmadd d7, d1, d2, d7\n\tfmadd d16, d1, d2, d16\n\tfmadd d17, d1, d2, d17\n\t"
               "subs %0, %0, #1\n\tb.ne 1b"
               : "+r"(n) : : "cc", "v0", "v1", "v2", "v3", "v4", "v5", "v6", "v7", "v16", "v17");
}

void load_chain(std::uint64_t n) {
  void* self[1];
  self[0] = &self[0];
  void* p = self;
  asm volatile("1:\n\t" REP8("ldr %1, [%1]\n\t") "subs %0, %0, #1\n\tb.ne 1b"
               : "+r"(n), "+r"(p) : : "cc", "memory");
}

void div_chain(std::uint64_t n) {
  asm volatile("fmov d0, #1.0\n\tfmov d1, #1.0\n"
               "1:\n\t" REP8("fdiv d0, d0, d1\n\t") "subs %0, %0, #1\n\tb.ne 1b"
               : "+r"(n) : : "cc", "v0", "v1");
}

void call_loop(std::uint64_t n) {
  asm volatile("1:\n\tbl rvd_micro_leaf\n\tbl rvd_micro_leaf\n\tbl rvd_micro_leaf\n\tbl rvd_micro_leaf\n\t"
               "subs %0, %0, #1\n\tb.ne 1b"
               : "+r"(n) : : "cc", "x30", "memory");
}

#elif defined(__arm__)
asm(".text\n.syntax unified\n.global rvd_micro_leaf\n.type rvd_micro_leaf, %function\n"
#if defined(__thumb__)
    ".thumb_func\n"
#endif
    "rvd_micro_leaf:\n\tbx lr\n");

#define REP8(x) x x x x x x x x

void fma_chain(std::uint64_t n64) {
  std::uint32_t n = static_cast<std::uint32_t>(n64);
  asm volatile("vmov.f64 d0, #1.0\n\tvmov.f64 d1, #1.0\n\tvmov.f64 d2, #0.5\n"
               "1:\n\t" REP8("vmla.f64 d0, d1, d2\n\t") "subs %0, %0, #1\n\tbne 1b"
               : "+r"(n) : : "cc", "d0", "d1", "d2");
}

void fma_stream(std::uint64_t n64) {
  std::uint32_t n = static_cast<std::uint32_t>(n64);
  asm volatile("vmov.f64 d1, #1.0\n\tvmov.f64 d2, #0.5\n"
               "1:\n\t"
               "vmla.f64 d0, d1, d2\n\tvmla.f64 d3, d1, d2\n\tvmla.f64 d4, d1, d2\n\tvmla.f64 d5, d1, d2\n\t"
               "vmla.f64 d6, d1, d2\n\tvmla.f64 d7, d1, d2\n\tvmla.f64 d16, d1, d2\n\tvmla.f64 d17, d1, d2\n\t"
               "subs %0, %0, #1\n\tbne 1b"
               : "+r"(n) : : "cc", "d0", "d1", "d2", "d3", "d4", "d5", "d6", "d7", "d16", "d17");
}

void load_chain(std::uint64_t n64) {
  std::uint32_t n = static_cast<std::uint32_t>(n64);
  void* self[1];
  self[0] = &self[0];
  void* p = self;
  asm volatile("1:\n\t" REP8("ldr %1, [%1]\n\t") "subs %0, %0, #1\n\tbne 1b"
               : "+r"(n), "+r"(p) : : "cc", "memory");
}

void div_chain(std::uint64_t n64) {
  std::uint32_t n = static_cast<std::uint32_t>(n64);
  asm volatile("vmov.f64 d0, #1.0\n\tvmov.f64 d1, #1.0\n"
               "1:\n\t" REP8("vdiv.f64 d0, d0, d1\n\t") "subs %0, %0, #1\n\tbne 1b"
               : "+r"(n) : : "cc", "d0", "d1");
}

void call_loop(std::uint64_t n64) {
  std::uint32_t n = static_cast<std::uint32_t>(n64);
  asm volatile("1:\n\tbl rvd_micro_leaf\n\tbl rvd_micro_leaf\n\tbl rvd_micro_leaf\n\tbl rvd_micro_leaf\n\t"
               "subs %0, %0, #1\n\tbne 1b"
               : "+r"(n) : : "cc", "lr", "memory");
}
#else
#error "the microbenchmarks are ARM assembly: build them with the cross compilers (rvd_pil/bench/microbench/run.py)"
#endif

struct Kernel {
  const char* name;
  void (*run)(std::uint64_t);
};

constexpr Kernel kKernels[] = {{"fma_chain", fma_chain}, {"fma_stream", fma_stream}, {"load_chain", load_chain},
                               {"div_chain", div_chain}, {"call_loop", call_loop}};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3 || argc % 2 == 0) {
    std::fprintf(stderr, "usage: %s KERNEL ITERATIONS [KERNEL ITERATIONS ...]\n", argv[0]);
    return 2;
  }
  rvd::SolveMarker marker(true);
  for (int i = 1; i + 1 < argc; i += 2) {
    const Kernel* k = nullptr;
    for (const Kernel& c : kKernels)
      if (std::strcmp(c.name, argv[i]) == 0) k = &c;
    char* end = nullptr;
    const unsigned long long n = std::strtoull(argv[i + 1], &end, 10);
    if (k == nullptr || end == argv[i + 1] || *end != '\0' || n == 0) {
      std::fprintf(stderr, "unknown kernel or bad count: %s %s\n", argv[i], argv[i + 1]);
      return 2;
    }
    const std::uint32_t step = static_cast<std::uint32_t>(i / 2);  // 0, 1, 2, ... in argument order
    marker.begin(step);
    k->run(n);
    const std::uint64_t insns = marker.end(step);
    std::printf("kernel=%s step=%u iterations=%llu insns=%llu\n", k->name, step, n,
                static_cast<unsigned long long>(insns));
  }
  return 0;
}
