#include "flight_sw/solver/fast_mpc.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#ifdef RVD_SOLVER_TRACE  // -DRVD_SOLVER_TRACE prints one line per interior-point iteration to stderr
#include <cstdio>
#endif

namespace rvd::solver {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();

// --- Newton systems
// Smallest Hessian regularisation of the input block: slack inputs have no quadratic cost, so their
// Hessian comes only from the barrier and can be near zero. The residuals are always those of the
// true problem, so this only makes the Newton step inexact, never the answer.
constexpr double kRegMin = 1e-10;
constexpr double kRegMax = 1e-2;
// Iterative refinement of a step (same factorisation, residual of the unreduced KKT system) while
// its residual exceeds this fraction of the tolerance, at most kMaxRefinements times, and only
// once the duality gap is below kRefineFromGap (relative): rounding in the reduced system grows
// with the largest barrier weight, which only late iterations have.
constexpr double kRefineBelow = 0.1;
constexpr int kMaxRefinements = 2;
constexpr double kRefineFromGap = 1e-5;

// --- Primal-dual interior point (Converged mode, phase 1, FixedBarrier's start)
// Fraction of the way to the boundary of the positive orthant a step may go.
constexpr double kStepToBoundary = 0.995;
// Drop Mehrotra's second-order term when the corrector's step is below this fraction of the
// predictor's; add Gondzio's centrality correctors while the step is shorter than kCorrectBelow.
constexpr double kSecondOrderKeep = 0.5;
constexpr double kCorrectBelow = 0.9;
constexpr int kMaxCentralityCorrectors = 2;
// Warm start: slacks and duals pushed at least this far inside (relative to the row's size).
// Tuned on closed-loop runs: larger for Converged mode, smaller when heading for the kappa-centre.
constexpr double kWarmPushConverged = 1e-2;
constexpr double kWarmPushBarrier = 1e-3;

// --- Fixed barrier (the seed's Fast MPC)
// Line search of the infeasible-start Newton method (Boyd & Vandenberghe §10.3.2), with a
// fraction-to-the-boundary cap: no slack loses more than 99% of its value in one step.
constexpr double kLsAlpha = 0.01, kLsBeta = 0.5;
constexpr int kLsMaxHalvings = 60;
constexpr double kNewtonToBoundary = 0.99;
// The primal-dual start hands over to Newton once the inequalities hold strictly and the
// complementarity is within this factor of kappa ...
constexpr double kBarrierHandover = 10.0;
// ... and takes over again when one of Newton's first kDampedNewtonSteps steps is damped below
// kDampedStep (a start that hugs the boundary: Newton would crawl).
constexpr double kDampedStep = 1.0 / 16.0;
constexpr int kDampedNewtonSteps = 2;

// --- Infeasibility
// The QP is infeasible when the elastic problem cannot bring the summed per-stage violation of
// the unit-normalised rows below this (units of the normalised rows: distance in (x, u) space).
constexpr double kInfeasibleViolation = 1e-6;
constexpr int kPhase1MaxIter = 100;
constexpr double kPhase1Tol = 1e-9;
// Relative primal residual below which an iterate counts as nearly feasible (no phase 1 needed).
constexpr double kFeasibleEnough = 1e-6;

double inf_norm(const Vector& v) { return v.size() ? v.lpNorm<Eigen::Infinity>() : 0.0; }
}  // namespace

Settings fixed_barrier_settings(double kappa, int max_iter) {
  Settings s;
  s.mode = Mode::FixedBarrier;
  s.barrier = kappa;
  s.max_iter = max_iter;
  s.warm_start = true;
  return s;
}

// ---------------------------------------------------------------------------------------------
// Workspace: every buffer the iterations touch, sized once for the dimensions.
struct FastMpcSolver::Work {
  int N = 0, nx = 0;
  std::vector<int> nu, nc;
  int rows_active = 0;  // inequality rows that involve a decision variable

  // Iterate: states (x[0] is the fixed initial state), inputs, dynamics multipliers, slacks, duals.
  std::vector<Vector> x, u, pi, s, lam;
  // Residuals at the iterate: stationarity in x and u, dynamics, inequalities (Gz + s - d), Gz.
  std::vector<Vector> rdx, rdu, rdyn, rin, gz;
  // Newton step and the affine (predictor) step of the slacks and duals.
  std::vector<Vector> dx, du, dpi, ds, dlam, ds_aff, dlam_aff;
  // A second step and complementarity target, swapped with the first to try a corrector.
  std::vector<Vector> dx2, du2, dpi2, ds2, dlam2, rc2;
  // Per row: 1 if active, 0 for constant rows (no decision variable in them: checked once, then ignored).
  std::vector<Vector> act;
  // The active rows of G_i = [D_i C_i] (columns: inputs, then states) as compressed rows, built
  // once per solve: box rows have one nonzero, cone rows two or three, so every product with G
  // and the Hessian term G'WG cost a fraction of the dense ones.
  // Row j's nonzeros are [row_ptr[j], row_mid[j]) on inputs (row_col: input index) and
  // [row_mid[j], row_ptr[j+1]) on states (row_col: state index).
  std::vector<std::vector<int>> row_ptr, row_mid, row_col;
  std::vector<std::vector<double>> row_val;
  // Barrier Hessian weight per row and its square root; complementarity right-hand side; scratch.
  std::vector<Vector> wgt, rc, vrow;
  // Riccati: gradient of the step's QP, the factor's right-hand-side recursion, stage matrices.
  std::vector<Vector> gx, gu, l, p;
  std::vector<Matrix> Z;  // [u; x] stage Hessian: Cholesky of the uu block, Y = L^-1 S in the ux block
  std::vector<Matrix> P;  // cost-to-go Hessian
  Matrix PB, PA;
  Vector tn, tm;
  // Iterative refinement: the linearised KKT system's dynamics residual and the correction.
  std::vector<Vector> edyn, cx, cu, cpi;
  // Trial point of the line search.
  std::vector<Vector> xt, ut, pit;
  // Problem scale for relative tolerances, updated by residuals().
  double grad_scale = 1.0, cons_scale = 1.0;

  explicit Work(const OcpQpDims& d) : N(d.N), nx(d.nx), nu(d.nu), nc(d.nc) {
    int mmax = 0;
    for (int i = 0; i <= N; ++i) {
      mmax = std::max(mmax, nu[i]);
    }
    auto stage_vecs = [&](std::vector<Vector>& v, const std::vector<int>& sz) {
      v.resize(N + 1);
      for (int i = 0; i <= N; ++i) v[i] = Vector::Zero(sz[i]);
    };
    std::vector<int> nxs(N + 1, nx), nxs_dyn(N, nx);
    for (auto* v : {&x, &rdx, &dx, &dx2, &gx, &p, &xt, &cx}) stage_vecs(*v, nxs);
    for (auto* v : {&u, &rdu, &du, &du2, &gu, &l, &ut, &cu}) stage_vecs(*v, nu);
    for (auto* v : {&s, &lam, &rin, &gz, &ds, &dlam, &ds_aff, &dlam_aff, &ds2, &dlam2, &act, &wgt, &rc, &rc2,
                    &vrow})
      stage_vecs(*v, nc);
    for (auto* v : {&pi, &rdyn, &dpi, &dpi2, &pit, &edyn, &cpi}) v->assign(N, Vector::Zero(nx));
    Z.resize(N + 1);
    P.assign(N + 1, Matrix::Zero(nx, nx));
    for (int i = 0; i <= N; ++i) Z[i] = Matrix::Zero(nu[i] + nx, nu[i] + nx);
    PB = Matrix::Zero(nx, mmax);
    PA = Matrix::Zero(nx, nx);
    tn = Vector::Zero(nx);
    tm = Vector::Zero(mmax);
    for (int i = 0; i <= N; ++i) act[i].setOnes();
    row_ptr.resize(N + 1);
    row_mid.resize(N + 1);
    row_col.resize(N + 1);
    row_val.resize(N + 1);
    for (int i = 0; i <= N; ++i) {
      row_ptr[i].assign(nc[i] + 1, 0);
      row_mid[i].assign(nc[i] + 1, 0);
      row_col[i].assign(static_cast<size_t>(nc[i]) * (nu[i] + nx), 0);
      row_val[i].assign(static_cast<size_t>(nc[i]) * (nu[i] + nx), 0.0);
    }
  }
};

