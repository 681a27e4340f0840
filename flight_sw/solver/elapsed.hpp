// Wall time in microseconds from steady_clock, converted by instructions that do not depend on the
// value: the deadline checks run inside the counted guidance step (rvd_pil/qemu/README.md, "Cycle model"),
// whose instructions and cycles must repeat from run to run although the clock's readings do not.
//
// Armv7's VFP has no 64-bit integer to double conversion, so `duration<double, micro>` calls
// libgcc's __aeabi_l2d, whose normalisation branches on the value's magnitude (below 2^21 ns, one
// path; above, another of the same length through other blocks): a step timed at 2.0 ms and one
// at 2.2 ms executed the same number of instructions but not the same ones. Two 32-bit halves take
// two VFP conversions (vcvt.f64.s32 / .u32) and a multiply-add, with no branch on any target;
// exact below 2^53 ns (104 days).
#pragma once

#include <chrono>
#include <cstdint>

namespace rvd::solver {

using SteadyClock = std::chrono::steady_clock;

inline double to_us(SteadyClock::duration d) {
  const std::int64_t ns = std::chrono::duration_cast<std::chrono::nanoseconds>(d).count();
  const auto high = static_cast<std::int32_t>(ns >> 32);
  const auto low = static_cast<std::uint32_t>(ns & 0xffffffff);
  return (static_cast<double>(high) * 4294967296.0 + static_cast<double>(low)) / 1e3;
}

inline double elapsed_us(SteadyClock::time_point t0) { return to_us(SteadyClock::now() - t0); }

}  // namespace rvd::solver
