// Infeasibility from the interior-point iterates: a Farkas certificate.
//
// Write the hard rows and the dynamics as Cin z <= din, Aeq z = beq over z = (u_0, x_1, u_1, ...,
// x_N, u_N) (x0 is data). They admit no z exactly when some y = (pi, lam), lam >= 0, has
//   Aeq'pi + Cin'lam = 0   and   V = beq'pi + din'lam < 0.
// Given the row multipliers, the x-part of Aeq'pi + Cin'lam = 0 fixes pi by a backward
// recursion (pi_{i-1} = A_i'pi_i + C_i'lam_i), and the u-part is cancelled by the multipliers of
// the inputs' bound rows (|u| <= u_max). So a candidate lam of the other rows yields an exact
// certificate whenever V < 0, with residual r only on inputs that have no bound rows; then
// |V| > |r|_inf R proves that no feasible z has |z|_1 <= R, and we ask R = certificate_reach x the
// iterate's size. On a QP without solution the duals of the infeasible-start interior point grow
// along such a direction while its primal residual stalls: the dual iterate (or its last step) is
// the candidate. Soft rows are never part of it (their slack absorbs any violation).
#include <algorithm>
#include <cmath>
#ifdef RVD_SOLVER_TRACE
#include <cstdio>
#endif

#include "flight_sw/solver/fast_mpc.hpp"
#include "flight_sw/solver/kkt.hpp"

namespace rvd::solver {

namespace {
using detail::Workspace;
using MapV = Eigen::Map<Vector>;
using MapCV = Eigen::Map<const Vector>;

struct Farkas {
  double residual, value, magnitude;  // |r|_inf, V, the size of V's terms (rounding)
};
// The certificate built from the multipliers lam of the hard rows (bound rows of inputs excluded:
// they are set here). Uses vrow (row multipliers), gx (pi), gu (input residual), spare.du as scratch.
Farkas farkas(Workspace& w, const OcpQp& qp, const double* lam) {
  const int N = w.N, n = w.nx;
  for (int k = 0; k < w.rows; ++k) w.vrow[k] = w.act[k] * (1.0 - w.soft[k]) * std::max(lam[k], 0.0);
  for (int c = 0; c < w.inputs; ++c) {
    if (w.ub_row[c] >= 0) w.vrow[w.ub_row[c]] = 0.0;
    if (w.lb_row[c] >= 0) w.vrow[w.lb_row[c]] = 0.0;
  }
  // pi_{i-1} = A_i'pi_i + C_i'lam_i, backwards from pi_{N-1} = C_N'lam_N; stored in gx + (i-1) n.
  for (int i = N; i >= 1; --i) {
    MapV p(w.gx + (i - 1) * n, n);
    if (i < N)
      p.noalias() = qp.A[i].transpose().lazyProduct(MapCV(w.gx + i * n, n));
    else
      p.setZero();
    detail::gt_mul_add(w, i, w.vrow, w.spare.du + w.uo[i], w.gx + (i - 1) * n);  // input part: scratch
  }
  double r = 0.0, V = 0.0, mag = 0.0;
  const MapCV x0(w.x, n);
  for (int i = 0; i <= N; ++i) {
    const int m = w.nu[i];
    MapV gu(w.gu + w.uo[i], m);
    gu.setZero();
    if (i < N) {
      const MapCV p(w.gx + i * n, n);
      gu.noalias() += qp.B[i].transpose().lazyProduct(p);
      double pax0 = 0.0;  // pi_0' A_0 x0 (x0 is data: it moves to the right-hand side)
      if (i == 0)
        for (int c = 0; c < n; ++c) pax0 += x0(c) * qp.A[0].col(c).dot(p);
      const double pb = qp.b[i].dot(p);
      V -= pb + pax0;
      mag += std::abs(pb) + std::abs(pax0);
    }
    detail::gt_mul_add(w, i, w.vrow, w.gu + w.uo[i], nullptr);
    // Cancel the input residual with the bound row of the right sign.
    for (int c = 0; c < m; ++c) {
      const int j = w.uo[i] + c;
      const double rho = w.gu[j];
      const int row = rho > 0.0 ? w.lb_row[j] : w.ub_row[j];
      if (rho == 0.0 || row < 0) continue;
      const double lam_b = std::abs(rho / w.val[w.ptr[row]]);
      w.vrow[row] = lam_b;
      w.gu[j] = 0.0;
    }
    for (int j = 0; j < w.nc[i]; ++j) {
      const int k = w.ro[i] + j;
      if (w.vrow[k] == 0.0) continue;
      const double rhs = w.dv[k] - (i == 0 ? qp.C[0].row(j).dot(x0) : 0.0);
      V += w.vrow[k] * rhs;
      mag += std::abs(w.vrow[k] * rhs);
    }
    if (m > 0) r = std::max(r, gu.cwiseAbs().maxCoeff());
  }
  return {r, V, mag};
}
}  // namespace

bool FastMpcSolver::infeasibility_certificate(const OcpQp& qp) {
  Workspace& w = *work_;
  double z1 = 0.0;
  for (int k = 0; k < w.inputs; ++k) z1 += std::abs(w.u[k]);
  for (int k = w.nx; k < (w.N + 1) * w.nx; ++k) z1 += std::abs(w.x[k]);
  const double reach = settings_.certificate_reach * std::max(1.0, z1);
  auto proves = [&](const Farkas& f) { return f.value < 0.0 && -f.value > f.residual * reach && -f.value > 1e-9 * f.magnitude; };
  const Farkas a = farkas(w, qp, w.lam);
#ifdef RVD_SOLVER_TRACE
  std::fprintf(stderr, "   certificate: iterate V=%.3e |r|=%.3e reach=%.3e\n", a.value, a.residual, reach);
#endif
  if (proves(a)) return true;
  const Farkas b = farkas(w, qp, w.step.dlam);
#ifdef RVD_SOLVER_TRACE
  std::fprintf(stderr, "   certificate: step V=%.3e |r|=%.3e\n", b.value, b.residual);
#endif
  return proves(b);
}

}  // namespace rvd::solver
