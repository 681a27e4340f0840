// Stage-wise optimal-control QP (the structure of HPIPM's OCP QP) and the Fast MPC solver API.
//
//   minimize   sum_{i=0..N} 1/2 x_i'Q_i x_i + q_i'x_i + 1/2 u_i'R_i u_i + r_i'u_i
//   subject to x_0 = x0,
//              x_{i+1} = A_i x_i + B_i u_i + b_i          i = 0..N-1
//              C_i x_i + D_i u_i <= d_i                    i = 0..N
//
// nx states on every stage, nu[i] inputs and nc[i] inequality rows on stage i; nu[N] may be 0.
// Slack variables of soft (penalty) constraints are ordinary inputs with a linear cost r_i.
//
// Data flow as in OSQP: dimensions -> solver workspace (allocated once, in the constructor) ->
// solve(qp, x0) (no heap allocation) -> info() / x() / u().
#pragma once

#include <Eigen/Dense>

#include <string>
#include <vector>

namespace rvd::solver {

using Matrix = Eigen::MatrixXd;
using Vector = Eigen::VectorXd;

struct OcpQpDims {
  int N = 0;            // number of dynamics stages; variables exist on stages 0..N
  int nx = 0;           // states per stage
  std::vector<int> nu;  // inputs on stage i, size N+1
  std::vector<int> nc;  // inequality rows on stage i, size N+1

  // A uniform shape: nu inputs and nc rows on stages 0..N-1, nu_N inputs and nc_N rows on stage N.
  static OcpQpDims uniform(int N, int nx, int nu, int nc, int nu_N = 0, int nc_N = -1);
  // Empty string when consistent, else what is wrong.
  std::string validate() const;
};

// Problem data. Sized (and zeroed) by the constructor; callers fill values in place so that
// re-building a QP every control period allocates nothing.
struct OcpQp {
  OcpQpDims dims;
  std::vector<Matrix> A, B;  // nx x nx, nx x nu[i]       (i = 0..N-1)
  std::vector<Vector> b;     // nx
  std::vector<Matrix> Q, R;  // nx x nx, nu[i] x nu[i]    (i = 0..N)
  std::vector<Vector> q, r;  // nx, nu[i]
  std::vector<Matrix> C, D;  // nc[i] x nx, nc[i] x nu[i] (i = 0..N)
  std::vector<Vector> d;     // nc[i]

  OcpQp() = default;
  explicit OcpQp(const OcpQpDims& dims);
  // Empty string when every block has the size dims says and every entry is finite.
  std::string validate() const;
};

enum class Status {
  Solved,        // converged to the requested tolerance (or, in FixedBarrier mode, the barrier problem)
  MaxIter,       // iteration cap reached. In FixedBarrier mode the iterate satisfies the inequalities
                 // strictly once Newton has started (primal_residual then only measures the dynamics)
  Infeasible,    // the inequalities and dynamics admit no solution
  InvalidInput,  // sizes inconsistent, or NaN/Inf in the data or x0
  NumericalError, // factorization failed (e.g. a non-convex Q/R)
  TimeLimit      // Settings::time_limit_us ran out; the returned iterate is the last one reached
};
const char* to_string(Status s);

enum class Mode {
  FixedBarrier,  // the seed's Wang-Boyd Fast MPC: one barrier weight, infeasible-start Newton, small cap
  Converged      // primal-dual interior point to the requested relative accuracy
};

struct Settings {
  Mode mode = Mode::Converged;
  int max_iter = 100;          // iteration cap (FixedBarrier: fixed_barrier_settings() uses 15)
  double tol = 1e-8;          // relative tolerance on residuals and duality gap (Converged mode)
  double barrier = 1e-4;      // barrier weight kappa (FixedBarrier mode)
  bool warm_start = true;     // start from the shifted previous solution when it is usable
  double time_limit_us = 0;   // wall-time budget of one solve(), checked between iterations (0 = none)
};

struct Info {
  Status status = Status::InvalidInput;
  int iterations = 0;
  double primal_residual = 0.0;  // inf-norm of dynamics and inequality residuals
  double dual_residual = 0.0;    // inf-norm of the stationarity residual
  double objective = 0.0;        // objective value at the returned iterate (constant terms excluded)
  double solve_time_us = 0.0;    // wall time of solve(), microseconds
};

}  // namespace rvd::solver