namespace {
using Work = FastMpcSolver::Work;

// The project's state dimension (LVLH position and velocity): its kernels are compiled with the
// size fixed (unrolled, vectorised); any other nx runs the same code with dynamic sizes.
constexpr int kFixedNx = 6;
template <int NX>
using VecN = Eigen::Matrix<double, NX, 1>;
template <int NX>
using MatNN = Eigen::Matrix<double, NX, NX>;
template <int NX>
using MatNU = Eigen::Matrix<double, NX, Eigen::Dynamic>;
template <int NX>
Eigen::Map<VecN<NX>> vx(Vector& v) {
  return Eigen::Map<VecN<NX>>(v.data(), v.size());
}
template <int NX>
Eigen::Map<const VecN<NX>> vx(const Vector& v) {
  return Eigen::Map<const VecN<NX>>(v.data(), v.size());
}
template <int NX>
Eigen::Map<MatNN<NX>> mxx(Matrix& m) {
  return Eigen::Map<MatNN<NX>>(m.data(), m.rows(), m.cols());
}
template <int NX>
Eigen::Map<const MatNN<NX>> mxx(const Matrix& m) {
  return Eigen::Map<const MatNN<NX>>(m.data(), m.rows(), m.cols());
}
template <int NX>
Eigen::Map<const MatNU<NX>> mxu(const Matrix& m) {
  return Eigen::Map<const MatNU<NX>>(m.data(), m.rows(), m.cols());
}

// Small dense kernels on the leading m x m block of Z (column-major), for m of a few inputs:
// plain loops beat the general library paths at these sizes.
// Cholesky in place (lower triangle); false if the block is not positive definite.
bool cholesky_in_place(Matrix& Z, int m) {
  for (int j = 0; j < m; ++j) {
    double d = Z(j, j);
    for (int k = 0; k < j; ++k) d -= Z(j, k) * Z(j, k);
    if (!(d > 0.0)) return false;
    d = std::sqrt(d);
    Z(j, j) = d;
    const double inv = 1.0 / d;
    for (int r = j + 1; r < m; ++r) {
      double v = Z(r, j);
      for (int k = 0; k < j; ++k) v -= Z(r, k) * Z(j, k);
      Z(r, j) = v * inv;
    }
  }
  return true;
}
// v <- L^-1 v
template <class V>
void lower_solve(const Matrix& L, int m, V&& v) {
  for (int r = 0; r < m; ++r) {
    double acc = v(r);
    for (int k = 0; k < r; ++k) acc -= L(r, k) * v(k);
    v(r) = acc / L(r, r);
  }
}
// v <- L^-T v
template <class V>
void lower_t_solve(const Matrix& L, int m, V&& v) {
  for (int r = m - 1; r >= 0; --r) {
    double acc = v(r);
    for (int k = r + 1; k < m; ++k) acc -= L(k, r) * v(k);
    v(r) = acc / L(r, r);
  }
}

// Marks rows without decision variables (on stage 0: rows of x0 only) as constant. Returns false
// when such a row is violated: then no choice of inputs can satisfy it and the QP is infeasible.
bool classify_rows(Work& w, const OcpQp& qp, double tol) {
  bool ok = true;
  w.rows_active = 0;
  for (int i = 0; i <= w.N; ++i) {
    for (int j = 0; j < w.nc[i]; ++j) {
      const bool no_u = w.nu[i] == 0 || (qp.D[i].row(j).array() == 0.0).all();
      const bool no_x = i == 0 || (qp.C[i].row(j).array() == 0.0).all();
      if (no_u && no_x) {
        w.act[i](j) = 0.0;
        const double lhs = i == 0 ? qp.C[0].row(j).dot(w.x[0]) : 0.0;
        const double rhs = qp.d[i](j);
        if (lhs - rhs > tol * (1.0 + std::abs(lhs) + std::abs(rhs))) ok = false;
      } else {
        w.act[i](j) = 1.0;
        ++w.rows_active;
      }
    }
    // Compressed active rows of [D_i C_i].
    const int m = w.nu[i];
    int* ptr = w.row_ptr[i].data();
    int* mid = w.row_mid[i].data();
    int* col = w.row_col[i].data();
    double* val = w.row_val[i].data();
    int k = 0;
    for (int j = 0; j < w.nc[i]; ++j) {
      ptr[j] = k;
      mid[j] = k;
      if (w.act[i](j) == 0.0) continue;
      for (int c = 0; c < m; ++c)
        if (qp.D[i](j, c) != 0.0) col[k] = c, val[k++] = qp.D[i](j, c);
      mid[j] = k;
      for (int c = 0; c < w.nx; ++c)
        if (qp.C[i](j, c) != 0.0) col[k] = c, val[k++] = qp.C[i](j, c);
    }
    ptr[w.nc[i]] = k;
  }
  return ok;
}

// out = G_i [u; x] on the active rows (0 on constant rows).
void g_mul(const Work& w, int i, const Vector& u, const Vector& x, Vector& out) {
  const int* ptr = w.row_ptr[i].data();
  const int* mid = w.row_mid[i].data();
  const int* col = w.row_col[i].data();
  const double* val = w.row_val[i].data();
  const double* pu = u.data();
  const double* px = x.data();
  for (int j = 0; j < w.nc[i]; ++j) {
    double acc = 0.0;
    for (int k = ptr[j]; k < mid[j]; ++k) acc += val[k] * pu[col[k]];
    for (int k = mid[j]; k < ptr[j + 1]; ++k) acc += val[k] * px[col[k]];
    out(j) = acc;
  }
}

// out_u += D_i' v and (unless out_x is null) out_x += C_i' v, over the active rows.
void gt_mul_add(const Work& w, int i, const Vector& v, Vector& out_u, Vector* out_x) {
  const int* ptr = w.row_ptr[i].data();
  const int* mid = w.row_mid[i].data();
  const int* col = w.row_col[i].data();
  const double* val = w.row_val[i].data();
  double* pu = out_u.data();
  double* px = out_x ? out_x->data() : nullptr;
  for (int j = 0; j < w.nc[i]; ++j) {
    const double vj = v(j);
    if (vj == 0.0) continue;
    for (int k = ptr[j]; k < mid[j]; ++k) pu[col[k]] += val[k] * vj;
    if (px)
      for (int k = mid[j]; k < ptr[j + 1]; ++k) px[col[k]] += val[k] * vj;
  }
}

// Residuals of the KKT conditions at (x, u, pi, lam); also Gz and the problem scales.
template <int NX>
void residuals_t(Work& w, const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u,
                 const std::vector<Vector>& pi, const std::vector<Vector>& lam) {
  double gscale = 0.0, cscale = 0.0;
  for (int i = 0; i <= w.N; ++i) {
    g_mul(w, i, u[i], x[i], w.gz[i]);
    cscale = std::max({cscale, inf_norm(qp.d[i]), inf_norm(w.gz[i])});

    w.rdu[i] = qp.r[i];
    w.rdu[i].noalias() += qp.R[i].lazyProduct(u[i]);
    gscale = std::max(gscale, inf_norm(w.rdu[i]));
    if (i < w.N) w.rdu[i].noalias() += mxu<NX>(qp.B[i]).transpose().lazyProduct(vx<NX>(pi[i]));

    if (i > 0) {
      auto rdx = vx<NX>(w.rdx[i]);
      rdx.noalias() = vx<NX>(qp.q[i]) + mxx<NX>(qp.Q[i]).lazyProduct(vx<NX>(x[i]));
      gscale = std::max(gscale, inf_norm(w.rdx[i]));
      rdx -= vx<NX>(pi[i - 1]);
      if (i < w.N) rdx.noalias() += mxx<NX>(qp.A[i]).transpose().lazyProduct(vx<NX>(pi[i]));
    }
    gt_mul_add(w, i, lam[i], w.rdu[i], i > 0 ? &w.rdx[i] : nullptr);
    if (i < w.N) {
      auto r = vx<NX>(w.rdyn[i]);
      r.noalias() = vx<NX>(qp.b[i]) - vx<NX>(x[i + 1]) + mxx<NX>(qp.A[i]).lazyProduct(vx<NX>(x[i]));
      r.noalias() += mxu<NX>(qp.B[i]).lazyProduct(u[i]);
    }
  }
  w.grad_scale = std::max(1.0, gscale);
  w.cons_scale = std::max(1.0, cscale);
}
void residuals(Work& w, const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u,
               const std::vector<Vector>& pi, const std::vector<Vector>& lam) {
  if (w.nx == kFixedNx)
    residuals_t<kFixedNx>(w, qp, x, u, pi, lam);
  else
    residuals_t<Eigen::Dynamic>(w, qp, x, u, pi, lam);
}

double dual_res(const Work& w) {
  double r = 0.0;
  for (int i = 0; i <= w.N; ++i) {
    r = std::max(r, inf_norm(w.rdu[i]));
    if (i > 0) r = std::max(r, inf_norm(w.rdx[i]));
  }
  return r;
}

double dyn_res(const Work& w) {
  double r = 0.0;
  for (int i = 0; i < w.N; ++i) r = std::max(r, inf_norm(w.rdyn[i]));
  return r;
}

// Largest violation max(Gz - d, 0) over active rows (uses w.gz).
double ineq_violation(const Work& w, const OcpQp& qp) {
  double r = 0.0;
  for (int i = 0; i <= w.N; ++i)
    for (int j = 0; j < w.nc[i]; ++j)
      if (w.act[i](j) > 0.0) r = std::max(r, w.gz[i](j) - qp.d[i](j));
  return r;
}

template <int NX>
double objective_t(Work& w, const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u) {
  double f = 0.0;
  auto t = vx<NX>(w.tn);
  for (int i = 0; i <= w.N; ++i) {
    t.noalias() = mxx<NX>(qp.Q[i]).lazyProduct(vx<NX>(x[i]));
    f += 0.5 * x[i].dot(w.tn) + qp.q[i].dot(x[i]);
    const int m = w.nu[i];
    if (m > 0) {
      auto tu = w.tm.head(m);
      tu.noalias() = qp.R[i].lazyProduct(u[i]);
      f += 0.5 * u[i].dot(tu) + qp.r[i].dot(u[i]);
    }
  }
  return f;
}
double objective(Work& w, const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u) {
  return w.nx == kFixedNx ? objective_t<kFixedNx>(w, qp, x, u) : objective_t<Eigen::Dynamic>(w, qp, x, u);
}
double objective(Work& w, const OcpQp& qp) { return objective(w, qp, w.x, w.u); }

// Riccati factorisation of the Newton system whose inequality rows carry Hessian weights wgt.
// Stage i's [u; x] Hessian plus the cost-to-go [B A]' P_{i+1} [B A] is factored: Cholesky L of
// the uu block, Y = L^-1 S_ux, P_i = Q_xx - Y'Y. One stage at a time, with the state size NX and
// the input count NU fixed at compile time where they are the project's (else Eigen::Dynamic).
template <int NX, int NU>
bool factor_stage(Work& w, const OcpQp& qp, int i, double reg) {
  const int n = w.nx, m = w.nu[i], k = w.nc[i];
  Matrix& Z = w.Z[i];
  Z.setZero();
  {  // G'WG, row by row over the nonzeros (stage 0: only the input block matters)
    const int* ptr = w.row_ptr[i].data();
    const int* mid = w.row_mid[i].data();
    const int* col = w.row_col[i].data();
    const double* val = w.row_val[i].data();
    for (int j = 0; j < k; ++j) {
      const double wj = w.wgt[i](j);
      if (wj == 0.0) continue;
      const int end = i == 0 ? mid[j] : ptr[j + 1];
      for (int a = ptr[j]; a < end; ++a) {
        const int za = a < mid[j] ? col[a] : m + col[a];
        const double wa = wj * val[a];
        for (int b = ptr[j]; b < end; ++b) Z(za, b < mid[j] ? col[b] : m + col[b]) += wa * val[b];
      }
    }
  }
  auto Zuu = Z.template block<NU, NU>(0, 0, m, m);
  auto Zux = Z.template block<NU, NX>(0, m, m, n);
  auto Zxx = Z.template block<NX, NX>(m, m, n, n);
  Zuu += Eigen::Map<const Eigen::Matrix<double, NU, NU>>(qp.R[i].data(), m, m);
  if (i > 0) Zxx += mxx<NX>(qp.Q[i]);
  if (i < w.N) {
    const auto P = mxx<NX>(w.P[i + 1]);
    const Eigen::Map<const Eigen::Matrix<double, NX, NU>> B(qp.B[i].data(), n, m);
    Eigen::Map<Eigen::Matrix<double, NX, NU>> PB(w.PB.data(), n, m);
    PB.noalias() = P.lazyProduct(B);
    Zuu.noalias() += B.transpose().lazyProduct(PB);
    if (i > 0) {
      const auto A = mxx<NX>(qp.A[i]);
      auto PA = mxx<NX>(w.PA);
      PA.noalias() = P.lazyProduct(A);
      Zux.noalias() += B.transpose().lazyProduct(PA);
      Zxx.noalias() += A.transpose().lazyProduct(PA);
    }
  }
  if (m > 0) {
    Zuu.diagonal().array() += reg;
    if (!cholesky_in_place(Z, m)) return false;
  }
  if (i > 0) {
    auto P = mxx<NX>(w.P[i]);
    P = Zxx;
    if (m > 0) {
      for (int c = 0; c < n; ++c) lower_solve(Z, m, Zux.col(c));  // Y = L^-1 S_ux
      P.noalias() -= Zux.transpose().lazyProduct(Zux);
    }
  }
  return true;
}

// Calls F<NX, NU>::run for stage i's input count (fixed sizes for the project's shapes).
template <template <int, int> class F, int NX, class... Args>
auto by_inputs(int m, Args&&... args) {
  switch (m) {
    case 3: return F<NX, 3>::run(std::forward<Args>(args)...);
    case 4: return F<NX, 4>::run(std::forward<Args>(args)...);
    case 7: return F<NX, 7>::run(std::forward<Args>(args)...);
    default: return F<NX, Eigen::Dynamic>::run(std::forward<Args>(args)...);
  }
}
template <int NX, int NU>
struct FactorStage {
  static bool run(Work& w, const OcpQp& qp, int i, double reg) { return factor_stage<NX, NU>(w, qp, i, reg); }
};

template <int NX>
bool factorize_t(Work& w, const OcpQp& qp, double reg) {
  for (int i = w.N; i >= 0; --i)
    if (!by_inputs<FactorStage, NX>(w.nu[i], w, qp, i, reg)) return false;
  return true;
}
bool factorize(Work& w, const OcpQp& qp, double reg) {
  return w.nx == kFixedNx ? factorize_t<kFixedNx>(w, qp, reg) : factorize_t<Eigen::Dynamic>(w, qp, reg);
}

// Solves the factored Newton system for the gradient (gx, gu) and dynamics residual c: the step
// (dx, du) and the dynamics multipliers' step dpi. Backward sweep (l_i = L^-1 g_u, p_i), then
// forward sweep (du_i = -L^-T (l_i + Y dx_i), dx_{i+1}, dpi_i = P_{i+1} dx_{i+1} + p_{i+1}).
template <int NX, int NU>
struct BackwardStage {
  static void run(Work& w, const OcpQp& qp, const std::vector<Vector>& c, int i) {
    const int n = w.nx, m = w.nu[i];
    Eigen::Map<Eigen::Matrix<double, NU, 1>> l(w.l[i].data(), m);
    l = Eigen::Map<const Eigen::Matrix<double, NU, 1>>(w.gu[i].data(), m);
    auto p = vx<NX>(w.p[i]);
    if (i < w.N) {
      auto tn = vx<NX>(w.tn);
      tn.noalias() = vx<NX>(w.p[i + 1]) + mxx<NX>(w.P[i + 1]).lazyProduct(vx<NX>(c[i]));
      l.noalias() += Eigen::Map<const Eigen::Matrix<double, NX, NU>>(qp.B[i].data(), n, m).transpose().lazyProduct(tn);
      if (i > 0) p.noalias() = vx<NX>(w.gx[i]) + mxx<NX>(qp.A[i]).transpose().lazyProduct(tn);
    } else {
      p = vx<NX>(w.gx[i]);
    }
    if (m > 0) {
      lower_solve(w.Z[i], m, l);
      if (i > 0) p.noalias() -= w.Z[i].template block<NU, NX>(0, m, m, n).transpose().lazyProduct(l);
    }
  }
};
template <int NX, int NU>
struct ForwardStage {
  static void run(Work& w, const OcpQp& qp, const std::vector<Vector>& c, std::vector<Vector>& dx,
                  std::vector<Vector>& du, std::vector<Vector>& dpi, int i) {
    const int n = w.nx, m = w.nu[i];
    Eigen::Map<Eigen::Matrix<double, NU, 1>> u(du[i].data(), m);
    if (m > 0) {
      const Eigen::Map<const Eigen::Matrix<double, NU, 1>> l(w.l[i].data(), m);
      if (i > 0)
        u.noalias() = l + w.Z[i].template block<NU, NX>(0, m, m, n).lazyProduct(vx<NX>(dx[i]));
      else
        u = l;
      lower_t_solve(w.Z[i], m, u);
      u = -u;
    }
    if (i < w.N) {
      auto d = vx<NX>(dx[i + 1]);
      d.noalias() = vx<NX>(c[i]) + mxx<NX>(qp.A[i]).lazyProduct(vx<NX>(dx[i]));
      d.noalias() += Eigen::Map<const Eigen::Matrix<double, NX, NU>>(qp.B[i].data(), n, m).lazyProduct(u);
      vx<NX>(dpi[i]).noalias() = vx<NX>(w.p[i + 1]) + mxx<NX>(w.P[i + 1]).lazyProduct(d);
    }
  }
};
template <int NX>
void solve_step_t(Work& w, const OcpQp& qp, const std::vector<Vector>& c, std::vector<Vector>& dx,
                  std::vector<Vector>& du, std::vector<Vector>& dpi) {
  for (int i = w.N; i >= 0; --i) by_inputs<BackwardStage, NX>(w.nu[i], w, qp, c, i);
  dx[0].setZero();
  for (int i = 0; i <= w.N; ++i) by_inputs<ForwardStage, NX>(w.nu[i], w, qp, c, dx, du, dpi, i);
}
void solve_step(Work& w, const OcpQp& qp, const std::vector<Vector>& c, std::vector<Vector>& dx,
                std::vector<Vector>& du, std::vector<Vector>& dpi) {
  if (w.nx == kFixedNx)
    solve_step_t<kFixedNx>(w, qp, c, dx, du, dpi);
  else
    solve_step_t<Eigen::Dynamic>(w, qp, c, dx, du, dpi);
}

// Factorisation with the smallest regularisation that works.
bool factorize_regularised(Work& w, const OcpQp& qp) {
  for (double reg = kRegMin; reg <= kRegMax; reg *= 100.0)
    if (factorize(w, qp, reg)) return true;
  return false;
}

// Gz of the step; stage 0's x is fixed, so its C block does not move.
void step_rows(Work& w, int i, Vector& out) {
  g_mul(w, i, w.du[i], w.dx[i], out);  // dx[0] = 0: x0 is fixed
}

// Residual of the unreduced linearised KKT system at the step: stationarity into (gx, gu), dynamics
// into edyn. Returns them scaled by the problem scales (inf-norm). Rounding in the reduced system
// grows with the largest barrier weight, so late iterations need this to reach tight tolerances.
template <int NX>
double step_error_t(Work& w, const OcpQp& qp) {
  double ed = 0.0, ep = 0.0;
  for (int i = 0; i <= w.N; ++i) {
    w.gu[i] = w.rdu[i];
    w.gu[i].noalias() += qp.R[i].lazyProduct(w.du[i]);
    if (i < w.N) w.gu[i].noalias() += mxu<NX>(qp.B[i]).transpose().lazyProduct(vx<NX>(w.dpi[i]));
    if (i > 0) {
      auto gx = vx<NX>(w.gx[i]);
      gx.noalias() = vx<NX>(w.rdx[i]) - vx<NX>(w.dpi[i - 1]) + mxx<NX>(qp.Q[i]).lazyProduct(vx<NX>(w.dx[i]));
      if (i < w.N) gx.noalias() += mxx<NX>(qp.A[i]).transpose().lazyProduct(vx<NX>(w.dpi[i]));
    }
    gt_mul_add(w, i, w.dlam[i], w.gu[i], i > 0 ? &w.gx[i] : nullptr);
    ed = std::max(ed, inf_norm(w.gu[i]));
    if (i > 0) ed = std::max(ed, inf_norm(w.gx[i]));
    if (i < w.N) {
      auto e = vx<NX>(w.edyn[i]);
      e.noalias() = vx<NX>(w.rdyn[i]) - vx<NX>(w.dx[i + 1]) + mxx<NX>(qp.A[i]).lazyProduct(vx<NX>(w.dx[i]));
      e.noalias() += mxu<NX>(qp.B[i]).lazyProduct(w.du[i]);
      ep = std::max(ep, inf_norm(w.edyn[i]));
    }
  }
  return std::max(ed / w.grad_scale, ep / w.cons_scale);
}
double step_error(Work& w, const OcpQp& qp) {
  return w.nx == kFixedNx ? step_error_t<kFixedNx>(w, qp) : step_error_t<Eigen::Dynamic>(w, qp);
}

// Slack and dual steps from the primal step: ds = -rin - G dz, dlam = (-rc - lam ds) / s.
void slack_dual_step(Work& w) {
  for (int i = 0; i <= w.N; ++i) {
    step_rows(w, i, w.ds[i]);
    w.ds[i] = (-w.rin[i] - w.ds[i]).cwiseProduct(w.act[i]);
    w.dlam[i] = ((-w.rc[i].array() - w.lam[i].array() * w.ds[i].array()) / w.s[i].array()).matrix();
  }
}

// States from x0 under the current inputs: x_{i+1} = A x_i + B u_i + b_i.
template <int NX>
void rollout_t(Work& w, const OcpQp& qp) {
  for (int i = 0; i < w.N; ++i) {
    auto x = vx<NX>(w.x[i + 1]);
    x.noalias() = vx<NX>(qp.b[i]) + mxx<NX>(qp.A[i]).lazyProduct(vx<NX>(w.x[i]));
    x.noalias() += mxu<NX>(qp.B[i]).lazyProduct(w.u[i]);
  }
}
void rollout(Work& w, const OcpQp& qp) {
  if (w.nx == kFixedNx)
    rollout_t<kFixedNx>(w, qp);
  else
    rollout_t<Eigen::Dynamic>(w, qp);
}

// Slack-like inputs (no Hessian, no effect on the dynamics, positive linear cost r) are set to
// their barrier-optimal value given the rest of the plan: just above their largest lower bound,
// max_k l_k + kappa * (number of bounds) / r. The shifted plan cannot know them (e.g. the
// terminal cone penalty after the horizon moved). Rows bounding from above are left to hold.
void reseat_slack_inputs(Work& w, const OcpQp& qp, double kappa) {
  for (int i = 0; i <= w.N; ++i) {
    g_mul(w, i, w.u[i], w.x[i], w.gz[i]);
    for (int j = 0; j < w.nu[i]; ++j) {
      if (!(qp.r[i](j) > 0.0) || !(qp.R[i].row(j).array() == 0.0).all() || !(qp.R[i].col(j).array() == 0.0).all())
        continue;
      if (i < w.N && !(qp.B[i].col(j).array() == 0.0).all()) continue;
      double lower = -kInf, upper = kInf;
      int n_lower = 0;
      for (int k = 0; k < w.nc[i]; ++k) {
        const double a = qp.D[i](k, j);
        if (a == 0.0 || w.act[i](k) == 0.0) continue;
        const double bound = (qp.d[i](k) - (w.gz[i](k) - a * w.u[i](j))) / a;  // row tight at u_j = bound
        if (a < 0.0) {
          lower = std::max(lower, bound);
          ++n_lower;
        } else {
          upper = std::min(upper, bound);
        }
      }
      if (n_lower == 0) continue;
      const double seat = lower + kappa * n_lower / qp.r[i](j);
      if (seat < upper) {
        const double change = seat - w.u[i](j);
        w.gz[i].noalias() += change * qp.D[i].col(j);
        w.u[i](j) = seat;
      }
    }
  }
}

double sum_complementarity(const Work& w) {
  double g = 0.0;
  for (int i = 0; i <= w.N; ++i) g += (w.act[i].array() * w.s[i].array() * w.lam[i].array()).sum();
  return g;
}

// Exchanges the step (and its complementarity target) with the spare one; O(1), no allocation.
void swap_steps(Work& w) {
  w.dx.swap(w.dx2);
  w.du.swap(w.du2);
  w.dpi.swap(w.dpi2);
  w.ds.swap(w.ds2);
  w.dlam.swap(w.dlam2);
  w.rc.swap(w.rc2);
}

bool all_finite(const Work& w) {
  for (int i = 0; i <= w.N; ++i)
    if (!w.dx[i].allFinite() || !w.du[i].allFinite() || !w.ds[i].allFinite() || !w.dlam[i].allFinite())
      return false;
  return true;
}
}  // namespace

