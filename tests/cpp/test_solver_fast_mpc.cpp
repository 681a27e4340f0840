// The Fast MPC solver against independent truth: a dense KKT solve, the KKT conditions computed
// from scratch, barrier theory, reachability, and its own contract (statuses, warm start, limits).
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <random>

#include "flight_sw/solver/fast_mpc.hpp"
#include "test_solver_problems.hpp"

using namespace rvd::solver;
using namespace rvd::solver::testing;

namespace {
// Smallest d - Cx - Du over all rows (positive: strictly feasible).
double min_slack(const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u) {
  double m = std::numeric_limits<double>::infinity();
  for (int i = 0; i <= qp.dims.N; ++i)
    if (qp.dims.nc[i] > 0) m = std::min(m, (qp.d[i] - qp.C[i] * x[i] - qp.D[i] * u[i]).minCoeff());
  return m;
}

int total_rows(const OcpQp& qp) {
  int m = 0;
  for (int k : qp.dims.nc) m += k;
  return m;
}
}  // namespace

TEST_CASE("without inequalities the solution is the dense KKT system's") {
  std::mt19937 rng(7);
  std::normal_distribution<double> nrm;
  const int N = 8, nx = 6;
  OcpQpDims dims = OcpQpDims::uniform(N, nx, 3, 0, 2, 0);  // stage N has 2 inputs of its own
  OcpQp qp(dims);
  const Matrix A = cw_phi(kMeanMotion500km, 20.0);
  for (int i = 0; i <= N; ++i) {
    const int m = dims.nu[i];
    if (i < N) {
      qp.A[i] = A;
      qp.B[i] = A.rightCols(3);
      for (int k = 0; k < nx; ++k) qp.b[i](k) = 0.1 * nrm(rng);
    }
    Matrix M = Matrix::NullaryExpr(nx, nx, [&] { return nrm(rng); });
    qp.Q[i] = M * M.transpose() * 1e-2;  // PSD, rank nx (almost surely)
    Matrix Rm = Matrix::NullaryExpr(m, m, [&] { return nrm(rng); });
    qp.R[i] = Rm * Rm.transpose() + Matrix::Identity(m, m);
    for (int k = 0; k < nx; ++k) qp.q[i](k) = nrm(rng);
    for (int k = 0; k < m; ++k) qp.r[i](k) = nrm(rng);
  }
  Vector x0(nx);
  x0 << 100, -200, 10, 0.1, -0.2, 0.05;

  // Dense KKT over z = [u0, x1, u1, ..., xN, uN] with the dynamics as equality constraints.
  std::vector<int> uo(N + 1), xo(N + 1);
  int nz = 0;
  for (int i = 0; i <= N; ++i) {
    if (i > 0) xo[i] = nz, nz += nx;
    uo[i] = nz, nz += dims.nu[i];
  }
  const int ne = N * nx;
  Matrix K = Matrix::Zero(nz + ne, nz + ne);
  Vector rhs = Vector::Zero(nz + ne);
  for (int i = 0; i <= N; ++i) {
    const int m = dims.nu[i];
    K.block(uo[i], uo[i], m, m) = qp.R[i];
    rhs.segment(uo[i], m) = -qp.r[i];
    if (i > 0) {
      K.block(xo[i], xo[i], nx, nx) = qp.Q[i];
      rhs.segment(xo[i], nx) = -qp.q[i];
    }
  }
  for (int i = 0; i < N; ++i) {  // x_{i+1} - A x_i - B u_i = b_i
    const int r = nz + i * nx, m = dims.nu[i];
    K.block(r, xo[i + 1], nx, nx) = Matrix::Identity(nx, nx);
    K.block(r, uo[i], nx, m) = -qp.B[i];
    rhs.segment(r, nx) = qp.b[i];
    if (i > 0) K.block(r, xo[i], nx, nx) = -qp.A[i];
    else rhs.segment(r, nx) += qp.A[0] * x0;
  }
  K.topRightCorner(nz, ne) = K.bottomLeftCorner(ne, nz).transpose();
  const Vector z = K.fullPivLu().solve(rhs);

  Settings interior = Settings::converged();
  interior.active_set_max_inputs = 0;
  FastMpcSolver solver(dims, interior), active_set(dims);
  REQUIRE(solver.solve(qp, x0) == Status::Solved);
  REQUIRE(active_set.solve(qp, x0) == Status::Solved);
  for (const FastMpcSolver* s : {&solver, &active_set}) {
    for (int i = 0; i <= N; ++i) {
      CHECK((s->u()[i] - z.segment(uo[i], dims.nu[i])).lpNorm<Eigen::Infinity>() < 1e-9 * (1 + z.lpNorm<Eigen::Infinity>()));
      if (i > 0) CHECK((s->x()[i] - z.segment(xo[i], nx)).lpNorm<Eigen::Infinity>() < 1e-9 * (1 + z.lpNorm<Eigen::Infinity>()));
    }
  }
  CHECK(solver.info().iterations == 1);  // no inequalities: one Newton step is exact
  CHECK(active_set.info().iterations == 0);  // the unconstrained minimiser of the condensed QP, no row changed
  CHECK(active_set.info().active_set_changes == 0);
}

