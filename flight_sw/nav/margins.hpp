// The navigation and actuation error budget turned into guidance margins (flight_sw/guidance/README.md,
// "Robustness margins"): how far the guidance keeps from each limit so that the truth stays inside it
// when the estimate is off by a few standard deviations, the thrusters deliver a few per cent less and
// the state moves on between two samples.
#pragma once

#include "flight_sw/guidance/params.hpp"

namespace rvd::nav {

// What the flight software knows of its disturbances: navigation noise (1 sigma per LVLH axis), the
// thrust amplitude error (1 sigma, fraction of the force), whether the thrusters burn for a finite time,
// and how many standard deviations the margins cover.
struct ErrorModel {
  double sigma_position_m = 0.0;
  double sigma_velocity_mps = 0.0;
  double thrust_error_sigma = 0.0;
  bool finite_burns = false;
  double sigmas = 3.0;
};

// Margins covering `errors` for a guidance with these parameters (k = errors.sigmas):
//   estimate_sigmas = k                 online, from the navigation filter's covariance: every geometric
//                                       limit moves in by k sigma_p, v_max by k sigma_v; each thruster's
//                                       input bound is u_max (s_j - k sigma_s) (s_j its estimated
//                                       relative force, sigma_s that estimate's error, sigma_w before it
//                                       is learnt); the overshoot plane by k sigma_s u_max (Ts - t_c) and
//                                       v_max by k sigma_s u_max,d (a burn off by k sigma_s of it)
//   plan_reserve_fraction = 0.1         stages 1.. leave 10 % of that authority to the next plan
//   approach_entry_brake_fraction = 0.5 rendezvous -> approach only when half the approach phase's
//                                       deceleration stops the motion towards a corridor face before it
//                                       (relative to the face, which turns with the target)
//   approach_cone_m = u_max,a t_c       a lateral burn shorter than a full pulse acts up to t_c earlier
//                                       than the prediction assumes
//   approach_speed_cap_mps = 0.8        the approach phase's closing speed (braking at its limit from
//                                       1.2 m/s, the CW coupling pushed it out of the corridor)
//   approach_brake_fraction = 0.75      and no faster than 75 % of the braking authority stops at the
//                                       overshoot plane (a braking thruster found weaker mid-braking);
//                             = 1       undisturbed: no faster than all of it stops there (a horizon
//                                       shorter than the braking otherwise plans past the point of no return)
//   rendezvous_brake_fraction = 0.75 / 1   the same curve in the rendezvous, towards each stage's keep-out
//                                       plane (a short horizon otherwise plans towards the sphere faster
//                                       than it can brake once the braking distance comes into view)
// The reserve and the speed cap apply when anything disturbs the run; the braking curves always.
//   keepout_m       = (1 m/s Ts_r)^2 / (8 r1)   the sagitta of a period's chord round the sphere
//   rotating_cone_factor = 2.5          a spinning target's corridor and plane turn between samples
//   v_max_mps       = dv of one minimum impulse bit + 3 n^2 (r2 + 2 m) Ts_d: a correction smaller than
//                     the bit is not fired, and near r2 the radial CW term alone speeds the chaser up
//                     by that much within one docking period
// The keep-out, rotating and first v_max terms are discretisation effects and apply to a noise-free run too.
guidance::Margins derive_margins(const ErrorModel& errors, const guidance::GuidanceParams& params);

}  // namespace rvd::nav