// ---------------------------------------------------------------------------------------------
FastMpcSolver::FastMpcSolver(const OcpQpDims& dims, const Settings& settings)
    : dims_(dims), settings_(settings) {
  if (!dims_.validate().empty()) return;  // every solve() then reports InvalidInput
  work_ = std::make_unique<Work>(dims_);
  OcpQpDims d1 = dims_;  // elastic problem: one violation input per stage and its row v >= 0
  for (int i = 0; i <= d1.N; ++i) {
    d1.nu[i] += 1;
    d1.nc[i] += 1;
  }
  work1_ = std::make_unique<Work>(d1);
  qp1_ = std::make_unique<OcpQp>(d1);
  for (int i = 0; i <= d1.N; ++i) {
    qp1_->r[i](d1.nu[i] - 1) = 1.0;
    qp1_->D[i](d1.nc[i] - 1, d1.nu[i] - 1) = -1.0;
  }
}

FastMpcSolver::~FastMpcSolver() = default;
FastMpcSolver::FastMpcSolver(FastMpcSolver&&) noexcept = default;
FastMpcSolver& FastMpcSolver::operator=(FastMpcSolver&&) noexcept = default;

namespace {
const std::vector<Vector> kEmpty;
}
const std::vector<Vector>& FastMpcSolver::x() const { return work_ ? work_->x : kEmpty; }
const std::vector<Vector>& FastMpcSolver::u() const { return work_ ? work_->u : kEmpty; }
const std::vector<Vector>& FastMpcSolver::lambda() const { return work_ ? work_->lam : kEmpty; }
const std::vector<Vector>& FastMpcSolver::pi() const { return work_ ? work_->pi : kEmpty; }

