// Every parameter of the three-phase guidance, with the defaults of dissertation Table 3.1 and, for the
// values the dissertation leaves unstated, the choices documented in flight_sw/guidance/README.md.
#pragma once

#include <Eigen/Dense>

#include <array>
#include <cstdint>
#include <string>

#include "flight_sw/guidance/allocation.hpp"
#include "flight_sw/guidance/attitude.hpp"
#include "flight_sw/guidance/cw.hpp"
#include "flight_sw/guidance/holding.hpp"
#include "flight_sw/guidance/obstacles.hpp"
#include "flight_sw/solver/ocp_qp.hpp"

namespace rvd::guidance {

enum class Phase : uint8_t { Rendezvous = 1, Approach = 2, Docking = 3, Docked = 4 };
const char* to_string(Phase p);

enum class TerminalWeight : uint8_t {
  StageWeight = 0,  // Q_f = Q of the phase
  Dare = 1          // Q_f = solution of the discrete algebraic Riccati equation of (A, B, Q, R)
};
enum class RendezvousObjective : uint8_t {
  Quadratic = 0,  // eq 3.2 / 3.7
  OneNorm = 1     // eq 2.10: ||Q (x - xs)||_1 + ||R u||_1 (an LP; Table 3.6)
};
enum class RelativeMotion : uint8_t {
  ClohessyWiltshire = 0,  // about a target on a circular orbit (mean motion from orbit_altitude_m)
  DoubleIntegrator = 1    // no orbit (an air-bearing table, deep space): n = 0, rho'' = u
};
enum class KeepoutDirection : uint8_t {
  NaturalMotion = 0,  // sec 3.1.3: shortest way when the axis is reachable within N capped steps,
                      // else the way the natural relative motion circulates (about -z of LVLH)
  Shortest = 1        // always the shorter great-circle way
};

struct PhaseParams {
  int N = 30;                     // prediction horizon (steps)
  double Ts_s = 30.0;             // control period [s]
  Vector6d Q_diag = Vector6d::Ones();            // state weight (position m, velocity m/s)
  Eigen::Vector3d R_diag = Eigen::Vector3d::Constant(1e3);  // delta-v weight
  double lambda = 10.0;           // line-of-sight cone penalty weight (per metre outside a face)
  double los_half_angle_deg = 15.0;  // half-angle of the four-sided pyramid around the docking axis
  double u_max_mps = 0.1786;      // |delta-v|_inf per period
  TerminalWeight terminal_weight = TerminalWeight::StageWeight;
  solver::Settings solver = default_solver();  // settings of this phase's Fast MPC solver

  // The solver's defaults with a 200-iteration cap: the recovery QPs (large elastic costs) need up to
  // ~100-200 interior point iterations; in flight the step's time budget is the binding limit.
  static solver::Settings default_solver() {
    solver::Settings s;
    s.max_iter = 200;
    return s;
  }
};

// How well the guidance knows what it plans from (the navigation filter's): the 1-sigma error of the
// state estimate on its worst axis, the thrusters' estimated relative force and its 1-sigma error
// (worst thruster). All zero / nominal: exact knowledge.
struct EstimateQuality {
  double position_m = 0.0;
  double velocity_mps = 0.0;
  ThrustScale thrust_scale = kNominalThrust;
  double thrust_scale_sigma = 0.0;
};

// Constraint tightening against the disturbances the flight lives with (flight_sw/guidance/README.md,
// "Under disturbances"). All zero is the dissertation's nominal MPC; nav::derive_margins() sets them from
// an error model. Each is applied on the prediction stages 1..N of the phase QPs and in the switching
// rules, plus `estimate_sigmas` times the current EstimateQuality: position sigma for the geometric
// limits, velocity sigma for v_max, and the thrusters' force sigma for the input bounds (per thruster:
// u_max min(1, s_j - k sigma_s)), for the braking before the overshoot plane and the acceleration before
// v_max.
struct Margins {
  double input_fraction = 0.0;   // every stage plans with |dv|_inf <= u_max (1 - input_fraction)
  double plan_reserve_fraction = 0.0;  // and stages 1.. with (1 - plan_reserve_fraction) of that
  double keepout_m = 0.0;        // rendezvous: keep-out planes at r1 + keepout_m
  double overshoot_m = 0.0;      // approach: docking-axis distance >= r2 + overshoot_m
  double approach_cone_m = 0.0;  // approach: the soft corridor penalty starts this far inside the faces
  double docking_cone_m = 0.0;   // docking: hard cone H (rho - port) <= -docking_cone_m
  double v_max_mps = 0.0;        // docking: |v|_inf <= v_max - v_max_mps
  double estimate_sigmas = 0.0;  // each limit above also moves in by this many estimate sigmas
  // Rendezvous -> approach only when the chaser, moving towards a corridor face, can stop before it with
  // this fraction of the approach phase's planned deceleration (0: no such check).
  double approach_entry_brake_fraction = 0.0;
  // Approach phase: closing speed along the docking axis <= this (0: no cap), from stage 1 on, reached
  // from the current closing speed at 90 % of the planned authority per period (so always reachable).
  double approach_speed_cap_mps = 0.0;
  // From stage 1 on: no faster than stops the chaser at the overshoot plane with this
  // fraction of the braking authority the plan's later stages have (0: no such limit). The rest is slack
  // for a braking thruster that turns out weaker than its estimate in the middle of the braking.
  double approach_brake_fraction = 0.0;
  // Rendezvous, from stage 1 on: closing speed towards the stage's keep-out plane no faster than stops the
  // chaser before it with this fraction of the braking authority (0: no such rows). A short horizon
  // otherwise plans towards the sphere faster than it can brake once the braking distance comes into view.
  double rendezvous_brake_fraction = 0.0;
  // Between two samples a spinning target's corridor turns by omega Ts while the chaser moves on a
  // chord: the corridor margin grows by rotating_cone_factor |rho_0| (omega Ts)^2 on a spinning target.
  double rotating_cone_factor = 0.0;
};

struct GuidanceParams {
  PhaseParams rendezvous = default_rendezvous();
  PhaseParams approach = default_approach();
  PhaseParams docking = default_docking();

