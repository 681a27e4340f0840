// Guest side of instruction counting: marks the start and end of each solve so that the QEMU
// plugin rvd_pil/qemu/plugin/insn_count.c can count the instructions in between and write the count back
// into this object, from where it travels in the flight software's own telemetry.
//
//   rvd::SolveMarker marker;          // on by default on ARM builds, off on the host
//   marker.begin(step);
//   solver.solve(qp, x0);
//   std::uint64_t insns = marker.end(step);   // 0 when not running under the plugin
//
// Marker ABI (shared with the plugin, flight_sw/solver/elapsed.hpp): syscall(kSolveMarkerSyscall,
// op, step, &slot), op 1 = begin, 2 = end. Linux has no such syscall: a real kernel, or QEMU without
// the plugin, answers ENOSYS, which is harmless. Before each call the slot holds kSlotRequest; the
// plugin answers a begin with kSlotAck and an end with the instruction count. If the first begin is
// not acknowledged, no plugin is listening and the marker switches itself off: from then on
// begin/end are a branch.
#pragma once

#include <cstdint>

#include "flight_sw/solver/elapsed.hpp"

namespace rvd {

#if defined(__linux__) && (defined(__arm__) || defined(__aarch64__))
inline constexpr bool kSolveMarkersByDefault = true;  // the builds QEMU emulates
#else
inline constexpr bool kSolveMarkersByDefault = false;  // host builds: no syscall at all
#endif

class SolveMarker {
 public:
  // enabled = false makes begin/end do nothing; true on a host build is allowed (ENOSYS, then off).
  explicit SolveMarker(bool enabled = kSolveMarkersByDefault) : state_(enabled ? kProbe : kOff) {}

  void begin(std::uint32_t step) {
    if (state_ == kOff) return;
    call(kMarkerBegin, step);
    if (state_ == kProbe) state_ = (slot_ == kSlotAck) ? kCounting : kOff;
  }

  // Instructions executed since begin(step), counted by the plugin; 0 when not under the plugin.
  std::uint64_t end(std::uint32_t step) {
    if (state_ != kCounting) return 0;
    call(kMarkerEnd, step);
    return slot_ == kSlotRequest ? 0 : slot_;
  }

  // True once the plugin has acknowledged a begin marker.
  bool counting() const { return state_ == kCounting; }

 private:
  enum State { kProbe, kCounting, kOff };

  void call(MarkerOp op, std::uint32_t step) {
    slot_ = kSlotRequest;
    marker_call(op, step, &slot_);
  }

  alignas(8) std::uint64_t slot_ = 0;  // the plugin writes here (guest memory)
  State state_;
};

}  // namespace rvd
