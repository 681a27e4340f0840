// The primal-dual interior-point core (Converged mode, and the fixed-barrier method's cold start):
// Mehrotra predictor-corrector on the OCP QP with soft rows.
//
// Variables per row k: slack t_k > 0 of g_k'z - s_k + t_k = d_k and its dual lam_k; per soft row
// also the soft slack s_k > 0 and the dual mu_k of s_k >= 0. Eliminating t, lam, s, mu leaves the
// stage-wise Newton system of kkt.hpp with row weight
//   hard row: w = lam/t;   soft row: w (Zs + nu) / (Zs + w + nu),  nu = mu/s,
// and right-hand side term v (below); one Riccati factorisation per iteration serves the
// predictor, the corrector and the refinement steps. Far from primal feasibility the primal and the
// dual variables take separate step lengths (Settings::separate_steps_above).
#include <algorithm>
#include <cmath>
#include <limits>
#ifdef RVD_SOLVER_TRACE  // -DRVD_SOLVER_TRACE prints one line per interior-point iteration to stderr
#include <cstdio>
#endif

#include "flight_sw/solver/fast_mpc.hpp"
#include "flight_sw/solver/kkt.hpp"

namespace rvd::solver {

using detail::kInf;
constexpr double kTiny = std::numeric_limits<double>::min();  // a reciprocal's floor (1/0 would give 0 * inf)
using detail::Step;
using detail::Workspace;

namespace {

// Factorisation with the smallest regularisation that works.
bool factorize_regularised(Workspace& w, const OcpQp& qp, const detail::Kernels& K, const Settings& s) {
  for (double reg = s.reg_min; reg <= s.reg_max; reg *= 100.0)
    if (K.factorize(w, qp, reg)) return true;
  return false;
}

// The largest steps keeping the slacks t, s (primal) and the duals lam, mu nonnegative (unbounded
// when nothing blocks); both() for one step length.
struct StepBounds {
  double primal, dual;
  double both() const { return std::min(primal, dual); }
};

// Row and soft-slack steps from the primal step (dx, du): dsig, dt, dlam, dmu by the elimination,
// and their bounds. The soft rows (few) add their slack step first; then one pass without branches
// over every row: dsig is 0 on hard rows (zeroed per solve) and a constant row's terms are all 0, so
// its steps are too. A bound is kept as its reciprocal max(-dv / v) = max(-dv * (1/v)), from the
// reciprocals of the iteration: no division per row and back-solve.
StepBounds recover_row_steps(Workspace& w, Step& s) {
  detail::g_mul_step(w, s.du, s.dx, s.dt);  // G dz
  double inv_primal = 0.0, inv_dual = 0.0;
  for (int j = 0; j < w.n_soft; ++j) {
    const int k = w.soft_list[j];
    const double dsig = (w.w[k] * s.dt[k] + w.asoft[k]) * w.inv_h[k];
    const double dmu = (-w.rcs[k] - w.mu[k] * dsig) * w.inv_s[k];
    s.dsig[k] = dsig;
    s.dmu[k] = dmu;
    inv_primal = std::max(inv_primal, -dsig * w.inv_s[k]);
    inv_dual = std::max(inv_dual, -dmu * w.inv_mu[k]);
  }
  for (int k = 0; k < w.rows; ++k) {
    const double dt = -w.rin[k] - s.dt[k] + s.dsig[k];
    const double dlam = (-w.rc[k] - w.lam[k] * dt) * w.inv_t[k];
    s.dt[k] = dt;
    s.dlam[k] = dlam;
    inv_primal = std::max(inv_primal, -dt * w.inv_t[k]);
    inv_dual = std::max(inv_dual, -dlam * w.inv_lam[k]);
  }
  return {1.0 / inv_primal, 1.0 / inv_dual};  // inf when nothing blocks
}

// NaN/Inf anywhere in the step shows in the sum of its entries.
bool step_finite(const Workspace& w, const Step& s) {
  double sum = 0.0;
  for (int k = 0; k < (w.N + 1) * w.nx; ++k) sum += s.dx[k];
  for (int k = 0; k < w.inputs; ++k) sum += s.du[k];
  for (int k = 0; k < w.rows; ++k) sum += s.dt[k] + s.dlam[k] + s.dsig[k] + s.dmu[k];
  return std::isfinite(sum);  // (an overflowing step counts as broken too)
}

}  // namespace

Status FastMpcSolver::solve_converged(const OcpQp& qp, bool warm, int max_iter, double mu_floor, double warm_push) {
  Workspace& w = *work_;
  const detail::Kernels& K = *kernels_;
  const Settings& S = settings_;
  const int N = w.N, nx = w.nx, M = w.rows;
  const double tol = S.tol;
  // Per solve: the rows of the step by kind (kkt.hpp), and the active soft rows, so the per-row
  // passes treat every row as a hard one and add the soft rows' terms in a second, short pass
  // (soft-slack steps stay 0 on the other rows in every step buffer).
  detail::prepare_step_rows(w);
  w.n_soft = 0;
  for (int r = 0; r < M; ++r)
    if (w.act[r] > 0.0 && w.soft[r] > 0.0) w.soft_list[w.n_soft++] = r;
  for (Step* s : {&w.step, &w.spare, &w.corr}) {
    std::fill(s->dsig, s->dsig + M, 0.0);
    std::fill(s->dmu, s->dmu + M, 0.0);
  }
  std::fill(w.dsig_aff, w.dsig_aff + M, 0.0);
  std::fill(w.dmu_aff, w.dmu_aff + M, 0.0);
  // Starting point. Cold: zero inputs, states rolled out through the dynamics. Warm: the previous
  // (shifted) plan. Row slacks and duals are pushed into the interior.
  auto start = [&](bool from_plan) {
    if (!from_plan) {
      for (int k = 0; k < w.inputs; ++k) w.u[k] = 0.0;
      for (int k = 0; k < N * nx; ++k) w.pi[k] = 0.0;
      K.rollout(w, qp, w.x, w.u);
    }
    K.residuals(w, qp, w.x, w.u, w.pi, w.lam);  // for Gz and the cost gradient's scale
    const double gs0 = w.grad_scale;
    for (int k = 0; k < M; ++k) {
      if (w.act[k] == 0.0) {
        w.t[k] = 1.0;
        w.lam[k] = w.mu[k] = 0.0;
        continue;
      }
      const bool soft = w.soft[k] > 0.0;
      const double viol = w.gz[k] - w.dv[k];
      if (!from_plan) {
        // Slack as large as the row's residual (at least cold_slack_floor). A hard row's dual makes
        // its product t lam the same on every row, cold_complementarity x the cost gradient's scale
        // (a centred start); a soft row starts with its slack above the violation and its two duals
        // splitting the penalty.
        w.sig[k] = soft ? std::max(viol, 0.0) + 1.0 : 0.0;
        w.t[k] = std::max(std::abs(w.sig[k] - viol), S.cold_slack_floor);
        const double dual = w.zs[k] > 0.0 ? 0.5 * w.zs[k] : gs0;  // (a soft row's)
        w.lam[k] = soft ? dual : S.cold_complementarity * gs0 / w.t[k];
        w.mu[k] = soft ? dual : 0.0;
      } else {
        const double push = warm_push * (1.0 + std::abs(w.dv[k]));
        if (soft) w.sig[k] = std::max(w.sig[k], push), w.mu[k] = std::max(w.mu[k], warm_push);
        else w.sig[k] = w.mu[k] = 0.0;
        w.t[k] = std::max(w.sig[k] - viol, push);
        w.lam[k] = std::max(w.lam[k], warm_push);
      }
    }
    // A warm point's complementarity products can differ by many orders of magnitude (a shifted
    // row that was active, a new row): lift the small ones to warm_centre x their mean, so the
    // first steps are not blocked by one pair sitting at the boundary.
    if (from_plan && S.warm_centre > 0.0) {
      double sum = 0.0;
      int n = 0;
      for (int k = 0; k < M; ++k) {
        if (w.act[k] == 0.0) continue;
        sum += w.t[k] * w.lam[k], ++n;
        if (w.soft[k] > 0.0) sum += w.sig[k] * w.mu[k], ++n;
      }
      const double floor = n > 0 ? S.warm_centre * sum / n : 0.0;
      for (int k = 0; k < M; ++k) {
        if (w.act[k] == 0.0) continue;
        w.lam[k] = std::max(w.lam[k], floor / w.t[k]);
        if (w.soft[k] > 0.0) w.mu[k] = std::max(w.mu[k], floor / w.sig[k]);
      }
    }
  };
  start(warm);

  const bool want_interior = mu_floor > 0.0;
  const int n_comp = w.rows_active + w.soft_active;
  double pres_hist[8];
  for (double& h : pres_hist) h = kInf;
  const int window = std::clamp(S.stall_window, 1, 7);
  Status st = Status::MaxIter;
  int k = 0;
  mark_iterations();
  for (;; ++k) {
    K.residuals(w, qp, w.x, w.u, w.pi, w.lam);
    double pres = detail::max_abs(w.rdyn, N * nx), dres = 0.0, gap = 0.0;
    // One pass over the rows: residuals, gap, and (for the step below) the Newton weights and the
    // predictor's complementarity targets rc = t lam, rcs = s mu; every row as a hard one (no
    // branch), then the soft rows' terms. Constant rows (act = 0) get zeros: t = 1, lam = 0.
    for (int r = 0; r < M; ++r) {
      const double t = w.t[r], lam = w.lam[r], act = w.act[r];
      w.rin[r] = (w.gz[r] - w.sig[r] + t - w.dv[r]) * act;
      pres = std::max(pres, std::abs(w.rin[r]));
      w.rc[r] = act * t * lam;
      gap += w.rc[r];
      w.inv_t[r] = 1.0 / t;
      w.inv_lam[r] = act / std::max(lam, kTiny);  // for the step bound; 0 on constant rows
      w.w[r] = w.weff[r] = act * lam * w.inv_t[r];
    }
    for (int j = 0; j < w.n_soft; ++j) {
      const int r = w.soft_list[j];
      w.rsig[r] = w.Zs[r] * w.sig[r] + w.zs[r] - w.lam[r] - w.mu[r];
      dres = std::max(dres, std::abs(w.rsig[r]));
      w.rcs[r] = w.sig[r] * w.mu[r];
      gap += w.rcs[r];
      w.inv_s[r] = 1.0 / w.sig[r];
      w.inv_mu[r] = 1.0 / std::max(w.mu[r], kTiny);
      const double nu = w.mu[r] * w.inv_s[r];
      w.inv_h[r] = 1.0 / (w.Zs[r] + w.w[r] + nu);
      w.weff[r] = w.w[r] * (w.Zs[r] + nu) * w.inv_h[r];
    }
    dres = std::max({dres, detail::max_abs(w.rdu, w.inputs), detail::max_abs(w.rdx + nx, N * nx)});
    const double mu = n_comp > 0 ? gap / n_comp : 0.0;
    const double obj = K.cost(w, qp, w.x, w.u) + detail::soft_cost(w, w.sig) + w.const_soft;
    if (want_interior && mu <= S.barrier_handover * mu_floor) {  // near the barrier minimiser: inside yet?
      bool interior = true;
      for (int r = 0; r < M && interior; ++r)
        if (w.act[r] > 0.0 && !(w.gz[r] - w.sig[r] < w.dv[r] && (w.soft[r] == 0.0 || w.sig[r] > 0.0))) interior = false;
      if (interior) {
        st = Status::Solved;
        break;
      }
    }
    if (pres <= tol * w.cons_scale && dres <= tol * w.grad_scale && gap <= tol * std::max(1.0, std::abs(obj))) {
      st = Status::Solved;
      break;
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "ipm k=%2d pres=%.2e/%.1e dres=%.2e/%.1e gap=%.2e obj=%.9e\n", k, pres, w.cons_scale, dres,
                 w.grad_scale, gap, obj);
#endif
    for (int h = 7; h > 0; --h) pres_hist[h] = pres_hist[h - 1];
    pres_hist[0] = pres / w.cons_scale;
    if (k >= max_iter) break;
    if (time_up()) {
      st = Status::TimeLimit;
      break;
    }
    // Infeasibility: the primal residual stopped shrinking; is the dual iterate a certificate?
    if (k >= window && pres_hist[0] > S.feasible_enough && pres_hist[0] > 0.5 * pres_hist[window] &&
        infeasibility_certificate(qp)) {
      st = Status::Infeasible;
      break;
    }

    if (!factorize_regularised(w, qp, K, S)) {
      st = Status::NumericalError;
      break;
    }
    // direction(): the step for the complementarity targets rc (rows) and rcs (soft slacks): the
    // step aims at t lam = t lam - rc, s mu = s mu - rcs. Returns the largest feasible step length.
    auto direction = [&](bool refine) {
      // Row term of the step QP; a constant row's is 0 (lam = rin = rc = 0).
      for (int r = 0; r < M; ++r) w.vrow[r] = (w.lam[r] * w.rin[r] - w.rc[r]) * w.inv_t[r];
      for (int j = 0; j < w.n_soft; ++j) {
        const int r = w.soft_list[j];
        const double a = w.vrow[r] - w.rcs[r] * w.inv_s[r] - w.rsig[r];
        w.asoft[r] = a;
        w.vrow[r] -= w.w[r] * w.inv_h[r] * a;
      }
      std::copy(w.rdu, w.rdu + w.inputs, w.gu);
      std::copy(w.rdx, w.rdx + (N + 1) * nx, w.gx);
      detail::gt_mul_add_step(w, w.vrow, w.gu, w.gx);
      K.back_solve(w, qp, w.rdyn, w.step);
      ++info_.back_solves;
      StepBounds bounds = recover_row_steps(w, w.step);
      for (int ref = 0; refine && ref < S.max_refinements && K.step_error(w, qp, w.step) > S.refine_below * tol; ++ref) {
        K.back_solve(w, qp, w.edyn, w.corr);
        ++info_.back_solves;
        for (int c = 0; c < (N + 1) * nx; ++c) w.step.dx[c] += w.corr.dx[c];
        for (int c = 0; c < w.inputs; ++c) w.step.du[c] += w.corr.du[c];
        for (int c = 0; c < N * nx; ++c) w.step.dpi[c] += w.corr.dpi[c];
        bounds = recover_row_steps(w, w.step);
      }
      return bounds;
    };
    const double amax_aff = std::min(1.0, direction(false).both());
    double gap_aff = 0.0;
    {
      const Step& s = w.step;
      for (int r = 0; r < M; ++r) gap_aff += w.act[r] * (w.t[r] + amax_aff * s.dt[r]) * (w.lam[r] + amax_aff * s.dlam[r]);
      for (int j = 0; j < w.n_soft; ++j) {
        const int r = w.soft_list[j];
        gap_aff += (w.sig[r] + amax_aff * s.dsig[r]) * (w.mu[r] + amax_aff * s.dmu[r]);
      }
    }
    // Keep the predictor's row steps: swap them into the *_aff buffers (no copy).
    std::swap(w.step.dt, w.dt_aff);
    std::swap(w.step.dlam, w.dlam_aff);
    std::swap(w.step.dsig, w.dsig_aff);
    std::swap(w.step.dmu, w.dmu_aff);
    const double ratio = gap > 0.0 ? gap_aff / gap : 0.0;
    const double sigma = std::clamp(ratio * ratio * ratio, 0.0, 1.0);
    const double smu = std::max(sigma * mu, mu_floor);
    auto centred_targets = [&](bool second_order) {
      for (int r = 0; r < M; ++r)
        w.rc[r] = w.act[r] * (w.t[r] * w.lam[r] + (second_order ? w.dt_aff[r] * w.dlam_aff[r] : 0.0) - smu);
      for (int j = 0; j < w.n_soft; ++j) {  // (rcs is read on soft rows only)
        const int r = w.soft_list[j];
        w.rcs[r] = w.sig[r] * w.mu[r] + (second_order ? w.dsig_aff[r] * w.dmu_aff[r] : 0.0) - smu;
      }
    };
    centred_targets(amax_aff >= S.second_order_from);
    // Rounding in the reduced system only matters once the barrier weights are large: refine the
    // step in the late iterations only.
    const bool refine = gap <= S.refine_from_gap * std::max(1.0, std::abs(obj));
    StepBounds bounds = direction(refine);
    // Mehrotra's second-order term is a prediction; when it shortens the step a lot (typical when
    // the affine step is huge along a direction of tiny curvature) take the plain centred step.
    if (bounds.both() < S.second_order_keep * amax_aff) {
      centred_targets(false);
      bounds = direction(refine);
    }
    // Gondzio's centrality corrector when the step is short: Mehrotra's direction alone can cycle
    // (e.g. an input bouncing between the two sides of its box). It pushes the complementarity
    // products at a longer trial step back into [1/band, band] * sigma mu.
    const double band = S.corrector_band, lo = smu / band, hi = smu * band;
    for (int c = 0; c < S.max_correctors && bounds.both() < S.correct_below; ++c) {
      const double atrial = std::min(1.0, 1.5 * bounds.both() + 0.1);
      std::swap(w.step, w.spare);  // the current step to the spare, rc/rcs keep their targets
      const Step& s0 = w.spare;
      auto push = [&](double prod) { return std::max(std::min(std::max(prod, lo), hi) - prod, -hi); };
      for (int r = 0; r < M; ++r)
        if (w.act[r] != 0.0) w.rc[r] -= push((w.t[r] + atrial * s0.dt[r]) * (w.lam[r] + atrial * s0.dlam[r]));
      for (int j = 0; j < w.n_soft; ++j) {
        const int r = w.soft_list[j];
        w.rcs[r] -= push((w.sig[r] + atrial * s0.dsig[r]) * (w.mu[r] + atrial * s0.dmu[r]));
      }
      const StepBounds b2 = direction(refine);
      if (b2.both() >= 1.01 * bounds.both()) {
        bounds = b2;
      } else {
        std::swap(w.step, w.spare);  // no better: keep the previous step (its bounds too)
        break;
      }
    }
    // Near the solution the fraction to the boundary only slows the last iterations down (each
    // would shrink the gap by 1 - step_to_boundary at best): go closer once the gap is small.
    // A warm start's first step stops further from the boundary: a shifted plan's products are far
    // from centred, and a first step taken 0.995 of the way leaves a pair at the boundary that blocks
    // the next predictors.
    const double tau = gap <= S.late_from_gap * std::max(1.0, std::abs(obj)) ? S.step_to_boundary_late
                       : warm && k == 0                                     ? S.warm_step_to_boundary
                                                                            : S.step_to_boundary;
    // Far from primal feasibility the primal and the dual variables each step to their own boundary
    // (Settings::separate_steps_above).
    const bool separate = pres > S.separate_steps_above * w.cons_scale;
    double alpha = std::min(1.0, tau * (separate ? bounds.primal : bounds.both()));
    double alpha_dual = separate ? std::min(1.0, tau * bounds.dual) : alpha;
    const Step& s = w.step;
    // On a primal-dual feasible iterate the gap after a step is quadratic in alpha with curvature
    // dt'dlam + ds'dmu = dz'H dz >= 0 (QPs, unlike LPs): a long step along a stiff direction can
    // raise it, and Mehrotra's iterations can then cycle. There, never step past its minimiser.
    if (pres <= tol * w.cons_scale && dres <= tol * w.grad_scale) {
      double lin = 0.0, quad = 0.0;
      for (int r = 0; r < M; ++r) {
        lin += w.act[r] * (w.t[r] * s.dlam[r] + w.lam[r] * s.dt[r]) + w.soft[r] * (w.sig[r] * s.dmu[r] + w.mu[r] * s.dsig[r]);
        quad += w.act[r] * s.dt[r] * s.dlam[r] + w.soft[r] * s.dsig[r] * s.dmu[r];
      }
      if (quad > 0.0 && lin < 0.0) alpha = std::min(alpha, -lin / (2.0 * quad));
      alpha_dual = alpha;  // (never separate here: pres is below tol)
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "   sigma=%.2e alpha_aff=%.3e alpha=%.3e alpha_dual=%.3e\n", sigma, amax_aff, alpha, alpha_dual);
#endif
    if (!step_finite(w, s)) {
      st = Status::NumericalError;
      break;
    }
    for (int c = nx; c < (N + 1) * nx; ++c) w.x[c] += alpha * s.dx[c];
    for (int c = 0; c < w.inputs; ++c) w.u[c] += alpha * s.du[c];
    for (int c = 0; c < N * nx; ++c) w.pi[c] += alpha_dual * s.dpi[c];
    for (int r = 0; r < M; ++r) {
      w.t[r] += alpha * s.dt[r];
      w.lam[r] += alpha_dual * s.dlam[r];
    }
    for (int j = 0; j < w.n_soft; ++j) {  // (dsig = dmu = 0 on hard rows)
      const int r = w.soft_list[j];
      w.sig[r] += alpha * s.dsig[r];
      w.mu[r] += alpha_dual * s.dmu[r];
    }
  }
  info_.iterations += k;
  return st;
}

}  // namespace rvd::solver
