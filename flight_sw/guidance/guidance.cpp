#include "flight_sw/guidance/guidance.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include "flight_sw/solver/elapsed.hpp"

namespace rvd::guidance {

namespace {
constexpr double kDeg = 3.14159265358979323846 / 180.0;
using solver::elapsed_us;
}  // namespace

const char* to_string(StepStatus s) {
  switch (s) {
    case StepStatus::Ok: return "ok";
    case StepStatus::ShiftedPlan: return "shifted_plan";
    case StepStatus::ZeroThrust: return "zero_thrust";
    case StepStatus::InvalidState: return "invalid_state";
    case StepStatus::Docked: return "docked";
    case StepStatus::Recovered: return "recovered";
  }
  return "unknown";
}

Guidance::Guidance(const GuidanceParams& params)
    : params_(params), x0_(solver::Vector::Zero(6)), holding_(params.holding()) {
  const std::string err = params_.validate();
  if (!err.empty()) throw std::invalid_argument("GuidanceParams: " + err);
  int longest = 0;
  for (Phase p : {Phase::Rendezvous, Phase::Approach, Phase::Docking}) {
    const int k = index(p);
    qps_[k] = std::make_unique<PhaseQp>(p, params_);
    solvers_[k] = std::make_unique<solver::FastMpcSolver>(qps_[k]->dims(), params_.phase(p).solver);
    recovery_qps_[k] = std::make_unique<PhaseQp>(p, params_, true);
    recovery_solvers_[k] = std::make_unique<solver::FastMpcSolver>(recovery_qps_[k]->dims(), params_.phase(p).solver);
    solvers_[k]->setup(qps_[k]->qp());  // the phase's dynamics and weights, condensed once
    recovery_solvers_[k]->setup(recovery_qps_[k]->qp());
    longest = std::max(longest, qps_[k]->N());
  }
  plan_.assign(longest, Eigen::Vector3d::Zero());
  predicted_.assign(longest + 1, Eigen::Vector3d::Zero());
  if (params_.obstacle_capacity > 0 || params_.holding_radius_m > 0.0)
    for (auto* set : {&qps_, &recovery_qps_})
      for (auto& qp : *set) qp->set_obstacles(&obstacles_, 0.0, predicted_.data());
}

void Guidance::set_obstacles(const Obstacle* list, int n, double t_s, const Eigen::Vector3d& chaser_lvlh_m) {
  select_obstacles(list, n, chaser_lvlh_m, t_s, params_.mean_motion_rad_s(), params_.obstacle_prediction, obstacles_);
  if (params_.obstacle_capacity == 0) {  // built without obstacle rows: nothing is held
    obstacles_.dropped_total += static_cast<uint32_t>(obstacles_.count);
    obstacles_.count = 0;
  }
}

// Where the previous plan (what is left of it, then coasting) takes the chaser from x over the phase's
// horizon: the points the obstacle rows are linearized about.
void Guidance::predict_positions(const PhaseQp& qp, const Vector6d& x) {
  Vector6d xi = x;
  predicted_[0] = xi.head<3>();
  const bool have_plan = plan_phase_ == phase_ && plan_next_ < plan_len_;
  for (int i = 0; i < qp.N(); ++i) {
    const int j = plan_next_ + i;
    const Eigen::Vector3d u = have_plan && j < plan_len_ ? plan_[j] : Eigen::Vector3d::Zero();
    xi = qp.A() * xi + qp.B() * u;
    predicted_[i + 1] = xi.head<3>();
  }
}

Guidance::~Guidance() = default;

const PhaseQp& Guidance::phase_qp(Phase p, bool recovery) const {
  return recovery ? *recovery_qps_[index(p)] : *qps_[index(p)];
}
const solver::FastMpcSolver& Guidance::solver(Phase p, bool recovery) const {
  return recovery ? *recovery_solvers_[index(p)] : *solvers_[index(p)];
}

void Guidance::reset(Phase start) {
  phase_ = start;
  plan_len_ = plan_next_ = 0;
  holding_.reset();
  for (auto& s : solvers_) s->reset_warm_start();
  for (auto& s : recovery_solvers_) s->reset_warm_start();
  lookahead_warm_ = false;
  docking_rows_ready_ = false;
}

bool Guidance::ready_for_approach(const Vector6d& x, const TargetState& target, const EstimateQuality& u) const {
  const double margin = params_.margins.approach_cone_m + params_.margins.estimate_sigmas * u.position_m;
  const Eigen::Vector3d rho = x.head<3>();
  const Matrix43d H = pyramid_rows_lvlh(target.q_lvlh_body, params_.approach.los_half_angle_deg * kDeg);
  if (!((H * rho).maxCoeff() <= -margin && rho.norm() <= params_.keepout_radius_m + params_.rendezvous_switch_margin_m))
    return false;
  const double fraction = params_.margins.approach_entry_brake_fraction;
  if (fraction <= 0.0) return true;
  // Entry only at a speed the approach phase can stop inside the corridor: towards each face, the
  // braking distance at `fraction` of the phase's planned deceleration fits into the distance to it.
  const PhaseParams& ap = params_.approach;
  const double decel = fraction * ap.u_max_mps * (1.0 - params_.margins.input_fraction) / ap.Ts_s;
  const Eigen::Vector4d inside = -(H * rho).array() - margin;
  // > 0: moving towards the face, which turns with the target: d/dt (h'rho) = h'(v - omega x rho).
  const Eigen::Vector4d rate = H * (x.tail<3>() - omega_lvlh(target).cross(rho));
  for (int j = 0; j < 4; ++j)
    if (rate(j) > 0.0 && rate(j) * rate(j) > 2.0 * decel * inside(j)) return false;
  return true;
}

bool Guidance::ready_for_docking(const Vector6d& x, const TargetState& target, const EstimateQuality& u) const {
  const Margins& m = params_.margins;
  // Within r2, slow enough for the docking QP's |v|_inf bound, and inside the docking pyramid (its hard
  // cone would make every docking QP infeasible otherwise).
  const Eigen::Vector3d rho = x.head<3>();
  const Eigen::Vector3d port = target.q_lvlh_body * params_.port_body_m;
  const Matrix43d H = pyramid_rows_lvlh(target.q_lvlh_body, params_.docking.los_half_angle_deg * kDeg);
  return rho.norm() <= params_.approach_stop_m + m.overshoot_m + params_.approach_switch_margin_m +
                           m.estimate_sigmas * u.position_m &&
         x.tail<3>().cwiseAbs().maxCoeff() <= params_.v_max_mps - m.v_max_mps - m.estimate_sigmas * u.velocity_mps &&
         (H * (rho - port)).maxCoeff() <= -(m.docking_cone_m + m.estimate_sigmas * u.position_m);
}

bool Guidance::docked(const Vector6d& x, const TargetState& target) const {
  const Eigen::Vector3d port = target.q_lvlh_body * params_.port_body_m;
  const Eigen::Vector3d port_v = omega_lvlh(target).cross(port);
  const Eigen::Vector3d rel = x.head<3>() - port;
  const Matrix43d H = pyramid_rows_lvlh(target.q_lvlh_body, params_.docking.los_half_angle_deg * kDeg);
  return rel.norm() <= params_.dock_tolerance_m &&
         (x.tail<3>() - port_v).cwiseAbs().maxCoeff() <= params_.v_max_mps &&
         (H * rel).maxCoeff() <= params_.dock_cone_tolerance_m;
}

bool Guidance::nav_plausible(const NavInput& nav) const {
  if (!std::isfinite(nav.t_s) || !nav.x_lvlh.allFinite() || !nav.q_lvlh_body.coeffs().allFinite() ||
      !nav.omega_body_rad_s.allFinite())
    return false;
  if (nav.x_lvlh.head<3>().norm() > params_.max_range_m || nav.x_lvlh.tail<3>().norm() > params_.max_speed_mps)
    return false;
  if (std::abs(nav.q_lvlh_body.norm() - 1.0) > 1e-3) return false;  // not an attitude
  return nav.omega_body_rad_s.norm() <= params_.max_spin_rad_s;
}

void Guidance::fall_back(Command& cmd) {
  if (plan_phase_ == phase_ && plan_next_ < plan_len_) {
    cmd.dv_cmd_mps = plan_[plan_next_];
    cmd.plan_age = plan_next_;
    ++plan_next_;
    cmd.fallback = Fallback::ShiftedPlan;
  } else {
    cmd.dv_cmd_mps.setZero();
    cmd.fallback = Fallback::ZeroThrust;
  }
}

bool Guidance::solve_into_plan(PhaseQp& qp, solver::FastMpcSolver& sol, const Vector6d& x,
                               const TargetState& target, const EstimateQuality& quality, double t_s,
                               double budget_left_us, solver::Info& info) {
  if (budget_left_us < 0.0) {  // the step's budget is spent already
    info = solver::Info{};
    info.status = solver::Status::TimeLimit;
    return false;
  }
  if (params_.obstacle_capacity > 0 || params_.holding_radius_m > 0.0) qp.set_obstacles(&obstacles_, t_s, predicted_.data());
  qp.set_holding_radius(holding_.radius());
  qp.build(x, target, quality);
  x0_ = x;
  sol.settings().time_limit_us = budget_left_us;
  if (observer_) observer_->before_solve();
  sol.solve(qp.qp(), x0_);
  if (observer_) observer_->after_solve();
  info = sol.info();
  const bool converged = info.status == solver::Status::Solved ||
                         (info.status == solver::Status::MaxIter &&
                          info.primal_residual <= params_.max_iter_accept_residual);
  if (!converged) return false;
  const auto& u = sol.u();
  for (int i = 0; i < qp.N(); ++i) {
    if (!u[i].head<3>().allFinite()) return false;
  }
  // Tiny excursions past the box (solver tolerance) are clipped so the command is exactly admissible.
  for (int i = 0; i < qp.N(); ++i) plan_[i] = u[i].head<3>().cwiseMax(-qp.u_max_mps()).cwiseMin(qp.u_max_mps());
  plan_len_ = qp.N();
  plan_next_ = 1;
  plan_phase_ = phase_;
  sol.shift_warm_start();
  return true;
}

// The first approach solve would start cold (interior point: 13-15 iterations against about 5 warm;
// active set: 20-35 row changes against 1-3). While the rendezvous plan predicts the approach entry
// (ready_for_approach on its planned state, target turned to that time) within
// approach_lookahead_steps samples, the approach QP at that predicted state gets up to
// approach_lookahead_iterations interior-point iterations per step, each step continuing the last
// one's iterate (no shift: the entry instant stays the same while it comes closer), or one solve by
// the active-set method, warm from the last one's working set. The entry's solve starts from that
// iterate or working set. A step without a prediction drops it: a stale iterate is no better a start
// than a cold one.
void Guidance::look_ahead(const solver::FastMpcSolver& rendezvous, const TargetState& target,
                          const EstimateQuality& quality, double budget_left_us, bool carried, solver::Info& info) {
  solver::FastMpcSolver& sol = *solvers_[index(Phase::Approach)];
  const int steps = std::min(params_.approach_lookahead_steps, qps_[index(Phase::Rendezvous)]->N());
  int entry = 0;
  TargetState later = target;
  if (budget_left_us >= 0.0 && params_.obstacle_capacity == 0 && !params_.holding_in(Phase::Approach)) {
    for (int j = 1; j <= steps && entry == 0; ++j) {
      later.q_lvlh_body = attitude_after(target, j * params_.rendezvous.Ts_s);
      const Vector6d xj = rendezvous.x()[j];
      if (ready_for_approach(xj, later, quality)) entry = j;
    }
  }
  if (entry == 0) return;
  PhaseQp& qp = *qps_[index(Phase::Approach)];
  x0_ = rendezvous.x()[entry];
  qp.build(x0_, later, quality);
  if (!carried) sol.reset_warm_start();
  // The interior point runs a few iterations; the dual active-set method solves the QP (its working
  // set is the warm start; the cap then only bounds its interior-point fallback).
  solver::Settings& s = sol.settings();
  const int cap = s.max_iter;
  s.max_iter = std::min(cap, params_.approach_lookahead_iterations);
  s.time_limit_us = budget_left_us;
  if (observer_) observer_->before_solve();
  sol.solve(qp.qp(), x0_);
  if (observer_) observer_->after_solve();
  s.max_iter = cap;
  info = sol.info();
  // Solved or stopped at the cap: an iterate to go on from (the solver keeps it as its warm start).
  lookahead_warm_ = info.status == solver::Status::Solved || info.status == solver::Status::MaxIter;
}

Command Guidance::step(const NavInput& nav, double time_limit_us) {
  const solver::TimePoint t0 = solver::clock_now();  // the flight clock (elapsed.hpp)
  // The look-ahead iterate serves the very next step only (look_ahead() renews it).
  const bool carried = lookahead_warm_;
  lookahead_warm_ = false;
  Command cmd;
  cmd.step = nav.step;
  cmd.t_s = nav.t_s;

  if (!nav_plausible(nav)) {
    cmd.phase = phase_;
    cmd.status = StepStatus::InvalidState;
    if (phase_ != Phase::Docked) fall_back(cmd);
    else cmd.fallback = Fallback::ZeroThrust;
  } else {
    TargetState target;
    target.q_lvlh_body = nav.q_lvlh_body.normalized();
    target.omega_body_rad_s = nav.omega_body_rad_s;
    const Vector6d& x = nav.x_lvlh;
    cmd.range_m = x.head<3>().norm();
    cmd.port_distance_m = (x.head<3>() - target.q_lvlh_body * params_.port_body_m).norm();

    holding_.observe(x.head<3>(), target.q_lvlh_body, params_.port_body_m, nav.chaser_attitude_error_rad);
    // Algorithm 1: the switching conditions are checked on the newest state; a state can pass several.
    const Phase before = phase_;
    if (phase_ == Phase::Rendezvous && ready_for_approach(x, target, nav.quality)) phase_ = Phase::Approach;
    if (phase_ == Phase::Approach && ready_for_docking(x, target, nav.quality)) phase_ = Phase::Docking;
    if (phase_ == Phase::Docking && docked(x, target)) phase_ = Phase::Docked;
    if (phase_ != before) plan_len_ = plan_next_ = 0;  // a plan is only valid with its own period
    const bool phase_has_plan = plan_len_ > 0;  // not the phase's first step (nor the run's)
    // The approach solve at the entry starts from the last step's look-ahead iterate, or cold.
    if (phase_ == Phase::Approach && before == Phase::Rendezvous && !carried)
      solvers_[index(Phase::Approach)]->reset_warm_start();
    cmd.phase = phase_;

    if (phase_ == Phase::Docked) {
      cmd.status = StepStatus::Docked;
    } else {
      const int k = index(phase_);
      // What is left of the step's budget: 0 means no limit (the solver's convention), -1 means spent.
      auto left_us = [&]() {
        if (!(time_limit_us > 0.0)) return 0.0;
        const double left = time_limit_us - elapsed_us(t0);
        return left > 0.0 ? left : -1.0;
      };
      cmd.solved = left_us() >= 0.0;
      if (params_.obstacle_capacity > 0 || params_.holding_in(phase_)) predict_positions(*qps_[k], x);  // before a new plan replaces it
      bool usable = solve_into_plan(*qps_[k], *solvers_[k], x, target, nav.quality, nav.t_s, left_us(), cmd.solver);
      if (usable) {
        cmd.status = StepStatus::Ok;
      } else if (cmd.solver.status == solver::Status::Infeasible && params_.recovery) {
        usable = solve_into_plan(*recovery_qps_[k], *recovery_solvers_[k], x, target, nav.quality, nav.t_s,
                                 left_us(), cmd.recovery);
        if (usable) cmd.status = StepStatus::Recovered;
      }
      if (usable) {
        cmd.dv_cmd_mps = plan_[0];
        if (phase_ == Phase::Rendezvous && params_.approach_lookahead_steps > 0)
          look_ahead(cmd.status == StepStatus::Recovered ? *recovery_solvers_[k] : *solvers_[k], target, nav.quality,
                     left_us(), carried, cmd.lookahead);
      } else {
        fall_back(cmd);
        cmd.status = cmd.fallback == Fallback::ShiftedPlan ? StepStatus::ShiftedPlan : StepStatus::ZeroThrust;
      }
      // Once, after the solve of a step before docking that is not its phase's first (the first
      // solve of a phase is the cold, costly one): the docking QP for this target, its rows
      // compressed and kept by the docking solver (setup condenses nothing again: A, B, Q, R are the
      // phase's). Its cone rows depend on the target's attitude alone, so the first docking solve
      // finds them kept (a turning target's take new values in place) and does not compress them
      // itself, a third of docking N = 5's first solve. In an approach step of N = 5 the same work
      // raised the step to 1.8-2.2x the phase's median; rendezvous steps cost 10-40x more.
      if (phase_ != Phase::Docking && phase_has_plan && !docking_rows_ready_ && left_us() >= 0.0) {
        const int d = index(Phase::Docking);
        if (solvers_[d]->uses_active_set()) {  // (the interior point compresses its rows every solve)
          qps_[d]->build(x, target, nav.quality);
          solvers_[d]->setup(qps_[d]->qp());
        }
        docking_rows_ready_ = true;
      }
    }
  }

  const PhaseParams& pp = params_.phase(cmd.phase);
  cmd.period_s = pp.Ts_s;
  if (cmd.status == StepStatus::Docked) cmd.dv_cmd_mps.setZero();
  const Allocation a = allocate_thrusters(cmd.dv_cmd_mps, max_pulse_s(pp.u_max_mps, params_.thrusters),
                                          params_.thrusters, nav.quality.thrust_scale);
  cmd.pulse_s = a.pulse_s;
  cmd.dv_alloc_mps = a.dv_alloc_mps;
  cmd.dv_nominal_mps = a.dv_nominal_mps;
  cmd.step_time_us = elapsed_us(t0);
  return cmd;
}

ScenarioCase dissertation_case(int number, double spin_deg_s) {
  ScenarioCase c;
  c.x0 << 140.0, -1580.0, 60.0, -0.90, -0.32, 0.0;
  c.omega_body_rad_s.setZero();
  switch (number) {
    case 1:  // V-bar: docking axis (body +x) along LVLH +y (sec. 3.6.1)
      c.q_lvlh_body = Eigen::AngleAxisd(90.0 * kDeg, Eigen::Vector3d::UnitZ());
      break;
    case 2:  // R-bar: docking axis along LVLH +x
      c.q_lvlh_body = Eigen::Quaterniond::Identity();
      break;
    case 3:  // starts like case 1 and spins about body z (= LVLH z)
      c.q_lvlh_body = Eigen::AngleAxisd(90.0 * kDeg, Eigen::Vector3d::UnitZ());
      c.omega_body_rad_s = Eigen::Vector3d(0.0, 0.0, spin_deg_s * kDeg);
      break;
    default: throw std::invalid_argument("dissertation_case: number must be 1, 2 or 3");
  }
  return c;
}

}  // namespace rvd::guidance