TEST_CASE("random MPC-like QPs: the returned point satisfies the KKT conditions") {
  std::mt19937 rng(11);
  for (int N : {5, 15, 45}) {
    for (int rep = 0; rep < 3; ++rep) {
      Vector x0;
      OcpQp qp = random_like(N, rng, x0);
      REQUIRE(qp.validate().empty());
      FastMpcSolver solver(qp.dims);
      CAPTURE(N);
      CAPTURE(rep);
      REQUIRE(solver.solve(qp, x0) == Status::Solved);
      const Kkt k = kkt(qp, x0, solver.x(), solver.u(), solver.lambda(), solver.pi());
      CHECK(k.primal < 1e-8);
      CHECK(k.dual_sign < 1e-12);
      CHECK(k.stationarity < 1e-8);
      CHECK(k.complementarity < 1e-8);
      CHECK(solver.info().objective == doctest::Approx(objective(qp, solver.x(), solver.u())).epsilon(1e-12));
      CHECK(solver.info().primal_residual < 1e-7);
      CHECK(solver.info().iterations < 40);
    }
  }
}

TEST_CASE("other state sizes (the generic code path) meet the KKT conditions too") {
  Vector x0;
  const OcpQp qp = planar_like(20, x0);
  for (Mode mode : {Mode::Converged, Mode::FixedBarrier}) {
    Settings s;
    s.mode = mode;
    s.barrier = 1e-6;
    FastMpcSolver solver(qp.dims, s);
    REQUIRE(solver.solve(qp, x0) == Status::Solved);
    const Kkt k = kkt(qp, x0, solver.x(), solver.u(), solver.lambda(), solver.pi());
    CHECK(k.primal < 1e-8);
    if (mode == Mode::Converged) {
      CHECK(k.stationarity < 1e-8);
      CHECK(k.complementarity < 1e-8);
    } else {
      CHECK(k.complementarity < 1e-5);  // lambda_j slack_j = kappa on every one of the 156 rows
    }
  }
}

TEST_CASE("docking: constant stage-0 rows that hold do not change the solution") {
  const int N = 12;
  OcpQp full = docking_like(N, 0.0);
  // The same QP without stage 0's x0-only rows (cone and velocity bounds on x0).
  OcpQpDims d = full.dims;
  d.nc[0] = 6;
  OcpQp reduced(d);
  reduced.A = full.A, reduced.B = full.B, reduced.b = full.b;
  reduced.Q = full.Q, reduced.q = full.q, reduced.R = full.R, reduced.r = full.r;
  reduced.C = full.C, reduced.D = full.D, reduced.d = full.d;
  reduced.C[0] = full.C[0].bottomRows(6);
  reduced.D[0] = full.D[0].bottomRows(6);
  reduced.d[0] = full.d[0].tail(6);
  const Vector x0 = docking_x0();
  FastMpcSolver a(full.dims), b(reduced.dims);
  REQUIRE(a.solve(full, x0) == Status::Solved);
  REQUIRE(b.solve(reduced, x0) == Status::Solved);
  CHECK(a.info().objective == doctest::Approx(b.info().objective).epsilon(1e-10));
  for (int i = 0; i <= N; ++i) CHECK((a.u()[i] - b.u()[i]).lpNorm<Eigen::Infinity>() < 1e-9);
  CHECK(a.info().iterations == b.info().iterations);

  // A row of x0 alone on its bound (equality) also holds: no disturbance either.
  OcpQp touching = full;
  touching.d[0](4) = x0(3);  // v_x <= v_x(0) exactly
  REQUIRE(a.solve(touching, x0) == Status::Solved);
  CHECK(a.info().objective == doctest::Approx(b.info().objective).epsilon(1e-10));
}

TEST_CASE("a violated constant row (x0 outside the docking cone) is infeasible at once") {
  OcpQp qp = docking_like(12, 0.0);
  Vector x0 = docking_x0();
  x0(0) = 5.0;  // 5 m off axis at 15 m range: outside the 8 deg cone
  for (Mode mode : {Mode::Converged, Mode::FixedBarrier}) {
    Settings s;
    s.mode = mode;
    FastMpcSolver solver(qp.dims, s);
    CHECK(solver.solve(qp, x0) == Status::Infeasible);
    CHECK(solver.info().iterations == 0);
  }
}

