// A peer of the three-phase MPC: the same phase switching (Algorithm 1, the MPC's own predicates) and
// the same phase QPs (flight_sw/guidance/phase_qp.cpp builds them), solved by C code that CVXPYgen
// generated from a CVXPY model of those QPs (generate.py; QOCOGEN or OSQP, one problem per phase and
// horizon, rvd_cpg.h). Built as cvxpygen_qoco and cvxpygen_osqp (their law.toml).
//
// Per step: the MPC's QP builder fills the QP for the navigation estimate, the law copies its
// changing data into the generated problem's parameters, solves, and commands the first delta-v.
// A solve whose status is not "solved" commands zero thrust (the harness's safe action; status
// ZERO_THRUST, the solver's status in solver_status, named value peer_failed = 1). Our MPC would
// fly the previous plan or its recovery QP there; the peer is kept to the comparison of solvers.
//
// law.shadow = 1 (for accuracy runs, not timing runs: it doubles the work of a step) also solves the
// same QP with our Fast MPC solver at its reference settings and reports the difference of the two
// solutions (named values ref_du_mps, ref_dobj_rel, ref_obj, peer_viol).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <string>
#include <vector>

#include "flight_sw/guidance/guidance.hpp"
#include "flight_sw/guidance/phase_qp.hpp"
#include "flight_sw/guidance/plugin/mpc_law.hpp"
#include "flight_sw/nav/margins.hpp"
#include "flight_sw/solver/fast_mpc.hpp"
#include "rvd_cpg.h"
#include "rvd_guidance.h"

