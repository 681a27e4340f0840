#include "flight_sw/solver/fast_mpc.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#ifdef RVD_SOLVER_TRACE  // -DRVD_SOLVER_TRACE prints one line per interior-point iteration to stderr
#include <cstdio>
#endif

namespace rvd::solver {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();
// Smallest Hessian regularisation of the input block: slack inputs have no quadratic cost, so their
// Hessian comes only from the barrier and can be near zero. The residuals are always those of the
// true problem, so this only makes the Newton step inexact, never the answer.
constexpr double kRegMin = 1e-10;
constexpr double kRegMax = 1e-2;
// Fraction of the way to the boundary of the positive orthant an interior-point step may go.
constexpr double kStepToBoundary = 0.995;
// Refine a Newton step while its linearised KKT residual exceeds this fraction of the tolerance.
constexpr double kRefineBelow = 0.1;
// Centrality correctors (Gondzio) when the corrector step is shorter than this.
constexpr double kCorrectBelow = 0.9;
constexpr int kMaxCentralityCorrectors = 2;
// FixedBarrier cold start: primal-dual iterations hand over to the barrier Newton method once the
// inequalities hold strictly and the complementarity is within this factor of kappa.
constexpr double kBarrierHandover = 10.0;
// ... and rescue Newton with them when one of its first steps is damped below this length.
constexpr double kDampedStep = 1.0 / 16.0;
constexpr int kDampedNewtonSteps = 2;
// Warm start of the primal-dual iterations: slacks and duals at least this far inside (relative
// to the row's size). Tuned on closed-loop runs: larger for Converged mode, smaller when heading
// for the kappa-centre.
constexpr double kWarmPushConverged = 1e-2;
constexpr double kWarmPushBarrier = 1e-3;
constexpr int kMaxRefinements = 2;
// Line search of the infeasible-start Newton method (Boyd & Vandenberghe §10.3.2).
constexpr double kLsAlpha = 0.01, kLsBeta = 0.5;
constexpr int kLsMaxHalvings = 60;
// The QP is infeasible when the elastic problem cannot bring the summed per-stage violation of
// the unit-normalised rows below this (units of the normalised rows: distance in (x, u) space).
constexpr double kInfeasibleViolation = 1e-6;
constexpr int kPhase1MaxIter = 100;
constexpr double kPhase1Tol = 1e-9;

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
  // Barrier Hessian weight per row and its square root; complementarity right-hand side; scratch.
  std::vector<Vector> wgt, sqw, rc, vrow;
  // Riccati: gradient of the step's QP, the factor's right-hand-side recursion, stage matrices.
  std::vector<Vector> gx, gu, l, p;
  std::vector<Matrix> Z;  // [u; x] stage Hessian: Cholesky of the uu block, Y = L^-1 S in the ux block
  std::vector<Matrix> P;  // cost-to-go Hessian
  Matrix T, PB, PA;
  Vector tn, tm;
  // Iterative refinement: the linearised KKT system's dynamics residual and the correction.
  std::vector<Vector> edyn, cx, cu, cpi;
  // Trial point of the line search.
  std::vector<Vector> xt, ut, pit;
  // Problem scale for relative tolerances, updated by residuals().
  double grad_scale = 1.0, cons_scale = 1.0;

