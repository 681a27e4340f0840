// Clohessy-Wiltshire relative motion in the target's LVLH frame (dissertation eqs 2.1-2.3, 3.1).
// LVLH: x radial out (R-bar), y along-track (V-bar), z orbit normal. State x = [rho; rho_dot] in m, m/s.
//   xdd = 3 n^2 x + 2 n yd,   ydd = -2 n xd,   zdd = -n^2 z.
#pragma once

#include <Eigen/Dense>

namespace rvd::guidance {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Matrix63d = Eigen::Matrix<double, 6, 3>;

// The same constants as rvd_pil/host_sim/constants.py (JGM-3 / EGM96 values), so that the guidance's CW model and
// the host simulator's CW truth have bit-for-bit the same mean motion.
constexpr double kEarthMu_m3_s2 = 3.986004415e14;
constexpr double kEarthRadius_m = 6378136.3;

// Mean motion of a circular orbit at this altitude above the equatorial radius [rad/s].
double mean_motion_rad_s(double altitude_m, double mu_m3_s2 = kEarthMu_m3_s2, double earth_radius_m = kEarthRadius_m);

// Closed-form CW state transition matrix Phi(t) = exp(Ac t) (no matrix exponential at run time);
// n = 0 gives the double integrator (no orbit).
Matrix6d cw_stm(double n_rad_s, double t_s);

// The continuous CW system matrix Ac (for tests and documentation; the guidance never integrates it).
Matrix6d cw_system_matrix(double n_rad_s);

// Impulsive-invariant discretisation over one period Ts: A = Phi(Ts), B = A [0; I]
// (the velocity impulse is applied at the start of the period, then the state drifts).
void cw_impulsive_model(double n_rad_s, double Ts_s, Matrix6d& A, Matrix63d& B);

// The same with the impulse applied `centroid_s` after the period start (a finite burn's centroid):
// A = Phi(Ts), B = Phi(Ts - centroid) [0; I]. centroid_s = 0 is cw_impulsive_model.
void cw_burn_model(double n_rad_s, double Ts_s, double centroid_s, Matrix6d& A, Matrix63d& B);

}  // namespace rvd::guidance
