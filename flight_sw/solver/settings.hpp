// Settings of the Fast MPC solver, and its named presets. Every tuned constant of the method is a
// field here, with what it does and why it has its value; the presets are the combinations the
// project uses. (HPIPM names its presets SPEED / BALANCE / ROBUST; ours are named by their use.)
#pragma once

namespace rvd::solver {

enum class Mode {
  FixedBarrier,  // Wang and Boyd's Fast MPC: one barrier weight, infeasible-start Newton, small cap
  Converged      // primal-dual interior point to the requested relative accuracy
};

struct Settings {
  Mode mode = Mode::Converged;
  int max_iter = 40;          // cap on factorisations per solve(): the deadline monitor's bound
  double tol = 1e-8;          // relative tolerance on residuals and duality gap (Converged mode)
  double barrier = 1e-4;      // barrier weight kappa (FixedBarrier mode)
  bool warm_start = true;     // start from the shifted previous solution when it is usable
  double time_limit_us = 0;   // wall-time budget of one solve(), checked between iterations (0 = none)

  // --- Method choice (Converged mode). QPs with at most active_set_max_inputs inputs in all (N nu)
  // and soft rows of linear penalty only (Zs = 0) are solved by the dual active-set method on the
  // condensed QP (active_set.cpp): on few inputs its per-iteration cost (O(n^2)) is below the
  // interior point's fixed per-stage overhead and it needs about one iteration per active row.
  // Others, and a solve that reaches active_set_max_iter (entering plus leaving rows), go to the
  // interior point (cold). 0: always the interior point. The workspace for it is allocated by the
  // constructor only when the inputs are within the limit then (and its stage-pair products within
  // ActiveSet::kMaxPairProducts: 8 MB, reached only by QPs with many states per input).
  int active_set_max_inputs = 96;
  int active_set_max_iter = 200;
  // Cold solves: at each primal point the most violated row enters the working set and, with it,
  // up to active_set_bulk more violated hard rows (the next by distance, each when well independent
  // of the working set), with zero multipliers; those whose multiplier then turns negative leave
  // again. One primal point and row scan then serve several entering rows (README, "Bulk entry":
  // 4 cuts cold docking and approach solves at N >= 12 by a quarter to a third; 8 or more adds
  // rows that only leave again). It stops for the rest of a solve at the first entering row found
  // dependent on the working set (a degenerate or infeasible QP) and past half of
  // active_set_max_iter (rows taken in bulk count as changes). Warm solves take one row at a
  // time. 0: always one (Goldfarb and Idnani's method as published). At most 32.
  int active_set_bulk = 4;
  static constexpr int kMaxActiveSetBulk = 32;

  // --- Newton systems
  // Smallest and largest regularisation of the input block tried when a factorisation fails (x100
  // per try). The residuals are always the true problem's, so it only makes a step inexact.
  double reg_min = 1e-10, reg_max = 1e-2;
  // Iterative refinement of a step (same factors, residual of the unreduced KKT system) while its
  // residual exceeds refine_below * tol, at most max_refinements times, and only once the relative
  // duality gap is below refine_from_gap: rounding in the reduced system grows with the largest
  // barrier weight, which only late iterations have.
  double refine_below = 0.1;
  int max_refinements = 2;
  double refine_from_gap = 1e-5;

