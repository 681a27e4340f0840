// The chaser's rotation about LVLH z where the truth has it (the planar truth of an air-bearing table,
// Dong, Ghiglino et al.'s eq. 4: I theta'' = tau). Their MPC carries x, y and theta in one QP with a
// diagonal Q and R; the rotation is decoupled from the translation in the dynamics, the cost and every
// constraint (|tau| <= tau_max only), so its part of their QP is this separate one, solved here by the
// same Fast MPC solver on the same horizon and period as the phase's:
//
//   min sum_i Q_angle e_i^2 + Q_rate e_dot_i^2 + R tau_i^2,  e = theta - theta_d (wrapped), e'' = tau / I,
//
// with tau held over each period (zero-order hold) and theta_d the docking attitude: the chaser's
// docking axis (its body +x) facing the target's, turning with the target (theta_d' = its rate).
#pragma once

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include <array>
#include <memory>

#include "flight_sw/solver/fast_mpc.hpp"
#include "flight_sw/solver/ocp_qp.hpp"

namespace rvd::guidance {

struct GuidanceParams;

struct AttitudeParams {
  double inertia_kgm2 = 0.0;   // about z; 0: the chaser's attitude is not this guidance's to control
  double torque_max_nm = 0.0;  // |tau| per period
  // Weights of Dong, Ghiglino et al.'s 2-D MPC (Table 2: Q = diag(10, 10, 10, 300, 300, 500),
  // R = diag(10, 10, 10): the third entries are the angle's, rate's and torque's).
  double Q_angle = 10.0;   // per rad^2
  double Q_rate = 500.0;   // per (rad/s)^2
  double R_torque = 10.0;  // per (N m)^2
};

// Angle of the rotation about z (w, 0, 0, z) of an attitude, in (-pi, pi] (planar attitudes only).
double yaw_rad(const Eigen::Quaterniond& q);

class AttitudeMpc {
 public:
  // One QP and solver per phase, with the phase's N and Ts (allocated here; step() allocates nothing).
  explicit AttitudeMpc(const GuidanceParams& params);
  ~AttitudeMpc();

  struct Result {
    double torque_nm = 0.0;
    double error_rad = 0.0;   // theta - theta_d, wrapped
    solver::Info info;
  };
  // phase_index 0..2 (rendezvous, approach, docking): the chaser's angle and rate about z, the target's.
  Result step(int phase_index, double angle_rad, double rate_rad_s, double target_angle_rad, double target_rate_rad_s);
  const AttitudeParams& params() const { return p_; }

 private:
  AttitudeParams p_;
  std::array<solver::OcpQp, 3> qp_;
  std::array<std::unique_ptr<solver::FastMpcSolver>, 3> solver_;
  solver::Vector x0_;
};

}  // namespace rvd::guidance
