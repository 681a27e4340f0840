#include "flight_sw/guidance/allocation.hpp"

#include <algorithm>
#include <cmath>

namespace rvd::guidance {

double max_pulse_s(double u_max_mps, const ThrusterParams& thr) { return u_max_mps * thr.mass_kg / thr.thrust_N; }

Allocation allocate_thrusters(const Eigen::Vector3d& dv, double max_pulse, const ThrusterParams& thr,
                              const ThrustScale& scale) {
  Allocation a;
  for (int axis = 0; axis < 3; ++axis) {
    const double v = dv(axis);
    if (!std::isfinite(v) || v == 0.0) continue;
    const int j = 2 * axis + (v > 0.0 ? 0 : 1);
    // An implausible estimate (or none) is the nominal force: the filter's is clamped, this is the guard.
    const double s = std::isfinite(scale[j]) && scale[j] > 0.5 && scale[j] < 1.5 ? scale[j] : 1.0;
    double t = thr.mass_kg * std::abs(v) / (s * thr.thrust_N);
    t = std::min(t, max_pulse);
    if (t < thr.min_impulse_bit_s) continue;  // eq 2.6: below the minimum impulse bit nothing is fired
    a.pulse_s[j] = t;
    a.dv_nominal_mps(axis) = std::copysign(thr.thrust_N * t / thr.mass_kg, v);
    a.dv_alloc_mps(axis) = s * a.dv_nominal_mps(axis);
  }
  return a;
}

}  // namespace rvd::guidance
