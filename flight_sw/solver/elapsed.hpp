// The flight clock: what every deadline decision and step time of the guidance step is measured on.
//
// By default it is the host's steady_clock. Under QEMU user mode the host's clock runs at the
// emulator's speed, not the target's (a step of 0.2 s on the flight computer can take seconds of
// host time), so the harness configures the target clock instead (use_target(), the flight's
// --target-clock CPI,HZ): the QEMU plugin (rvd_pil/qemu/plugin/insn_count.c, marker op 3) hands back
// the guest's instruction count, and elapsed = instructions x CPI / f_clk. Its readings are a
// function of the code executed, so budget decisions and step times repeat from run to run. When
// no plugin answers (a native run, QEMU without the plugin), use_target() keeps steady_clock and
// says so (source() == StepClock::TargetUnanswered).
//
// Conversions take instructions that do not depend on the value: the deadline checks run inside
// the counted guidance step (rvd_pil/qemu/README.md, "Cycle model"), whose instructions and cycles
// must repeat from run to run although the clock's readings do not. Armv7's VFP has no 64-bit
// integer to double conversion, so `duration<double, micro>` calls libgcc's __aeabi_l2d, whose
// normalisation branches on the value's magnitude (below 2^21 ns, one path; above, another of the
// same length through other blocks): a step timed at 2.0 ms and one at 2.2 ms executed the same
// number of instructions but not the same ones. Two 32-bit halves take two VFP conversions
// (vcvt.f64.s32 / .u32) and a multiply-add, with no branch on any target; exact below 2^53 ticks
// (104 days of nanoseconds). Both clocks take the same path: ticks / the clock's ticks per microsecond.
#pragma once

#include <cerrno>
#include <chrono>
#include <cstdint>
#include <limits>

#if defined(__linux__)
#include <sys/syscall.h>
#include <unistd.h>
#endif

namespace rvd {

// Marker ABI, shared with the QEMU plugin insn_count.c: syscall(kSolveMarkerSyscall, op, step, &slot).
inline constexpr long kSolveMarkerSyscall = 0x5256;  // "RV": unallocated on arm, aarch64 and x86-64 Linux
inline constexpr std::uint64_t kSlotRequest = 0x525644534c4f543fULL;  // "RVDSLOT?"
inline constexpr std::uint64_t kSlotAck = 0x525644534c4f5421ULL;      // "RVDSLOT!"
enum MarkerOp : long { kMarkerBegin = 1, kMarkerEnd = 2, kMarkerReadCount = 3 };

// One marker call; the plugin, if any, answers in *slot (which must hold kSlotRequest before).
// Without a plugin Linux answers ENOSYS, which must not leak into the caller's error handling.
inline void marker_call(MarkerOp op, std::uint32_t step, std::uint64_t* slot) {
#if defined(__linux__)
  const int saved_errno = errno;
  ::syscall(kSolveMarkerSyscall, static_cast<long>(op), static_cast<long>(step), slot);
  errno = saved_errno;
#else
  (void)op, (void)step, (void)slot;
#endif
}

}  // namespace rvd

namespace rvd::solver {

using SteadyClock = std::chrono::steady_clock;

// Which clock the flight's step times and deadlines are on (hello and telemetry: step_clock).
enum class StepClock : std::uint8_t {
  Host = 0,              // this computer's steady_clock (native, a board, QEMU system mode)
  Target = 1,            // instructions counted by the QEMU plugin x CPI / f_clk
  TargetUnanswered = 2,  // the target clock was asked for, no plugin answered: steady_clock
};
const char* to_string(StepClock c);

// A reading: ticks of the clock in use, and which configuration of it (`epoch`) took it, so that
// a reading is never compared with one of another clock.
struct TimePoint {
  std::int64_t ticks = 0;
  std::uint32_t epoch = 0;
};

class FlightClock {
 public:
  // The target clock at `cpi` cycles per instruction and `clock_hz`, if the plugin answers a read;
  // otherwise steady_clock (TargetUnanswered). Returns the clock now in use.
  StepClock use_target(double cpi, double clock_hz);
  void use_host();  // steady_clock (the default)
  StepClock source() const { return source_; }
  double cpi() const { return cpi_; }
  double clock_hz() const { return clock_hz_; }

  TimePoint now() {
    if (source_ == StepClock::Target) {
      alignas(8) std::uint64_t slot = kSlotRequest;  // the plugin checks the alignment
      marker_call(kMarkerReadCount, 0, &slot);
      if (slot != kSlotRequest) return {static_cast<std::int64_t>(slot), epoch_};
      lost_plugin();  // answered before, silent now: steady_clock from here on
    }
    return {std::chrono::duration_cast<std::chrono::nanoseconds>(SteadyClock::now().time_since_epoch()).count(),
            epoch_};
  }

  // Microseconds from t0 to now. A reading of another clock configuration (the plugin fell silent
  // in between) gives +infinity: whatever budget it was timing is spent, and the step degrades.
  double elapsed_us(TimePoint t0) { return between_us(t0, now()); }
  double between_us(TimePoint t0, TimePoint t1) const {
    if (t1.epoch != t0.epoch) return std::numeric_limits<double>::infinity();
    return to_us(t1.ticks - t0.ticks);
  }

  double to_us(std::int64_t ticks) const {
    const auto high = static_cast<std::int32_t>(ticks >> 32);
    const auto low = static_cast<std::uint32_t>(ticks & 0xffffffff);
    return (static_cast<double>(high) * 4294967296.0 + static_cast<double>(low)) / ticks_per_us_;
  }

 private:
  void lost_plugin();

  StepClock source_ = StepClock::Host;
  double ticks_per_us_ = 1e3;  // steady_clock: nanoseconds
  double cpi_ = 0.0, clock_hz_ = 0.0;
  std::uint32_t epoch_ = 0;
};

// The process's flight clock (one per process: the flight software is single-threaded).
FlightClock& flight_clock();

inline TimePoint clock_now() { return flight_clock().now(); }
inline double elapsed_us(TimePoint t0) { return flight_clock().elapsed_us(t0); }

}  // namespace rvd::solver
