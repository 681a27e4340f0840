// Wang and Boyd's Fast MPC (2010, sec. III): infeasible-start Newton on the log-barrier
// problem
//   f(z) + sum_soft (zs s + Zs s^2 / 2) - kappa sum log(d + s - Gz) - kappa sum_soft log(s)
// subject to the dynamics, with a fixed weight kappa, from a point that satisfies the rows
// strictly (the shifted previous plan, or the first strictly interior iterate of the primal-dual
// method, ipm.cpp). The barrier's implied duals are lam = kappa / t, mu = kappa / s; its Newton
// system is the primal-dual one with exact complementarity, so it shares the elimination and the
// Riccati recursion (kkt.hpp). Backtracking line search: the residual norm while the dynamics are
// violated (infeasible start), then the barrier objective.
#include <algorithm>
#include <cmath>
#ifdef RVD_SOLVER_TRACE
#include <cstdio>
#endif

#include "flight_sw/solver/fast_mpc.hpp"
#include "flight_sw/solver/kkt.hpp"

namespace rvd::solver {

using detail::Step;
using detail::Workspace;

namespace {

// The barrier-optimal soft slack of a row with room r = d - g'z: the minimiser over s > max(0, -r)
// of zs s - kappa log(s) - kappa log(r + s) (Zs > 0 folded into zs at the current s).
double seat_soft_slack(double r, double zs, double Zs, double s_now, double kappa) {
  const double z = zs + Zs * std::max(s_now, 0.0);
  if (!(z > 0.0)) return std::max(-r, 0.0) + 1.0;
  const double b = z * r - 2.0 * kappa, root = std::sqrt(z * z * r * r + 4.0 * kappa * kappa);
  return b > 0.0 ? 2.0 * kappa * r / (b + root) : (root - b) / (2.0 * z);
}

}  // namespace

Status FastMpcSolver::solve_barrier(const OcpQp& qp, bool warm) {
  Workspace& w = *work_;
  const detail::Kernels& K = *kernels_;
  const Settings& S = settings_;
  const int N = w.N, nx = w.nx, M = w.rows, X = (N + 1) * nx, D = N * nx;
  const double kappa = S.barrier, tol = S.tol;

  // Rows strictly inside at (x, u, sig)? Leaves gz of that point.
  auto strictly_inside = [&](const double* x, const double* u, const double* sig) {
    detail::g_mul_all(w, u, x, w.gz);
    for (int k = 0; k < M; ++k) {
      if (w.act[k] == 0.0) continue;
      if (!(w.gz[k] - w.soft[k] * sig[k] < w.dv[k])) return false;
      if (w.soft[k] > 0.0 && !(sig[k] > 0.0)) return false;
    }
    return true;
  };
  // Barrier duals and residuals at (x, u, pi, sig) (uses w.gz of that point); returns the residual
  // 2-norm, the infeasible-start method's merit.
  auto evaluate = [&](const double* x, const double* u, const double* pi, const double* sig) {
    for (int k = 0; k < M; ++k) {
      if (w.act[k] == 0.0) {
        w.t[k] = 1.0, w.lam[k] = w.mu[k] = 0.0;
        continue;
      }
      w.t[k] = w.dv[k] + w.soft[k] * sig[k] - w.gz[k];
      w.lam[k] = kappa / w.t[k];
      w.mu[k] = w.soft[k] > 0.0 ? kappa / sig[k] : 0.0;
    }
    K.residuals(w, qp, x, u, pi, w.lam);
    double r2 = 0.0;
    for (int k = 0; k < w.inputs; ++k) r2 += w.rdu[k] * w.rdu[k];
    for (int k = nx; k < X; ++k) r2 += w.rdx[k] * w.rdx[k];
    for (int k = 0; k < D; ++k) r2 += w.rdyn[k] * w.rdyn[k];
    for (int k = 0; k < M; ++k) {
      w.rsig[k] = w.soft[k] > 0.0 ? w.Zs[k] * sig[k] + w.zs[k] - w.lam[k] - w.mu[k] : 0.0;
      r2 += w.rsig[k] * w.rsig[k];
    }
    return std::sqrt(r2);
  };
  // f + soft penalty - kappa sum log(t) - kappa sum log(s) (uses w.gz of that point): the merit on the dynamics.
  auto barrier_objective = [&](const double* x, const double* u, const double* sig) {
    double logs = 0.0;
    for (int k = 0; k < M; ++k) {
      if (w.act[k] == 0.0) continue;
      logs += std::log(w.dv[k] + w.soft[k] * sig[k] - w.gz[k]);
      if (w.soft[k] > 0.0) logs += std::log(sig[k]);
    }
    return K.cost(w, qp, x, u) + detail::soft_cost(w, sig) - kappa * logs;
  };
  auto reseat_soft = [&](const double* x, const double* u) {
    detail::g_mul_all(w, u, x, w.gz);
    for (int k = 0; k < M; ++k)
      if (w.soft[k] > 0.0 && w.act[k] > 0.0) w.sig[k] = seat_soft_slack(w.dv[k] - w.gz[k], w.zs[k], w.Zs[k], w.sig[k], kappa);
  };
  auto swap_trial = [&] {
    std::swap_ranges(w.x, w.x + X, w.xt);
    std::swap_ranges(w.u, w.u + w.inputs, w.ut);
    std::swap_ranges(w.pi, w.pi + D, w.pit);
    std::swap_ranges(w.sig, w.sig + M, w.sigt);
  };
  for (int k = 0; k < M; ++k)
    if (w.soft[k] == 0.0 && w.act[k] > 0.0) w.sig[k] = 0.0;

  // Warm start: the shifted plan's inputs rolled out from the new x0 satisfy the dynamics, so
  // Newton need not repair them (an inconsistent start makes the strict-feasibility line search
  // crawl). Use that if it is strictly inside the rows, else the shifted plan as it is.
  bool inside = false;
  if (warm) {
    std::copy(w.x, w.x + X, w.xt);
    K.rollout(w, qp, w.x, w.u);
    reseat_soft(w.x, w.u);
    inside = strictly_inside(w.x, w.u, w.sig);
    if (!inside) {
      std::swap_ranges(w.x + nx, w.x + X, w.xt + nx);
      reseat_soft(w.x, w.u);
      inside = strictly_inside(w.x, w.u, w.sig);
    }
    // Neither is inside: the old plan says little about the new rows (tuned on closed loops, a
    // cold primal-dual start then beats one from the old plan).
    if (!inside) warm = false;
  }
  mark_iterations();
  // Primal-dual iterations along the central path down to complementarity ~kappa: the cold
  // start, and the rescue when the warm plan hugs the boundary so closely that Newton crawls.
  // Returns true when Newton can take over; otherwise st0 is the solve's answer.
  bool primal_dual_done = false;
  Status st0 = Status::MaxIter;
  auto central_path_start = [&](bool from_iterate) {
    primal_dual_done = true;
    const int left = std::max(0, S.max_iter - info_.iterations);
    st0 = solve_converged(qp, from_iterate, left, kappa, S.warm_push_barrier);
    return st0 == Status::Solved && strictly_inside(w.x, w.u, w.sig);
  };
  if (!inside && !central_path_start(warm)) return st0;
  auto evaluate_iterate = [&] {
    strictly_inside(w.x, w.u, w.sig);
    return evaluate(w.x, w.u, w.pi, w.sig);
  };

  double rnorm = evaluate_iterate();
  Status st = Status::MaxIter;
  for (int k = 0; k < M; ++k) w.rin[k] = w.rc[k] = w.rcs[k] = 0.0;  // exact complementarity: lam t = kappa
  for (int newton = 0;; ++newton) {
    const double pres = detail::max_abs(w.rdyn, D);
    double dres = std::max(detail::max_abs(w.rdu, w.inputs), detail::max_abs(w.rdx + nx, N * nx));
    dres = std::max(dres, detail::max_abs(w.rsig, M));
    if (pres <= tol * w.cons_scale && dres <= tol * w.grad_scale) {
      st = Status::Solved;
      break;
    }
    if (info_.iterations >= S.max_iter) break;
    if (time_up()) {
      st = Status::TimeLimit;
      break;
    }
    for (int k = 0; k < M; ++k) {
      const double wk = w.act[k] * w.lam[k] / w.t[k];  // kappa / t^2
      w.w[k] = wk;
      if (w.soft[k] > 0.0) {
        const double nu = w.mu[k] / w.sig[k];
        w.hs[k] = w.Zs[k] + wk + nu;
        w.weff[k] = wk * (w.Zs[k] + nu) / w.hs[k];
        w.vrow[k] = wk / w.hs[k] * w.rsig[k];
      } else {
        w.hs[k] = 1.0;
        w.weff[k] = wk;
        w.vrow[k] = 0.0;
      }
    }
    bool factored = false;
    for (double reg = S.reg_min; reg <= S.reg_max && !factored; reg *= 100.0) factored = K.factorize(w, qp, reg);
    if (!factored) {
      st = Status::NumericalError;
      break;
    }
    std::copy(w.rdu, w.rdu + w.inputs, w.gu);
    std::copy(w.rdx, w.rdx + X, w.gx);
    for (int i = 0; i <= N; ++i) detail::gt_mul_add(w, i, w.vrow, w.gu + w.uo[i], i > 0 ? w.gx + i * nx : nullptr);
    Step& s = w.step;
    K.back_solve(w, qp, w.rdyn, s);
    ++info_.back_solves;
    // dsig, dt from the elimination (rin = rc = rcs = 0).
    for (int i = 0; i <= N; ++i) detail::g_mul(w, i, s.du + w.uo[i], s.dx + i * nx, s.dt);
    for (int k = 0; k < M; ++k) {
      const double gdz = s.dt[k];
      s.dsig[k] = w.soft[k] > 0.0 && w.act[k] > 0.0 ? (w.w[k] * gdz - w.rsig[k]) / w.hs[k] : 0.0;
      s.dt[k] = w.act[k] * (s.dsig[k] - gdz);
    }
    // On the dynamics the step keeps them, and the Newton decrement lambda^2 = -grad'dz bounds the
    // barrier objective's distance to its minimum (about lambda^2 / 2).
    const bool on_dynamics = pres <= tol * w.cons_scale;
    double slope = 0.0;
    for (int k = 0; k < w.inputs; ++k) slope += w.rdu[k] * s.du[k];
    for (int k = nx; k < X; ++k) slope += w.rdx[k] * s.dx[k];
    for (int k = 0; k < M; ++k) slope += w.rsig[k] * s.dsig[k];
    const double f_now = K.cost(w, qp, w.x, w.u) + detail::soft_cost(w, w.sig);
    if (on_dynamics && -0.5 * slope <= tol * std::max(1.0, std::abs(f_now))) {
      st = Status::Solved;
      break;
    }
    ++info_.iterations;
    const double phi = on_dynamics ? barrier_objective(w.x, w.u, w.sig) : 0.0;
    // Fraction to the boundary: no slack may lose more than newton_to_boundary of its value in one step.
    double tau = 1.0;
    for (int k = 0; k < M; ++k) {
      if (s.dt[k] < 0.0) tau = std::min(tau, S.newton_to_boundary * w.t[k] / -s.dt[k]);
      if (s.dsig[k] < 0.0) tau = std::min(tau, S.newton_to_boundary * w.sig[k] / -s.dsig[k]);
    }
    bool moved = false;
    double r_trial = rnorm;
    for (int h = 0; h < S.ls_max_halvings; ++h, tau *= S.ls_beta) {
      for (int c = 0; c < X; ++c) w.xt[c] = w.x[c] + tau * s.dx[c];
      for (int c = 0; c < w.inputs; ++c) w.ut[c] = w.u[c] + tau * s.du[c];
      for (int c = 0; c < D; ++c) w.pit[c] = w.pi[c] + tau * s.dpi[c];
      for (int c = 0; c < M; ++c) w.sigt[c] = w.sig[c] + tau * s.dsig[c];
      if (!strictly_inside(w.xt, w.ut, w.sigt)) continue;
      if (on_dynamics) {
        moved = barrier_objective(w.xt, w.ut, w.sigt) <= phi + S.ls_alpha * tau * slope;
      } else {
        r_trial = evaluate(w.xt, w.ut, w.pit, w.sigt);
        moved = r_trial <= (1.0 - S.ls_alpha * tau) * rnorm;
      }
      if (moved) break;
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "newton it=%d rnorm=%.3e t=%.3e pres=%.2e moved=%d\n", info_.iterations, rnorm, tau, pres, moved);
#endif
    if ((!moved || (newton < S.damped_newton_steps && tau < S.damped_step)) && !primal_dual_done) {
      // Newton crawls: this start is too close to the boundary. Rescue from the current point,
      // keeping it (strictly feasible) in case the budget runs out before the rescue is inside.
      std::copy(w.x, w.x + X, w.xt);
      std::copy(w.u, w.u + w.inputs, w.ut);
      std::copy(w.pi, w.pi + D, w.pit);
      std::copy(w.sig, w.sig + M, w.sigt);
      evaluate_iterate();  // the primal-dual start reads t and lam
      if (!central_path_start(true)) {
        if (st0 != Status::MaxIter && st0 != Status::TimeLimit) return st0;
        swap_trial();
        st = st0;
        break;
      }
      rnorm = evaluate_iterate();
      for (int k = 0; k < M; ++k) w.rin[k] = w.rc[k] = w.rcs[k] = 0.0;
      continue;
    }
    if (!moved) break;  // no decrease along the Newton direction: rounding level reached
    swap_trial();
    // Off the dynamics the line search evaluated the accepted point already; on them only its merit
    // (w.gz is the accepted point's: its strictly_inside() was the last).
    rnorm = on_dynamics ? evaluate(w.x, w.u, w.pi, w.sig) : r_trial;
  }
  // Leave gz, t, lam and the residuals consistent with the returned iterate.
  if (st == Status::MaxIter || st == Status::TimeLimit || st == Status::Solved) evaluate_iterate();
  return st;
}

}  // namespace rvd::solver