  explicit Work(const OcpQpDims& d) : N(d.N), nx(d.nx), nu(d.nu), nc(d.nc) {
    int mmax = 0, cmax = 0;
    for (int i = 0; i <= N; ++i) {
      mmax = std::max(mmax, nu[i]);
      cmax = std::max(cmax, nc[i]);
    }
    auto stage_vecs = [&](std::vector<Vector>& v, const std::vector<int>& sz) {
      v.resize(N + 1);
      for (int i = 0; i <= N; ++i) v[i] = Vector::Zero(sz[i]);
    };
    std::vector<int> nxs(N + 1, nx), nxs_dyn(N, nx);
    for (auto* v : {&x, &rdx, &dx, &dx2, &gx, &p, &xt, &cx}) stage_vecs(*v, nxs);
    for (auto* v : {&u, &rdu, &du, &du2, &gu, &l, &ut, &cu}) stage_vecs(*v, nu);
    for (auto* v : {&s, &lam, &rin, &gz, &ds, &dlam, &ds_aff, &dlam_aff, &ds2, &dlam2, &act, &wgt, &sqw, &rc, &rc2,
                    &vrow})
      stage_vecs(*v, nc);
    for (auto* v : {&pi, &rdyn, &dpi, &dpi2, &pit, &edyn, &cpi}) v->assign(N, Vector::Zero(nx));
    Z.resize(N + 1);
    P.assign(N + 1, Matrix::Zero(nx, nx));
    for (int i = 0; i <= N; ++i) Z[i] = Matrix::Zero(nu[i] + nx, nu[i] + nx);
    T = Matrix::Zero(cmax, mmax + nx);
    PB = Matrix::Zero(nx, mmax);
    PA = Matrix::Zero(nx, nx);
    tn = Vector::Zero(nx);
    tm = Vector::Zero(mmax);
    for (int i = 0; i <= N; ++i) act[i].setOnes();
  }
};

namespace {
using Work = FastMpcSolver::Work;

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
  }
  return ok;
}