  // Orbit of the target (circular): sets the CW mean motion.
  double orbit_altitude_m = 500e3;
  RelativeMotion relative_motion = RelativeMotion::ClohessyWiltshire;

  // Geometry (unstated in the dissertation; see README).
  double keepout_radius_m = 200.0;     // r1: keep-out sphere around the target CoM (rendezvous)
  double approach_stop_m = 30.0;       // r2: overshoot plane along the docking axis (approach)
  double dock_tolerance_m = 0.5;       // r3: docked when this close to the port (plus speed and cone)
  double v_max_mps = 0.1;              // docking |v|_inf bound, also required to enter docking
  double dock_cone_tolerance_m = 0.01;  // docked only inside the docking pyramid, to this tolerance
  Eigen::Vector3d port_body_m = Eigen::Vector3d(0.5, 0.0, 0.0);  // docking port; docking axis is body +x

  // Rendezvous objective and set point (Table 3.6 variants).
  RendezvousObjective rendezvous_objective = RendezvousObjective::Quadratic;
  bool rendezvous_use_setpoint = true;       // false: the set point is the target CoM (origin)
  double rendezvous_setpoint_offset_m = 0.0;  // set point on the axis at r1 + offset from the CoM
  double approach_setpoint_offset_m = 0.0;    // approach set point on the axis at r2 + offset
  // Docking set point on the axis this far beyond the apex of the docking cone as the margins tighten it
  // (the port when they are 0), and inside the docked distance r3 (README, "Set points"). 0: the apex.
  // 5 cm: the tightened cone is 7 mm wide there, so a plan stopped on it has come to the axis.
  double docking_setpoint_offset_m = 0.05;
  // A soft plane through the docking set point, normal to the axis, on stages 1..N: axial distance from
  // the port >= the set point's, at this penalty per metre past it (0: no plane, the dissertation's
  // docking QP). With its weights (R / Q = 5e4) a plan brakes for constraints, not for the set point:
  // without the plane it coasted into the apex of the tightened cone, three or four of its facets
  // tight on each late stage (README, "Set points").
  double docking_stop_penalty = 1e4;

  // Phase switching (Algorithm 1).
  double rendezvous_switch_margin_m = 20.0;  // rendezvous -> approach: inside the cone and |rho| <= r1 + margin
  double approach_switch_margin_m = 2.0;     // approach -> docking: |rho| <= r2 + margin, |v|_inf <= v_max,
                                             // inside the docking pyramid

  // Rotating keep-out hyperplanes (eqs 3.5-3.6).
  double keepout_rate_cap_factor = 1.0;  // per-step rotation cap = factor * mean motion * Ts
  KeepoutDirection keepout_direction = KeepoutDirection::NaturalMotion;

  ThrusterParams thrusters;

