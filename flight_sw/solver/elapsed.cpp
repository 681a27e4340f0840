// The process's flight clock (elapsed.hpp): configuration, and the one message when it falls back.
#include "flight_sw/solver/elapsed.hpp"

#include <cmath>
#include <cstdio>

namespace rvd::solver {

const char* to_string(StepClock c) {
  switch (c) {
    case StepClock::Host: return "host steady_clock";
    case StepClock::Target: return "target clock (instructions x CPI / f_clk)";
    case StepClock::TargetUnanswered: return "host steady_clock (target clock asked for, no plugin answered)";
  }
  return "unknown";
}

FlightClock& flight_clock() {
  static FlightClock clock;
  return clock;
}

StepClock FlightClock::use_target(double cpi, double clock_hz) {
  use_host();
  if (!(cpi > 0.0) || !(clock_hz > 0.0) || !std::isfinite(cpi) || !std::isfinite(clock_hz)) {
    source_ = StepClock::TargetUnanswered;
    return source_;
  }
  cpi_ = cpi;
  clock_hz_ = clock_hz;
  alignas(8) std::uint64_t slot = kSlotRequest;
  marker_call(kMarkerReadCount, 0, &slot);
  if (slot == kSlotRequest) {
    source_ = StepClock::TargetUnanswered;  // steady_clock, said so in hello and telemetry
    return source_;
  }
  source_ = StepClock::Target;
  ticks_per_us_ = clock_hz / (cpi * 1e6);  // instructions per microsecond
  ++epoch_;
  return source_;
}

void FlightClock::use_host() {
  if (source_ == StepClock::Target) ++epoch_;
  source_ = StepClock::Host;
  ticks_per_us_ = 1e3;
}

void FlightClock::lost_plugin() {
  std::fprintf(stderr, "[flight_sw] the instruction-counting plugin stopped answering the flight clock: "
                       "host steady_clock from here on\n");
  source_ = StepClock::TargetUnanswered;
  ticks_per_us_ = 1e3;
  ++epoch_;
}

}  // namespace rvd::solver