// Residuals of the KKT conditions at (x, u, pi, lam); also Gz and the problem scales.
void residuals(Work& w, const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u,
               const std::vector<Vector>& pi, const std::vector<Vector>& lam) {
  double gscale = 0.0, cscale = 0.0;
  for (int i = 0; i <= w.N; ++i) {
    w.gz[i].noalias() = qp.C[i] * x[i];
    w.gz[i].noalias() += qp.D[i] * u[i];
    cscale = std::max({cscale, inf_norm(qp.d[i]), inf_norm(w.gz[i])});

    w.rdu[i] = qp.r[i];
    w.rdu[i].noalias() += qp.R[i] * u[i];
    gscale = std::max(gscale, inf_norm(w.rdu[i]));
    w.rdu[i].noalias() += qp.D[i].transpose() * lam[i];
    if (i < w.N) w.rdu[i].noalias() += qp.B[i].transpose() * pi[i];

    if (i > 0) {
      w.rdx[i] = qp.q[i];
      w.rdx[i].noalias() += qp.Q[i] * x[i];
      gscale = std::max(gscale, inf_norm(w.rdx[i]));
      w.rdx[i].noalias() += qp.C[i].transpose() * lam[i];
      w.rdx[i] -= pi[i - 1];
      if (i < w.N) w.rdx[i].noalias() += qp.A[i].transpose() * pi[i];
    }
    if (i < w.N) {
      w.rdyn[i] = qp.b[i] - x[i + 1];
      w.rdyn[i].noalias() += qp.A[i] * x[i];
      w.rdyn[i].noalias() += qp.B[i] * u[i];
    }
  }
  w.grad_scale = std::max(1.0, gscale);
  w.cons_scale = std::max(1.0, cscale);
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

double objective(Work& w, const OcpQp& qp) {
  double f = 0.0;
  for (int i = 0; i <= w.N; ++i) {
    w.tn.noalias() = qp.Q[i] * w.x[i];
    f += 0.5 * w.x[i].dot(w.tn) + qp.q[i].dot(w.x[i]);
    const int m = w.nu[i];
    if (m > 0) {
      auto t = w.tm.head(m);
      t.noalias() = qp.R[i] * w.u[i];
      f += 0.5 * w.u[i].dot(t) + qp.r[i].dot(w.u[i]);
    }
  }
  return f;
}

// Riccati factorisation of the Newton system whose inequality rows carry Hessian weights wgt
// (passed as their square roots in sqw). Stage i's [u; x] Hessian plus the cost-to-go
// [B A]' P_{i+1} [B A] is factored: Cholesky L of the uu block, Y = L^-1 S_ux, P_i = Q_xx - Y'Y.
bool factorize(Work& w, const OcpQp& qp, double reg) {
  const int n = w.nx;
  for (int i = w.N; i >= 0; --i) {
    const int m = w.nu[i], k = w.nc[i];
    Matrix& Z = w.Z[i];
    if (k > 0) {
      auto T = w.T.topLeftCorner(k, m + n);
      T.leftCols(m).noalias() = w.sqw[i].asDiagonal() * qp.D[i];
      T.rightCols(n).noalias() = w.sqw[i].asDiagonal() * qp.C[i];
      Z.noalias() = T.transpose() * T;
    } else {
      Z.setZero();
    }
    Z.topLeftCorner(m, m) += qp.R[i];
    Z.bottomRightCorner(n, n) += qp.Q[i];
    if (i < w.N) {
      auto PB = w.PB.leftCols(m);
      PB.noalias() = w.P[i + 1] * qp.B[i];
      Z.topLeftCorner(m, m).noalias() += qp.B[i].transpose() * PB;
      if (i > 0) {
        w.PA.noalias() = w.P[i + 1] * qp.A[i];
        Z.topRightCorner(m, n).noalias() += qp.B[i].transpose() * w.PA;
        Z.bottomRightCorner(n, n).noalias() += qp.A[i].transpose() * w.PA;
      }
    }
    if (m > 0) {
      Z.topLeftCorner(m, m).diagonal().array() += reg;
      Eigen::Ref<Matrix> Luu(Z.topLeftCorner(m, m));
      Eigen::LLT<Eigen::Ref<Matrix>> llt(Luu);  // in place: the lower triangle becomes L
      if (llt.info() != Eigen::Success) return false;
    }
    if (i > 0) {
      w.P[i] = Z.bottomRightCorner(n, n);
      if (m > 0) {
        auto Y = Z.topRightCorner(m, n);
        Z.topLeftCorner(m, m).triangularView<Eigen::Lower>().solveInPlace(Y);
        w.P[i].noalias() -= Y.transpose() * Y;
      }
    }
  }
  return true;
}

// Solves the factored Newton system for the gradient (gx, gu) and dynamics residual rdyn:
// the step (dx, du) and the dynamics multipliers' step dpi.
void solve_step(Work& w, const OcpQp& qp, const std::vector<Vector>& c, std::vector<Vector>& dx,
                std::vector<Vector>& du, std::vector<Vector>& dpi) {
  const int n = w.nx;
  for (int i = w.N; i >= 0; --i) {
    const int m = w.nu[i];
    if (i < w.N) {
      w.tn = w.p[i + 1];
      w.tn.noalias() += w.P[i + 1] * c[i];
      w.l[i] = w.gu[i];
      w.l[i].noalias() += qp.B[i].transpose() * w.tn;
      if (i > 0) {
        w.p[i] = w.gx[i];
        w.p[i].noalias() += qp.A[i].transpose() * w.tn;
      }
    } else {
      w.l[i] = w.gu[i];
      w.p[i] = w.gx[i];
    }
    if (m > 0) {
      w.Z[i].topLeftCorner(m, m).triangularView<Eigen::Lower>().solveInPlace(w.l[i]);
      if (i > 0) w.p[i].noalias() -= w.Z[i].topRightCorner(m, n).transpose() * w.l[i];
    }
  }
  dx[0].setZero();
  for (int i = 0; i <= w.N; ++i) {
    const int m = w.nu[i];
    if (m > 0) {
      auto t = w.tm.head(m);
      t = w.l[i];
      if (i > 0) t.noalias() += w.Z[i].topRightCorner(m, n) * dx[i];
      w.Z[i].topLeftCorner(m, m).triangularView<Eigen::Lower>().adjoint().solveInPlace(t);
      du[i] = -t;
    }
    if (i < w.N) {
      dx[i + 1] = c[i];
      dx[i + 1].noalias() += qp.A[i] * dx[i];
      dx[i + 1].noalias() += qp.B[i] * du[i];
      dpi[i] = w.p[i + 1];
      dpi[i].noalias() += w.P[i + 1] * dx[i + 1];
    }
  }
}

// Factorisation with the smallest regularisation that works.
bool factorize_regularised(Work& w, const OcpQp& qp) {
  for (double reg = kRegMin; reg <= kRegMax; reg *= 100.0)
    if (factorize(w, qp, reg)) return true;
  return false;
}

// Gz of the step; stage 0's x is fixed, so its C block does not move.
void step_rows(Work& w, const OcpQp& qp, int i, Vector& out) {
  out.noalias() = qp.D[i] * w.du[i];
  if (i > 0) out.noalias() += qp.C[i] * w.dx[i];
}

// Residual of the unreduced linearised KKT system at the step: stationarity into (gx, gu), dynamics
// into edyn. Returns them scaled by the problem scales (inf-norm). Rounding in the reduced system
// grows with the largest barrier weight, so late iterations need this to reach tight tolerances.
double step_error(Work& w, const OcpQp& qp) {
  double ed = 0.0, ep = 0.0;
  for (int i = 0; i <= w.N; ++i) {
    w.gu[i] = w.rdu[i];
    w.gu[i].noalias() += qp.R[i] * w.du[i];
    w.gu[i].noalias() += qp.D[i].transpose() * w.dlam[i];
    if (i < w.N) w.gu[i].noalias() += qp.B[i].transpose() * w.dpi[i];
    ed = std::max(ed, inf_norm(w.gu[i]));
    if (i > 0) {
      w.gx[i] = w.rdx[i] - w.dpi[i - 1];
      w.gx[i].noalias() += qp.Q[i] * w.dx[i];
      w.gx[i].noalias() += qp.C[i].transpose() * w.dlam[i];
      if (i < w.N) w.gx[i].noalias() += qp.A[i].transpose() * w.dpi[i];
      ed = std::max(ed, inf_norm(w.gx[i]));
    }
    if (i < w.N) {
      w.edyn[i] = w.rdyn[i] - w.dx[i + 1];
      w.edyn[i].noalias() += qp.A[i] * w.dx[i];
      w.edyn[i].noalias() += qp.B[i] * w.du[i];
      ep = std::max(ep, inf_norm(w.edyn[i]));
    }
  }
  return std::max(ed / w.grad_scale, ep / w.cons_scale);
}

// Slack and dual steps from the primal step: ds = -rin - G dz, dlam = (-rc - lam ds) / s.
void slack_dual_step(Work& w, const OcpQp& qp) {
  for (int i = 0; i <= w.N; ++i) {
    step_rows(w, qp, i, w.ds[i]);
    w.ds[i] = (-w.rin[i] - w.ds[i]).cwiseProduct(w.act[i]);
    w.dlam[i] = ((-w.rc[i].array() - w.lam[i].array() * w.ds[i].array()) / w.s[i].array()).matrix();
  }
}

// States from x0 under the current inputs: x_{i+1} = A x_i + B u_i + b_i.
void rollout(Work& w, const OcpQp& qp) {
  for (int i = 0; i < w.N; ++i) {
    w.x[i + 1] = qp.b[i];
    w.x[i + 1].noalias() += qp.A[i] * w.x[i];
    w.x[i + 1].noalias() += qp.B[i] * w.u[i];
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
        w.x[i + 1].noalias() += qp.A[i] * w.x[i];
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
    if (k >= max_iter) break;
    if (time_up()) {
      st = Status::TimeLimit;
      break;
    }
    // Infeasibility suspicion: the primal residual stopped shrinking. Ask the elastic problem.
    for (int h = 5; h > 0; --h) pres_hist[h] = pres_hist[h - 1];
    pres_hist[0] = pres / w.cons_scale;
    if (!phase1_done && k >= 6 && pres_hist[0] > 1e-6 && pres_hist[0] > 0.5 * pres_hist[5]) {
      phase1_done = true;
      if (phase1_infeasible(qp)) {
        st = Status::Infeasible;
        break;
      }
    }

    for (int i = 0; i <= N; ++i) {
      w.wgt[i] = (w.lam[i].array() / w.s[i].array() * w.act[i].array()).matrix();
      w.sqw[i] = w.wgt[i].cwiseSqrt();
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
        w.gu[i].noalias() += qp.D[i].transpose() * w.vrow[i];
        if (i > 0) {
          w.gx[i] = w.rdx[i];
          w.gx[i].noalias() += qp.C[i].transpose() * w.vrow[i];
        }
      }
      solve_step(w, qp, w.rdyn, w.dx, w.du, w.dpi);
      slack_dual_step(w, qp);
      // Iterative refinement: the same factorisation, the residual of the unreduced system.
      for (int ref = 0; refine && ref < kMaxRefinements && step_error(w, qp) > kRefineBelow * tol; ++ref) {
        solve_step(w, qp, w.edyn, w.cx, w.cu, w.cpi);
        for (int i = 0; i <= N; ++i) {
          w.dx[i] += w.cx[i];
          w.du[i] += w.cu[i];
          if (i < N) w.dpi[i] += w.cpi[i];
        }
        slack_dual_step(w, qp);
      }
      double amax = 1.0;
      for (int i = 0; i <= N; ++i) {
        for (int j = 0; j < w.nc[i]; ++j) {
          if (w.ds[i](j) < 0.0) amax = std::min(amax, -w.s[i](j) / w.ds[i](j));
          if (w.dlam[i](j) < 0.0) amax = std::min(amax, -w.lam[i](j) / w.dlam[i](j));
        }
      }
      return amax;
    };
    for (int i = 0; i <= N; ++i) w.rc[i] = w.s[i].cwiseProduct(w.lam[i]);
    const double amax_aff = direction(false);
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
    double amax = direction(true);
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
      const double a2 = direction(true);
      if (a2 >= 1.01 * amax) {
        amax = a2;
      } else {
        swap_steps(w);  // no better: keep the previous step
        break;
      }
    }
    const double alpha = std::min(1.0, kStepToBoundary * amax);
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
  if ((st == Status::MaxIter || st == Status::NumericalError) && is_main && !phase1_done && phase1_infeasible(qp))
    st = Status::Infeasible;
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
      w.gz[i].noalias() = qp.C[i] * x[i];
      w.gz[i].noalias() += qp.D[i] * u[i];
      for (int j = 0; j < w.nc[i]; ++j)
        if (w.act[i](j) > 0.0 && !(w.gz[i](j) < qp.d[i](j))) return false;
    }
    return true;
  };
  // Barrier duals lam = kappa / (d - Gz) and residuals at (x, u, pi); returns the residual 2-norm.
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

  // Warm start: the shifted plan's inputs rolled out from the new x0 satisfy the dynamics, so
  // Newton need not repair them (an inconsistent start makes the strict-feasibility line search
  // crawl). Use that if it is strictly inside the inequalities, else the shifted plan as it is.
  bool inside = false;
  if (warm) {
    for (int i = 1; i <= N; ++i) w.xt[i] = w.x[i];
    rollout(w, qp);
    inside = strictly_inside(w.x, w.u);
    if (!inside) {
      for (int i = 1; i <= N; ++i) w.x[i].swap(w.xt[i]);
      inside = strictly_inside(w.x, w.u);
      if (!inside) rollout(w, qp);
    }
  }
  // Primal-dual iterations along the central path down to complementarity ~kappa, i.e. into the
  // neighbourhood of the barrier minimiser: the cold start, and the rescue when the warm plan
  // hugs the boundary so closely that Newton's steps are heavily damped.
  bool primal_dual_done = false;
  auto central_path_start = [&](bool from_iterate) {
    primal_dual_done = true;
    const int left = std::max(0, settings_.max_iter - info_.iterations);
    const Status st0 = solve_converged(w, qp, from_iterate, left, tol, kappa, kWarmPushBarrier);
    if (st0 != Status::Solved) return st0;
    // Solved without an interior iterate: the QP's own solution (it sits on the boundary).
    return strictly_inside(w.x, w.u) ? Status::MaxIter : Status::Solved;
  };
  if (!inside) {
    const Status st0 = central_path_start(warm);
    if (st0 != Status::MaxIter) return st0;
  }

  double rnorm = evaluate(w.x, w.u, w.pi);
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
      w.sqw[i] = (std::sqrt(kappa) / w.s[i].array() * w.act[i].array()).matrix();
      w.gu[i] = w.rdu[i];
      if (i > 0) w.gx[i] = w.rdx[i];
    }
    if (!factorize_regularised(w, qp)) {
      st = Status::NumericalError;
      break;
    }
    solve_step(w, qp, w.rdyn, w.dx, w.du, w.dpi);
    // On the dynamics the Newton decrement lambda^2 = -rd' dz bounds the barrier objective's
    // distance to its minimum (about lambda^2 / 2): stop when that is below the tolerance.
    if (pres <= tol * w.cons_scale) {
      double decrement = 0.0;
      for (int i = 0; i <= N; ++i) {
        decrement -= w.rdu[i].dot(w.du[i]);
        if (i > 0) decrement -= w.rdx[i].dot(w.dx[i]);
      }
      if (0.5 * decrement <= tol * std::max(1.0, std::abs(objective(w, qp)))) {
        st = Status::Solved;
        break;
      }
    }
    ++info_.iterations;
    // Backtracking: first stay strictly inside the inequalities, then decrease the residual norm.
    double t = 1.0;
    bool moved = false;
    for (int h = 0; h < kLsMaxHalvings; ++h, t *= kLsBeta) {
      for (int i = 0; i <= N; ++i) {
        w.xt[i] = w.x[i] + t * w.dx[i];
        w.ut[i] = w.u[i] + t * w.du[i];
        if (i < N) w.pit[i] = w.pi[i] + t * w.dpi[i];
      }
      if (!strictly_inside(w.xt, w.ut)) continue;
      const double rt = evaluate(w.xt, w.ut, w.pit);
      if (rt <= (1.0 - kLsAlpha * t) * rnorm) {
        rnorm = rt;
        moved = true;
        break;
      }
    }