bool FastMpcSolver::time_up() const {
  if (settings_.time_limit_us <= 0.0) return false;
  const double us = std::chrono::duration<double, std::micro>(Clock::now() - t_start_).count();
  return us > settings_.time_limit_us;
}

// Shapes and finiteness, without allocating (OcpQp::validate() builds a message; callers that want
// the reason call it themselves).
bool FastMpcSolver::inputs_ok(const OcpQp& qp, const Vector& x0) const {
  if (!work_) return false;
  const int N = dims_.N, nx = dims_.nx;
  if (qp.dims.N != N || qp.dims.nx != nx || qp.dims.nu != dims_.nu || qp.dims.nc != dims_.nc) return false;
  if (x0.size() != nx || !x0.allFinite()) return false;
  const size_t n1 = static_cast<size_t>(N) + 1;
  if (qp.A.size() + 1 != n1 || qp.B.size() + 1 != n1 || qp.b.size() + 1 != n1 || qp.Q.size() != n1 ||
      qp.q.size() != n1 || qp.R.size() != n1 || qp.r.size() != n1 || qp.C.size() != n1 || qp.D.size() != n1 ||
      qp.d.size() != n1)
    return false;
  auto ok = [](const auto& m, long rows, long cols) {
    return m.rows() == rows && m.cols() == cols && m.allFinite();
  };
  for (int i = 0; i <= N; ++i) {
    const int m = dims_.nu[i], k = dims_.nc[i];
    if (i < N && !(ok(qp.A[i], nx, nx) && ok(qp.B[i], nx, m) && ok(qp.b[i], nx, 1))) return false;
    if (!(ok(qp.Q[i], nx, nx) && ok(qp.q[i], nx, 1) && ok(qp.R[i], m, m) && ok(qp.r[i], m, 1) &&
          ok(qp.C[i], k, nx) && ok(qp.D[i], k, m) && ok(qp.d[i], k, 1)))
      return false;
  }
  return true;
}

