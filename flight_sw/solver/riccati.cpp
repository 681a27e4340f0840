// Stage kernels of the Newton system: residuals, the Riccati factorisation and back-solve,
// rollout, cost. Compiled twice: with nx = 6 and nu in {0, 3} fixed (the guidance's every phase
// and variant) and with dynamic sizes (any other shape).
//
// Structure used:
//  - B_i = A_i [0; I] (impulsive CW: a delta-v enters as the velocity at the start of the period)
//    is detected per solve. Then B'PB and B'PA are blocks of A'PA, B'v = (A'v) tail and
//    A x + B u = A (x + [0; u]): one product with A instead of three.
//  - Q_i, R_i diagonal (detected per solve): diagonal products.
//  - rows are compressed (a box row has one nonzero, a cone facet three), so G'WG and G z cost
//    their nonzeros.
//  - soft rows: the slack s of row k (t = d + s - g'z, s >= 0, multipliers lam, mu) is eliminated
//    from the Newton system row by row: with w = lam/t and h = Zs + w + mu/s the row enters the
//    Riccati recursion with weight w (Zs + mu/s) / h instead of w, a diagonal change.
#include <Eigen/Dense>

#include <algorithm>

#include "flight_sw/solver/kkt.hpp"

namespace rvd::solver::detail {

namespace {
template <int R, int C>
using Mat = Eigen::Matrix<double, R, C>;
template <int R, int C>
using MapM = Eigen::Map<Mat<R, C>>;
template <int R, int C>
using MapCM = Eigen::Map<const Mat<R, C>>;
template <int R>
using MapV = Eigen::Map<Mat<R, 1>>;
template <int R>
using MapCV = Eigen::Map<const Mat<R, 1>>;

// Exactly B = A [0; I]: the inputs are the last nu state components' increments.
bool is_a_tail(const Matrix& A, const Matrix& B) {
  const int n = static_cast<int>(A.rows()), m = static_cast<int>(B.cols());
  if (m == 0 || m > n) return false;
  for (int c = 0; c < m; ++c)
    for (int r = 0; r < n; ++r)
      if (B(r, c) != A(r, n - m + c)) return false;
  return true;
}
bool is_diagonal(const Matrix& M) {
  for (int c = 0; c < M.cols(); ++c)
    for (int r = 0; r < M.rows(); ++r)
      if (r != c && M(r, c) != 0.0) return false;
  return true;
}

// Cholesky of the leading m x m block in place (lower triangle); false if not positive definite.
template <int NU>
bool cholesky(MapM<NU, NU>& Z, int m) {
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
template <class L, class V>
void lower_solve(const L& Lm, int m, V&& v) {  // v <- L^-1 v
  for (int r = 0; r < m; ++r) {
    double acc = v(r);
    for (int k = 0; k < r; ++k) acc -= Lm(r, k) * v(k);
    v(r) = acc / Lm(r, r);
  }
}
template <class L, class V>
void lower_t_solve(const L& Lm, int m, V&& v) {  // v <- L^-T v
  for (int r = m - 1; r >= 0; --r) {
    double acc = v(r);
    for (int k = r + 1; k < m; ++k) acc -= Lm(k, r) * v(k);
    v(r) = acc / Lm(r, r);
  }
}

template <int NX, int NU>
struct StageKernels {
  // The sizes, compile-time constants in the fixed instances (so the hand-written loops below unroll).
  static int dim_x(const Workspace& w) { return NX == Eigen::Dynamic ? w.nx : NX; }
  static int dim_u(const Workspace& w, int i) { return NU == Eigen::Dynamic ? w.nu[i] : NU; }
  // H u for the stage's R (diagonal when flagged); out = r + R u.
  template <class Out>
  static void grad_u(const Workspace& w, const OcpQp& qp, int i, const double* u, Out& out) {
    const int m = dim_u(w, i);
    const MapCV<NU> ui(u, m);
    out = MapCV<NU>(qp.r[i].data(), m);
    if (w.r_diag[i])
      out.array() += qp.R[i].diagonal().array() * ui.array();
    else
      out.noalias() += MapCM<NU, NU>(qp.R[i].data(), m, m).lazyProduct(ui);
  }
  template <class Out>
  static void grad_x(const Workspace& w, const OcpQp& qp, int i, const double* x, Out& out) {
    const int n = dim_x(w);
    const MapCV<NX> xi(x, n);
    out = MapCV<NX>(qp.q[i].data(), n);
    if (w.q_diag[i])
      out.array() += qp.Q[i].diagonal().array() * xi.array();
    else
      out.noalias() += MapCM<NX, NX>(qp.Q[i].data(), n, n).lazyProduct(xi);
  }
  // out = A x + B u (+ b when with_b).
  template <class Out>
  static void dynamics(const Workspace& w, const OcpQp& qp, int i, const double* x, const double* u, Out& out,
                       double* scratch) {
    const int n = dim_x(w), m = dim_u(w, i);
    const MapCM<NX, NX> A(qp.A[i].data(), n, n);
    if (w.b_tail[i]) {
      MapV<NX> xs(scratch, n);
      xs = MapCV<NX>(x, n);
      xs.tail(m) += MapCV<NU>(u, m);
      out.noalias() += A.lazyProduct(xs);
    } else {
      out.noalias() += A.lazyProduct(MapCV<NX>(x, n));
      if (m > 0) out.noalias() += MapCM<NX, NU>(qp.B[i].data(), n, m).lazyProduct(MapCV<NU>(u, m));
    }
  }
  // at = A' v; bu = B' v (from at when B is A's tail).
  template <class Out>
  static void dyn_transpose_add(const Workspace& w, const OcpQp& qp, int i, const double* v, double* out_x,
                                Out&& out_u, bool want_x) {
    const int n = dim_x(w), m = dim_u(w, i);
    const MapCM<NX, NX> A(qp.A[i].data(), n, n);
    const MapCV<NX> vi(v, n);
    if (w.b_tail[i]) {
      MapV<NX> at(w.tn, n);
      at.noalias() = A.transpose().lazyProduct(vi);
      if (want_x) MapV<NX>(out_x, n) += at;
      out_u += at.tail(m);
    } else {
      if (want_x) MapV<NX>(out_x, n).noalias() += A.transpose().lazyProduct(vi);
      if (m > 0) out_u.noalias() += MapCM<NX, NU>(qp.B[i].data(), n, m).transpose().lazyProduct(vi);
    }
  }

  static void residuals(Workspace& w, const OcpQp& qp, int i, const double* x, const double* u, const double* pi,
                        const double* lam, double& gscale) {
    const int n = dim_x(w), m = dim_u(w, i), N = w.N;
    const double* xi = x + i * n;
    const double* ui = u + w.uo[i];
    MapV<NU> rdu(w.rdu + w.uo[i], m);
    if (m > 0) {
      grad_u(w, qp, i, ui, rdu);
      gscale = std::max(gscale, rdu.cwiseAbs().maxCoeff());
    }
    double* rdx = w.rdx + i * n;
    if (i > 0) {
      MapV<NX> rx(rdx, n);
      grad_x(w, qp, i, xi, rx);
      // The costates are terms of the same sum: with many tight rows they exceed the cost gradient by
      // 1e3, and a dual residual measured against the gradient alone never met tol (README).
      const MapCV<NX> pi_prev(pi + (i - 1) * n, n);
      gscale = std::max({gscale, rx.cwiseAbs().maxCoeff(), pi_prev.cwiseAbs().maxCoeff()});
      rx -= pi_prev;
    }
    if (i < N) dyn_transpose_add(w, qp, i, pi + i * n, rdx, rdu, i > 0);
    gt_mul_add(w, i, lam, w.rdu + w.uo[i], i > 0 ? rdx : nullptr);
    if (i < N) {
      MapV<NX> r(w.rdyn + i * n, n);
      r = MapCV<NX>(qp.b[i].data(), n) - MapCV<NX>(x + (i + 1) * n, n);
      dynamics(w, qp, i, xi, ui, r, w.tm);
    }
  }

  static bool factor(Workspace& w, const OcpQp& qp, int i, double reg) {
    const int n = dim_x(w), m = dim_u(w, i), N = w.N;
    MapM<NU, NU> Muu(w.L + w.lo[i], m, m);
    MapM<NU, NX> Mux(w.Y + w.uo[i] * n, m, n);
    MapM<NX, NX> Mxx(w.P + i * n * n, n, n);
    // The cost-to-go's terms are written (not added to zeroed blocks), then Q and R added.
    if (i < N && i > 0) {
      const MapCM<NX, NX> P1(w.P + (i + 1) * n * n, n, n);
      const MapCM<NX, NX> A(qp.A[i].data(), n, n);
      MapM<NX, NX> PA(w.s_xx, n, n);
      PA.noalias() = P1.lazyProduct(A);
      // A'PA (symmetric: the lower triangle, mirrored); B'PB and B'PA are its blocks when B = A [0; I].
      for (int c = 0; c < n; ++c)
        for (int r = c; r < n; ++r) Mxx(r, c) = Mxx(c, r) = A.col(r).dot(PA.col(c));
      if (m > 0) {
        if (w.b_tail[i]) {
          Muu = Mxx.bottomRightCorner(m, m);
          Mux = Mxx.bottomRows(m);
        } else {
          const MapCM<NX, NU> B(qp.B[i].data(), n, m);
          MapM<NX, NU> PB(w.s_ux, n, m);
          PB.noalias() = P1.lazyProduct(B);
          Muu.noalias() = B.transpose().lazyProduct(PB);
          Mux.noalias() = B.transpose().lazyProduct(PA);
        }
      }
    } else {
      if (i > 0) Mxx.setZero();
      if (m > 0) {
        Mux.setZero();
        if (i < N) {  // stage 0: x0 is fixed, only the input block matters
          const MapCM<NX, NX> P1(w.P + (i + 1) * n * n, n, n);
          const MapCM<NX, NU> B(qp.B[i].data(), n, m);
          MapM<NX, NU> PB(w.s_ux, n, m);
          PB.noalias() = P1.lazyProduct(B);
          Muu.noalias() = B.transpose().lazyProduct(PB);
        } else {
          Muu.setZero();
        }
      }
    }
    if (m > 0) {
      if (w.r_diag[i])
        Muu.diagonal() += qp.R[i].diagonal();
      else
        Muu += MapCM<NU, NU>(qp.R[i].data(), m, m);
    }
    if (i > 0) {
      if (w.q_diag[i])
        Mxx.diagonal() += qp.Q[i].diagonal();
      else
        Mxx += MapCM<NX, NX>(qp.Q[i].data(), n, n);
    }
    // G'WG over the nonzeros (stage 0: only the input block).
    for (int k = w.ro[i]; k < w.ro[i + 1]; ++k) {
      const double wk = w.weff[k];
      if (wk == 0.0) continue;
      const int b0 = w.ptr[k], bm = w.mid[k], be = i == 0 ? w.mid[k] : w.ptr[k + 1];
      if (be - b0 == 1) {  // a bound row: one diagonal entry
        const double v = w.val[b0];
        if (b0 < bm)
          Muu(w.col[b0], w.col[b0]) += wk * v * v;
        else
          Mxx(w.col[b0], w.col[b0]) += wk * v * v;
        continue;
      }
      for (int a = b0; a < be; ++a) {
        const double wa = wk * w.val[a];
        const int ca = w.col[a];
        if (a < bm) {
          for (int b = b0; b < bm; ++b) Muu(ca, w.col[b]) += wa * w.val[b];
          for (int b = bm; b < be; ++b) Mux(ca, w.col[b]) += wa * w.val[b];
        } else {
          for (int b = bm; b < be; ++b) Mxx(ca, w.col[b]) += wa * w.val[b];
        }
      }
    }
    if (m > 0) {
      Muu.diagonal().array() += reg;
      if (!cholesky<NU>(Muu, m)) return false;
      if (i > 0) {
        for (int c = 0; c < n; ++c) lower_solve(Muu, m, Mux.col(c));  // Y = L^-1 S_ux
        for (int c = 0; c < n; ++c)                                    // P_i = M_xx - Y'Y (symmetric)
          for (int r = c; r < n; ++r) {
            const double yy = Mux.col(r).dot(Mux.col(c));
            Mxx(r, c) -= yy;
            if (r != c) Mxx(c, r) -= yy;
          }
      }
    }
    return true;
  }

  static void backward(Workspace& w, const OcpQp& qp, int i, const double* c) {
    const int n = dim_x(w), m = dim_u(w, i), N = w.N;
    MapV<NU> l(w.l + w.uo[i], m);
    if (m > 0) l = MapCV<NU>(w.gu + w.uo[i], m);
    MapV<NX> p(w.p + i * n, n);
    if (i > 0) p = MapCV<NX>(w.gx + i * n, n);
    if (i < N) {
      MapV<NX> v(w.s_xx, n);  // p_{i+1} + P_{i+1} c_i
      v.noalias() = MapCV<NX>(w.p + (i + 1) * n, n) + MapCM<NX, NX>(w.P + (i + 1) * n * n, n, n).lazyProduct(MapCV<NX>(c + i * n, n));
      dyn_transpose_add(w, qp, i, w.s_xx, w.p + i * n, l, i > 0);
    }
    if (m > 0) {
      const MapCM<NU, NU> Lm(w.L + w.lo[i], m, m);
      lower_solve(Lm, m, l);
      if (i > 0) p.noalias() -= MapCM<NU, NX>(w.Y + w.uo[i] * n, m, n).transpose().lazyProduct(l);
    }
  }
  static void forward(Workspace& w, const OcpQp& qp, int i, const double* c, Step& s) {
    const int n = dim_x(w), m = dim_u(w, i), N = w.N;
    MapV<NU> du(s.du + w.uo[i], m);
    if (m > 0) {
      du = MapCV<NU>(w.l + w.uo[i], m);
      if (i > 0) du.noalias() += MapCM<NU, NX>(w.Y + w.uo[i] * n, m, n).lazyProduct(MapCV<NX>(s.dx + i * n, n));
      lower_t_solve(MapCM<NU, NU>(w.L + w.lo[i], m, m), m, du);
      du = -du;
    }
    if (i < N) {
      MapV<NX> dx1(s.dx + (i + 1) * n, n);
      dx1 = MapCV<NX>(c + i * n, n);
      dynamics(w, qp, i, s.dx + i * n, s.du + w.uo[i], dx1, w.tm);
      MapV<NX>(s.dpi + i * n, n).noalias() =
          MapCV<NX>(w.p + (i + 1) * n, n) + MapCM<NX, NX>(w.P + (i + 1) * n * n, n, n).lazyProduct(dx1);
    }
  }
  static double cost(const Workspace& w, const OcpQp& qp, int i, const double* x, const double* u) {
    const int n = dim_x(w), m = dim_u(w, i);
    double f = 0.0;
    MapV<NX> g(w.tn, n);
    grad_x(w, qp, i, x + i * n, g);  // q + Q x: f = (q + (q + Q x))' x / 2
    f += 0.5 * (g + MapCV<NX>(qp.q[i].data(), n)).dot(MapCV<NX>(x + i * n, n));
    if (m > 0) {
      MapV<NU> gu(w.tm, m);
      grad_u(w, qp, i, u + w.uo[i], gu);
      f += 0.5 * (gu + MapCV<NU>(qp.r[i].data(), m)).dot(MapCV<NU>(u + w.uo[i], m));
    }
    return f;
  }
  // Stationarity and dynamics residual of the unreduced system at step s, into gu/gx and edyn.
  static void step_error(Workspace& w, const OcpQp& qp, int i, const Step& s, double& ed, double& ep) {
    const int n = dim_x(w), m = dim_u(w, i), N = w.N;
    MapV<NU> gu(w.gu + w.uo[i], m);
    if (m > 0) {
      grad_u(w, qp, i, s.du + w.uo[i], gu);
      gu += MapCV<NU>(w.rdu + w.uo[i], m) - MapCV<NU>(qp.r[i].data(), m);
    }
    double* gx = w.gx + i * n;
    if (i > 0) {
      MapV<NX> g(gx, n);
      grad_x(w, qp, i, s.dx + i * n, g);
      g += MapCV<NX>(w.rdx + i * n, n) - MapCV<NX>(qp.q[i].data(), n) - MapCV<NX>(s.dpi + (i - 1) * n, n);
    }
    if (i < N) dyn_transpose_add(w, qp, i, s.dpi + i * n, gx, gu, i > 0);
    gt_mul_add(w, i, s.dlam, w.gu + w.uo[i], i > 0 ? gx : nullptr);
    if (m > 0) ed = std::max(ed, gu.cwiseAbs().maxCoeff());
    if (i > 0) ed = std::max(ed, MapV<NX>(gx, n).cwiseAbs().maxCoeff());
    if (i < N) {
      MapV<NX> e(w.edyn + i * n, n);
      e = MapCV<NX>(w.rdyn + i * n, n) - MapCV<NX>(s.dx + (i + 1) * n, n);
      dynamics(w, qp, i, s.dx + i * n, s.du + w.uo[i], e, w.tm);
      ep = std::max(ep, e.cwiseAbs().maxCoeff());
    }
  }
};

// Per-stage dispatch: the fixed instance has nu = 3 on stages 0..N-1 and 0 or 3 on stage N.
template <int NX, int NU>
struct Solver {
  // Stages without inputs (the terminal one) get their own instance when sizes are fixed.
  static constexpr int kNone = NU == Eigen::Dynamic ? Eigen::Dynamic : 0;
  static void residuals(Workspace& w, const OcpQp& qp, const double* x, const double* u, const double* pi,
                        const double* lam) {
    double gscale = 0.0;
    for (int i = 0; i <= w.N; ++i) {
      if (w.nu[i] == 0)
        StageKernels<NX, kNone>::residuals(w, qp, i, x, u, pi, lam, gscale);
      else
        StageKernels<NX, NU>::residuals(w, qp, i, x, u, pi, lam, gscale);
    }
    g_mul_all(w, u, x, w.gz);
    double cscale = w.d_max;
    for (int k = 0; k < w.rows; ++k) cscale = std::max(cscale, std::abs(w.gz[k]) * w.act[k]);
    w.grad_scale = std::max({1.0, gscale, w.zs_max});
    w.cons_scale = std::max(1.0, cscale);
  }
  static bool factorize(Workspace& w, const OcpQp& qp, double reg) {
    for (int i = w.N; i >= 0; --i) {
      const bool ok = w.nu[i] == 0 ? StageKernels<NX, kNone>::factor(w, qp, i, reg) : StageKernels<NX, NU>::factor(w, qp, i, reg);
      if (!ok) return false;
    }
    return true;
  }
  static void back_solve(Workspace& w, const OcpQp& qp, const double* c, Step& s) {
    for (int i = w.N; i >= 0; --i) {
      if (w.nu[i] == 0)
        StageKernels<NX, kNone>::backward(w, qp, i, c);
      else
        StageKernels<NX, NU>::backward(w, qp, i, c);
    }
    for (int k = 0; k < w.nx; ++k) s.dx[k] = 0.0;
    for (int i = 0; i <= w.N; ++i) {
      if (w.nu[i] == 0)
        StageKernels<NX, kNone>::forward(w, qp, i, c, s);
      else
        StageKernels<NX, NU>::forward(w, qp, i, c, s);
    }
  }
  static void rollout(Workspace& w, const OcpQp& qp, double* x, const double* u) {
    const int n = w.nx;
    for (int i = 0; i < w.N; ++i) {
      MapV<NX> x1(x + (i + 1) * n, n);
      x1 = MapCV<NX>(qp.b[i].data(), n);
      if (w.nu[i] == 0)
        StageKernels<NX, kNone>::dynamics(w, qp, i, x + i * n, u + w.uo[i], x1, w.tm);
      else
        StageKernels<NX, NU>::dynamics(w, qp, i, x + i * n, u + w.uo[i], x1, w.tm);
    }
  }
  static double cost(Workspace& w, const OcpQp& qp, const double* x, const double* u) {
    double f = 0.0;
    for (int i = 0; i <= w.N; ++i)
      f += w.nu[i] == 0 ? StageKernels<NX, kNone>::cost(w, qp, i, x, u) : StageKernels<NX, NU>::cost(w, qp, i, x, u);
    return f;
  }
  static double step_error(Workspace& w, const OcpQp& qp, const Step& s) {
    double ed = 0.0, ep = 0.0;
    for (int i = 0; i <= w.N; ++i) {
      if (w.nu[i] == 0)
        StageKernels<NX, kNone>::step_error(w, qp, i, s, ed, ep);
      else
        StageKernels<NX, NU>::step_error(w, qp, i, s, ed, ep);
    }
    return std::max(ed / w.grad_scale, ep / w.cons_scale);
  }
};

template <int NX, int NU>
const Kernels kKernels = {&Solver<NX, NU>::residuals, &Solver<NX, NU>::factorize, &Solver<NX, NU>::back_solve,
                          &Solver<NX, NU>::rollout,   &Solver<NX, NU>::cost,      &Solver<NX, NU>::step_error};
}  // namespace

const Kernels& kernels_for(const Workspace& w) {
  if (w.fixed_kernels) return kKernels<6, 3>;
  return kKernels<Eigen::Dynamic, Eigen::Dynamic>;
}

void prepare_step_rows(Workspace& w) {
  StepRows& s = w.srows;
  s.n_bu = s.n_bx = s.n_gen = 0;
  for (int i = 0; i <= w.N; ++i)
    for (int k = w.ro[i]; k < w.ro[i + 1]; ++k) {
      const int b0 = w.ptr[k], bm = w.mid[k], be = i == 0 ? bm : w.ptr[k + 1];
      if (be - b0 == 1 && bm - b0 == 1) {
        s.bu_row[s.n_bu] = k, s.bu_idx[s.n_bu] = w.uo[i] + w.col[b0], s.bu_val[s.n_bu++] = w.val[b0];
      } else if (be - b0 == 1) {
        s.bx_row[s.n_bx] = k, s.bx_idx[s.n_bx] = i * w.nx + w.col[b0], s.bx_val[s.n_bx++] = w.val[b0];
      } else {
        s.gen_row[s.n_gen] = k, s.gen_uo[s.n_gen] = w.uo[i], s.gen_xo[s.n_gen] = i * w.nx, s.gen_end[s.n_gen++] = be;
      }
    }
}

bool prepare_rows(Workspace& w, const OcpQp& qp, double tol) {
  bool ok = true;
  w.rows_active = w.soft_active = 0;
  w.const_soft = w.d_max = w.zs_max = 0.0;
  int nz = 0;
  for (int i = 0; i <= w.N; ++i) {
    if (i < w.N) w.b_tail[i] = is_a_tail(qp.A[i], qp.B[i]);
    w.q_diag[i] = is_diagonal(qp.Q[i]);
    w.r_diag[i] = is_diagonal(qp.R[i]);
    const int r0 = w.ro[i], m = w.nu[i];
    for (int j = 0; j < w.nc[i]; ++j) {
      w.soft[r0 + j] = 0.0;
      w.zs[r0 + j] = w.Zs[r0 + j] = 0.0;
    }
    for (int k = 0; k < qp.dims.soft_rows(i); ++k) {
      const int j = qp.idxs[i][k];
      w.soft[r0 + j] = 1.0;
      w.zs[r0 + j] = qp.zs[i](k);
      w.Zs[r0 + j] = qp.Zs[i](k);
    }
    for (int j = 0; j < w.nc[i]; ++j) {
      const int k = r0 + j;
      w.dv[k] = qp.d[i](j);
      w.ptr[k] = w.mid[k] = nz;
      bool any = false;
      for (int c = 0; c < m; ++c)
        if (qp.D[i](j, c) != 0.0) w.col[nz] = c, w.val[nz++] = qp.D[i](j, c), any = true;
      w.mid[k] = nz;
      for (int c = 0; c < w.nx; ++c)
        if (qp.C[i](j, c) != 0.0) {
          w.col[nz] = c, w.val[nz++] = qp.C[i](j, c);
          any = any || i > 0;
        }
      if (any) {
        w.act[k] = 1.0;
        ++w.rows_active;
        w.d_max = std::max(w.d_max, std::abs(w.dv[k]));
        if (w.soft[k] > 0.0) ++w.soft_active, w.zs_max = std::max(w.zs_max, w.zs[k]);
        continue;
      }
      // Constant row: on stage 0, C x0 <= d is data; a hard one that fails makes the QP infeasible,
      // a soft one costs its penalty at the violation.
      w.act[k] = 0.0;
      const double lhs = i == 0 ? qp.C[0].row(j).dot(Eigen::Map<const Vector>(w.x, w.nx)) : 0.0;
      const double viol = lhs - w.dv[k];
      if (w.soft[k] > 0.0) {
        const double s = std::max(viol, 0.0);
        w.const_soft += s * (w.zs[k] + 0.5 * w.Zs[k] * s);
        w.soft[k] = 0.0;
        w.sig[k] = s;
      } else if (viol > tol * (1.0 + std::abs(lhs) + std::abs(w.dv[k]))) {
        ok = false;
      }
    }
    w.ptr[r0 + w.nc[i]] = nz;
    // Hard bound rows of single inputs (a u_j <= d): the certificate test cancels input residuals with them.
    for (int c = 0; c < m; ++c) w.ub_row[w.uo[i] + c] = w.lb_row[w.uo[i] + c] = -1;
    for (int j = 0; j < w.nc[i]; ++j) {
      const int k = r0 + j;
      if (w.act[k] == 0.0 || w.soft[k] > 0.0 || w.mid[k] - w.ptr[k] != 1 || w.ptr[k + 1] != w.mid[k]) continue;
      const int c = w.uo[i] + w.col[w.ptr[k]];
      const double a = w.val[w.ptr[k]], bound = w.dv[k] / a;
      int& slot = a > 0.0 ? w.ub_row[c] : w.lb_row[c];
      if (slot < 0) {
        slot = k;
      } else {
        const double old = w.dv[slot] / w.val[w.ptr[slot]];
        if (a > 0.0 ? bound < old : bound > old) slot = k;
      }
    }
  }
  return ok;
}

}  // namespace rvd::solver::detail
