#include "flight_sw/guidance/params.hpp"

#include <cmath>
#include <sstream>

namespace rvd::guidance {

const char* to_string(Phase p) {
  switch (p) {
    case Phase::Rendezvous: return "rendezvous";
    case Phase::Approach: return "approach";
    case Phase::Docking: return "docking";
    case Phase::Docked: return "docked";
  }
  return "unknown";
}

// Table 3.1 of the dissertation.
PhaseParams GuidanceParams::default_rendezvous() {
  PhaseParams p;
  p.N = 30;
  p.Ts_s = 30.0;
  p.Q_diag << 1.0, 1.0, 100.0, 1.0, 1.0, 10.0;
  p.R_diag.setConstant(1e3);
  p.lambda = 10.0;
  p.los_half_angle_deg = 15.0;
  p.u_max_mps = 0.1786;
  // Its plans saturate most inputs (30+ active rows of 45 at N = 15): the dual active-set method
  // needs 80-160 row changes there, the interior point is faster (solver README, "Method choice").
  p.solver.active_set_max_inputs = 0;
  // Its cold solves are the phase's first, from a kilometre or more out, with u = 0: every input
  // bound (0.15-0.18 m/s) then holds with that slack. A slack floor of 1 started them at 1 instead,
  // a primal residual of about 0.85 m/s on each for the first steps to remove. Floor 1 -> 0.1: the
  // first QPs of the whole campaign's 23 scenarios (in-process, nonlinear truth, noise) take 11.2 /
  // 13.8 / 14.2 -> 9.4 / 11.5 / 12.4 iterations on average at N = 15 / 30 / 45, at most 13 / 17 /
  // 19 -> 11 / 14 / 15. 0.2 alike; 0.01-0.05 let a row the noisy estimate puts near its bound start
  // with a tiny slack and a huge dual (one first QP: 15 -> 21). With it, the more centred start the
  // phase took before (cold_complementarity 100) gains nothing over the solver's 30: 400 noise-free
  // random starts' first solves, before -> now, 10.0 / 12.3 / 12.9 -> 9.1 / 11.3 / 11.9 on average,
  // at most 14 / 17 / 18 -> 13 / 15 / 16 (solver README, "Rendezvous: what the worst solves are").
  p.solver.cold_slack_floor = 0.1;
  return p;
}

PhaseParams GuidanceParams::default_approach() {
  PhaseParams p;
  p.N = 15;
  p.Ts_s = 20.0;
  p.Q_diag.setOnes();
  p.R_diag.setConstant(1e3);
  // Table 3.1's lambda = 10 read per kilometre (= 1e4 per metre): an exact penalty that keeps the chaser
  // in the approach corridor; 10 per metre lets Case 3 cut 48 m outside the cone inside r1 (README).
  p.lambda = 1e4;
  p.los_half_angle_deg = 15.0;
  p.u_max_mps = 0.1786;
  return p;
}

PhaseParams GuidanceParams::default_docking() {
  PhaseParams p;
  p.N = 12;
  p.Ts_s = 5.0;
  p.Q_diag.setConstant(20.0);
  p.R_diag.setConstant(1e6);
  p.lambda = 10.0;  // listed in Table 3.1; the docking cone is hard, so lambda is unused there
  p.los_half_angle_deg = 8.0;
  p.u_max_mps = 0.0357;
  return p;
}

double GuidanceParams::mean_motion_rad_s() const {
  return relative_motion == RelativeMotion::DoubleIntegrator ? 0.0 : guidance::mean_motion_rad_s(orbit_altitude_m);
}

namespace {
int phase_bit(Phase p) { return p == Phase::Rendezvous ? 1 : p == Phase::Approach ? 2 : 4; }
}  // namespace

HoldingParams GuidanceParams::holding() const {
  HoldingParams h;
  h.radius_m = holding_radius_m;
  h.radius_min_m = holding_radius_min_m;
  h.shrink = holding_shrink;
  h.tolerance_m = holding_tolerance_m;
  h.attitude_tolerance_rad = holding_attitude_tolerance_deg * 3.14159265358979323846 / 180.0;
  return h;
}
bool GuidanceParams::holding_in(Phase p) const { return holding_radius_m > 0.0 && (holding_phases & phase_bit(p)) != 0; }
bool GuidanceParams::entry_cone_in(Phase p) const {
  return entry_cone_half_angle_deg > 0.0 && (entry_cone_phases & phase_bit(p)) != 0;
}

const PhaseParams& GuidanceParams::phase(Phase p) const {
  switch (p) {
    case Phase::Rendezvous: return rendezvous;
    case Phase::Approach: return approach;
    default: return docking;
  }
}
PhaseParams& GuidanceParams::phase(Phase p) {
  return const_cast<PhaseParams&>(static_cast<const GuidanceParams*>(this)->phase(p));
}

namespace {
bool positive(double v) { return std::isfinite(v) && v > 0.0; }
bool nonnegative(double v) { return std::isfinite(v) && v >= 0.0; }

void check_phase(std::ostringstream& err, const char* name, const PhaseParams& p) {
  if (p.N < 1 || p.N > 1000) err << name << ".N must be in 1..1000 (got " << p.N << "); ";
  if (!positive(p.Ts_s)) err << name << ".Ts_s must be > 0; ";
  if (!p.Q_diag.allFinite() || (p.Q_diag.array() < 0.0).any()) err << name << ".Q_diag must be >= 0; ";
  if (!p.R_diag.allFinite() || (p.R_diag.array() <= 0.0).any()) err << name << ".R_diag must be > 0; ";
  if (!nonnegative(p.lambda)) err << name << ".lambda must be >= 0; ";
  if (!(p.los_half_angle_deg > 0.0 && p.los_half_angle_deg < 89.0))
    err << name << ".los_half_angle_deg must be in (0, 89); ";
  if (!positive(p.u_max_mps)) err << name << ".u_max_mps must be > 0; ";
  if (p.solver.max_iter < 1) err << name << ".solver.max_iter must be >= 1; ";
}
}  // namespace

std::string GuidanceParams::validate() const {
  std::ostringstream err;
  check_phase(err, "rendezvous", rendezvous);
  check_phase(err, "approach", approach);
  check_phase(err, "docking", docking);
  if (!(orbit_altitude_m > 100e3 && orbit_altitude_m < 1e8)) err << "orbit_altitude_m must be in (100 km, 1e8 m); ";
  if (!positive(keepout_radius_m)) err << "keepout_radius_m must be > 0; ";
  if (!positive(approach_stop_m) || !(approach_stop_m < keepout_radius_m))
    err << "approach_stop_m must be > 0 and < keepout_radius_m; ";
  if (!positive(dock_tolerance_m)) err << "dock_tolerance_m must be > 0; ";
  if (!positive(v_max_mps)) err << "v_max_mps must be > 0; ";
  if (!nonnegative(dock_cone_tolerance_m)) err << "dock_cone_tolerance_m must be >= 0; ";
  if (!port_body_m.allFinite() || !(port_body_m.x() >= 0.0 && port_body_m.x() < approach_stop_m))
    err << "port_body_m must be finite with 0 <= x < approach_stop_m (the cones open along body +x); ";
  if (!std::isfinite(rendezvous_setpoint_offset_m) || keepout_radius_m + rendezvous_setpoint_offset_m < 0.0)
    err << "rendezvous_setpoint_offset_m must keep the set point range >= 0; ";
  if (!std::isfinite(approach_setpoint_offset_m) || approach_stop_m + approach_setpoint_offset_m < 0.0)
    err << "approach_setpoint_offset_m must keep the set point range >= 0; ";
  if (!nonnegative(docking_setpoint_offset_m)) err << "docking_setpoint_offset_m must be >= 0; ";
  if (!nonnegative(docking_stop_penalty)) err << "docking_stop_penalty must be >= 0; ";
  if (!nonnegative(rendezvous_switch_margin_m)) err << "rendezvous_switch_margin_m must be >= 0; ";
  if (!nonnegative(approach_switch_margin_m)) err << "approach_switch_margin_m must be >= 0; ";
  if (!positive(keepout_rate_cap_factor)) err << "keepout_rate_cap_factor must be > 0; ";
  if (!positive(thrusters.mass_kg) || !positive(thrusters.thrust_N) || !nonnegative(thrusters.min_impulse_bit_s))
    err << "thrusters need mass_kg > 0, thrust_N > 0, min_impulse_bit_s >= 0; ";
  if (!positive(max_range_m) || !positive(max_speed_mps) || !positive(max_spin_rad_s))
    err << "max_range_m, max_speed_mps, max_spin_rad_s must be > 0; ";
  if (!positive(recovery_weight) || !nonnegative(recovery_quadratic) || !positive(recovery_speed_factor))
    err << "recovery_weight and recovery_speed_factor must be > 0, recovery_quadratic >= 0; ";
  if (!(obstacle_capacity == 0 || obstacle_capacity == kMaxObstacles))
    err << "obstacle_capacity must be 0 or " << kMaxObstacles << "; ";
  if (!nonnegative(obstacle_margin_m) || !positive(obstacle_penalty) || !nonnegative(obstacle_penalty_quadratic))
    err << "obstacle_margin_m and obstacle_penalty_quadratic must be >= 0, obstacle_penalty > 0; ";
  if (!positive(hyperplane_rate_rad_s) || !positive(hyperplane_active_range_m))
    err << "hyperplane_rate_rad_s and hyperplane_active_range_m must be > 0; ";
  if (holding_radius_m != 0.0) {
    if (!positive(holding_radius_m) || !nonnegative(holding_radius_min_m) || !(holding_radius_min_m <= holding_radius_m))
      err << "holding_radius_m must be > 0 (or 0: off) and >= holding_radius_min_m >= 0; ";
    if (!(holding_shrink > 0.0 && holding_shrink < 1.0)) err << "holding_shrink must be in (0, 1); ";
    if (!nonnegative(holding_tolerance_m) || !nonnegative(holding_attitude_tolerance_deg))
      err << "holding_tolerance_m and holding_attitude_tolerance_deg must be >= 0; ";
    if (holding_phases < 1 || holding_phases > 3)
      err << "holding_phases must be 1 (rendezvous), 2 (approach) or 3 (both): the docking phase has no stand-off row; ";
  }
  if (entry_cone_half_angle_deg != 0.0) {
    if (!(entry_cone_half_angle_deg > 0.0 && entry_cone_half_angle_deg < 89.0))
      err << "entry_cone_half_angle_deg must be in (0, 89) (or 0: off); ";
    if (!nonnegative(entry_cone_range_m) || !positive(entry_cone_penalty))
      err << "entry_cone_range_m must be >= 0 and entry_cone_penalty > 0; ";
    if (entry_cone_phases < 1 || entry_cone_phases > 7) err << "entry_cone_phases must be a phase mask in 1..7; ";
  }
  if (attitude.inertia_kgm2 != 0.0 &&
      (!positive(attitude.inertia_kgm2) || !positive(attitude.torque_max_nm) || !nonnegative(attitude.Q_angle) ||
       !nonnegative(attitude.Q_rate) || !positive(attitude.R_torque)))
    err << "attitude needs inertia_kgm2 > 0 (or 0: not controlled), torque_max_nm > 0, Q >= 0, R > 0; ";
  if (!nonnegative(max_iter_accept_residual)) err << "max_iter_accept_residual must be >= 0; ";
  if (approach_lookahead_steps < 0 || approach_lookahead_iterations < 1)
    err << "approach_lookahead_steps must be >= 0, approach_lookahead_iterations >= 1; ";
  if (!(margins.input_fraction >= 0.0 && margins.input_fraction < 1.0)) err << "margins.input_fraction must be in [0, 1); ";
  if (!(margins.plan_reserve_fraction >= 0.0 && margins.plan_reserve_fraction < 1.0))
    err << "margins.plan_reserve_fraction must be in [0, 1); ";
  if (!nonnegative(margins.keepout_m) || !nonnegative(margins.rotating_cone_factor) || !nonnegative(margins.estimate_sigmas) || !nonnegative(margins.approach_speed_cap_mps) ||
      !(margins.approach_entry_brake_fraction >= 0.0 && margins.approach_entry_brake_fraction <= 1.0) ||
      !(margins.approach_brake_fraction >= 0.0 && margins.approach_brake_fraction <= 1.0) ||
      !(margins.rendezvous_brake_fraction >= 0.0 && margins.rendezvous_brake_fraction <= 1.0) || !nonnegative(margins.overshoot_m) || !nonnegative(margins.approach_cone_m) || !nonnegative(margins.docking_cone_m) ||
      !nonnegative(margins.v_max_mps))
    err << "margins must be finite and >= 0; ";
  if (!(margins.v_max_mps < v_max_mps)) err << "margins.v_max_mps must be < v_max_mps; ";
  return err.str();
}

}  // namespace rvd::guidance