namespace {

using rvd::guidance::Guidance;
using rvd::guidance::GuidanceParams;
using rvd::guidance::Phase;
using rvd::guidance::PhaseQp;
using rvd::guidance::TargetState;
using rvd::guidance::Vector6d;

const char* kPhaseName[3] = {"rendezvous", "approach", "docking"};

struct Slot {
  const rvd_cpg_problem* problem = nullptr;
  std::unique_ptr<PhaseQp> qp;
  std::unique_ptr<rvd::solver::FastMpcSolver> reference;  // shadow mode only
  std::array<std::vector<double>, RVD_CPG_N_PARAMS> values;
  std::vector<int> cone_stages;  // stages with the 4 pyramid rows
  bool dynamics_set = false;     // A and B are set once, at the phase's first solve
};

struct Law {
  GuidanceParams params;
  std::unique_ptr<Guidance> rules;  // the MPC's switching predicates (its solvers are never called)
  Phase phase = Phase::Rendezvous;
  std::array<Slot, 3> slot;
  bool shadow = false;
  uint32_t failures = 0;
  rvd::solver::Vector x0;
};

void put(rvd_guidance_output* out, const char* name, double v) {
  if (out->n_named >= RVD_MAX_NAMED) return;
  rvd_named_value& n = out->named[out->n_named++];
  std::snprintf(n.name, sizeof n.name, "%s", name);
  n.value = v;
}

// Our OCP objective (solver/ocp_qp.hpp) at a plan (x stage-major 6(N+1), u 3N): the same definition
// for both solutions, so that the comparison does not depend on what either solver counts in its own.
double objective(const rvd::solver::OcpQp& qp, const double* x, const double* u) {
  const int N = qp.dims.N;
  double J = 0.0;
  for (int i = 0; i <= N; ++i) {
    const double* xi = x + 6 * i;
    for (int r = 0; r < 6; ++r) {
      double Qx = 0.0;
      for (int c = 0; c < 6; ++c) Qx += qp.Q[i](r, c) * xi[c];
      J += 0.5 * xi[r] * Qx + qp.q[i](r) * xi[r];
    }
    const int nu = qp.dims.nu[i];
    for (int r = 0; r < nu && r < 3 && i < N; ++r) {
      double Ru = 0.0;
      for (int c = 0; c < 3; ++c) Ru += qp.R[i](r, c) * u[3 * i + c];
      J += 0.5 * u[3 * i + r] * Ru + qp.r[i](r) * u[3 * i + r];
    }
    // Soft rows: their penalty at the smallest slack, (row - d)+.
    for (int k = 0; k < qp.dims.soft_rows(i); ++k) {
      const int row = qp.idxs[i][k];
      double v = -qp.d[i](row);
      for (int c = 0; c < 6; ++c) v += qp.C[i](row, c) * xi[c];
      for (int c = 0; c < nu && c < 3 && i < N; ++c) v += qp.D[i](row, c) * u[3 * i + c];
      const double s = std::max(0.0, v);
      J += qp.zs[i](k) * s + 0.5 * qp.Zs[i](k) * s * s;
    }
  }
  return J;
}

// Largest violation of our QP's hard rows and dynamics by a plan.
double violation(const rvd::solver::OcpQp& qp, const double* x, const double* u) {
  const int N = qp.dims.N;
  double worst = 0.0;
  for (int i = 0; i <= N; ++i) {
    const double* xi = x + 6 * i;
    const int nu = i < N ? std::min(qp.dims.nu[i], 3) : 0;
    if (i < N) {
      for (int r = 0; r < 6; ++r) {
        double v = xi[6 + r] - qp.b[i](r);
        for (int c = 0; c < 6; ++c) v -= qp.A[i](r, c) * xi[c];
        for (int c = 0; c < nu; ++c) v -= qp.B[i](r, c) * u[3 * i + c];
        worst = std::max(worst, std::abs(v));
      }
    }
    for (int row = 0; row < qp.dims.nc[i]; ++row) {
      bool soft = false;
      for (int k = 0; k < qp.dims.soft_rows(i); ++k) soft = soft || qp.idxs[i][k] == row;
      if (soft) continue;
      double v = -qp.d[i](row);
      for (int c = 0; c < 6; ++c) v += qp.C[i](row, c) * xi[c];
      for (int c = 0; c < nu; ++c) v += qp.D[i](row, c) * u[3 * i + c];
      worst = std::max(worst, v);
    }
  }
  return worst;
}

// The generated problem for a phase at the run's horizon, checked against our QP builder's weights and
// row layout; nullptr with the reason in `error`.
bool attach(Slot& s, Phase p, const GuidanceParams& params, bool shadow, std::string& error) {
  const int k = static_cast<int>(p) - 1;
  const int N = params.phase(p).N;
  std::string have;
  for (int j = 0; j < rvd_cpg_n_problems; ++j) {
    const rvd_cpg_problem* c = rvd_cpg_problems[j];
    if (c->phase != static_cast<int>(p)) continue;
    have += (have.empty() ? "" : ", ") + std::to_string(c->N);
    if (c->N == N) s.problem = c;
  }
  if (!s.problem) {
    error = std::string("no generated ") + kPhaseName[k] + " QP for N = " + std::to_string(N) + " (generated: " + have +
            "; law.toml [generate] args --horizons)";
    return false;
  }
  s.qp = std::make_unique<PhaseQp>(p, params);
  const rvd::solver::OcpQp& qp = s.qp->qp();
  // Weights: generated constants against what our builder puts in (the OCP's 1/2 x'(2Q)x).
  double dw = 0.0;
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) {
      dw = std::max(dw, std::abs(qp.Q[0](r, c) / 2 - s.problem->Q[6 * r + c]));
      dw = std::max(dw, std::abs(qp.Q[N](r, c) / 2 - s.problem->Qf[6 * r + c]));
    }
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) dw = std::max(dw, std::abs(qp.R[0](r, c) / 2 - s.problem->R[3 * r + c]));
  if (dw > 1e-9 * (1.0 + params.phase(p).R_diag.maxCoeff())) {
    error = std::string(kPhaseName[k]) + ": this run's Q, Q_f or R differ from the generated QP's (regenerate)";
    return false;
  }
  // Layout: the rows generate.py modelled, where our builder put them.
  const int* n = s.problem->sizes;
  int keepout = 0, cone = 0, vel = 0, stop = 0;
  for (int i = 1; i <= N; ++i) {
    const PhaseQp::StageLayout L = s.qp->stage(i);
    keepout += L.keepout_row >= 0;
    vel += L.vel_row >= 0;
    if (L.stop_row >= 0) {
      ++stop;
      for (int j = 0; j < qp.dims.soft_rows(i); ++j)
        if (qp.idxs[i][j] == L.stop_row && std::abs(qp.zs[i](j) - s.problem->stop_penalty) > 1e-12) {
          error = std::string(kPhaseName[k]) + ": the stop plane's penalty differs from the generated QP's";
          return false;
        }
    }
    if (L.cone_row >= 0) {
      s.cone_stages.push_back(i);
      ++cone;
      for (int j = 0; j < qp.dims.soft_rows(i); ++j)
        if (qp.idxs[i][j] >= L.cone_row && qp.idxs[i][j] < L.cone_row + 4 &&
            std::abs(qp.zs[i](j) - s.problem->lambda) > 1e-12) {
          error = std::string(kPhaseName[k]) + ": the cone penalty lambda differs from the generated QP's";
          return false;
        }
    }
    if (L.t_row >= 0 || L.obstacle_row >= 0) {
      error = "the 1-norm rendezvous and obstacle rows are not generated";
      return false;
    }
  }
  if (n[RVD_CPG_KEEPOUT_D] != keepout || n[RVD_CPG_CONE_D] != 4 * cone || n[RVD_CPG_VEL_D] != 6 * vel ||
      n[RVD_CPG_STOP_D] != stop ||
      n[RVD_CPG_Q] != 6 * (N + 1) || n[RVD_CPG_UBOX] != 6 * N) {
    error = std::string(kPhaseName[k]) + ": our QP's rows are not those of the generated QP (regenerate)";
    return false;
  }
  for (int j = 0; j < RVD_CPG_N_PARAMS; ++j) s.values[j].assign(n[j], 0.0);
  if (shadow) {
    s.reference = std::make_unique<rvd::solver::FastMpcSolver>(qp.dims, rvd::solver::Settings::reference());
  }
  return true;
}