TEST_CASE("infeasible through the dynamics: a target beyond the reachable set") {
  // From 15 m out, closing at <= 0.1 m/s and with |dv| <= 0.0357 m/s per 5 s step, the chaser
  // cannot be 40 m further out (y <= -55 m) ten steps later: every row alone is satisfiable,
  // only the dynamics make them contradictory.
  const int N = 12;
  OcpQpDims dims = docking_like(N, 0.0).dims;
  dims.nc[10] += 1;
  OcpQp base = docking_like(N, 0.0), qp(dims);
  qp.A = base.A, qp.B = base.B, qp.b = base.b, qp.Q = base.Q, qp.q = base.q, qp.R = base.R, qp.r = base.r;
  qp.C = base.C, qp.D = base.D, qp.d = base.d;
  qp.C[10].conservativeResize(17, 6);
  qp.D[10].conservativeResize(17, 3);
  qp.d[10].conservativeResize(17);
  qp.C[10].row(16) << 0, 1, 0, 0, 0, 0;  // y <= -55
  qp.D[10].row(16).setZero();
  qp.d[10](16) = -55.0;
  REQUIRE(qp.validate().empty());
  const Vector x0 = docking_x0();
  for (Mode mode : {Mode::Converged, Mode::FixedBarrier}) {
    Settings s;
    s.mode = mode;
    s.max_iter = 100;
    FastMpcSolver solver(qp.dims, s);
    CHECK(solver.solve(qp, x0) == Status::Infeasible);
  }
  // The same row at a reachable distance (y <= -16 m) is fine.
  qp.d[10](16) = -16.0;
  FastMpcSolver solver(qp.dims);
  CHECK(solver.solve(qp, x0) == Status::Solved);
}

TEST_CASE("FixedBarrier: strictly feasible, and within m*kappa of the optimum") {
  std::mt19937 rng(3);
  for (int N : {5, 20}) {
    Vector x0;
    OcpQp qp = random_like(N, rng, x0);
    FastMpcSolver exact(qp.dims);
    REQUIRE(exact.solve(qp, x0) == Status::Solved);
    const double fstar = exact.info().objective;
    for (double kappa : {1e-2, 1e-4}) {
      FastMpcSolver fb(qp.dims, fixed_barrier_settings(kappa, 100));
      CAPTURE(N);
      CAPTURE(kappa);
      REQUIRE(fb.solve(qp, x0) == Status::Solved);
      CHECK(min_slack(qp, fb.x(), fb.u()) > 0.0);
      CHECK(fb.info().primal_residual < 1e-8);  // dynamics hold (no inequality is violated)
      // Barrier theory: the exact minimiser of f - kappa sum log(slack) on the dynamics has duality
      // gap m*kappa, so 0 <= f - f* <= m*kappa. The returned point meets the barrier problem to
      // relative tolerance 1e-8, hence the small allowance.
      const double m = total_rows(qp);
      const double allowance = 1e-7 * std::max(1.0, std::abs(fstar));
      CHECK(fb.info().objective - fstar >= -allowance);
      CHECK(fb.info().objective - fstar <= m * kappa + allowance);
    }
  }
}

TEST_CASE("FixedBarrier with a small cap keeps every warm-started plan strictly feasible") {
  // Wang and Boyd's use: a generous first solve, then a few Newton iterations per control period.
  const int N = 30;
  const OcpQp qp = docking_like(N, 0.0);
  FastMpcSolver fb(qp.dims, fixed_barrier_settings(1e-4, 60));
  Vector x = docking_x0();
  REQUIRE(fb.solve(qp, x) == Status::Solved);
  fb.settings().max_iter = 3;
  for (int step = 0; step < 10; ++step) {
    x = qp.A[0] * x + qp.B[0] * fb.u()[0];
    x(0) += 2e-3;  // navigation error, 2 mm radial
    fb.shift_warm_start();
    const Status st = fb.solve(qp, x);
    CAPTURE(step);
    REQUIRE((st == Status::MaxIter || st == Status::Solved));
    CHECK(min_slack(qp, fb.x(), fb.u()) > 0.0);
  }
}