Status FastMpcSolver::solve(const OcpQp& qp, const Vector& x0) {
  t_start_ = Clock::now();
  info_ = Info{};
  Status st = Status::InvalidInput;
  const bool valid_settings = settings_.max_iter >= 0 && settings_.tol > 0.0 &&
                              (settings_.mode != Mode::FixedBarrier || settings_.barrier > 0.0);
  if (valid_settings && inputs_ok(qp, x0)) {
    Work& w = *work_;
    w.x[0] = x0;
    if (!classify_rows(w, qp, settings_.tol)) {
      st = Status::Infeasible;
    } else {
      const bool warm = settings_.warm_start && has_warm_;
      // The shifted plan's last state: one step past the new x_{N-1}. (Not in FixedBarrier mode:
      // its warm start needs strict feasibility more than consistent dynamics, which its
      // infeasible-start Newton repairs anyway; the propagated state can leave a tight terminal row.)
      if (warm && shifted_ && settings_.mode == Mode::Converged) {
        const int N = w.N;
        w.x[N] = qp.b[N - 1];
        w.x[N].noalias() += qp.A[N - 1].lazyProduct(w.x[N - 1]);
        w.x[N].noalias() += qp.B[N - 1].lazyProduct(w.u[N - 1]);
      }
      shifted_ = false;
      st = settings_.mode == Mode::Converged
               ? solve_converged(w, qp, warm, settings_.max_iter, settings_.tol, 0.0, kWarmPushConverged)
                                             : solve_barrier(qp, warm);
    }
    residuals(w, qp, w.x, w.u, w.pi, w.lam);
    info_.primal_residual = std::max(dyn_res(w), ineq_violation(w, qp));
    info_.dual_residual = dual_res(w);
    info_.objective = objective(w, qp);
    has_warm_ = st == Status::Solved || st == Status::MaxIter || st == Status::TimeLimit;
  } else {
    has_warm_ = false;
  }
  info_.status = st;
  info_.solve_time_us = std::chrono::duration<double, std::micro>(Clock::now() - t_start_).count();
  return st;
}

