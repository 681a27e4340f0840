/* rvd_corridor.h: the docking corridor of Dong, Ghiglino et al. ("Fast model predictive control with
 * moving obstacle avoidance") for any guidance law (C ABI, C99 / C++): the dynamic holding radius
 * (their eq. 9) and the two-plane entry cone (eq. 10). The built-in MPC uses the same functions
 * (flight_sw/guidance/holding.hpp); a plug-in law linked with the harness calls them directly.
 *
 * Frames and units as rvd_guidance.h: LVLH about the target's centre of mass, the target's docking
 * axis along its body +x, quaternions (w, x, y, z) LVLH <- body, SI units. None of them allocates.
 */
#ifndef RVD_CORRIDOR_H
#define RVD_CORRIDOR_H

#ifdef __cplusplus
extern "C" {
#endif

/* The holding radius over a run. Set up with rvd_holding_init; call rvd_holding_observe once per
 * control step. */
typedef struct rvd_holding_radius {
  double radius_m;               /* r_hold the current step plans with [m] */
  double next_radius_m;          /* r_hold of the next step [m] (gamma r_hold after a step that met both conditions) */
  double radius_min_m;           /* r_hold,min: never below (the centre-of-mass distance when docked) [m] */
  double shrink;                 /* gamma in (0, 1) */
  double tolerance_m;            /* eta: the chaser within this of the holding position [m] ... */
  double attitude_tolerance_rad; /* epsilon: ... and within this of its docking attitude [rad] */
} rvd_holding_radius;

void rvd_holding_init(rvd_holding_radius* h, double radius_m, double radius_min_m, double shrink,
                      double tolerance_m, double attitude_tolerance_rad);

/* One step: returns the radius to plan with now, and shrinks the next one when the chaser (LVLH
 * position) is within eta of the holding position and attitude_error_rad within epsilon (NaN:
 * attitude unknown, the position alone decides). */
double rvd_holding_observe(rvd_holding_radius* h, const double chaser_lvlh_m[3], const double q_lvlh_body[4],
                           const double port_body_m[3], double attitude_error_rad);

/* The holding position: on the sphere of radius_m about the target's centre of mass, directly in
 * front of the port (the port itself when the sphere lies inside it). */
void rvd_holding_position(const double q_lvlh_body[4], const double port_body_m[3], double radius_m,
                          double position_lvlh_m[3]);

/* Eq. 9 linearized about a predicted position: normal' rho >= *bound_m (normal unit, along
 * about_lvlh_m; +x when it is at the centre). */
void rvd_holding_row(double radius_m, const double about_lvlh_m[3], double normal[3], double* bound_m);

/* Eq. 10: rows[j]' rho <= bounds[j], j = 0, 1: the two planes through the port at half_angle_rad
 * about the docking axis, in the target's body x-y plane (rows unit: the excess is in metres). */
void rvd_entry_cone(const double q_lvlh_body[4], const double port_body_m[3], double half_angle_rad,
                    double rows[2][3], double bounds[2]);

/* Angle [rad] between the chaser's docking axis (its body +x, q_lvlh_chaser) and minus the target's:
 * the attitude error of the holding radius' second condition. */
double rvd_docking_attitude_error(const double q_lvlh_chaser[4], const double q_lvlh_target[4]);

#ifdef __cplusplus
}
#endif

#endif /* RVD_CORRIDOR_H */