TEST_CASE("warm start from the shifted plan takes fewer iterations over a closed loop") {
  const int N = 20;
  const OcpQp qp = docking_like(N, 0.0);
  for (Mode mode : {Mode::Converged, Mode::FixedBarrier}) {
    Settings s;
    s.mode = mode;
    s.barrier = 1e-3;
    s.max_iter = 60;
    s.active_set_max_inputs = 0;  // the interior point's warm start (the active set starts cold)
    Settings cold_settings = s;
    cold_settings.warm_start = false;
    FastMpcSolver warm(qp.dims, s), cold(qp.dims, cold_settings);
    Vector x = docking_x0();
    int warm_iters = 0, cold_iters = 0;
    for (int step = 0; step < 8; ++step) {
      REQUIRE(warm.solve(qp, x) == Status::Solved);
      REQUIRE(cold.solve(qp, x) == Status::Solved);
      CHECK(warm.info().objective == doctest::Approx(cold.info().objective).epsilon(1e-6));
      if (step > 0) warm_iters += warm.info().iterations, cold_iters += cold.info().iterations;
      // The plant follows the first input; the plan's tail is the next warm start.
      x = qp.A[0] * x + qp.B[0] * warm.u()[0];
      x(1) += 1e-3;  // a navigation error of 1 mm along-track
      warm.shift_warm_start();
    }
    CAPTURE(static_cast<int>(mode));
    CHECK(warm_iters < cold_iters);
    MESSAGE("iterations over 7 periods: warm " << warm_iters << ", cold " << cold_iters);
  }
}

TEST_CASE("bad input gives InvalidInput and never crashes") {
  const OcpQp good = docking_like(5, 0.0);
  const Vector x0 = docking_x0();
  FastMpcSolver solver(good.dims);
  REQUIRE(solver.solve(good, x0) == Status::Solved);

  OcpQp q1 = good;
  q1.A[2](3, 3) = std::numeric_limits<double>::quiet_NaN();
  CHECK(solver.solve(q1, x0) == Status::InvalidInput);
  OcpQp q2 = good;
  q2.d[5](0) = std::numeric_limits<double>::infinity();
  CHECK(solver.solve(q2, x0) == Status::InvalidInput);
  OcpQp q3 = good;
  q3.B[1].resize(6, 2);
  CHECK(solver.solve(q3, x0) == Status::InvalidInput);
  OcpQp q4 = good;
  q4.R.pop_back();
  CHECK(solver.solve(q4, x0) == Status::InvalidInput);
  CHECK(solver.solve(good, Vector::Zero(5)) == Status::InvalidInput);
  Vector xnan = x0;
  xnan(2) = std::nan("");
  CHECK(solver.solve(good, xnan) == Status::InvalidInput);
  const OcpQp other = docking_like(6, 0.0);  // another horizon than the workspace's
  CHECK(solver.solve(other, x0) == Status::InvalidInput);
  CHECK(solver.info().status == Status::InvalidInput);
  // Still usable afterwards.
  CHECK(solver.solve(good, x0) == Status::Solved);

  solver.settings().tol = -1.0;
  CHECK(solver.solve(good, x0) == Status::InvalidInput);
  solver.settings().tol = 1e-8;
  solver.settings().warm_step_to_boundary = 1.0;  // a step onto the boundary
  CHECK(solver.solve(good, x0) == Status::InvalidInput);
  solver.settings().warm_step_to_boundary = 0.97;
  solver.settings().corrector_band = 0.5;  // an empty band
  CHECK(solver.solve(good, x0) == Status::InvalidInput);
  solver.settings().corrector_band = 5.0;
  CHECK(solver.solve(good, x0) == Status::Solved);

  OcpQpDims bad_dims = good.dims;
  bad_dims.nu.pop_back();
  FastMpcSolver broken(bad_dims);
  CHECK(broken.solve(good, x0) == Status::InvalidInput);
  CHECK(broken.x().empty());
  broken.shift_warm_start();  // harmless
}

TEST_CASE("the time limit stops the iterations and says so") {
  std::mt19937 rng(5);
  Vector x0;
  const OcpQp qp = random_like(45, rng, x0);
  FastMpcSolver solver(qp.dims);
  // A budget of one nanosecond, less than one clock tick of the work done before the first check
  // (the row preparation alone takes microseconds): spent on any machine, and a loaded machine only
  // spends it sooner. No elapsed time is asserted; only that the check stops the iterations.
  solver.settings().time_limit_us = 1e-3;
  CHECK(solver.solve(qp, x0) == Status::TimeLimit);
  CHECK(solver.info().iterations <= 1);
  for (const Vector& v : solver.x()) CHECK(v.allFinite());
  CHECK(std::string(to_string(Status::TimeLimit)) == "time_limit");
  solver.settings().time_limit_us = 0.0;
  CHECK(solver.solve(qp, x0) == Status::Solved);
}

TEST_CASE("the iteration cap gives MaxIter on a feasible QP, not Infeasible") {
  std::mt19937 rng(9);
  Vector x0;
  const OcpQp qp = random_like(15, rng, x0);
  Settings s;
  s.max_iter = 3;
  FastMpcSolver solver(qp.dims, s);
  CHECK(solver.solve(qp, x0) == Status::MaxIter);
  CHECK(solver.info().iterations >= 3);
}
