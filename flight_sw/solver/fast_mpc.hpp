// Fast MPC solver for the stage-wise OCP QP of ocp_qp.hpp (Wang & Boyd, "Fast model predictive
// control using online optimization", 2010).
//
// Two methods share one structure-exploiting Newton step (kkt.hpp, riccati.cpp: a Riccati
// recursion over the stages, soft rows eliminated into it as diagonal terms, fixed-size kernels
// for nx = 6, nu = 3):
//  - Mode::Converged (ipm.cpp): primal-dual interior point, Mehrotra predictor-corrector with a
//    Gondzio correctors when the step is short and iterative refinement in the late iterations, to
//    Settings::tol on the relative primal and dual residuals and duality gap (README, "When the
//    interior point stops").
//  - Mode::FixedBarrier (fixed_barrier.cpp): Wang and Boyd's infeasible-start Newton method on the
//    log-barrier problem with a fixed weight kappa; its iterates satisfy the rows strictly and its
//    answer is at most m*kappa worse than the optimum (m = rows).
// Infeasibility (infeasibility.cpp) is decided from the interior-point iterates: a scaled dual
// iterate that is a Farkas certificate for the hard rows and the dynamics. No second solve.
// Constant rows (no decision variable in them, e.g. stage-0 rows of x0 alone) are checked once:
// a violated hard one means Infeasible at once.
//
// Worst case: solve() factors at most Settings::max_iter Newton systems, each followed by at most
// 1 + (2 + max_correctors) (1 + max_refinements) back-solves (Info::iterations, Info::back_solves); the
// work per factorisation and per back-solve is fixed by the dimensions (no data-dependent loops
// besides the fixed-barrier line search, <= ls_max_halvings trial points per iteration).
//
// Warm start (Settings::warm_start): the next solve starts from the last solution, shifted one
// stage by shift_warm_start().
//
// Data flow as in OSQP: dims + settings -> constructor allocates the workspace (one arena,
// workspace.hpp) -> solve(qp, x0) does no heap allocation (tests/cpp/test_solver_fast_mpc_alloc.cpp)
// -> info(), x(), u(), lambda(), pi(), soft_slack().
#pragma once

#include <memory>
#include <vector>

#include "flight_sw/solver/elapsed.hpp"
#include "flight_sw/solver/ocp_qp.hpp"
#include "flight_sw/solver/settings.hpp"

namespace rvd::solver {

namespace detail {
struct Workspace;
struct Kernels;
struct ActiveSet;
}  // namespace detail

class FastMpcSolver {
 public:
  explicit FastMpcSolver(const OcpQpDims& dims, const Settings& settings = Settings::converged());
  ~FastMpcSolver();
  FastMpcSolver(FastMpcSolver&&) noexcept;
  FastMpcSolver& operator=(FastMpcSolver&&) noexcept;

  Status solve(const OcpQp& qp, const Vector& x0);  // no heap allocation; never throws; fills info()
  // Condense the QP's A, B, Q, R for the dual active-set method and prepare its rows ahead of the
  // first solve (solve() does both itself, without allocating, when they differ from the last ones).
  // The rows are kept with qp's nonzero pattern: a later QP whose nonzeros are among those (values
  // changed, some zero) takes the fast path, any other nonzero prepares the rows again. A caller
  // whose rows change per period can pass a structural fill (nonzeros wherever a period may put one),
  // at the cost of carrying its zeros through every later solve. No heap allocation either, so a
  // guidance may call it within a step (for the next phase's rows).
  void setup(const OcpQp& qp);
  const Info& info() const { return info_; }
  const std::vector<Vector>& x() const { return x_; }  // N+1 states of the last solve
  const std::vector<Vector>& u() const { return u_; }  // N+1 inputs (u[N] has dims.nu[N] entries, maybe 0)
  // Inequality multipliers (N+1 vectors, nc[i] each; 0 on constant rows) and dynamics multipliers
  // (N vectors) of the last solve. In FixedBarrier mode lam = kappa / slack, the barrier's duals.
  const std::vector<Vector>& lambda() const { return lam_; }
  const std::vector<Vector>& pi() const { return pi_; }
  // Soft slacks (N+1 vectors, ns[i] each, in the order of idxs): each soft row's violation
  // max(g'z - d, 0) at the returned plan.
  const std::vector<Vector>& soft_slack() const { return sig_; }
  void shift_warm_start();  // shift the last solution one stage: the warm start for the next period
  void reset_warm_start();  // forget the previous solution: the next solve starts cold
  // Converged-mode solves go to the dual active-set method (unless a soft row has a quadratic
  // penalty): Settings::active_set_max_inputs. Warm, it starts from the last solution's working set,
  // shifted one stage.
  bool uses_active_set() const;
  const OcpQpDims& dims() const { return dims_; }
  Settings& settings() { return settings_; }
  const Settings& settings() const { return settings_; }
  size_t workspace_bytes() const;  // the arena's size: all the solver's working memory but the published solution

  // Internal: the methods (ipm.cpp, fixed_barrier.cpp, infeasibility.cpp).
  // mu_floor > 0: follow the central path only down to complementarity mu_floor and stop once the
  // rows hold strictly with mu near it (the barrier mode's cold start).
  Status solve_converged(const OcpQp& qp, bool warm, int max_iter, double mu_floor, double warm_push);
  Status solve_barrier(const OcpQp& qp, bool warm);
  bool infeasibility_certificate(const OcpQp& qp);  // true when the dual iterate proves infeasibility
  bool time_up() const;
  bool active_set_applies() const;           // Settings::active_set_max_inputs, soft rows linear only
  Status solve_active_set(const OcpQp& qp, bool warm);  // active_set.cpp
  // Where solve()'s time splits (Info::update_time_us / iterate_time_us / output_time_us): a method
  // marks the start of its iterations and of its outputs; the first mark of each counts (an
  // active-set solve handed to the interior point keeps its own start).
  void mark_iterations() {
    if (!iterations_marked_) t_iterate_ = clock_now(), iterations_marked_ = true;
  }
  void mark_output() {
    if (!output_marked_) t_output_ = clock_now(), output_marked_ = true;
  }

 private:
  bool inputs_ok(const OcpQp& qp, const Vector& x0, detail::ActiveSet* kept = nullptr) const;
  bool prepare_active_set(const OcpQp& qp);  // active_set.cpp: prepare_rows for the kept rows
  void publish(const OcpQp& qp);  // iterate -> x_, u_, lam_, pi_, sig_

  OcpQpDims dims_;
  Settings settings_;
  Info info_;
  std::unique_ptr<detail::Workspace> work_;
  const detail::Kernels* kernels_ = nullptr;
  std::unique_ptr<detail::ActiveSet> dense_;  // the condensed QP, when the inputs are few enough
  std::vector<Vector> x_, u_, lam_, pi_, sig_;  // the solution, sized once
  Vector setup_x0_;  // zeros: setup()'s x0 for the input checks, so that it allocates nothing either
  TimePoint t_start_, t_iterate_, t_output_;  // on the flight clock (elapsed.hpp)
  bool iterations_marked_ = false, output_marked_ = false;
  bool has_warm_ = false;
  bool outputs_formed_ = false;  // this solve's residuals and sigt are formed already (solve_active_set)
  bool shifted_ = false;  // the warm plan was shifted: its tail x_N needs the new QP's dynamics
  friend struct SolverAccess;
};

}  // namespace rvd::solver
