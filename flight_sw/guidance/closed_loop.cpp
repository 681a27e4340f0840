#include "flight_sw/guidance/closed_loop.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace rvd::guidance {

namespace {
constexpr double kDeg = 3.14159265358979323846 / 180.0;
// A sample on the keep-out plane (or a cone face) sits there up to the solver's tolerance: 1 mm is not
// an entry into the sphere (or an exit from the cone).
constexpr double kKeepoutSlack_m = 1e-3;
}

ClosedLoopResult run_closed_loop(const GuidanceParams& params, const Vector6d& x0, const Eigen::Quaterniond& q0,
                                 const Eigen::Vector3d& omega_body, double timeout_s, bool record_qps,
                                 double time_limit_us) {
  Guidance g(params);
  const double n = params.mean_motion_rad_s();
  TargetState target0;
  target0.q_lvlh_body = q0.normalized();
  target0.omega_body_rad_s = omega_body;

  ClosedLoopResult res;
  res.min_range_outside_cone_m = std::numeric_limits<double>::infinity();
  Vector6d x = x0;
  double t = 0.0;
  for (uint32_t k = 0;; ++k) {
    NavInput nav;
    nav.step = k;
    nav.t_s = t;
    nav.x_lvlh = x;
    nav.q_lvlh_body = attitude_after(target0, t);
    nav.omega_body_rad_s = omega_body;
    const Command cmd = g.step(nav, time_limit_us);

    ClosedLoopStep s;
    s.step = k;
    s.t_s = t;
    s.x = x;
    s.q_lvlh_body = nav.q_lvlh_body;
    s.phase = cmd.phase;
    s.period_s = cmd.period_s;
    s.dv_cmd_mps = cmd.dv_cmd_mps;
    s.dv_alloc_mps = cmd.dv_alloc_mps;
    s.status = cmd.status;
    s.solver_status = cmd.solver.status;
    s.solved = cmd.solved;
    s.iterations = cmd.solver.iterations;
    s.active_set_changes = cmd.solver.active_set_changes;
    s.solve_time_us = cmd.solver.solve_time_us;
    s.step_time_us = cmd.step_time_us;
    res.log.push_back(s);

    if (record_qps && cmd.solved) {
      const solver::FastMpcSolver& sol = g.solver(cmd.phase);
      RecordedQp r;
      r.step = k;
      r.phase = cmd.phase;
      r.qp = g.phase_qp(cmd.phase).qp();
      r.x0 = g.phase_qp(cmd.phase).x0();
      r.status = cmd.solver.status;
      r.u0 = cmd.status == StepStatus::Ok ? cmd.dv_cmd_mps : Eigen::Vector3d(sol.u()[0].head<3>());
      res.qps.push_back(std::move(r));
    }

    // Safety figures, from the state as sampled.
    TargetState tgt = target0;
    tgt.q_lvlh_body = nav.q_lvlh_body;
    const Eigen::Vector3d rho = x.head<3>();
    const Matrix43d H_app = pyramid_rows_lvlh(tgt.q_lvlh_body, params.approach.los_half_angle_deg * kDeg);
    const bool in_cone = (H_app * rho).maxCoeff() <= kKeepoutSlack_m;
    if (!in_cone) {
      res.min_range_outside_cone_m = std::min(res.min_range_outside_cone_m, rho.norm());
      if (rho.norm() < params.keepout_radius_m - kKeepoutSlack_m) ++res.keepout_violations;
    }
    if (cmd.phase == Phase::Approach)
      res.max_approach_cone_violation_m = std::max(res.max_approach_cone_violation_m, (H_app * rho).maxCoeff());
    const Eigen::Vector3d port = tgt.q_lvlh_body * params.port_body_m;
    if (cmd.phase == Phase::Docking || cmd.phase == Phase::Docked) {
      const Matrix43d H_dock = pyramid_rows_lvlh(tgt.q_lvlh_body, params.docking.los_half_angle_deg * kDeg);
      res.max_docking_cone_violation_m = std::max(res.max_docking_cone_violation_m, (H_dock * (rho - port)).maxCoeff());
      res.max_docking_speed_inf_mps = std::max(res.max_docking_speed_inf_mps, x.tail<3>().cwiseAbs().maxCoeff());
    }
    if (cmd.status == StepStatus::ShiftedPlan || cmd.status == StepStatus::ZeroThrust ||
        cmd.status == StepStatus::InvalidState)
      ++res.fallbacks;
    if (cmd.status == StepStatus::Recovered) ++res.recoveries;
    res.final_port_distance_m = (rho - port).norm();
    res.final_closing_speed_mps = (x.tail<3>() - omega_lvlh(tgt).cross(port)).norm();

    if (cmd.phase == Phase::Docked) {
      res.docked = true;
      res.reason = "docked";
      res.t_final_s = t;
      break;
    }
    const PhaseParams& pp = params.phase(cmd.phase);
    res.max_u_inf_ratio = std::max(res.max_u_inf_ratio, cmd.dv_cmd_mps.cwiseAbs().maxCoeff() / pp.u_max_mps);
    PhaseTotals& pt = res.phases[static_cast<int>(cmd.phase) - 1];
    pt.dv_mps += cmd.dv_alloc_mps.norm();
    pt.dv_l1_mps += cmd.dv_alloc_mps.lpNorm<1>();
    pt.time_s += cmd.period_s;
    pt.steps += 1;

    // The plant: impulse at the start of the period, then the exact CW drift over the period.
    Vector6d xp = x;
    xp.tail<3>() += cmd.dv_alloc_mps;
    x = cw_stm(n, cmd.period_s) * xp;
    t += cmd.period_s;
    if (t >= timeout_s) {
      std::ostringstream why;
      why << "timeout after " << t << " s in phase " << to_string(g.phase());
      res.reason = why.str();
      res.t_final_s = t;
      break;
    }
  }
  for (const PhaseTotals& p : res.phases) {
    res.total.dv_mps += p.dv_mps;
    res.total.dv_l1_mps += p.dv_l1_mps;
    res.total.time_s += p.time_s;
    res.total.steps += p.steps;
  }
  return res;
}

}  // namespace rvd::guidance
