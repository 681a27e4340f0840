// In-process closed loop: the guidance against an impulsive, noise-free, zero-delay CW plant.
// Each period the plant applies the *allocated* delta-v at the start of the period and propagates with
// the exact CW STM of that phase's Ts:  x+ = Phi(Ts) (x + [0; dv_alloc]).  (The host simulator's CW truth
// in impulsive, noise-free, zero-delay mode does the same; keep this plant exactly that simple.)
#pragma once

#include <array>
#include <string>
#include <vector>

#include "flight_sw/guidance/guidance.hpp"

namespace rvd::guidance {

struct ClosedLoopStep {
  uint32_t step = 0;
  double t_s = 0.0;
  Vector6d x = Vector6d::Zero();  // state at t_s, before the impulse
  Eigen::Quaterniond q_lvlh_body = Eigen::Quaterniond::Identity();
  Phase phase = Phase::Rendezvous;
  double period_s = 0.0;
  Eigen::Vector3d dv_cmd_mps = Eigen::Vector3d::Zero();
  Eigen::Vector3d dv_alloc_mps = Eigen::Vector3d::Zero();
  StepStatus status = StepStatus::ZeroThrust;
  solver::Status solver_status = solver::Status::InvalidInput;
  bool solved = false;         // a phase QP was handed to the solver (else solver_status means nothing)
  int iterations = 0;          // interior-point iterations of the phase QP's solve
  int active_set_changes = 0;  // or the active-set method's row changes (entering and leaving)
  double solve_time_us = 0.0;
  double step_time_us = 0.0;
};

// One QP the loop solved, with what the guidance took from it.
struct RecordedQp {
  uint32_t step = 0;
  Phase phase = Phase::Rendezvous;
  solver::OcpQp qp;
  Vector6d x0 = Vector6d::Zero();
  solver::Status status = solver::Status::InvalidInput;
  Eigen::Vector3d u0 = Eigen::Vector3d::Zero();  // commanded first delta-v when solved, else the last iterate
};

struct PhaseTotals {
  double dv_mps = 0.0;     // sum of |dv_alloc|_2 (the resultant, as the dissertation's tables)
  double dv_l1_mps = 0.0;  // sum of |dv_alloc|_1 (what six axis thrusters burn)
  double time_s = 0.0;     // periods spent in the phase
  int steps = 0;
};

struct ClosedLoopResult {
  bool docked = false;
  std::string reason;  // "docked", or why not ("timeout after ...")
  double t_final_s = 0.0;
  std::vector<ClosedLoopStep> log;
  std::array<PhaseTotals, 3> phases;  // rendezvous, approach, docking
  PhaseTotals total;
  // Safety figures from the logged (sampled) states.
  double min_range_outside_cone_m = 0.0;  // smallest |rho| outside the approach pyramid (+1 mm)
  int keepout_violations = 0;             // samples with |rho| < r1 - 1 mm outside the approach pyramid (+1 mm)
  double max_approach_cone_violation_m = 0.0;  // largest (H rho)_+ during approach (a soft constraint)
  double max_docking_cone_violation_m = 0.0;   // largest (H (rho - port))_+ during docking (hard)
  double max_u_inf_ratio = 0.0;           // max over steps of |dv_cmd|_inf / u_max of the phase
  double max_docking_speed_inf_mps = 0.0;  // max |v|_inf over docking samples
  int fallbacks = 0;                      // steps with ShiftedPlan / ZeroThrust / InvalidState
  int recoveries = 0;                     // steps with Recovered (phase QP infeasible, recovery QP used)
  double final_port_distance_m = 0.0;
  double final_closing_speed_mps = 0.0;   // |v - v_port|_2 at the end
  std::vector<RecordedQp> qps;
};

ClosedLoopResult run_closed_loop(const GuidanceParams& params, const Vector6d& x0, const Eigen::Quaterniond& q0,
                                 const Eigen::Vector3d& omega_body_rad_s, double timeout_s = 200.0 * 60.0,
                                 bool record_qps = false, double time_limit_us = 0.0);

}  // namespace rvd::guidance
