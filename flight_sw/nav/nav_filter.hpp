// Onboard relative-navigation filter: a Kalman filter on the Clohessy-Wiltshire model that knows the
// delta-v the flight software commanded and learns how far each thruster is off its nominal force. It
// turns the raw relative measurements (position and velocity in the target's LVLH frame, independent
// Gaussian noise per axis) into the estimate the guidance plans from, so that constraints near the
// docking port act on a state several times better than one sample.
//
// State: x = [rho; v] (6) and the six thrusters' relative force errors b (+x, -x, +y, -y, +z, -z),
// b_j = w_j / 100 of the host's thrust model. Between navigation inputs t_k -> t_{k+1} (T = t_{k+1} - t_k):
//   x_{k+1} = Phi(T) x_k + sum_axes Phi(T - tc_i) [0; e_i] dv_i (1 + b_j(i)) + w_k
//   b_{k+1} = exp(-T / tau) b_k + u_k,   var(u_k) = sigma_b^2 (1 - exp(-2 T / tau))
// dv_i is what the pulse on axis i realises nominally, j(i) the thruster that fired it and tc_i the
// centroid of the pulse (half its width after the burn start at t_k): a finite burn acts, to second
// order, like an impulse at its centroid. The force errors are slow (tau of an hour, sigma_b of a few
// per cent) and the same for every burn of a thruster, so a filter that treated them as white noise
// per burn would drift by centimetres over a docking phase of small, same-signed pulses; estimated,
// they are learnt from the large rendezvous burns. w_k: an unmodelled acceleration of spectral density
// q_a (J2, differential drag, the CW linearisation), integrated as a white acceleration per axis.
// Measurement: z_k = x_k + v_k, v_k ~ N(0, diag(sigma_p^2 I, sigma_v^2 I)).
//
// Safety: a measurement whose innovation is implausible (squared Mahalanobis distance above the gate,
// chi-square with 6 degrees of freedom) is not fused; after `max_rejections` in a row the filter
// re-initialises from the measurement (its own estimate is then the suspect). NaN/Inf inputs are never
// fused. With zero measurement noise the filter is the identity (the estimate is the measurement).
// Everything is fixed-size: no heap allocation.
#pragma once

#include <Eigen/Dense>

#include <array>
#include <cstdint>

#include "flight_sw/guidance/cw.hpp"

namespace rvd::nav {

using guidance::Matrix6d;
using guidance::Vector6d;

struct NavFilterParams {
  bool enabled = true;
  double sigma_position_m = 0.0;     // measurement noise, 1 sigma per LVLH axis
  double sigma_velocity_mps = 0.0;
  double thrust_error_sigma = 0.0;   // 1-sigma relative force error of a thruster (0.046 = 4.6 %)
  double thrust_error_tau_s = 3600.0;  // its correlation time
  bool finite_burns = true;          // false: a burn is an impulse at the command time
  // Unmodelled acceleration, sqrt of its spectral density. The largest unmodelled term in LEO is the
  // Coriolis acceleration of the LVLH frame's roll under J2 (about 1e-6 rad/s) on a chaser closing at
  // 1 m/s: 2e-6 m/s^2, held for minutes; 3e-5 m/s^2/sqrt(Hz) lets the filter follow it (README).
  double accel_noise_mps2_rthz = 3e-5;
  double gate_chi2 = 50.0;           // 6-dof chi-square gate (p ~ 1e-8 for a consistent filter)
  int max_rejections = 3;            // consecutive gated measurements before a re-initialisation
  // Empty when usable, else what is wrong.
  const char* validate() const;
  bool passthrough() const { return !enabled || (sigma_position_m == 0.0 && sigma_velocity_mps == 0.0); }
};

enum class NavUpdate : uint8_t {
  Initialised = 0,  // first measurement of a run (or after a reset): estimate = measurement
  Fused = 1,        // predicted and updated
  Gated = 2,        // predicted; the measurement was rejected as implausible
  Reinitialised = 3,  // too many rejections in a row: restarted from the measurement
  Passthrough = 4,  // filter off or noise-free sensors: estimate = measurement
  Invalid = 5,      // NaN/Inf measurement or time: predicted only (or nothing to predict)
};
const char* to_string(NavUpdate u);

using Vector12d = Eigen::Matrix<double, 12, 1>;
using Matrix12d = Eigen::Matrix<double, 12, 12>;

struct NavEstimate {
  Vector6d x = Vector6d::Zero();                  // relative state [m, m/s], LVLH
  Matrix6d P = Matrix6d::Zero();                  // its covariance
  Eigen::Matrix<double, 6, 1> thrust_error = Eigen::Matrix<double, 6, 1>::Zero();  // b, fractions (clamped to +-0.3)
  double thrust_error_sigma = 0.0;  // 1-sigma of b, worst thruster
  NavUpdate update = NavUpdate::Initialised;
  double innovation_chi2 = 0.0;  // squared Mahalanobis distance of the last innovation
};

class NavFilter {
 public:
  NavFilter(const NavFilterParams& params, double mean_motion_rad_s);
  void reset() { initialised_ = false; rejections_ = 0; command_pending_ = false; }

  // The command issued at time t_s: the delta-v per LVLH axis its pulses give at nominal force
  // (F t / m) and the pulse widths (+x, -x, +y, -y, +z, -z); the burn starts at t_s.
  void command(double t_s, const Eigen::Vector3d& dv_lvlh_mps, const std::array<double, 6>& pulse_s);

  // Fuse the measurement z (LVLH) taken at time t_s; returns the estimate to plan from.
  const NavEstimate& update(double t_s, const Vector6d& z);

  const NavEstimate& estimate() const { return est_; }
  const NavFilterParams& params() const { return p_; }
  uint32_t gated() const { return gated_; }
  uint32_t reinitialisations() const { return reinit_; }

 private:
  void initialise(double t_s, const Vector6d& z, NavUpdate why);
  void predict(double t_s);

  void publish(NavUpdate why);

  NavFilterParams p_;
  double n_;
  Matrix6d R_ = Matrix6d::Zero();
  Vector12d s_ = Vector12d::Zero();   // [x; b]
  Matrix12d Ps_ = Matrix12d::Zero();  // its covariance
  NavEstimate est_;
  double t_ = 0.0;
  bool initialised_ = false;
  int rejections_ = 0;
  uint32_t gated_ = 0, reinit_ = 0;
  bool command_pending_ = false;
  double t_cmd_ = 0.0;
  Eigen::Vector3d dv_cmd_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d centroid_s_ = Eigen::Vector3d::Zero();
  std::array<int, 3> thruster_{};  // the thruster that fired on each axis (index into b), -1 none
};

}  // namespace rvd::nav
