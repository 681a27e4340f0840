// A peer of the three-phase MPC: a linear-quadratic (LQ) controller with an extended command governor
// (ECG), after Petersen, Jaunzemis, Baldwin, Holzinger and Kolmanovsky, "Model predictive control and
// extended command governor for improving robustness of relative motion guidance and control" (AAS
// Space Flight Mechanics, 2014): eqs 13-22 and 29.
//
// Per phase (the MPC's phases, switching rules, weights, periods, limits and margins):
//   LQ:  u = K x + Gamma v  (eqs 15-17): K from the DARE of the phase's CW model (A, B) and the MPC's
//        Q, R; Gamma makes the position track a constant v: C_t (I - A - BK)^-1 B Gamma = I.
//   ECG: v(k + j) = rho + xbar_{j+1} (j < L), rho afterwards: the shift-register sequence of eq 22 with
//        L stages. Each period it picks (rho, xbar) minimising |rho - r|^2 + w |xbar|^2 (eq 20) such
//        that the closed loop predicted from the current estimate keeps the phase's constraints on
//        stages j = 0..n_c (eq 29, with the time-varying rows of our MPC: the rotating keep-out
//        hyperplanes, the overshoot plane, the corridor and docking pyramids predicted with the target's
//        spin, |v|_inf, the per-thruster input box) and rho is admissible at rest (the steady state
//        of the inner loop for v = rho, in place of the finitely determined set O_infinity: the rows
//        turn with time, so only the horizon n_c is checked). The approach corridor is soft (a slack
//        with a quadratic cost), as the MPC's is.
//   The governor's QP (3 + 3L + 1 variables, about 17 (n_c + 1) rows) is solved by a dense dual
//   active-set method (dense_qp.hpp). When it is infeasible the law commands zero thrust (the
//   harness's safe action; status ZERO_THRUST, solver_status INFEASIBLE).
// r, the command the governor follows, is the MPC's set point of the phase: on the docking axis at
// r1 (rendezvous), at r2 (approach), the port (docking).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "dense_qp.hpp"
#include "flight_sw/guidance/guidance.hpp"
#include "flight_sw/guidance/phase_qp.hpp"
#include "flight_sw/guidance/plugin/mpc_law.hpp"
#include "flight_sw/nav/margins.hpp"
#include "rvd_guidance.h"

