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
// A random start swept through the corridor at 1.2 m/s sideways, switched to the approach phase on the
// way and left the corridor by 31 m; entering only when half the approach phase's deceleration stops the
// sideways motion inside the corridor keeps the other half for the closing and the CW coupling.
constexpr double kEntryBrakeFraction = 0.5;
// Authority the later stages of a plan leave unused for the next plan (when anything disturbs the run).
constexpr double kPlanReserve = 0.1;
// Approach closing-speed cap when disturbed. Uncapped, the approach phase reached 1.2 m/s and braked for
// 160 s at its limit; the radial CW term 2 n v (2.6e-3 m/s^2, a third of the lateral authority) then
// made the plan brake with radial burns and leave the corridor near its end (2 of 300 Monte Carlo
// runs, by 5 cm and 42 cm). At 0.8 m/s braking takes 110 s and 45 m: no run of 100 left the corridor,
// and the mean delta-v fell by 0.45 m/s at +0.4 min.
constexpr double kApproachSpeedCap_mps = 0.8;
// Approach braking curve (when disturbed): the plan brakes with at most this fraction of its braking
// authority. Braking with all of it at the last moment, a braking thruster found 6 % weaker than its
// estimate in the middle of the braking (unused since the rendezvous, its force had drifted by 10 %) left
// the overshoot plane reachable only through a lateral swing 7 m out of the corridor (2 of 5880 runs).
constexpr double kApproachBrakeFraction = 0.75;
// Undisturbed, the curve with all of the braking authority: the closing speed from which the chaser can
// still stop at the overshoot plane. A plan's horizon need not reach the plane (approach N = 5 at Ts 5-20 s
// sees 25-100 s ahead); without the curve such a plan closed faster than it could brake, met the plane
// infeasible and left the corridor or hit the target in 500 of 500 ideal-world runs of the ch. 4 study.
constexpr double kApproachBrakeFractionIdeal = 1.0;
// The same curve in the rendezvous, towards each stage's keep-out plane, with the same fractions: a
// 15-stage rendezvous (450 s) round a turning target closed at 2.9 m/s, met the braking distance only
// when it no longer fitted, and 3 of 400 disturbed random starts entered the sphere (by up to 25 m).
constexpr double kRendezvousBrakeFraction = kApproachBrakeFraction;
constexpr double kRendezvousBrakeFractionIdeal = kApproachBrakeFractionIdeal;
}  // namespace

guidance::Margins derive_margins(const ErrorModel& e, const guidance::GuidanceParams& p) {
  guidance::Margins m;
  const double n = p.mean_motion_rad_s();
  const bool disturbed = e.sigma_position_m > 0.0 || e.sigma_velocity_mps > 0.0 || e.thrust_error_sigma > 0.0 ||
                         e.finite_burns;
  m.plan_reserve_fraction = disturbed ? kPlanReserve : 0.0;
  m.approach_speed_cap_mps = disturbed ? kApproachSpeedCap_mps : 0.0;
  m.approach_brake_fraction = disturbed ? kApproachBrakeFraction : kApproachBrakeFractionIdeal;
  m.rendezvous_brake_fraction = disturbed ? kRendezvousBrakeFraction : kRendezvousBrakeFractionIdeal;
  m.estimate_sigmas = e.sigmas;
  const double chord = kSlideSpeed_mps * p.rendezvous.Ts_s;
  m.keepout_m = chord * chord / (8.0 * p.keepout_radius_m);
  m.rotating_cone_factor = kRotatingConeFactor;
  m.approach_entry_brake_fraction = kEntryBrakeFraction;
  const double mib_dv = p.thrusters.thrust_N * p.thrusters.min_impulse_bit_s / p.thrusters.mass_kg;
  const double drift = 3.0 * n * n * (p.approach_stop_m + p.approach_switch_margin_m) * p.docking.Ts_s;
  m.v_max_mps = mib_dv + drift;
  // The prediction puts every burn at a full pulse's centroid; a shorter lateral burn acts up to that
  // much earlier: a position error of up to u_max t_c by the next sample.
  const double u_app = p.approach.u_max_mps;
  const double centroid = e.finite_burns ? 0.5 * guidance::max_pulse_s(u_app, p.thrusters) : 0.0;
  m.approach_cone_m = u_app * centroid;
  return m;
}

}  // namespace rvd::nav