#ifdef RVD_SOLVER_TRACE
    std::fprintf(stderr, "newton it=%d rnorm=%.3e t=%.3e pres=%.2e moved=%d\n", info_.iterations, rnorm, t, pres, moved);
#endif
    if (moved) {
      for (int i = 0; i <= N; ++i) {
        w.x[i].swap(w.xt[i]);
        w.u[i].swap(w.ut[i]);
        if (i < N) w.pi[i].swap(w.pit[i]);
      }
    } else {  // leave gz, s, lam and the residuals at the current point
      strictly_inside(w.x, w.u);
      rnorm = evaluate(w.x, w.u, w.pi);
    }
#ifdef RVD_SOLVER_TRACE
    {
      double xm = 0, um = 0, dxm = 0, dum = 0;
      for (int i = 0; i <= N; ++i) { xm = std::max(xm, inf_norm(w.x[i])); um = std::max(um, inf_norm(w.u[i])); dxm = std::max(dxm, inf_norm(w.dx[i])); dum = std::max(dum, inf_norm(w.du[i])); }
      std::fprintf(stderr, "   |x|=%.2e |u|=%.2e |dx|=%.2e |du|=%.2e\n", xm, um, dxm, dum);
    }
#endif
    if (newton < kDampedNewtonSteps && t < kDampedStep && !primal_dual_done) {
      const Status st0 = central_path_start(true);
      if (st0 != Status::MaxIter) return st0;
      rnorm = evaluate(w.x, w.u, w.pi);
      continue;
    }
    if (!moved) break;  // no decrease along the Newton direction: rounding level reached
  }
  // Dynamics still violated at the cap: the plan is unusable, so find out whether any plan exists.
  if (st == Status::MaxIter && dyn_res(w) > tol * w.cons_scale && phase1_infeasible(qp)) st = Status::Infeasible;
  if (st == Status::MaxIter || st == Status::TimeLimit || st == Status::Solved) {
    strictly_inside(w.x, w.u);  // leave gz, s, lam consistent with the returned iterate
    evaluate(w.x, w.u, w.pi);
  }
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