namespace {

using namespace rvd::guidance;
constexpr double kDeg = 3.14159265358979323846 / 180.0;
constexpr int kMaxL = 6, kMaxHorizon = 20;
using RowZ = Eigen::Matrix<double, 1, ecg::kMaxVars>;
using Matrix6Z = Eigen::Matrix<double, 6, ecg::kMaxVars>;
using Matrix3Z = Eigen::Matrix<double, 3, ecg::kMaxVars>;

struct Settings {
  int L = 6;                  // shift-register length (eq 22)
  int n_c = 10;               // constraint horizon (eq 29), periods
  double xbar_weight = 1.0;   // w: cost of the transient command xbar against |rho - r|^2 [1/m^2 relative]
  double slack_weight = 1e4;  // approach corridor slack, per m^2
};

struct PhaseModel {
  Phase phase = Phase::Rendezvous;
  double Ts = 0.0, u_max = 0.0;
  Matrix6d A, Phi;
  Matrix63d B;
  Eigen::Matrix<double, 3, 6> K;
  Eigen::Matrix3d Gamma, U_ss;  // u at the inner loop's rest point per unit of v
  std::array<Matrix6Z, kMaxHorizon + 1> Gz;  // X_j = Phi^j x + Gz_j z
  std::array<Matrix3Z, kMaxHorizon + 1> Uz;  // u_j = K Phi^j x + Uz_j z
};

struct Law {
  GuidanceParams params;
  Settings s;
  std::unique_ptr<Guidance> rules;  // the MPC's switching predicates (its solvers are never called)
  std::array<PhaseModel, 3> model;
  Phase phase = Phase::Rendezvous;
  ecg::DenseQp qp;
  ecg::DualActiveSet solver;
  double z[ecg::kMaxVars] = {};
  uint32_t failures = 0;
};

void put(rvd_guidance_output* out, const char* name, double v) {
  if (out->n_named >= RVD_MAX_NAMED) return;
  rvd_named_value& n = out->named[out->n_named++];
  std::snprintf(n.name, sizeof n.name, "%s", name);
  n.value = v;
}

void build_model(PhaseModel& m, Phase p, const GuidanceParams& params, const Settings& s) {
  const PhaseParams& pp = params.phase(p);
  m.phase = p;
  m.Ts = pp.Ts_s;
  m.u_max = pp.u_max_mps;
  const double centroid = params.finite_burns ? std::min(0.5 * max_pulse_s(m.u_max, params.thrusters), 0.5 * m.Ts) : 0.0;
  cw_burn_model(params.mean_motion_rad_s(), m.Ts, centroid, m.A, m.B);
  const Matrix6d Q = pp.Q_diag.asDiagonal();
  const Eigen::Matrix3d R = pp.R_diag.asDiagonal();
  const Matrix6d P = solve_dare(m.A, m.B, Q, R);
  m.K = -(R + m.B.transpose() * P * m.B).ldlt().solve(m.B.transpose() * P * m.A);
  m.Phi = m.A + m.B * m.K;
  const Eigen::Matrix<double, 6, 3> S = (Matrix6d::Identity() - m.Phi).partialPivLu().solve(m.B);  // x_ss = S Gamma v
  m.Gamma = S.topRows<3>().inverse();                                                               // eq 17, D_t = 0
  m.U_ss = m.K * S * m.Gamma + m.Gamma;
  // v_j = M_j z: rho (z 0..2) plus xbar_{j+1} (z 3+3j..) for j < L.
  const int nz = 3 + 3 * s.L + 1;
  auto M = [&](int j) {
    Matrix3Z Mj = Matrix3Z::Zero();
    Mj.leftCols<3>().setIdentity();
    if (j < s.L) Mj.block<3, 3>(0, 3 + 3 * j).setIdentity();
    return Mj;
  };
  m.Gz[0].setZero();
  for (int j = 0; j <= s.n_c; ++j) {
    m.Uz[j] = m.K * m.Gz[j] + m.Gamma * M(j);
    if (j < s.n_c) m.Gz[j + 1] = m.Phi * m.Gz[j] + m.B * m.Gamma * M(j);
  }
  (void)nz;
}

void* create(const rvd_guidance_config* c, char* error, size_t error_size) {
  try {
    auto law = std::make_unique<Law>();
    law->params = params_from_config(*c);
    rvd::nav::ErrorModel errors;  // the margins the flight executable derives for the MPC
    errors.sigma_position_m = c->sigma_position_m;
    errors.sigma_velocity_mps = c->sigma_velocity_mps;
    errors.thrust_error_sigma = c->thrust_error_sigma;
    errors.finite_burns = c->finite_burns != 0;
    law->params.margins = rvd::nav::derive_margins(errors, law->params);
    for (uint32_t i = 0; i < c->n_params; ++i) {
      const std::string name = c->params[i].name;
      const double v = c->params[i].value;
      if (name == "L") law->s.L = static_cast<int>(v);
      else if (name == "n_c") law->s.n_c = static_cast<int>(v);
      else if (name == "xbar_weight") law->s.xbar_weight = v;
      else if (name == "slack_weight") law->s.slack_weight = v;
      else throw std::invalid_argument("unknown parameter law." + name + " (known: L, n_c, xbar_weight, slack_weight)");
    }
    const Settings& s = law->s;
    if (s.L < 0 || s.L > kMaxL || s.n_c < 1 || s.n_c > kMaxHorizon || !(s.xbar_weight > 0) || !(s.slack_weight > 0))
      throw std::invalid_argument("law.L in 0.." + std::to_string(kMaxL) + ", law.n_c in 1.." +
                                  std::to_string(kMaxHorizon) + ", weights > 0");
    if ((s.n_c + 1) * 17 + 12 > ecg::kMaxRows) throw std::invalid_argument("law.n_c: too many rows");
    law->rules = std::make_unique<Guidance>(law->params);
    for (Phase p : {Phase::Rendezvous, Phase::Approach, Phase::Docking})
      build_model(law->model[static_cast<int>(p) - 1], p, law->params, s);
    return law.release();
  } catch (const std::exception& e) {
    if (error && error_size) std::snprintf(error, error_size, "%s", e.what());
  }
  return nullptr;
}

void reset(void* p) {
  auto& law = *static_cast<Law*>(p);
  law.phase = Phase::Rendezvous;
  law.failures = 0;
}

// One row g z <= h of the governor's QP.
void row(ecg::DenseQp& qp, const RowZ& g, double h) {
  if (qp.m >= ecg::kMaxRows) return;
  for (int i = 0; i < qp.n; ++i) qp.G[qp.m][i] = g(i);
  qp.h[qp.m++] = h;
}

// The governor's QP for state x: rows on the predicted closed loop, stages 0..n_c, and rho at rest.
void build_qp(Law& law, const PhaseModel& m, const Vector6d& x, const TargetState& target,
              const EstimateQuality& quality, Eigen::Vector3d& r_cmd) {
  const GuidanceParams& gp = law.params;
  const Margins& mg = gp.margins;
  const Settings& s = law.s;
  ecg::DenseQp& qp = law.qp;
  const int nz = 3 + 3 * s.L + 1, sigma = nz - 1;
  qp.n = nz;
  qp.m = 0;
  const double k_pos = mg.estimate_sigmas * quality.position_m;
  const Eigen::Vector3d axis0 = target.q_lvlh_body * Eigen::Vector3d::UnitX();
  // The command: the MPC's set point of the phase.
  if (m.phase == Phase::Rendezvous)
    r_cmd = (gp.rendezvous_use_setpoint ? gp.keepout_radius_m + gp.rendezvous_setpoint_offset_m : 0.0) * axis0;
  else if (m.phase == Phase::Approach)
    r_cmd = (gp.approach_stop_m + gp.approach_setpoint_offset_m) * axis0;
  else
    r_cmd = target.q_lvlh_body * gp.port_body_m;
  for (int i = 0; i < nz; ++i) {
    qp.H[i] = 2.0 * (i < 3 ? 1.0 : s.xbar_weight);
    qp.c[i] = i < 3 ? -2.0 * r_cmd(i) : 0.0;
  }
  qp.H[sigma] = 2.0 * s.slack_weight;
  qp.c[sigma] = 0.0;

  // Geometry of the phase, as the MPC's QP builder sets it (phase_qp.cpp).
  KeepoutPlanes plan;
  double r_keep = 0.0;
  if (m.phase == Phase::Rendezvous) {
    const Eigen::Vector3d axis_N = attitude_after(target, s.n_c * m.Ts) * Eigen::Vector3d::UnitX();
    plan = plan_keepout_rotation(x.head<3>(), axis_N, s.n_c, gp.keepout_rate_cap_factor * gp.mean_motion_rad_s() * m.Ts,
                                 gp.keepout_direction);
    r_keep = std::min(gp.keepout_radius_m + mg.keepout_m + k_pos, x.head<3>().norm());
  }
  const double turn = omega_lvlh(target).norm() * m.Ts, turning = mg.rotating_cone_factor * turn * turn;
  const double braking = mg.estimate_sigmas * quality.thrust_scale_sigma * m.u_max * m.Ts;
  const double plane_m = gp.approach_stop_m + mg.overshoot_m + k_pos + braking + turning * gp.approach_stop_m;
  const double approach_margin = mg.approach_cone_m + k_pos + turning * x.head<3>().norm();
  const double docking_margin = mg.docking_cone_m + k_pos;
  const double v_bound = gp.v_max_mps - mg.v_max_mps - mg.estimate_sigmas * quality.velocity_mps;
  const double approach_angle = gp.approach.los_half_angle_deg * kDeg, docking_angle = gp.docking.los_half_angle_deg * kDeg;
  const Eigen::Vector3d u0 = x.head<3>().norm() > 1e-9 ? Eigen::Vector3d(x.head<3>().normalized()) : axis0;

  Vector6d xf = x;  // Phi^j x, the free response
  RowZ g;
  for (int j = 0; j <= s.n_c; ++j) {
    if (j > 0) xf = m.Phi * xf;
    // Input box of every thruster direction (fill_input_box's bounds: what the thrusters are known to deliver).
    const Eigen::Vector3d uf = m.K * xf;
    const double common = m.u_max * (1.0 - mg.input_fraction) * (j == 0 ? 1.0 : 1.0 - mg.plan_reserve_fraction);
    for (int a = 0; a < 3; ++a)
      for (int sign = 0; sign < 2; ++sign) {
        const double sc = quality.thrust_scale[2 * a + sign];
        const double bound = common * (std::isfinite(sc) ? std::clamp(sc - mg.estimate_sigmas * quality.thrust_scale_sigma, 0.5, 1.0) : 0.5);
        const double sg = sign == 0 ? 1.0 : -1.0;
        g = sg * m.Uz[j].row(a);
        row(qp, g, bound - sg * uf(a));
      }
    if (j == 0) continue;
    const Matrix3Z Gp = m.Gz[j].topRows<3>(), Gv = m.Gz[j].bottomRows<3>();
    const Eigen::Vector3d pf = xf.head<3>(), vf = xf.tail<3>();
    const Eigen::Quaterniond q_j = attitude_after(target, j * m.Ts);
    const Eigen::Vector3d axis_j = q_j * Eigen::Vector3d::UnitX();
    switch (m.phase) {
      case Phase::Rendezvous: {  // n_j' rho_j >= r
        const Eigen::Vector3d n_j = Eigen::AngleAxisd(j * plan.step_rad, plan.rotation_axis) * u0;
        g = -n_j.transpose() * Gp;
        row(qp, g, -r_keep + n_j.dot(pf));
        break;
      }
      case Phase::Approach: {  // overshoot plane, and the corridor (soft)
        g = -axis_j.transpose() * Gp;
        row(qp, g, -plane_m + axis_j.dot(pf));
        const Matrix43d H = pyramid_rows_lvlh(q_j, approach_angle);
        for (int k = 0; k < 4; ++k) {
          g = H.row(k) * Gp;
          g(sigma) = -1.0;
          row(qp, g, -approach_margin - H.row(k).dot(pf));
        }
        break;
      }
      default: {  // docking pyramid (hard) and |v|_inf
        const Matrix43d H = pyramid_rows_lvlh(q_j, docking_angle);
        const Eigen::Vector3d port = q_j * gp.port_body_m;
        for (int k = 0; k < 4; ++k) {
          g = H.row(k) * Gp;
          row(qp, g, -docking_margin - H.row(k).dot(pf - port));
        }
        for (int a = 0; a < 3; ++a)
          for (double sg : {1.0, -1.0}) {
            g = sg * Gv.row(a);
            row(qp, g, v_bound - sg * vf(a));
          }
        break;
      }
    }
  }
  // rho at rest: the position rows of the phase at rho, and the inner loop's rest input within the box.
  const Eigen::Quaterniond q_end = attitude_after(target, s.n_c * m.Ts);
  RowZ e[3];
  for (int a = 0; a < 3; ++a) {
    e[a].setZero();
    e[a](a) = 1.0;
  }
  auto at_rho = [&](const Eigen::Vector3d& n) { RowZ r = RowZ::Zero(); for (int a = 0; a < 3; ++a) r(a) = n(a); return r; };
  switch (m.phase) {
    case Phase::Rendezvous: {
      const Eigen::Vector3d n_end = Eigen::AngleAxisd(s.n_c * plan.step_rad, plan.rotation_axis) * u0;
      row(qp, -at_rho(n_end), -r_keep);
      break;
    }
    case Phase::Approach: {
      const Eigen::Vector3d a_end = q_end * Eigen::Vector3d::UnitX();
      row(qp, -at_rho(a_end), -plane_m);
      const Matrix43d H = pyramid_rows_lvlh(q_end, approach_angle);
      for (int k = 0; k < 4; ++k) {
        g = at_rho(H.row(k).transpose());
        g(sigma) = -1.0;
        row(qp, g, -approach_margin);
      }
      break;
    }
    default: {
      const Matrix43d H = pyramid_rows_lvlh(q_end, docking_angle);
      const Eigen::Vector3d port = q_end * gp.port_body_m;
      for (int k = 0; k < 4; ++k) row(qp, at_rho(H.row(k).transpose()), -docking_margin + H.row(k).dot(port));
      break;
    }
  }
  const double rest_bound = m.u_max * (1.0 - mg.input_fraction) * (1.0 - mg.plan_reserve_fraction) * 0.5;
  for (int a = 0; a < 3; ++a) {
    row(qp, at_rho(m.U_ss.row(a).transpose()), rest_bound);
    row(qp, -at_rho(m.U_ss.row(a).transpose()), rest_bound);
  }
  (void)e;
}

int step(void* p, const rvd_nav_input* nav, double budget_s, rvd_guidance_output* out) {
  (void)budget_s;
  auto& law = *static_cast<Law*>(p);
  Vector6d x;
  for (int i = 0; i < 3; ++i) {
    x(i) = nav->position_lvlh_m[i];
    x(3 + i) = nav->velocity_lvlh_mps[i];
  }
  TargetState target;
  target.q_lvlh_body = Eigen::Quaterniond(nav->q_lvlh_body[0], nav->q_lvlh_body[1], nav->q_lvlh_body[2], nav->q_lvlh_body[3]);
  target.omega_body_rad_s = Eigen::Vector3d(nav->omega_body_rad_s[0], nav->omega_body_rad_s[1], nav->omega_body_rad_s[2]);
  EstimateQuality quality;
  quality.position_m = nav->sigma_position_m;
  quality.velocity_mps = nav->sigma_velocity_mps;
  for (int j = 0; j < 6; ++j) quality.thrust_scale[j] = nav->thrust_scale[j];
  quality.thrust_scale_sigma = nav->thrust_scale_sigma;
  out->solver_status = RVD_SOLVER_NONE;
  if (!x.allFinite() || !target.q_lvlh_body.coeffs().allFinite() || !target.omega_body_rad_s.allFinite() ||
      std::abs(target.q_lvlh_body.norm() - 1.0) > 1e-3) {
    out->phase = static_cast<uint8_t>(law.phase);
    out->status = RVD_STATUS_INVALID_STATE;
    return 0;
  }
  target.q_lvlh_body.normalize();
  const Guidance& g = *law.rules;  // Algorithm 1, as the MPC switches
  if (law.phase == Phase::Rendezvous && g.ready_for_approach(x, target, quality)) law.phase = Phase::Approach;
  if (law.phase == Phase::Approach && g.ready_for_docking(x, target, quality)) law.phase = Phase::Docking;
  if (law.phase == Phase::Docking && g.docked(x, target)) law.phase = Phase::Docked;
  out->phase = static_cast<uint8_t>(law.phase);
  if (law.phase == Phase::Docked) {
    out->status = RVD_STATUS_DOCKED;
    return 0;
  }
  const PhaseModel& m = law.model[static_cast<int>(law.phase) - 1];
  Eigen::Vector3d r_cmd;
  build_qp(law, m, x, target, quality, r_cmd);
  const ecg::QpStatus st = law.solver.solve(law.qp, law.z);
  out->computed = 1;
  out->iterations = static_cast<uint32_t>(law.solver.iterations);
  out->solve_time_us = -1.0;
  out->primal_residual = -1.0;
  out->dual_residual = -1.0;
  if (st == ecg::QpStatus::Solved) {
    const Eigen::Vector3d v0(law.z[0] + (law.s.L > 0 ? law.z[3] : 0.0), law.z[1] + (law.s.L > 0 ? law.z[4] : 0.0),
                             law.z[2] + (law.s.L > 0 ? law.z[5] : 0.0));
    const Eigen::Vector3d u = m.K * x + m.Gamma * v0;
    for (int i = 0; i < 3; ++i) out->dv_lvlh_mps[i] = std::clamp(u(i), -m.u_max, m.u_max);
    out->status = RVD_STATUS_OK;
    out->solver_status = RVD_SOLVER_SOLVED;
    double J = 0.0;
    for (int i = 0; i < law.qp.n; ++i) J += 0.5 * law.qp.H[i] * law.z[i] * law.z[i] + law.qp.c[i] * law.z[i];
    out->objective = J;
    put(out, "rho_error_m", (Eigen::Vector3d(law.z[0], law.z[1], law.z[2]) - r_cmd).norm());
    put(out, "corridor_slack_m", law.z[law.qp.n - 1]);
  } else {  // the safe action: zero thrust, and why
    ++law.failures;
    out->status = RVD_STATUS_ZERO_THRUST;
    out->solver_status = static_cast<uint8_t>(st == ecg::QpStatus::Infeasible ? RVD_SOLVER_INFEASIBLE : RVD_SOLVER_MAX_ITER);
  }
  put(out, "governor_rows", law.qp.m);
  put(out, "active_rows", law.solver.active_rows());
  put(out, "peer_failures", law.failures);
  return 0;
}

void destroy(void* p) { delete static_cast<Law*>(p); }

}  // namespace

extern "C" const rvd_guidance_law* rvd_guidance_law_entry(void) {
  static const rvd_guidance_law law{RVD_GUIDANCE_ABI_VERSION, "lq_ecg", create, reset, step, destroy};
  return &law;
}
