// Stage-wise optimal-control QP (the structure of HPIPM's OCP QP), with soft constraints.
//
//   minimize   sum_{i=0..N} 1/2 x_i'Q_i x_i + q_i'x_i + 1/2 u_i'R_i u_i + r_i'u_i
//                         + sum_{k soft on stage i} zs_ik s_ik + 1/2 Zs_ik s_ik^2
//   subject to x_0 = x0,
//              x_{i+1} = A_i x_i + B_i u_i + b_i          i = 0..N-1
//              C_i x_i + D_i u_i <= d_i                    i = 0..N, hard rows
//              (C_i x_i + D_i u_i)_j - s_ik <= d_ij,  s_ik >= 0    for the soft rows j = idxs_i[k]
//
// nx states on every stage, nu[i] inputs, nc[i] inequality rows and ns[i] soft rows on stage i;
// nu[N] may be 0. A soft row is a penalty, not a constraint: its slack s >= 0 pays zs per unit of
// violation (an exact penalty once zs exceeds the row's multiplier) plus Zs/2 per unit squared.
// The slacks are no inputs: the solver eliminates them row by row inside its Newton systems, so a
// soft row costs about what a hard row costs.
//
// Data flow as in OSQP: dimensions -> solver workspace (allocated once, in the constructor) ->
// solve(qp, x0) (no heap allocation) -> info() / x() / u().
#pragma once

#include <Eigen/Dense>

#include <string>
#include <vector>

#include "flight_sw/solver/settings.hpp"  // the solver settings travel with the problem data

namespace rvd::solver {

using Matrix = Eigen::MatrixXd;
using Vector = Eigen::VectorXd;

struct OcpQpDims {
  int N = 0;            // number of dynamics stages; variables exist on stages 0..N
  int nx = 0;           // states per stage
  std::vector<int> nu;  // inputs on stage i, size N+1
  std::vector<int> nc;  // inequality rows on stage i, size N+1
  std::vector<int> ns;  // of those, soft rows on stage i, size N+1 (empty: none anywhere)

  // A uniform shape: nu inputs and nc rows on stages 0..N-1, nu_N inputs and nc_N rows on stage N.
  static OcpQpDims uniform(int N, int nx, int nu, int nc, int nu_N = 0, int nc_N = -1);
  int soft_rows(int i) const { return ns.empty() ? 0 : ns[i]; }
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
  std::vector<std::vector<int>> idxs;  // ns[i] distinct row indices of C_i/D_i that are soft
  std::vector<Vector> zs, Zs;          // ns[i] linear and quadratic penalties, >= 0 each

  OcpQp() = default;
  explicit OcpQp(const OcpQpDims& dims);
  // Empty string when every block has the size dims says, every entry is finite, the soft row
  // indices are distinct and in range and the penalties are >= 0.
  std::string validate() const;
};

enum class Status {
  Solved,        // converged to the requested tolerance (or, in FixedBarrier mode, the barrier problem)
  MaxIter,       // iteration cap reached. In FixedBarrier mode the iterate satisfies the inequalities
                 // strictly once Newton has started (primal_residual then only measures the dynamics)
  Infeasible,    // the hard inequalities and the dynamics admit no solution (a Farkas certificate)
  InvalidInput,  // sizes inconsistent, NaN/Inf in the data or x0, negative soft penalties, bad settings
  NumericalError, // factorization failed (e.g. a non-convex Q/R)
  TimeLimit      // Settings::time_limit_us ran out; the returned iterate is the last one reached
};
const char* to_string(Status s);

struct Info {
  Status status = Status::InvalidInput;
  int iterations = 0;            // Newton systems factored (interior-point iterations)
  int back_solves = 0;           // solves with those factors (predictor, correctors, refinement)
  int active_set_changes = 0;    // rows that entered or left the active set (dual active-set method,
                                 // settings.hpp); iterations = 0 when it answered alone
  bool rows_compressed = false;  // this solve compressed its rows itself (the interior point always;
                                 // the active set when they differ from the ones kept, e.g. by setup())
  double primal_residual = 0.0;  // inf-norm of dynamics residuals and hard-row violations
  double dual_residual = 0.0;    // inf-norm of the stationarity residual
  double objective = 0.0;        // objective at the returned iterate (constant terms excluded),
                                 // soft penalties included
  double solve_time_us = 0.0;    // wall time of solve(), microseconds, on the flight clock
  // solve_time_us by part (their sum, up to rounding): the update takes in this QP (input checks,
  // its rows, x0's terms, the start point); the iterations run the method to the answer's primal
  // point; the output forms what is published (multipliers, residuals, objective). An answer
  // without iterations (invalid input, a constant row violated) is all update.
  double update_time_us = 0.0;
  double iterate_time_us = 0.0;
  double output_time_us = 0.0;
};

}  // namespace rvd::solver