  // --- Primal-dual interior point (Converged mode, and FixedBarrier's cold start)
  double step_to_boundary = 0.995;  // fraction of the way to the boundary of the positive orthant
  // ... once the relative duality gap is below late_from_gap (rendezvous closed loops: 3-7 % fewer iterations;
  // the early iterations keep 0.995, closer steps there raise the worst solves).
  double step_to_boundary_late = 0.9999;
  double late_from_gap = 1e-4;
  // Gondzio centrality correctors while the step is shorter than correct_below (each costs one
  // back-solve), each pushing the products at a trial step into [1/corrector_band, corrector_band]
  // x sigma mu. Noisy rendezvous loops (bench.noisy_loops): 3 / 0.8 / 5 with warm_step_to_boundary
  // take 5-6 % fewer iterations and 7 % more back-solves than 1 / 0.5 / 10 (total time alike), and
  // the largest warm solve falls from 26-28 to 13-16 iterations at N = 30 / 45: correctors on steps
  // of 0.5-0.8 keep a pair from reaching the boundary and blocking the next predictor (a 2-cycle of
  // sigma near 1 and near 0.1).
  int max_correctors = 3;
  double correct_below = 0.8;
  double corrector_band = 5.0;
  // Warm start: fraction to the boundary of the first step only (a shifted plan's products are far
  // from centred; 0.995 there left pairs at the boundary). 0.95-0.98 about alike.
  double warm_step_to_boundary = 0.97;
  // Cold start: every hard row's slack t and dual lam start with t lam = cold_complementarity x the
  // cost gradient's scale, the same on every row. Duals at that scale whatever the slack (the start
  // before) gave the rows far inside the largest products. On the closed-loop set's cold solves the
  // centred start needs 5-15 % fewer iterations in every phase and horizon, on the first rendezvous
  // solve of noisy closed loops 1-3.5 fewer (README, "Rendezvous: what the worst solves are"); 3
  // gains less, 10 and 100 about as much, 300 leaves an approach QP unsolved.
  double cold_complementarity = 30.0;
  // Cold start: a hard row's slack is its residual at the start, at least cold_slack_floor (in the
  // row's units). 1 suits rows of order 1 or more: on random MPC QPs 0.3 and 0.1 take 1.35x and
  // 1.9x the iterations. The rendezvous sets 0.1 (GuidanceParams::default_rendezvous).
  double cold_slack_floor = 1.0;
  // Warm start: row slacks and duals pushed at least this far inside (relative to the row's size).
  double warm_push = 1e-2;
  // Warm start: complementarity products lifted to at least warm_centre x their mean (0: off;
  // tuned on closed loops: 0.01 saves 6 % of the iterations, 0.1 more on average but raises maxima).
  double warm_centre = 0.01;
  // While the relative primal residual exceeds separate_steps_above, the primal variables (states,
  // inputs, slacks) and the dual ones (multipliers) each step to their own boundary, as LP interior
  // points do; below it, one step length. After a QP changed under the shifted plan (a keep-out way
  // that turned round), a row the new QP releases keeps the large dual of the plan that violated it,
  // and its fall to zero held every step to a few percent for several iterations. Noisy rendezvous
  // loops (bench.noisy_loops, 12 seeds): warm solves of 13 or more iterations 8 -> 0 at N = 30 and
  // 31 -> 14 at N = 45, their largest 13 -> 12 and 16 -> 14, every mean a little lower. Kept apart
  // down to small duality gaps instead, the dual residual bounced near the optimum and some solves
  // took longer (N = 15: 12 -> 13-16). inf: one step length always.
  double separate_steps_above = 0.1;
  // Infeasibility: the dual iterate, scaled, is a Farkas certificate when its residual times
  // certificate_reach * |z| stays below its margin (so no plan within that reach of the iterate
  // exists); tested once the primal residual stalls (no halving over stall_window iterations).
  double certificate_reach = 10.0;
  int stall_window = 3;
  double feasible_enough = 1e-6;  // relative primal residual below which no certificate is sought
  // Mehrotra: drop the second-order term when it shortens the step below this fraction of the
  // predictor's (one more back-solve; 0 = never).
  double second_order_keep = 0.5;
  // ... and leave it out when the predictor's step is shorter than second_order_from: its term
  // dt_aff dlam_aff is the error of a full affine step, and a predictor that goes 0.2 % of the way
  // makes it thousands of times too large. Near the optimum that term then drove a 4-cycle of the
  // gap (1.1 -> 6.6 -> 5.6 -> 10.5 -> 1.1) that the gap-curvature limit could only slow to a stall:
  // 24 iterations instead of 12 on one rendezvous QP of a disturbed Case 1 on the Cortex-A53
  // (0 = always keep it).
  double second_order_from = 0.1;

  // --- Fixed barrier (Wang and Boyd's Fast MPC)
  // Backtracking line search of the infeasible-start Newton method (Boyd & Vandenberghe 10.3.2):
  // sufficient decrease ls_alpha, halving factor ls_beta, at most ls_max_halvings; no row slack
  // loses more than newton_to_boundary of its value in one step.
  double ls_alpha = 0.01, ls_beta = 0.5;
  int ls_max_halvings = 60;
  double newton_to_boundary = 0.99;
  // The primal-dual start hands over to Newton once the rows hold strictly and the complementarity
  // is within barrier_handover * kappa; it takes over again when one of Newton's first
  // damped_newton_steps steps is damped below damped_step (a start that hugs the boundary).
  double barrier_handover = 10.0;
  double damped_step = 1.0 / 16.0;
  int damped_newton_steps = 2;
  double warm_push_barrier = 1e-3;

  // Presets.
  // The flight default: Converged mode, tol 1e-8, cap 40, warm start.
  static Settings converged(int max_iter = 40);
  // Reference-grade answers for tests and benchmarks: tol 1e-10, no warm start, cap 100.
  static Settings reference();
  // Wang and Boyd's Fast MPC: fixed barrier weight kappa, small iteration cap, warm start.
  static Settings fixed_barrier(double kappa = 1e-4, int max_iter = 15);
  // nullptr when usable, else what is wrong.
  const char* invalid() const;
};

// Wang and Boyd's Fast MPC mode (kept for its callers): Settings::fixed_barrier.
inline Settings fixed_barrier_settings(double kappa = 1e-4, int max_iter = 15) {
  return Settings::fixed_barrier(kappa, max_iter);
}

}  // namespace rvd::solver