void* create(const rvd_guidance_config* c, char* error, size_t error_size) {
  try {
    auto law = std::make_unique<Law>();
    law->params = rvd::guidance::params_from_config(*c);
    rvd::nav::ErrorModel errors;  // the margins the flight executable derives for the MPC
    errors.sigma_position_m = c->sigma_position_m;
    errors.sigma_velocity_mps = c->sigma_velocity_mps;
    errors.thrust_error_sigma = c->thrust_error_sigma;
    errors.finite_burns = c->finite_burns != 0;
    law->params.margins = rvd::nav::derive_margins(errors, law->params);
    for (uint32_t i = 0; i < c->n_params; ++i) {
      if (std::strcmp(c->params[i].name, "shadow") == 0) law->shadow = c->params[i].value != 0.0;
      else throw std::invalid_argument(std::string("unknown parameter law.") + c->params[i].name + " (known: shadow)");
    }
    law->rules = std::make_unique<Guidance>(law->params);
    std::string why;
    for (Phase p : {Phase::Rendezvous, Phase::Approach, Phase::Docking})
      if (!attach(law->slot[static_cast<int>(p) - 1], p, law->params, law->shadow, why))
        throw std::invalid_argument(why);
    for (Slot& s : law->slot) s.problem->settings();
    law->x0 = rvd::solver::Vector::Zero(6);
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

// The QP our builder made, into the generated problem's parameters.
void load(Slot& s, bool with_dynamics) {
  const rvd::solver::OcpQp& qp = s.qp->qp();
  const int N = s.qp->N();
  auto& v = s.values;
  for (int r = 0; r < 6; ++r) v[RVD_CPG_X0][r] = s.qp->x0()(r);
  for (int i = 0; i <= N; ++i)
    for (int r = 0; r < 6; ++r) v[RVD_CPG_Q][6 * i + r] = qp.q[i](r);
  int keep = 0, speed = 0, vel = 0, cone = 0, stop = 0;
  for (int i = 0; i <= N; ++i) {
    const PhaseQp::StageLayout L = s.qp->stage(i);
    if (L.box_row >= 0)
      for (int r = 0; r < 6; ++r) v[RVD_CPG_UBOX][6 * i + r] = qp.d[i](L.box_row + r);
    if (i == 0) continue;
    if (L.keepout_row >= 0) {
      for (int c = 0; c < 3; ++c) v[RVD_CPG_KEEPOUT_C][3 * keep + c] = qp.C[i](L.keepout_row, c);
      v[RVD_CPG_KEEPOUT_D][keep++] = qp.d[i](L.keepout_row);
    }
    if (!v[RVD_CPG_SPEED_D].empty()) {  // generated on every approach and rendezvous stage; else 0 <= 1
      for (int c = 0; c < 3; ++c) v[RVD_CPG_SPEED_C][3 * speed + c] = L.speed_row >= 0 ? qp.C[i](L.speed_row, 3 + c) : 0.0;
      v[RVD_CPG_SPEED_D][speed++] = L.speed_row >= 0 ? qp.d[i](L.speed_row) : 1.0;
    }
    if (L.cone_row >= 0) {
      for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 3; ++c) v[RVD_CPG_CONE_C][12 * cone + 3 * r + c] = qp.C[i](L.cone_row + r, c);
        v[RVD_CPG_CONE_D][4 * cone + r] = qp.d[i](L.cone_row + r);
      }
      ++cone;
    }
    if (L.vel_row >= 0) {
      for (int r = 0; r < 6; ++r) v[RVD_CPG_VEL_D][6 * vel + r] = qp.d[i](L.vel_row + r);
      ++vel;
    }
    if (L.stop_row >= 0) {
      for (int c = 0; c < 3; ++c) v[RVD_CPG_STOP_C][3 * stop + c] = qp.C[i](L.stop_row, c);
      v[RVD_CPG_STOP_D][stop++] = qp.d[i](L.stop_row);
    }
  }
  if (with_dynamics) {
    for (int r = 0; r < 6; ++r) {
      for (int c = 0; c < 6; ++c) v[RVD_CPG_A][6 * r + c] = s.qp->A()(r, c);
      for (int c = 0; c < 3; ++c) v[RVD_CPG_B][3 * r + c] = s.qp->B()(r, c);
    }
  }
  for (int j = 0; j < RVD_CPG_N_PARAMS; ++j) {
    if (v[j].empty() || ((j == RVD_CPG_A || j == RVD_CPG_B) && !with_dynamics)) continue;
    s.problem->set(j, v[j].data());
  }
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
  rvd::guidance::EstimateQuality quality;
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
  // Algorithm 1, as the MPC switches: a state can pass several conditions at once.
  const Guidance& g = *law.rules;
  if (law.phase == Phase::Rendezvous && g.ready_for_approach(x, target, quality)) law.phase = Phase::Approach;
  if (law.phase == Phase::Approach && g.ready_for_docking(x, target, quality)) law.phase = Phase::Docking;
  if (law.phase == Phase::Docking && g.docked(x, target)) law.phase = Phase::Docked;
  out->phase = static_cast<uint8_t>(law.phase);
  if (law.phase == Phase::Docked) {
    out->status = RVD_STATUS_DOCKED;
    return 0;
  }
  Slot& s = law.slot[static_cast<int>(law.phase) - 1];
  s.qp->build(x, target, quality);
  load(s, !s.dynamics_set);
  s.dynamics_set = true;
  s.problem->solve();
  const int st = s.problem->status();
  out->computed = 1;
  out->iterations = static_cast<uint32_t>(std::max(0, s.problem->iterations()));
  out->solve_time_us = -1.0;  // the harness's time of the whole step
  out->primal_residual = s.problem->primal_residual();
  out->dual_residual = s.problem->dual_residual();
  out->objective = s.problem->objective();
  const double* u = s.problem->u();
  const double u_max = s.qp->u_max_mps();
  const bool finite = std::isfinite(u[0]) && std::isfinite(u[1]) && std::isfinite(u[2]);
  if (st == RVD_CPG_SOLVED && finite) {
    for (int i = 0; i < 3; ++i) out->dv_lvlh_mps[i] = std::clamp(u[i], -u_max, u_max);
    out->status = RVD_STATUS_OK;
    out->solver_status = RVD_SOLVER_SOLVED;
  } else {  // the safe action: zero thrust, and the solver's word for why
    ++law.failures;
    out->status = RVD_STATUS_ZERO_THRUST;
    out->solver_status = static_cast<uint8_t>(st == RVD_CPG_SOLVED ? RVD_SOLVER_NUMERICAL_ERROR : st);
  }
  put(out, "peer_failed", out->status == RVD_STATUS_OK ? 0.0 : 1.0);
  put(out, "peer_failures", law.failures);
  if (law.shadow) {
    law.x0 = x;
    s.reference->solve(s.qp->qp(), law.x0);
    const auto& info = s.reference->info();
    const int N = s.qp->N();
    // Our plan as stage-major arrays (values[] buffers are not needed after the solve: reuse them).
    std::vector<double>& xs = s.values[RVD_CPG_Q];  // 6(N+1)
    std::vector<double>& us = s.values[RVD_CPG_UBOX];  // 6N >= 3N
    for (int i = 0; i <= N; ++i)
      for (int r = 0; r < 6; ++r) xs[6 * i + r] = s.reference->x()[i](r);
    for (int i = 0; i < N; ++i)
      for (int r = 0; r < 3; ++r) us[3 * i + r] = s.reference->u()[i](r);
    const double J_ref = objective(s.qp->qp(), xs.data(), us.data());
    const double J_peer = objective(s.qp->qp(), s.problem->x(), u);
    double du = 0.0;
    for (int r = 0; r < 3; ++r) du = std::max(du, std::abs(u[r] - us[r]));
    put(out, "ref_ok", info.status == rvd::solver::Status::Solved ? 1.0 : 0.0);
    put(out, "ref_du_mps", du);
    put(out, "ref_obj", J_ref);
    put(out, "ref_dobj_rel", (J_peer - J_ref) / std::max(1.0, std::abs(J_ref)));
    put(out, "peer_viol", violation(s.qp->qp(), s.problem->x(), u));
    put(out, "ref_iterations", info.iterations);
  }
  return 0;
}

void destroy(void* p) { delete static_cast<Law*>(p); }

}  // namespace

extern "C" const rvd_guidance_law* rvd_guidance_law_entry(void) {
#ifdef RVD_PEER_NAME
#define RVD_STR2(x) #x
#define RVD_STR(x) RVD_STR2(x)
  static const rvd_guidance_law law{RVD_GUIDANCE_ABI_VERSION, RVD_STR(RVD_PEER_NAME), create, reset, step, destroy};
#else
  static const rvd_guidance_law law{RVD_GUIDANCE_ABI_VERSION, "cvxpygen_peer", create, reset, step, destroy};
#endif
  return &law;
}
