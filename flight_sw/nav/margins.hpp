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
//   input_fraction  = k sigma_w         stages 1.. plan with what the thrusters deliver at -k sigma
//   estimate_sigmas = k                 every geometric limit moves in by k sigma_p of the current
//                                       estimate, v_max by k sigma_v (the filter's covariance, online)
//   keepout_m       = (1 m/s Ts_r)^2 / (8 r1)   the sagitta of a period's chord round the sphere
//   rotating_cone_factor = 2.5          a spinning target's corridor and plane turn between samples
//   v_max_mps       = dv of one minimum impulse bit + 3 n^2 (r2 + 2 m) Ts_d: a correction smaller than
//                     the bit is not fired, and near r2 the radial CW term alone speeds the chaser up
//                     by that much within one docking period
//   overshoot_m    += k sigma_w u_max,a (Ts_a - t_c)  the braking burn before a sample is short by up to
//                                                     k sigma_w of it (t_c: its centroid)
//   v_max_mps      += k sigma_w u_max,d               likewise an accelerating docking burn
// The keep-out, rotating and first v_max terms are discretisation effects and apply to a noise-free run too.
guidance::Margins derive_margins(const ErrorModel& errors, const guidance::GuidanceParams& params);

}  // namespace rvd::nav