// Primal-dual interior point, Mehrotra predictor-corrector. In phase-1 use (w = *work1_) the
// problem is always feasible; on the QP itself a stalling primal residual triggers the phase-1
// test, which either proves infeasibility or lets the iterations continue.
Status FastMpcSolver::solve_converged(Work& w, const OcpQp& qp, bool warm, int max_iter, double tol,
                                      double mu_floor, double warm_push) {
  const bool is_main = &w == work_.get();
  const int N = w.N;
  // Starting point. Cold: zero inputs, states rolled out through the dynamics. Warm: the previous
  // (shifted) plan. Slacks and duals are pushed into the interior.
  if (!warm) {
    for (int i = 0; i <= N; ++i) {
      w.u[i].setZero();
      if (i < N) {
        w.x[i + 1] = qp.b[i];
        w.x[i + 1].noalias() += qp.A[i].lazyProduct(w.x[i]);
        w.pi[i].setZero();
      }
    }
  }
  residuals(w, qp, w.x, w.u, w.pi, w.lam);  // for Gz and the cost gradient's scale (lam-independent)
  const double gs0 = w.grad_scale;
  for (int i = 0; i <= N; ++i) {
    for (int j = 0; j < w.nc[i]; ++j) {
      const double slack = qp.d[i](j) - w.gz[i](j);
      if (w.act[i](j) == 0.0) {
        w.s[i](j) = 1.0;
        w.lam[i](j) = 0.0;
      } else if (warm) {
        w.s[i](j) = std::max(slack, warm_push * (1.0 + std::abs(qp.d[i](j))));
        w.lam[i](j) = std::max(w.lam[i](j), warm_push);
      } else {
        // Slack as large as the row's residual (at least 1), duals at the cost gradient's scale.
        w.s[i](j) = std::max(std::abs(slack), 1.0);
        w.lam[i](j) = gs0;
      }
    }
  }

  const bool want_interior = mu_floor > 0.0;
  bool phase1_done = !is_main;
  double pres_hist[6] = {kInf, kInf, kInf, kInf, kInf, kInf};
  Status st = Status::MaxIter;
  int k = 0;
  for (;; ++k) {
    residuals(w, qp, w.x, w.u, w.pi, w.lam);
    double pres_in = 0.0;
    for (int i = 0; i <= N; ++i) {
      w.rin[i] = (w.gz[i] + w.s[i] - qp.d[i]).cwiseProduct(w.act[i]);
      pres_in = std::max(pres_in, inf_norm(w.rin[i]));
    }
    const double pres = std::max(pres_in, dyn_res(w));
    const double dres = dual_res(w);
    const double gap = sum_complementarity(w);
    const double mu = w.rows_active > 0 ? gap / w.rows_active : 0.0;
    if (want_interior && mu <= kBarrierHandover * mu_floor) {  // near the barrier minimiser: inside yet?
      bool interior = true;
      for (int i = 0; i <= N && interior; ++i)
        for (int j = 0; j < w.nc[i]; ++j)
          if (w.act[i](j) > 0.0 && !(w.gz[i](j) < qp.d[i](j))) {
            interior = false;
            break;
          }
      if (interior) {
        st = Status::Solved;
        break;
      }
    }
    if (pres <= tol * w.cons_scale && dres <= tol * w.grad_scale &&
        gap <= tol * std::max(1.0, std::abs(objective(w, qp)))) {
      st = Status::Solved;
      break;
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "%s k=%2d pres=%.2e/%.1e dres=%.2e/%.1e gap=%.2e obj=%.6e\n", is_main ? "main" : "ph1 ", k, pres,
                 w.cons_scale, dres, w.grad_scale, gap, objective(w, qp));
#endif
    for (int h = 5; h > 0; --h) pres_hist[h] = pres_hist[h - 1];
    pres_hist[0] = pres / w.cons_scale;
    if (k >= max_iter) break;
    if (time_up()) {
      st = Status::TimeLimit;
      break;
    }
    // Infeasibility suspicion: the primal residual stopped shrinking. Ask the elastic problem.
    if (!phase1_done && k >= 6 && pres_hist[0] > kFeasibleEnough && pres_hist[0] > 0.5 * pres_hist[5]) {
      phase1_done = true;
      if (phase1_infeasible(qp)) {
        st = Status::Infeasible;
        break;
      }
    }

    for (int i = 0; i <= N; ++i) {
      w.wgt[i] = (w.lam[i].array() / w.s[i].array() * w.act[i].array()).matrix();
    }
    if (!factorize_regularised(w, qp)) {
      st = Status::NumericalError;
      break;
    }
    // Predictor (affine) then corrector, both with this factorisation. direction() takes the
    // complementarity right-hand side rc (the step aims at s .* lam - rc) and returns the largest
    // step that keeps s and lam nonnegative.
    auto direction = [&](bool refine) {
      for (int i = 0; i <= N; ++i) {
        w.rc[i].array() *= w.act[i].array();
        // Step QP gradient: rd + G'(W rin - rc / s)
        w.vrow[i] = (w.wgt[i].array() * w.rin[i].array() - w.rc[i].array() / w.s[i].array()).matrix();
        w.gu[i] = w.rdu[i];
        if (i > 0) w.gx[i] = w.rdx[i];
        gt_mul_add(w, i, w.vrow[i], w.gu[i], i > 0 ? &w.gx[i] : nullptr);
      }
      solve_step(w, qp, w.rdyn, w.dx, w.du, w.dpi);
      slack_dual_step(w);
      // Iterative refinement: the same factorisation, the residual of the unreduced system.
      for (int ref = 0; refine && ref < kMaxRefinements && step_error(w, qp) > kRefineBelow * tol; ++ref) {
        solve_step(w, qp, w.edyn, w.cx, w.cu, w.cpi);
        for (int i = 0; i <= N; ++i) {
          w.dx[i] += w.cx[i];
          w.du[i] += w.cu[i];
          if (i < N) w.dpi[i] += w.cpi[i];
        }
        slack_dual_step(w);
      }
      double amax = kInf;  // largest step keeping s, lam >= 0 (unbounded when nothing blocks)
      for (int i = 0; i <= N; ++i) {
        for (int j = 0; j < w.nc[i]; ++j) {
          if (w.ds[i](j) < 0.0) amax = std::min(amax, -w.s[i](j) / w.ds[i](j));
          if (w.dlam[i](j) < 0.0) amax = std::min(amax, -w.lam[i](j) / w.dlam[i](j));
        }
      }
      return amax;
    };
    for (int i = 0; i <= N; ++i) w.rc[i] = w.s[i].cwiseProduct(w.lam[i]);
    const double amax_aff = std::min(1.0, direction(false));
    double gap_aff = 0.0;
    for (int i = 0; i <= N; ++i) {
      gap_aff += ((w.s[i] + amax_aff * w.ds[i]).array() * (w.lam[i] + amax_aff * w.dlam[i]).array() *
                  w.act[i].array())
                     .sum();
      w.ds_aff[i] = w.ds[i];
      w.dlam_aff[i] = w.dlam[i];
    }
    const double ratio = gap > 0.0 ? gap_aff / gap : 0.0;
    const double sigma = std::clamp(ratio * ratio * ratio, 0.0, 1.0);
    const double smu = std::max(sigma * mu, mu_floor);
    for (int i = 0; i <= N; ++i)
      w.rc[i] = (w.s[i].array() * w.lam[i].array() + w.ds_aff[i].array() * w.dlam_aff[i].array() - smu).matrix();
    // Rounding in the reduced system only matters once the barrier weights are large: refine the
    // step in the late iterations only.
    const bool refine = gap <= kRefineFromGap * std::max(1.0, std::abs(objective(w, qp)));
    double amax = direction(refine);
    // Mehrotra's second-order term is a prediction; when it shortens the step a lot (typical when
    // the affine step is huge along a direction of tiny curvature) take the plain centred step.
    if (amax < kSecondOrderKeep * amax_aff) {
      for (int i = 0; i <= N; ++i) w.rc[i] = (w.s[i].array() * w.lam[i].array() - smu).matrix();
      amax = direction(refine);
    }
    // Gondzio's centrality correctors when the step is short: Mehrotra's direction alone can
    // cycle (e.g. an input bouncing between the two sides of its box). Each corrector pushes the
    // complementarity products at a longer trial step back into [0.1, 10] * sigma mu.
    for (int c = 0; c < kMaxCentralityCorrectors && amax < kCorrectBelow; ++c) {
      const double atrial = std::min(1.0, 1.5 * amax + 0.1);
      for (int i = 0; i <= N; ++i) {
        auto prod = (w.s[i] + atrial * w.ds[i]).array() * (w.lam[i] + atrial * w.dlam[i]).array();
        auto push = (prod.max(0.1 * smu).min(10.0 * smu) - prod).max(-10.0 * smu);
        w.rc2[i] = (w.rc[i].array() - push).matrix();
      }
      swap_steps(w);  // the current step goes to the spare buffers, rc now holds the corrected target
      const double a2 = direction(refine);
      if (a2 >= 1.01 * amax) {
        amax = a2;
      } else {
        swap_steps(w);  // no better: keep the previous step
        break;
      }
    }
    double alpha = std::min(1.0, kStepToBoundary * amax);
    // On a primal-dual feasible iterate the gap after a step is quadratic in alpha with curvature
    // ds'dlam = dz'H dz >= 0 (QPs, unlike LPs): a long step along a stiff direction can raise it,
    // and Mehrotra's iterations can then cycle. There, never step past the gap's minimiser.
    if (pres <= tol * w.cons_scale && dres <= tol * w.grad_scale) {
      double lin = 0.0, quad = 0.0;
      for (int i = 0; i <= N; ++i) {
        lin += (w.act[i].array() * (w.s[i].array() * w.dlam[i].array() + w.lam[i].array() * w.ds[i].array())).sum();
        quad += (w.act[i].array() * w.ds[i].array() * w.dlam[i].array()).sum();
      }
      if (quad > 0.0 && lin < 0.0) alpha = std::min(alpha, -lin / (2.0 * quad));
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "   sigma=%.2e alpha_aff=%.3e alpha=%.3e\n", sigma, amax_aff, alpha);
#endif
    if (!all_finite(w)) {
      st = Status::NumericalError;
      break;
    }
    for (int i = 0; i <= N; ++i) {
      if (i > 0) w.x[i] += alpha * w.dx[i];
      w.u[i] += alpha * w.du[i];
      if (i < N) w.pi[i] += alpha * w.dpi[i];
      w.s[i] += alpha * w.ds[i];
      w.lam[i] += alpha * w.dlam[i];
    }
  }
  info_.iterations += k;
  // A QP without solution makes the iterates diverge: the cap, a failed factorisation or overflow.
  // (At the cap with an almost primal-feasible iterate there is nothing to ask.)
  const bool suspicious = st == Status::NumericalError || (st == Status::MaxIter && pres_hist[0] > kFeasibleEnough);
  if (suspicious && is_main && !phase1_done && phase1_infeasible(qp)) st = Status::Infeasible;
  return st;
}

