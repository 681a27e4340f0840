// Fast MPC solver for the stage-wise OCP QP of ocp_qp.hpp (Wang & Boyd 2010; seeds/000 §III).
//
// Two modes share one structure-exploiting Newton step: a Riccati recursion over the stages,
// O(N (nx+nu)^3) (kernels compiled with nx = 6 and nu in {3, 4, 7} fixed, generic otherwise).
//  - Mode::Converged: primal-dual interior point (Mehrotra predictor-corrector, Gondzio
//    centrality correctors when steps get short, iterative refinement in the late iterations) to
//    Settings::tol on the relative primal and dual residuals and duality gap.
//  - Mode::FixedBarrier: the seed's infeasible-start Newton method on the log-barrier problem
//    f(z) - kappa sum log(d - Gz) with a fixed weight kappa (Settings::barrier), backtracking line
//    search (residual norm while the dynamics are violated, then the barrier objective), few
//    iterations, warm started from the shifted previous plan. Its iterates satisfy the
//    inequalities strictly; the exact barrier minimiser is at most m*kappa worse than the optimum
//    (m = rows). A cold start (or a warm plan outside the new inequalities) first follows the
//    primal-dual central path down to complementarity ~kappa, then hands over to Newton.
// Constant rows (no decision variable in them, e.g. stage-0 rows of x0 alone) are checked once:
// violated means Infeasible at once, satisfied means ignored. Infeasibility otherwise is decided
// by an elastic phase-1 problem (minimise the summed normalised violation, same Riccati step),
// run when the iterations stall, break down or hit the cap with a sizeable primal residual; its
// optimum is positive exactly when the QP has no solution. Info::iterations counts all Newton
// systems solved, phase 1 included.
//
// Warm start (Settings::warm_start): the next solve starts from the last solution, shifted one
// stage by shift_warm_start() (u_i <- u_{i+1}, x_i <- x_{i+1}, duals alike; the tail is kept, and
// in Converged mode its last state re-propagated through the new QP's dynamics).
//
// Data flow as in OSQP: dims + settings -> constructor allocates every buffer -> solve(qp, x0) does
// no heap allocation (tests/cpp/test_solver_fast_mpc_alloc.cpp) -> info(), x(), u().
#pragma once

#include <chrono>
#include <memory>
#include <vector>

#include "flight_sw/solver/ocp_qp.hpp"

namespace rvd::solver {

// Settings for the seed's Fast MPC mode: fixed barrier weight, small iteration cap, warm start.
Settings fixed_barrier_settings(double kappa = 1e-4, int max_iter = 15);

class FastMpcSolver {
 public:
  explicit FastMpcSolver(const OcpQpDims& dims, const Settings& settings = {});  // allocates the workspace
  ~FastMpcSolver();
  FastMpcSolver(FastMpcSolver&&) noexcept;
  FastMpcSolver& operator=(FastMpcSolver&&) noexcept;

  Status solve(const OcpQp& qp, const Vector& x0);  // no heap allocation; never throws; fills info()
  const Info& info() const { return info_; }
  const std::vector<Vector>& x() const;  // N+1 states of the last solve
  const std::vector<Vector>& u() const;  // N+1 inputs (u[N] has dims.nu[N] entries, maybe 0)
  void shift_warm_start();               // shift the last solution one stage: the warm start for the next period
  void reset_warm_start();               // forget the previous solution: the next solve starts cold
  const OcpQpDims& dims() const { return dims_; }
  Settings& settings() { return settings_; }

  // Inequality multipliers (N+1 vectors, nc[i] each) and dynamics multipliers (N vectors) of the
  // last solve. In FixedBarrier mode lambda = kappa / slack, the barrier's implied duals.
  const std::vector<Vector>& lambda() const;
  const std::vector<Vector>& pi() const;

  struct Work;  // iterate, residuals, Riccati factors (defined in fast_mpc.cpp)

 private:
  using Clock = std::chrono::steady_clock;
  bool inputs_ok(const OcpQp& qp, const Vector& x0) const;
  // mu_floor > 0: follow the central path only down to complementarity mu_floor and stop once the
  // inequalities hold strictly with mu near it (the barrier mode's cold start).
  // warm_push: how far into the interior a warm start's slacks and duals are pushed.
  Status solve_converged(Work& w, const OcpQp& qp, bool warm, int max_iter, double tol, double mu_floor,
                         double warm_push);
  Status solve_barrier(const OcpQp& qp, bool warm);
  bool phase1_infeasible(const OcpQp& qp);  // true when the elastic problem proves infeasibility
  bool time_up() const;

  OcpQpDims dims_;
  Settings settings_;
  Info info_;
  std::unique_ptr<Work> work_;    // the QP itself
  std::unique_ptr<Work> work1_;   // the elastic phase-1 problem (one extra input and row per stage)
  std::unique_ptr<OcpQp> qp1_;    // its data, filled in place from the QP
  Clock::time_point t_start_;
  bool has_warm_ = false;
  bool shifted_ = false;  // the warm plan was shifted: its tail x_N needs the new QP's dynamics
};

}  // namespace rvd::solver
