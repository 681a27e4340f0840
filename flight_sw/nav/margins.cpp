#include "flight_sw/nav/margins.hpp"

#include <algorithm>
#include <cmath>

namespace rvd::nav {

namespace {
// Fastest sliding speed round the keep-out sphere assumed for the chord allowance: the Monte Carlo
// of 100 random starts peaks at 0.6 m/s.
constexpr double kSlideSpeed_mps = 1.0;
// Case 3 (0.25 deg/s, CW truth, no noise): a chaser inside the corridor at every sample is up to
// 0.46 m outside it between samples at 140 m, i.e. 1.2 |rho| (omega Ts)^2 with omega Ts = 5 deg;
// the factor takes twice that.
constexpr double kRotatingConeFactor = 2.5;
}  // namespace

guidance::Margins derive_margins(const ErrorModel& e, const guidance::GuidanceParams& p) {
  guidance::Margins m;
  const double n = p.mean_motion_rad_s();
  m.input_fraction = std::min(0.5, e.sigmas * e.thrust_error_sigma);
  m.estimate_sigmas = e.sigmas;
  const double chord = kSlideSpeed_mps * p.rendezvous.Ts_s;
  m.keepout_m = chord * chord / (8.0 * p.keepout_radius_m);
  m.rotating_cone_factor = kRotatingConeFactor;
  const double mib_dv = p.thrusters.thrust_N * p.thrusters.min_impulse_bit_s / p.thrusters.mass_kg;
  const double drift = 3.0 * n * n * (p.approach_stop_m + p.approach_switch_margin_m) * p.docking.Ts_s;
  m.v_max_mps = mib_dv + drift;
  // The burn before a sample misses its delta-v by up to k sigma_w of it: at u_max that is a velocity
  // error of k sigma_w u_max and, from the burn's centroid to the sample, a position error of
  // k sigma_w u_max (Ts - t_c). The overshoot plane (approach braking at u_max) and v_max (docking
  // acceleration at u_max) take it; the docking cone's lateral corrections are millimetres per second.
  const double ke = e.sigmas * e.thrust_error_sigma;
  const double u_app = p.approach.u_max_mps;
  const double centroid = e.finite_burns ? 0.5 * guidance::max_pulse_s(u_app, p.thrusters) : 0.0;
  m.overshoot_m = ke * u_app * (p.approach.Ts_s - centroid);
  m.v_max_mps += ke * p.docking.u_max_mps;
  return m;
}

}  // namespace rvd::nav