// The seed's Fast MPC: infeasible-start Newton on  f(z) - kappa * sum log(d - Gz)  s.t. dynamics,
// from a point that satisfies the inequalities strictly (the shifted previous plan, or the first
// strictly interior iterate of the primal-dual method).
Status FastMpcSolver::solve_barrier(const OcpQp& qp, bool warm) {
  Work& w = *work_;
  const int N = w.N;
  const double kappa = settings_.barrier, tol = settings_.tol;
  auto strictly_inside = [&](const std::vector<Vector>& x, const std::vector<Vector>& u) {
    for (int i = 0; i <= N; ++i) {
      g_mul(w, i, u[i], x[i], w.gz[i]);
      for (int j = 0; j < w.nc[i]; ++j)
        if (w.act[i](j) > 0.0 && !(w.gz[i](j) < qp.d[i](j))) return false;
    }
    return true;
  };
  // Barrier duals lam = kappa / (d - Gz) and residuals at (x, u, pi) (uses w.gz of that point);
  // returns the residual 2-norm, the infeasible-start method's merit.
  auto evaluate = [&](const std::vector<Vector>& x, const std::vector<Vector>& u, const std::vector<Vector>& pi) {
    for (int i = 0; i <= N; ++i) {
      w.s[i] = qp.d[i] - w.gz[i];
      for (int j = 0; j < w.nc[i]; ++j) {
        if (w.act[i](j) == 0.0) w.s[i](j) = 1.0;
        w.lam[i](j) = w.act[i](j) * kappa / w.s[i](j);
      }
    }
    residuals(w, qp, x, u, pi, w.lam);
    double r2 = 0.0;
    for (int i = 0; i <= N; ++i) {
      r2 += w.rdu[i].squaredNorm();
      if (i > 0) r2 += w.rdx[i].squaredNorm();
      if (i < N) r2 += w.rdyn[i].squaredNorm();
    }
    return std::sqrt(r2);
  };
  // Barrier objective f(z) - kappa sum log(d - Gz) (uses w.gz of that point): the merit once the
  // dynamics hold.
  auto barrier_objective = [&](const std::vector<Vector>& x, const std::vector<Vector>& u) {
    double logs = 0.0;
    for (int i = 0; i <= N; ++i)
      for (int j = 0; j < w.nc[i]; ++j)
        if (w.act[i](j) > 0.0) logs += std::log(qp.d[i](j) - w.gz[i](j));
    return objective(w, qp, x, u) - kappa * logs;
  };

  // Warm start: the shifted plan's inputs rolled out from the new x0 satisfy the dynamics, so
  // Newton need not repair them (an inconsistent start makes the strict-feasibility line search
  // crawl). Use that if it is strictly inside the inequalities, else the shifted plan as it is.
  bool inside = false;
  if (warm) {
    for (int i = 1; i <= N; ++i) w.xt[i] = w.x[i];
    rollout(w, qp);
    reseat_slack_inputs(w, qp, kappa);
    inside = strictly_inside(w.x, w.u);
    if (!inside) {
      for (int i = 1; i <= N; ++i) w.x[i].swap(w.xt[i]);
      inside = strictly_inside(w.x, w.u);
    }
    // Neither is inside: the old plan says little about the new rows (tuned on closed loops,
    // a cold primal-dual start then beats one from the old plan).
    if (!inside) warm = false;
  }
  // Primal-dual iterations along the central path down to complementarity ~kappa, i.e. into the
  // neighbourhood of the barrier minimiser: the cold start, and the rescue when the warm plan
  // hugs the boundary so closely that Newton's steps are heavily damped.
  // Returns true when Newton can take over; otherwise `st0` is the solve's answer (the cap or the
  // time ran out before an interior point, infeasibility, or the QP's own solution on the boundary).
  bool primal_dual_done = false;
  Status st0 = Status::MaxIter;
  auto central_path_start = [&](bool from_iterate) {
    primal_dual_done = true;
    const int left = std::max(0, settings_.max_iter - info_.iterations);
    st0 = solve_converged(w, qp, from_iterate, left, tol, kappa, kWarmPushBarrier);
    return st0 == Status::Solved && strictly_inside(w.x, w.u);
  };
  if (!inside && !central_path_start(warm)) return st0;
#ifdef RVD_SOLVER_TRACE
  std::fprintf(stderr, "barrier warm=%d inside=%d\n", warm, inside);
#endif
  // gz, s, lam and the residuals at the current iterate; returns the residual norm.
  auto evaluate_iterate = [&] {
    strictly_inside(w.x, w.u);
    return evaluate(w.x, w.u, w.pi);
  };

  double rnorm = evaluate_iterate();
  Status st = Status::MaxIter;
  for (int newton = 0;; ++newton) {
    const double pres = dyn_res(w);
    if (pres <= tol * w.cons_scale && dual_res(w) <= tol * w.grad_scale) {
      st = Status::Solved;
      break;
    }
    if (info_.iterations >= settings_.max_iter) break;
    if (time_up()) {
      st = Status::TimeLimit;
      break;
    }
    for (int i = 0; i <= N; ++i) {
      w.wgt[i] = (kappa / w.s[i].array().square() * w.act[i].array()).matrix();
      w.gu[i] = w.rdu[i];
      if (i > 0) w.gx[i] = w.rdx[i];
    }
    if (!factorize_regularised(w, qp)) {
      st = Status::NumericalError;
      break;
    }
    solve_step(w, qp, w.rdyn, w.dx, w.du, w.dpi);
    // On the dynamics the step keeps them, and the Newton decrement lambda^2 = -rd'dz bounds the
    // barrier objective's distance to its minimum (about lambda^2 / 2).
    const bool on_dynamics = pres <= tol * w.cons_scale;
    double slope = 0.0;
    for (int i = 0; i <= N; ++i) {
      slope += w.rdu[i].dot(w.du[i]);
      if (i > 0) slope += w.rdx[i].dot(w.dx[i]);
    }
    const double f_now = objective(w, qp);
    if (on_dynamics && -0.5 * slope <= tol * std::max(1.0, std::abs(f_now))) {
      st = Status::Solved;
      break;
    }
    ++info_.iterations;
    // Backtracking: stay strictly inside the inequalities, then decrease the merit: the residual
    // norm while the dynamics are violated (infeasible start), else the barrier objective (Armijo).
    const double phi = on_dynamics ? barrier_objective(w.x, w.u) : 0.0;
    // Fraction to the boundary: no slack may lose more than 99% of its value in one step (a full
    // step that lands next to the boundary costs many Newton steps to get away from it again).
    double t = 1.0;
    for (int i = 0; i <= N; ++i) {
      step_rows(w, i, w.ds[i]);  // G dz: the slacks d - Gz change by -G dz
      for (int j = 0; j < w.nc[i]; ++j)
        if (w.act[i](j) > 0.0 && w.ds[i](j) > 0.0) t = std::min(t, kNewtonToBoundary * w.s[i](j) / w.ds[i](j));
    }
    bool moved = false;
    double r_trial = rnorm;
    for (int h = 0; h < kLsMaxHalvings; ++h, t *= kLsBeta) {
      for (int i = 0; i <= N; ++i) {
        w.xt[i] = w.x[i] + t * w.dx[i];
        w.ut[i] = w.u[i] + t * w.du[i];
        if (i < N) w.pit[i] = w.pi[i] + t * w.dpi[i];
      }
      if (!strictly_inside(w.xt, w.ut)) continue;
      if (on_dynamics) {
        moved = barrier_objective(w.xt, w.ut) <= phi + kLsAlpha * t * slope;
      } else {
        r_trial = evaluate(w.xt, w.ut, w.pit);
        moved = r_trial <= (1.0 - kLsAlpha * t) * rnorm;
      }
      if (moved) break;
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "newton it=%d rnorm=%.3e t=%.3e pres=%.2e moved=%d\n", info_.iterations, rnorm, t, pres, moved);
#endif
    if ((!moved || (newton < kDampedNewtonSteps && t < kDampedStep)) && !primal_dual_done) {
      // Newton crawls: this start is too close to the boundary. Rescue from the current point,
      // keeping it (strictly feasible) in case the budget runs out before the rescue is inside.
      for (int i = 0; i <= N; ++i) {
        w.xt[i] = w.x[i];
        w.ut[i] = w.u[i];
        if (i < N) w.pit[i] = w.pi[i];
      }
      evaluate_iterate();  // the primal-dual start reads s and lam
      if (!central_path_start(true)) {
        if (st0 != Status::MaxIter && st0 != Status::TimeLimit) return st0;
        for (int i = 0; i <= N; ++i) {
          w.x[i].swap(w.xt[i]);
          w.u[i].swap(w.ut[i]);
          if (i < N) w.pi[i].swap(w.pit[i]);
        }
        st = st0;
        break;
      }
      rnorm = evaluate_iterate();
      continue;
    }
    if (!moved) break;  // no decrease along the Newton direction: rounding level reached
    for (int i = 0; i <= N; ++i) {
      w.x[i].swap(w.xt[i]);
      w.u[i].swap(w.ut[i]);
      if (i < N) w.pi[i].swap(w.pit[i]);
    }
    // Off the dynamics the line search evaluated the accepted point already; on them only its
    // merit (w.gz is the accepted point's: its strictly_inside() was the last).
    rnorm = on_dynamics ? evaluate(w.x, w.u, w.pi) : r_trial;
  }
  // Leave gz, s, lam and the residuals consistent with the returned iterate.
  if (st == Status::MaxIter || st == Status::TimeLimit || st == Status::Solved) evaluate_iterate();
  // Dynamics still violated at the cap: the plan is unusable, so find out whether any plan exists.
  if (st == Status::MaxIter && dyn_res(w) > tol * w.cons_scale && phase1_infeasible(qp)) st = Status::Infeasible;
  return st;
}