  // Plausibility limits of a navigation input; beyond them the state is rejected as absurd.
  double max_range_m = 100e3;
  double max_speed_mps = 100.0;
  double max_spin_rad_s = 1.0;
  // When a phase QP is infeasible, solve it again with its hard state constraints elastic (cost
  // recovery_weight * e + recovery_quadratic * e^2 for the worst violation e >= 0 on a stage, in m or m/s)
  // before falling back to the previous plan.
  bool recovery = true;
  double recovery_weight = 1e4;
  double recovery_quadratic = 10.0;
  double recovery_speed_factor = 10.0;  // the docking |v|_inf rows' penalty is this many times the cone's
  // A solve that stopped at the iteration cap is used when its primal residual is this small.
  double max_iter_accept_residual = 1e-6;
  // Warm start of the first approach solve. A cold interior point needs 13-15 iterations on the first
  // approach QP, a warm one about 5. While the rendezvous plan reaches the approach entry within
  // approach_lookahead_steps samples, each rendezvous step also runs up to approach_lookahead_iterations
  // iterations of the approach QP built at that predicted entry state (continuing the previous
  // step's iterate): the first approach solve then starts from them (one step of 8: 5-8 iterations
  // at the entry instead of 13-16; two steps: 3-5, for twice the rendezvous steps made costlier). An
  // approach on the dual active-set method gets one whole solve per step instead (its working set is
  // the warm start). Speed only: the approach QP at the entry is solved to the usual tolerance either
  // way. 0 steps: off.
  int approach_lookahead_steps = 1;
  int approach_lookahead_iterations = 8;

  // Obstacles (obstacles.hpp): rows for this many keep-out zones on stages 1..N of every phase QP,
  // 0 (the default) or kMaxObstacles. With 0 the QPs are the dissertation's, and obstacle lists are
  // only counted. Each row is soft: obstacle_penalty per metre inside the linearized zone's tangent
  // plane plus obstacle_penalty_quadratic per metre squared (the zone may be out of reach of the
  // thrusters; the plan then gets as far out as it can instead of the QP being infeasible).
  int obstacle_capacity = 0;
  double obstacle_margin_m = 0.0;  // every zone grown by this, plus estimate_sigmas x the position sigma
  double obstacle_penalty = 1e4;
  double obstacle_penalty_quadratic = 10.0;
  ObstaclePrediction obstacle_prediction = ObstaclePrediction::ConstantVelocity;
  ObstacleMethod obstacle_method = ObstacleMethod::DirectLinearization;
  double hyperplane_rate_rad_s = 0.002;       // rotating hyperplane: turn rate of its normal (~2x the orbit rate)
  double hyperplane_active_range_m = 500.0;   // rotating hyperplane: rows only within this of the zone

  // The docking corridor of Dong, Ghiglino et al. (holding.hpp). Phases as a bit mask: 1 rendezvous,
  // 2 approach, 4 docking.
  // Dynamic holding radius (their eq. 9): in the phases of holding_phases (rendezvous and approach
  // only) it replaces the stand-off row (the rendezvous keep-out plane, the approach overshoot plane)
  // by the holding circle linearized about the previous plan, and the set point by the holding
  // position. 0 (the default): off.
  double holding_radius_m = 0.0;
  double holding_radius_min_m = 0.0;
  double holding_shrink = 0.95;
  double holding_tolerance_m = 0.0;
  double holding_attitude_tolerance_deg = 10.0;
  int holding_phases = 1;
  // Two-plane entry cone at the port (their eq. 10) in the phases of entry_cone_phases, active while the
  // chaser is within entry_cone_range_m of the port: two soft rows per stage 1..N with penalty
  // entry_cone_penalty per metre outside (plus obstacle_penalty_quadratic per metre squared).
  // entry_cone_half_angle_deg 0 (the default): off.
  double entry_cone_half_angle_deg = 0.0;
  double entry_cone_range_m = 0.0;
  double entry_cone_penalty = 1e4;
  int entry_cone_phases = 7;
  // The chaser's rotation (attitude.hpp), commanded where the truth has it (the planar truth).
  AttitudeParams attitude;
  HoldingParams holding() const;
  bool holding_in(Phase p) const;     // the phase plans with the holding radius
  bool entry_cone_in(Phase p) const;  // the phase has the entry cone's rows

  Margins margins;
  // The thrusters burn for a finite time: the prediction models each period's delta-v as an impulse at
  // the centroid of a full-length pulse (half of u_max m / F after the period start) instead of at the
  // start, so that planned braking is not credited earlier than the burn delivers it.
  bool finite_burns = false;

  double mean_motion_rad_s() const;
  const PhaseParams& phase(Phase p) const;  // Docked maps to docking
  PhaseParams& phase(Phase p);
  // Empty when usable, else what is wrong (the Guidance constructor throws with this text).
  std::string validate() const;

  static PhaseParams default_rendezvous();
  static PhaseParams default_approach();
  static PhaseParams default_docking();
};

}  // namespace rvd::guidance
