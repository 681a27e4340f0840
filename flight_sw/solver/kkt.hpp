// The KKT machinery shared by the interior-point methods (internal to the solver): the stage
// kernels (residuals, Riccati factorisation and back-solve, rollout, objective), compiled with
// fixed sizes for the project's shape (nx = 6, nu = 3) and with dynamic sizes for any other, and
// the sparse row products.
//
// Newton system. With row weights W (rows, soft slacks eliminated: see riccati.cpp) the step of
// the stage variables solves the equality-constrained QP
//   min sum 1/2 dz_i'(H_i + G_i'W_i G_i)dz_i + g_i'dz_i  s.t.  dx_{i+1} = A_i dx_i + B_i du_i + c_i, dx_0 = 0
// by a Riccati recursion over the stages: O(N (nx + nu)^3), no fill-in.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "flight_sw/solver/ocp_qp.hpp"
#include "flight_sw/solver/settings.hpp"
#include "flight_sw/solver/workspace.hpp"

namespace rvd::solver::detail {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Stage kernels, chosen once per solver from the dimensions.
struct Kernels {
  // rdx, rdu, rdyn and gz at (x, u, pi, lam); grad_scale from the cost gradient and the costates,
  // cons_scale from the rows.
  void (*residuals)(Workspace&, const OcpQp&, const double* x, const double* u, const double* pi,
                    const double* lam);
  // Factor the Newton system with row weights w.weff; false when the input block is not positive definite.
  bool (*factorize)(Workspace&, const OcpQp&, double reg);
  // Step (s.dx, s.du, s.dpi) for the gradient (w.gx, w.gu) and dynamics residual c.
  void (*back_solve)(Workspace&, const OcpQp&, const double* c, Step& s);
  // States from x0 under the inputs: x_{i+1} = A x_i + B u_i + b_i.
  void (*rollout)(Workspace&, const OcpQp&, double* x, const double* u);
  // Quadratic and linear cost of (x, u) (soft penalties not included).
  double (*cost)(Workspace&, const OcpQp&, const double* x, const double* u);
  // Residual of the unreduced linearised KKT system at step s (stationarity into gx/gu, dynamics
  // into edyn); returns it relative to the problem scales. Uses w.rdx, w.rdu, w.rdyn.
  double (*step_error)(Workspace&, const OcpQp&, const Step& s);
};
const Kernels& kernels_for(const Workspace& w);

// Per solve: compressed rows of [D_i C_i], constant rows, soft rows and penalties, structure flags.
// Returns false when a constant row is violated (no plan can satisfy it: infeasible); a violated
// constant soft row is only a constant cost.
bool prepare_rows(Workspace& w, const OcpQp& qp, double tol);

// G_k [u; x] of row k, with u and x its stage's inputs and states.
inline double g_row(const Workspace& w, int k, const double* u, const double* x) {
  double acc = 0.0;
  for (int a = w.ptr[k]; a < w.mid[k]; ++a) acc += w.val[a] * u[w.col[a]];
  for (int a = w.mid[k]; a < w.ptr[k + 1]; ++a) acc += w.val[a] * x[w.col[a]];
  return acc;
}
// out[k] = G_k [u; x] over the rows of stage i (0 on constant rows).
inline void g_mul(const Workspace& w, int i, const double* u, const double* x, double* out) {
  for (int k = w.ro[i]; k < w.ro[i + 1]; ++k) out[k] = g_row(w, k, u, x);
}
// out_u += D_i' v, and out_x += C_i' v unless out_x is null, over the rows of stage i.
inline void gt_mul_add(const Workspace& w, int i, const double* v, double* out_u, double* out_x) {
  for (int k = w.ro[i]; k < w.ro[i + 1]; ++k) {
    const double vk = v[k];
    if (vk == 0.0) continue;
    for (int a = w.ptr[k]; a < w.mid[k]; ++a) out_u[w.col[a]] += w.val[a] * vk;
    if (out_x)
      for (int a = w.mid[k]; a < w.ptr[k + 1]; ++a) out_x[w.col[a]] += w.val[a] * vk;
  }
}
// How many leading rows of stage i take stage i + 1's row data when a plan shifts one stage: all
// of them when the two stages have as many rows; otherwise (the first stage has no state rows) the
// leading rows that read alike (as many input and state nonzeros, both hard or both soft), e.g.
// the input bounds, so the first input's bound multipliers match the input shifted into its place.
inline int shifted_rows(const Workspace& w, int i) {
  if (w.nc[i] == w.nc[i + 1]) return w.nc[i];
  int j = 0;
  for (; j < std::min(w.nc[i], w.nc[i + 1]); ++j) {
    const int a = w.ro[i] + j, b = w.ro[i + 1] + j;
    if (w.mid[a] - w.ptr[a] != w.mid[b] - w.ptr[b] || w.ptr[a + 1] - w.mid[a] != w.ptr[b + 1] - w.mid[b] ||
        w.soft[a] != w.soft[b] || w.act[a] != w.act[b])
      break;
  }
  return j;
}

// G z over all stages (stage 0: x0 is data, so it enters gz too).
inline void g_mul_all(const Workspace& w, const double* u, const double* x, double* out) {
  for (int i = 0; i <= w.N; ++i) g_mul(w, i, u + w.uo[i], x + i * w.nx, out);
}

// The rows of a Newton step, split by kind: one nonzero on an input (the input boxes), one on a
// state, the others; with indices into the whole u / x vectors, so the interior point's per-step
// products (G dz, G'v: several per iteration) cost one multiply per bound row and no per-stage
// loop. Stage 0's state nonzeros are dropped (dx_0 = 0; its C'v is not wanted). Built per solve.
void prepare_step_rows(Workspace& w);
// out = G dz over all rows (a step: dx_0 = 0).
inline void g_mul_step(const Workspace& w, const double* du, const double* dx, double* out) {
  const StepRows& s = w.srows;
  for (int j = 0; j < s.n_bu; ++j) out[s.bu_row[j]] = s.bu_val[j] * du[s.bu_idx[j]];
  for (int j = 0; j < s.n_bx; ++j) out[s.bx_row[j]] = s.bx_val[j] * dx[s.bx_idx[j]];
  for (int j = 0; j < s.n_gen; ++j) {
    const int k = s.gen_row[j];
    const double* u = du + s.gen_uo[j];
    const double* x = dx + s.gen_xo[j];
    double acc = 0.0;
    for (int a = w.ptr[k]; a < w.mid[k]; ++a) acc += w.val[a] * u[w.col[a]];
    for (int a = w.mid[k]; a < s.gen_end[j]; ++a) acc += w.val[a] * x[w.col[a]];
    out[k] = acc;
  }
}
// gu += D'v, gx += C'v over all rows (stage 0: inputs only).
inline void gt_mul_add_step(const Workspace& w, const double* v, double* gu, double* gx) {
  const StepRows& s = w.srows;
  for (int j = 0; j < s.n_bu; ++j) gu[s.bu_idx[j]] += s.bu_val[j] * v[s.bu_row[j]];
  for (int j = 0; j < s.n_bx; ++j) gx[s.bx_idx[j]] += s.bx_val[j] * v[s.bx_row[j]];
  for (int j = 0; j < s.n_gen; ++j) {
    const int k = s.gen_row[j];
    const double vk = v[k];
    double* u = gu + s.gen_uo[j];
    double* x = gx + s.gen_xo[j];
    for (int a = w.ptr[k]; a < w.mid[k]; ++a) u[w.col[a]] += w.val[a] * vk;
    for (int a = w.mid[k]; a < s.gen_end[j]; ++a) x[w.col[a]] += w.val[a] * vk;
  }
}

// No NaN or Inf among v[0..n): the exponent bits, no branch per entry (Eigen's allFinite costs a
// call and an early exit per block: most of the input check on small QPs).
inline bool all_finite(const double* v, long n) {
  unsigned long long bad = 0;
  for (long k = 0; k < n; ++k) {
    unsigned long long bits;
    std::memcpy(&bits, v + k, sizeof bits);
    bad |= (bits & 0x7ff0000000000000ULL) == 0x7ff0000000000000ULL;
  }
  return bad == 0;
}

inline double max_abs(const double* v, int n) {
  double m = 0.0;
  for (int k = 0; k < n; ++k) m = std::max(m, std::abs(v[k]));
  return m;
}
// Row k's share of the returned plan's residuals (hard rows: g'z - d into pres; soft rows, which hold
// with s*: the stationarity of their slack into dres) and its slack for the objective: soft rows at
// their least violation s* = max(g'z - d, 0) (an iterate's slacks are at most tol above it), in sigt.
inline void plan_row(Workspace& w, int k, double& pres, double& dres) {
  const double r = w.gz[k] - w.dv[k];
  w.sigt[k] = w.soft[k] > 0.0 ? std::max(r, 0.0) : w.sig[k];
  if (w.act[k] == 0.0) return;
  if (w.soft[k] == 0.0)
    pres = std::max(pres, r);
  else
    dres = std::max(dres, std::abs(w.Zs[k] * w.sig[k] + w.zs[k] - w.lam[k] - w.mu[k]));
}
// Soft penalty of the slacks sig (zs sig + Zs sig^2 / 2 over soft rows).
inline double soft_cost(const Workspace& w, const double* sig) {
  double f = 0.0;
  for (int k = 0; k < w.rows; ++k)
    if (w.soft[k] > 0.0) f += sig[k] * (w.zs[k] + 0.5 * w.Zs[k] * sig[k]);
  return f;
}

}  // namespace rvd::solver::detail