// Elastic phase 1: minimise sum_i v_i subject to the dynamics and (row_j z - d_j)/|row_j| <= v_i,
// v_i >= 0. It is always feasible; its optimum is zero exactly when the QP is feasible.
bool FastMpcSolver::phase1_infeasible(const OcpQp& qp) {
  const Work& w = *work_;
  OcpQp& p = *qp1_;
  for (int i = 0; i <= w.N; ++i) {
    const int m = w.nu[i], k = w.nc[i];
    if (i < w.N) {
      p.A[i] = qp.A[i];
      p.b[i] = qp.b[i];
      p.B[i].leftCols(m) = qp.B[i];
    }
    for (int j = 0; j < k; ++j) {
      if (w.act[i](j) == 0.0) {  // constant row, already known to hold
        p.C[i].row(j).setZero();
        p.D[i].row(j).setZero();
        p.d[i](j) = 1.0;
        continue;
      }
      double nrm2 = qp.D[i].row(j).squaredNorm();
      if (i > 0) nrm2 += qp.C[i].row(j).squaredNorm();
      const double inv = 1.0 / std::sqrt(nrm2);
      p.C[i].row(j) = qp.C[i].row(j) * inv;
      p.D[i].row(j).head(m) = qp.D[i].row(j) * inv;
      p.D[i](j, m) = -1.0;
      p.d[i](j) = qp.d[i](j) * inv;
    }
  }
  Work& w1 = *work1_;
  w1.x[0] = w.x[0];
  classify_rows(w1, p, settings_.tol);
  const Status st = solve_converged(w1, p, false, kPhase1MaxIter, kPhase1Tol, 0.0, kWarmPushConverged);
  double v = 0.0;
  for (int i = 0; i <= w.N; ++i) v += w1.u[i](w.nu[i]);
  if (st == Status::Solved) return v > kInfeasibleViolation;
  // Not converged to the tolerance (e.g. the factorisation broke down at the very end): decide only
  // if the iterate is primal feasible for the elastic problem and its duality gap is a small
  // fraction of the violation, so that the optimal violation is surely positive.
  residuals(w1, p, w1.x, w1.u, w1.pi, w1.lam);
  double pres = dyn_res(w1);
  for (int i = 0; i <= w1.N; ++i)
    pres = std::max(pres, ((w1.gz[i] + w1.s[i] - p.d[i]).cwiseProduct(w1.act[i])).lpNorm<Eigen::Infinity>());
  const double gap = sum_complementarity(w1);
  return st == Status::NumericalError && pres <= 1e-8 * w1.cons_scale && v > kInfeasibleViolation && gap < 0.1 * v;
}

void FastMpcSolver::shift_warm_start() {
  if (!work_ || !has_warm_) return;
  shifted_ = true;
  Work& w = *work_;
  const int N = w.N;
  for (int i = 0; i < N; ++i) {
    w.x[i] = w.x[i + 1];
    if (w.nu[i] == w.nu[i + 1]) w.u[i] = w.u[i + 1];
    if (w.nc[i] == w.nc[i + 1]) w.lam[i] = w.lam[i + 1];
    if (i + 1 < N) w.pi[i] = w.pi[i + 1];
  }
}

void FastMpcSolver::reset_warm_start() { has_warm_ = false; }

}  // namespace rvd::solver
