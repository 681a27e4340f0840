// The dual active-set method on the condensed QP (Goldfarb & Idnani 1983; the recursive
// factorisation updates of DAQP: Arnstrom, Bemporad & Axehill 2022), for QPs with few inputs.
//
// With H = L L' and v = L'u the condensed QP is min 1/2|v|^2 + c'v s.t. m_k'v <= h_k
// (c = L^-1 f, m_k = L^-1 gbar_k). Its dual, min 1/2|c + M lam|^2 + h'lam over 0 <= lam <= ub,
// is solved by a primal active-set method: the multipliers of the working set W are free, the
// others sit at a bound. Its gradient is the primal slack s = h - M'v with v = -(c + M lam), so a
// row with lam = 0 and s < 0 (violated) or lam = ub and s > 0 enters W; a multiplier that leaves
// [0, ub] on the way to the subproblem's minimiser is stopped at the bound and its row leaves W.
// Hard rows have ub = inf. A soft row with linear penalty zs (and Zs = 0) has ub = zs: at lam = zs
// it is violated by s = g'z - d >= 0 and adds zs g to the gradient, exactly the penalty zs s.
// (Soft rows with Zs > 0 stay on the interior point.) The Gram matrix M_W'M_W keeps a Cholesky
// factor, updated by one row per entering row and by Givens rotations per leaving row.
// The method never forms v: the primal point is kept in inputs, u = L^-T v = uc - U_W lam with
// uc = -L^-T c and U_k = L^-T m_k = H^-1 gbar_k (a sum of the row's nonzeros' columns of H^-1 and
// H^-1 Gamma_i'), and a slack e_k = h_k + m_k'c is the row's slack d_k - g_k'z at u = uc. So a primal
// point costs O(|W| n) and a rollout, not a triangular solve of O(n^2) as well.
// A row that enters linearly dependent on W leaves the Gram matrix singular: the multipliers then
// move along the null-space direction p (M p = 0: the primal point stays) until one reaches a
// bound; when none ever does (p >= 0 on hard rows only), y = p is a Farkas certificate (y >= 0,
// G'y = 0, h'y = s_k < 0): the QP is infeasible.
//
// Cost per iteration: O(n nnz + |W|^2) for an entering row (its direction U_k; its Gram column from
// the stage-pair products P_ij, a few products per entry), O(|W|^2) for a leaving one, O(|W| n +
// N nx^2 + rows) for the primal point and its slacks.
#include "flight_sw/solver/active_set.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "flight_sw/solver/fast_mpc.hpp"
#include "flight_sw/solver/kkt.hpp"

namespace rvd::solver {

namespace detail {

namespace {
// A row that joins W in bulk must be well independent of it: its new Gram pivot at least this share
// of |m_k|^2 (the entering row's least is 1e-10). A row nearly in W's span would make the Gram
// factor ill-conditioned for the sake of a row that may not belong to the answer; left out, it
// enters later on its own if it is still violated.
constexpr double kBulkPivot = 1e-4;

// Dot product with four partial sums (the compiler may not reassociate one chain of additions).
inline double dot(const double* x, const double* y, int n) {
  double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
  int k = 0;
  for (; k + 4 <= n; k += 4) {
    s0 += x[k] * y[k];
    s1 += x[k + 1] * y[k + 1];
    s2 += x[k + 2] * y[k + 2];
    s3 += x[k + 3] * y[k + 3];
  }
  for (; k < n; ++k) s0 += x[k] * y[k];
  return (s0 + s1) + (s2 + s3);
}
// y <- L^-T y for a lower triangular L of size n stored by rows `stride` apart: back substitution
// along L's rows (contiguous axpys, not strided column reads).
void solve_lt(const double* L, size_t stride, int n, double* y) {
  for (int t = n - 1; t >= 0; --t) {
    const double* Lt = L + static_cast<size_t>(t) * stride;
    const double yt = y[t] /= Lt[t];
    for (int r = 0; r < t; ++r) y[r] -= Lt[r] * yt;
  }
}
// Bytewise equality of n doubles, as memcmp (-0 differs from 0, a NaN equals its own bits). On
// 32-bit ARM word by word, without an early exit (the blocks are short and nearly always equal):
// there the C library's memcmp compares bytes, a fifth of a docking solve's instructions on the A9.
// Elsewhere the library's is the faster (aarch64, x86-64: vector compares).
bool equal(const double* a, const double* b, size_t n) {
#if defined(__arm__)
  std::uint64_t diff = 0;
  for (size_t k = 0; k < n; ++k) {
    std::uint64_t x, y;
    std::memcpy(&x, a + k, sizeof x);
    std::memcpy(&y, b + k, sizeof y);
    diff |= x ^ y;
  }
  return diff == 0;
#else
  return n == 0 || std::memcmp(a, b, sizeof(double) * n) == 0;  // (an empty block has no data)
#endif
}
// M has the shape (rows, cols) and the entries a (column-major): a shape check first, so that a
// QP of the wrong shape is never read past the copy.
template <class M>
bool equal(const double* a, const M& m, long rows, long cols) {
  return m.rows() == rows && m.cols() == cols && equal(a, m.data(), static_cast<size_t>(rows * cols));
}
// Stage i's copy in `c` is m, of shape (rows, cols).
template <class M>
bool same_block(const StageCopies& c, int i, const M& m, long rows, long cols) {
  return c.len[i] == rows * cols && equal(c.data.data() + c.at[i], m, rows, cols);
}
// The stage products of the active set's passes (states of a plan, the adjoint recursions), with
// fixed sizes for the guidance's shape (nx = 6, nu = 3 on stages 0..N-1, none on stage N:
// Workspace::fixed_kernels) and dynamic ones otherwise; inlined into the loops over the stages.
template <int NX, int NU>
struct Stage {
  template <int R, int C>
  using CMap = Eigen::Map<const Eigen::Matrix<double, R, C>>;
  using XMap = Eigen::Map<Eigen::Matrix<double, NX, 1>>;
  // x_{i+1} = A x_i + B u_i + b_i for i < N (as the kernels' rollout: A (x + [0; u]) when B is
  // A's tail, flags[3 i]); x_0 given.
  static void rollout(const ActiveSet& a, const OcpQp& qp, double* x, const double* u, double* scratch) {
    const int nx = a.nx;
    for (int i = 0; i < a.N; ++i) {
      const int m = a.nu[i];
      XMap x1(x + (i + 1) * nx, nx);
      x1 = CMap<NX, 1>(qp.b[i].data(), nx);
      const CMap<NX, NX> A(qp.A[i].data(), nx, nx);
      if (m > 0 && a.flags[3 * i]) {
        XMap xs(scratch, nx);
        xs = CMap<NX, 1>(x + i * nx, nx);
        xs.tail(m) += CMap<NU, 1>(u + a.uo[i], m);
        x1.noalias() += A.lazyProduct(xs);
      } else {
        x1.noalias() += A.lazyProduct(CMap<NX, 1>(x + i * nx, nx));
        if (m > 0) x1.noalias() += CMap<NX, NU>(qp.B[i].data(), nx, m).lazyProduct(CMap<NU, 1>(u + a.uo[i], m));
      }
    }
  }
  // out = Q_i x_i + q_i (+ A_i' next when next); with gscale, the cost gradient Q_i x_i + q_i's
  // largest entry is folded into it.
  static void adjoint_x(const OcpQp& qp, int i, int nx, const double* x, const double* next, double* out,
                        double* gscale = nullptr) {
    XMap o(out, nx);
    o = CMap<NX, 1>(qp.q[i].data(), nx);
    o.noalias() += CMap<NX, NX>(qp.Q[i].data(), nx, nx).lazyProduct(CMap<NX, 1>(x, nx));
    if (gscale) *gscale = std::max(*gscale, o.cwiseAbs().maxCoeff());
    if (next) o.noalias() += CMap<NX, NX>(qp.A[i].data(), nx, nx).transpose().lazyProduct(CMap<NX, 1>(next, nx));
  }
  // out = r_i + B_i' next (i < N), r_i on stage N.
  static void adjoint_u(const OcpQp& qp, int i, int nx, int m, const double* next, double* out) {
    if (m == 0) return;
    Eigen::Map<Eigen::Matrix<double, NU, 1>> o(out, m);
    o = CMap<NU, 1>(qp.r[i].data(), m);
    if (next) o.noalias() += CMap<NX, NU>(qp.B[i].data(), nx, m).transpose().lazyProduct(CMap<NX, 1>(next, nx));
  }
  // Free response x_free and the condensed gradient f (the cost's adjoint recursion at u = 0).
  static void gradient(ActiveSet& a, const OcpQp& qp, const double* x0, double* zeros, double* scratch) {
    std::copy(x0, x0 + a.nx, a.xf.data());
    std::fill(zeros, zeros + a.n, 0.0);
    rollout(a, qp, a.xf.data(), zeros, scratch);
    for (int i = a.N; i >= 0; --i) {
      const double* next = i < a.N ? a.lamx.data() + (i + 1) * a.nx : nullptr;
      adjoint_u(qp, i, a.nx, a.nu[i], next, a.f.data() + a.uo[i]);
      adjoint_x(qp, i, a.nx, a.xf.data() + i * a.nx, next, a.lamx.data() + i * a.nx);
    }
  }
  // The dynamics multipliers by the adjoint recursion pi_{i-1} = Q_i x_i + q_i + A_i'pi_i + C_i'lam_i
  // (the residuals' conventions: the state stationarity holds by construction) and, on the way, the
  // input stationarity rdu_i = R_i u_i + r_i + B_i'pi_i + D_i'lam_i. Returns the cost gradient's
  // largest entry (the dual residual's scale).
  static double multipliers(const ActiveSet& a, Workspace& w, const OcpQp& qp) {
    const int nx = a.nx;
    double gscale = 0.0;
    for (int i = a.N; i >= 0; --i) {
      const int m = a.nu[i];
      const double* next = i < a.N ? w.pi + i * nx : nullptr;
      if (m > 0) {
        Eigen::Map<Eigen::Matrix<double, NU, 1>> g(w.rdu + a.uo[i], m);
        g = CMap<NU, 1>(qp.r[i].data(), m);
        g.noalias() += CMap<NU, NU>(qp.R[i].data(), m, m).lazyProduct(CMap<NU, 1>(w.u + a.uo[i], m));
        gscale = std::max(gscale, g.cwiseAbs().maxCoeff());
        if (next) g.noalias() += CMap<NX, NU>(qp.B[i].data(), nx, m).transpose().lazyProduct(CMap<NX, 1>(next, nx));
      }
      double* pi_prev = i > 0 ? w.pi + (i - 1) * nx : nullptr;
      if (pi_prev) adjoint_x(qp, i, nx, w.x + i * nx, next, pi_prev, &gscale);
      detail::gt_mul_add(w, i, w.lam, w.rdu + a.uo[i], pi_prev);
    }
    return gscale;
  }
};
using FixedStage = Stage<6, 3>;
using AnyStage = Stage<Eigen::Dynamic, Eigen::Dynamic>;

}  // namespace

ActiveSet::ActiveSet(const OcpQpDims& d) : dims(d), N(d.N), nx(d.nx) {
  for (int i = 0; i <= N; ++i) n += d.nu[i], rows += d.nc[i];
  cap = n + 1;
}

void ActiveSet::carve(Arena& arena) {
  const OcpQpDims& d = dims;
  const size_t n1 = static_cast<size_t>(N) + 1, un = static_cast<size_t>(n), nr = static_cast<size_t>(rows);
  arena.take(nu, n1), arena.take(uo, n1 + 1);
  size_t blocks = 0, a = 0, b = 0, q = 0, r = 0, cs = 0, ds = 0, ss = 0;
  int nu_max = 0;
  for (int i = 0; i <= N; ++i) {
    blocks += static_cast<size_t>(N - i) * nx * d.nu[i];
    if (i < N) a += nx * nx, b += nx * d.nu[i];
    q += nx * nx, r += d.nu[i] * d.nu[i];
    cs += static_cast<size_t>(d.nc[i]) * nx, ds += static_cast<size_t>(d.nc[i]) * d.nu[i], ss += d.soft_rows(i);
    nu_max = std::max(nu_max, d.nu[i]);
  }
  A.carve(arena, a, n1), B.carve(arena, b, n1), Q.carve(arena, q, n1), R.carve(arena, r, n1);
  arena.take(go, n1), arena.take(gam, blocks);
  arena.take(L, un * un), arena.take(Hinv, un * un), arena.take(Yx, n1 * un * nx);
  arena.take(f, un), arena.take(uc, un), arena.take(tmp, std::max(un + 1, static_cast<size_t>(nx)));
  arena.take(xf, n1 * nx), arena.take(lamx, n1 * nx);
  arena.take(po, n1 * n1), arena.take(P, pair_products(d));
  arena.take(row_stage, nr), arena.take(inv_norm, nr), arena.take(scan0, nr);
  const size_t c = static_cast<size_t>(cap), nnz = nr * (nx + nu_max);
  arena.take(Uw, c * un), arena.take(Kl, c * c);
  arena.take(e, c), arena.take(lam, c), arena.take(lam_star, c), arena.take(dir, c), arena.take(slot_row, c);
  arena.take(gram_col, c);
  arena.take(state, nr), arena.take(warm_state, nr), arena.take(ub, nr);
  arena.take(so, n1 + 1);
  Cc.carve(arena, cs, n1), Dc.carve(arena, ds, n1);
  arena.take(zsc, ss), arena.take(Zsc, ss), arena.take(idxc, ss);
  arena.take(stage_same, n1), arena.take(flags, 3 * n1);
  for (auto* list : {&const_rows, &const_soft, &bound_rows, &bound_col, &active_rows, &one_row, &one_pos, &multi_row, &multi_end})
    arena.take(*list, nr, true);
  arena.take(one_src, nr, true);
  arena.take(multi_pos, nnz, true), arena.take(multi_src, nnz, true);
  arena.take(ent, nnz);
}

void ActiveSet::init() {
  const OcpQpDims& d = dims;
  for (int i = 0; i <= N; ++i) nu[i] = d.nu[i], uo[i + 1] = uo[i] + nu[i];
  size_t blocks = 0, pairs = 0;
  for (int i = 0; i <= N; ++i) go[i] = static_cast<int>(blocks), blocks += static_cast<size_t>(N - i) * nx * nu[i];
  for (int i = 0; i <= N; ++i)
    for (int j = i; j <= N; ++j) po[i * (N + 1) + j] = static_cast<int>(pairs), pairs += static_cast<size_t>(nu[i] + nx) * (nu[j] + nx);
  for (int i = 0, k = 0; i <= N; ++i)
    for (int j = 0; j < d.nc[i]; ++j) row_stage[k++] = i;
  std::fill(slot_row.begin(), slot_row.end(), -1);
  for (int i = 0; i <= N; ++i) so[i + 1] = so[i] + d.soft_rows(i);
}

size_t ActiveSet::pair_products(const OcpQpDims& d) {
  size_t sum = 0, squares = 0;
  for (int i = 0; i <= d.N; ++i) sum += d.nu[i] + d.nx, squares += static_cast<size_t>(d.nu[i] + d.nx) * (d.nu[i] + d.nx);
  return (sum * sum + squares) / 2;  // sum over i <= j of m_i m_j
}

void StageCopies::carve(Arena& arena, size_t doubles, size_t stages) {
  arena.take(data, doubles, true), arena.take(at, stages), arena.take(len, stages);
}

void StageCopies::keep(int i, const Matrix& m) {
  const size_t n = static_cast<size_t>(m.size());
  len[i] = static_cast<int>(n);
  if (i > 0 && len[i - 1] == len[i] && equal(data.data() + at[i - 1], m.data(), n)) {
    at[i] = at[i - 1];
    return;
  }
  at[i] = static_cast<int>(data.size());
  for (size_t k = 0; k < n; ++k) data.push_back(m.data()[k]);  // (within the capacity: every stage's length)
}

bool ActiveSet::same_rows(const OcpQp& qp, int i) const {
  const int ns = so[i + 1] - so[i], nc = dims.nc[i];
  if (!rows_valid || !same_block(Cc, i, qp.C[i], nc, nx) || !same_block(Dc, i, qp.D[i], nc, nu[i])) return false;
  return ns == 0 || (static_cast<int>(qp.idxs[i].size()) == ns &&
                     std::memcmp(idxc.data() + so[i], qp.idxs[i].data(), sizeof(int) * ns) == 0 &&
                     equal(zsc.data() + so[i], qp.zs[i], ns, 1) && equal(Zsc.data() + so[i], qp.Zs[i], ns, 1));
}

bool ActiveSet::same_d(const OcpQp& qp, int i) const {
  return rows_valid && same_block(Dc, i, qp.D[i], dims.nc[i], nu[i]);
}

bool ActiveSet::same_pattern(Workspace& w, const OcpQp& qp, int i, bool d_same) {
  const int ns = so[i + 1] - so[i];
  if (ns > 0 && !(std::memcmp(idxc.data() + so[i], qp.idxs[i].data(), sizeof(int) * ns) == 0 &&
                  equal(zsc.data() + so[i], qp.zs[i], ns, 1) && equal(Zsc.data() + so[i], qp.Zs[i], ns, 1)))
    return false;
  const Matrix &C = qp.C[i], &D = qp.D[i];
  for (int j = 0, k = w.ro[i]; k < w.ro[i + 1]; ++j, ++k) {
    int t = w.ptr[k];  // (the kept entries of a row are in column order: inputs, then states)
    bool changed = false;
    if (d_same) {
      t = w.mid[k];  // the kept D entries hold D's values already
    } else {
      for (int c = 0; c < nu[i]; ++c) {
        if (t < w.mid[k] && w.col[t] == c) {
          changed = changed || w.val[t] != D(j, c);
          w.val[t++] = D(j, c);  // a kept entry, zero now or not
        } else if (D(j, c) != 0.0) {
          return false;  // a nonzero the kept rows do not hold
        }
      }
    }
    for (int c = 0; c < nx; ++c) {
      if (t < w.ptr[k + 1] && w.col[t] == c) {
        changed = changed || w.val[t] != C(j, c);
        w.val[t++] = C(j, c);
      } else if (C(j, c) != 0.0) {
        return false;
      }
    }
    if (changed) row_norm(w, k);
  }
  return true;
}

void ActiveSet::keep_copies(const OcpQp& qp) {
  Cc.clear(), Dc.clear();
  for (int i = 0; i <= N; ++i) {
    Cc.keep(i, qp.C[i]), Dc.keep(i, qp.D[i]);
    const int ns = so[i + 1] - so[i];
    if (ns == 0) continue;
    std::copy(qp.idxs[i].begin(), qp.idxs[i].end(), idxc.begin() + so[i]);
    std::copy(qp.zs[i].data(), qp.zs[i].data() + ns, zsc.data() + so[i]);
    std::copy(qp.Zs[i].data(), qp.Zs[i].data() + ns, Zsc.data() + so[i]);
  }
}

void ActiveSet::keep_rows(const Workspace& w, const OcpQp& qp) {
  keep_copies(qp);
  for (int i = 0; i <= N; ++i) {
    flags[3 * i] = i < N ? w.b_tail[i] : 0;
    flags[3 * i + 1] = w.q_diag[i];
    flags[3 * i + 2] = w.r_diag[i];
  }
  for (auto* list : {&const_rows, &const_soft, &bound_rows, &bound_col, &active_rows, &one_row, &one_pos, &multi_row, &multi_end,
                     &multi_pos})
    list->clear();  // capacity reserved: no allocation
  one_src.clear(), multi_src.clear();
  quadratic_soft = false;
  for (int k = 0; k < rows; ++k) ub[k] = w.soft[k] > 0.0 ? w.zs[k] : std::numeric_limits<double>::infinity();
  for (int i = 0; i <= N; ++i)
    for (int k = w.ro[i]; k < w.ro[i + 1]; ++k) {
      if (w.act[k] == 0.0) {  // prepare_rows cleared soft on constant rows: the QP's idxs say
        bool soft = false;
        for (int s = so[i]; s < so[i + 1]; ++s) soft = soft || idxc[s] == k - w.ro[i];
        const_rows.push_back(k), const_soft.push_back(soft);
        continue;
      }
      active_rows.push_back(k);
      if (w.soft[k] > 0.0 && w.Zs[k] != 0.0) quadratic_soft = true;
      const int nu_k = w.mid[k] - w.ptr[k], nx_k = w.ptr[k + 1] - w.mid[k];
      if (w.soft[k] == 0.0 && nu_k == 1 && nx_k == 0) bound_rows.push_back(k), bound_col.push_back(w.uo[i] + w.col[w.ptr[k]]);
      auto src = [&](int t) -> const double* { return t < w.mid[k] ? w.u + w.uo[i] + w.col[t] : w.x + i * nx + w.col[t]; };
      if (nu_k + nx_k == 1) {
        one_row.push_back(k), one_src.push_back(src(w.ptr[k])), one_pos.push_back(w.ptr[k]);
      } else {
        multi_row.push_back(k);
        for (int t = w.ptr[k]; t < w.ptr[k + 1]; ++t) multi_src.push_back(src(t)), multi_pos.push_back(t);
        multi_end.push_back(static_cast<int>(multi_pos.size()));
      }
    }
  for (int i = 0; i <= N; ++i)
    for (int k = w.ro[i]; k < w.ro[i + 1]; ++k)
      for (int t = w.ptr[k]; t < w.ptr[k + 1]; ++t) ent[t] = t < w.mid[k] ? w.col[t] : nu[i] + w.col[t];
  if (condensed)
    for (int i = 0; i <= N; ++i) row_norms(w, i);
  rows_valid = true;
}

void ActiveSet::row_norms(const Workspace& w, int i) {
  for (int k = w.ro[i]; k < w.ro[i + 1]; ++k) row_norm(w, k);
}

void ActiveSet::row_norm(const Workspace& w, int k) {
  const double sq = gram(w, k, k);
  inv_norm[k] = sq > 0.0 ? 1.0 / std::sqrt(sq) : std::numeric_limits<double>::infinity();  // no input moves it: first
  scan0[k] = scan_weight(k, 0);
}

double ActiveSet::gram(const Workspace& w, int r, int k) const {
  int i = row_stage[r], j = row_stage[k];
  if (i > j) std::swap(i, j), std::swap(r, k);
  const int mj = nu[j] + nx;
  const double* Pij = P.data() + po[i * (N + 1) + j];
  double sum = 0.0;
  const int k0 = w.ptr[k], k1 = w.ptr[k + 1];
  for (int t = w.ptr[r]; t < w.ptr[r + 1]; ++t) {
    const double* row = Pij + ent[t] * mj;
    double acc = 0.0;
    for (int t2 = k0; t2 < k1; ++t2) acc += row[ent[t2]] * w.val[t2];
    sum += w.val[t] * acc;
  }
  return sum;
}

bool ActiveSet::same_data(const OcpQp& qp) const {
  if (!condensed) return false;
  for (int i = 0; i <= N; ++i) {
    if (i < N && !(same_block(A, i, qp.A[i], nx, nx) && same_block(B, i, qp.B[i], nx, nu[i]))) return false;
    if (!(same_block(Q, i, qp.Q[i], nx, nx) && same_block(R, i, qp.R[i], nu[i], nu[i]))) return false;
  }
  return true;
}

bool ActiveSet::condense(const OcpQp& qp) {
  condensed = false;
  rows_valid = false;  // the structure flags kept with the rows are those of the old A, B, Q, R
  A.clear(), B.clear(), Q.clear(), R.clear();  // capacity reserved: no allocation
  for (int i = 0; i <= N; ++i) {
    if (i < N) A.keep(i, qp.A[i]), B.keep(i, qp.B[i]);
    Q.keep(i, qp.Q[i]), R.keep(i, qp.R[i]);
  }
  // Gamma(j, i) = A_{j-1} ... A_{i+1} B_i.
  for (int i = 0; i < N; ++i) {
    const int m = nu[i];
    double* blk = gam.data() + go[i];
    for (int k = 0; k < nx * m; ++k) blk[k] = qp.B[i].data()[k];
    for (int j = i + 1; j < N; ++j) {
      const double* prev = blk + static_cast<size_t>(j - i - 1) * nx * m;
      double* next = blk + static_cast<size_t>(j - i) * nx * m;
      const Matrix& Aj = qp.A[j];
      for (int cc = 0; cc < m; ++cc)
        for (int r = 0; r < nx; ++r) {
          double acc = 0.0;
          for (int k = 0; k < nx; ++k) acc += Aj(r, k) * prev[cc * nx + k];
          next[cc * nx + r] = acc;
        }
    }
  }
  auto G = [&](int j, int i, int r, int cc) { return gam[go[i] + static_cast<size_t>(j - i - 1) * nx * nu[i] + cc * nx + r]; };
  // H = Rbar + sum_j Gamma_j' Q_j Gamma_j (lower triangle; row-major).
  std::fill(L.begin(), L.end(), 0.0);
  for (int i = 0; i <= N; ++i)
    for (int a = 0; a < nu[i]; ++a)
      for (int b = 0; b <= a; ++b) L[static_cast<size_t>(uo[i] + a) * n + uo[i] + b] += 0.5 * (qp.R[i](a, b) + qp.R[i](b, a));
  for (int j = 1; j <= N; ++j) {
    const Matrix& Qj = qp.Q[j];
    for (int k = 0; k < j; ++k)      // column stage
      for (int b = 0; b < nu[k]; ++b) {
        for (int r = 0; r < nx; ++r) {  // tmp = Q_j Gamma(j, k) e_b
          double acc = 0.0;
          for (int s = 0; s < nx; ++s) acc += 0.5 * (Qj(r, s) + Qj(s, r)) * G(j, k, s, b);
          tmp[r] = acc;
        }
        for (int i = k; i < j; ++i)  // row stage >= column stage
          for (int a = 0; a < nu[i]; ++a) {
            const int row = uo[i] + a, col = uo[k] + b;
            if (col > row) continue;
            double acc = 0.0;
            for (int r = 0; r < nx; ++r) acc += G(j, i, r, a) * tmp[r];
            L[static_cast<size_t>(row) * n + col] += acc;
          }
      }
  }
  // Cholesky in place (lower, row-major).
  for (int j = 0; j < n; ++j) {
    double* Lj = L.data() + static_cast<size_t>(j) * n;
    double dd = Lj[j];
    for (int k = 0; k < j; ++k) dd -= Lj[k] * Lj[k];
    if (!(dd > 0.0)) return false;
    Lj[j] = std::sqrt(dd);
    const double inv = 1.0 / Lj[j];
    for (int r = j + 1; r < n; ++r) {
      double* Lr = L.data() + static_cast<size_t>(r) * n;
      double acc = Lr[j];
      for (int k = 0; k < j; ++k) acc -= Lr[k] * Lj[k];
      Lr[j] = acc * inv;
    }
  }
  // L^-1 column by column (L Linv e_j = e_j) into Hinv's place, then Wx_i column s = L^-1 Gamma_i' e_s
  // into Yx's: the v-space columns of P (below); each becomes its L^-T image after.
  double* Linv = Hinv.data();
  double* Wx = Yx.data();
  std::fill(Hinv.begin(), Hinv.end(), 0.0);
  for (int j = 0; j < n; ++j) {
    double* col = Linv + static_cast<size_t>(j) * n;
    for (int r = j; r < n; ++r) {
      const double* Lr = L.data() + static_cast<size_t>(r) * n;
      double acc = r == j ? 1.0 : 0.0;
      for (int k = j; k < r; ++k) acc -= Lr[k] * col[k];
      col[r] = acc / Lr[r];
    }
  }
  std::fill(Yx.begin(), Yx.end(), 0.0);
  for (int i = 1; i <= N; ++i)
    for (int s = 0; s < nx; ++s) {
      double* out = Wx + (static_cast<size_t>(i) * nx + s) * n;
      for (int j = 0; j < i; ++j)
        for (int cc = 0; cc < nu[j]; ++cc) {
          const double gv = G(i, j, s, cc);  // d x_i,s / d u_j,cc
          if (gv == 0.0) continue;
          const int q = uo[j] + cc;
          const double* col = Linv + static_cast<size_t>(q) * n;
          for (int r = q; r < n; ++r) out[r] += gv * col[r];
        }
    }
  // P_ij: column a of stage i is Linv's column uo_i + a (a < nu_i, zero above its diagonal) or
  // Wx_i's column a - nu_i (zero on stage 0: x_0 is given).
  auto column = [&](int i, int a) {
    return a < nu[i] ? Linv + static_cast<size_t>(uo[i] + a) * n : Wx + (static_cast<size_t>(i) * nx + a - nu[i]) * n;
  };
  for (int i = 0; i <= N; ++i)
    for (int j = i; j <= N; ++j) {
      const int mi = nu[i] + nx, mj = nu[j] + nx;
      double* Pij = P.data() + po[i * (N + 1) + j];
      for (int a = 0; a < mi; ++a)
        for (int b = 0; b < mj; ++b) Pij[a * mj + b] = i == j && b < a ? Pij[b * mj + a] : dot(column(i, a), column(j, b), n);
    }
  // Each column y becomes L^-T y in place: L^-1's into H^-1's, L^-1 Gamma_i''s into H^-1 Gamma_i''s.
  for (int j = 0; j < n; ++j) solve_lt(L.data(), n, n, Linv + static_cast<size_t>(j) * n);
  for (int c = nx; c < (N + 1) * nx; ++c) solve_lt(L.data(), n, n, Wx + static_cast<size_t>(c) * n);
  condensed = true;
  return true;
}

void ActiveSet::shift_warm_state(const Workspace& w) {
  for (int i = 0; i < N; ++i) {
    const int j = shifted_rows(w, i);
    std::copy(warm_state.begin() + w.ro[i + 1], warm_state.begin() + w.ro[i + 1] + j, warm_state.begin() + w.ro[i]);
    std::fill(warm_state.begin() + w.ro[i] + j, warm_state.begin() + w.ro[i + 1], 0);  // no stale row in W
  }
}

}  // namespace detail

using detail::ActiveSet;
using detail::Workspace;

bool FastMpcSolver::uses_active_set() const {
  return dense_ && settings_.mode == Mode::Converged && dense_->n <= settings_.active_set_max_inputs;
}

bool FastMpcSolver::active_set_applies() const {
  return uses_active_set() && dense_->rows_valid && !dense_->quadratic_soft;
}

// detail::prepare_rows for the active-set path. Rows whose stage data (C, D, soft rows) are those
// of the rows kept keep their compression; per solve only what d and x0 change is redone, in the
// order prepare_rows does it: d, its largest entry on active rows, the constant rows (x0 alone:
// checked, or their soft penalty counted) and the tightest single-input bounds. Any other stage,
// or new A, B, Q, R (condensed again here), prepares every row as prepare_rows and keeps them.
bool FastMpcSolver::prepare_active_set(const OcpQp& qp) {
  Workspace& w = *work_;
  ActiveSet& a = *dense_;
  if (!a.dyn_same) a.condense(qp);  // on failure (H not positive definite) the solve goes to the interior point
  // A stage with new C, D values but the same nonzeros (a turning target's cone rows) takes the
  // values in place.
  using StageData = detail::ActiveSet::StageData;
  bool same = a.rows_valid, new_values = false;
  for (int i = 0; i <= a.N && same; ++i)
    if (a.stage_same[i] != StageData::Same && (same = a.same_pattern(w, qp, i, a.stage_same[i] == StageData::SameD)))
      new_values = true;
  if (same && new_values) a.keep_copies(qp);
  if (!same) {
    info_.rows_compressed = true;
    const bool ok = detail::prepare_rows(w, qp, settings_.tol);
    a.keep_rows(w, qp);
    return ok;
  }
  for (int i = 0; i <= a.N; ++i) {
    if (i < a.N) w.b_tail[i] = a.flags[3 * i];
    w.q_diag[i] = a.flags[3 * i + 1];
    w.r_diag[i] = a.flags[3 * i + 2];
    std::copy(qp.d[i].data(), qp.d[i].data() + w.nc[i], w.dv + w.ro[i]);
  }
  w.d_max = 0.0;
  for (int k : a.active_rows) w.d_max = std::max(w.d_max, std::abs(w.dv[k]));
  bool ok = true;
  w.const_soft = 0.0;
  for (size_t c = 0; c < a.const_rows.size(); ++c) {
    const int k = a.const_rows[c];
    const double lhs = k < w.ro[1] ? qp.C[0].row(k).dot(Eigen::Map<const Vector>(w.x, w.nx)) : 0.0;
    const double viol = lhs - w.dv[k];
    if (a.const_soft[c]) {
      const double s = std::max(viol, 0.0);
      w.const_soft += s * (w.zs[k] + 0.5 * w.Zs[k] * s);
      w.sig[k] = s;
    } else if (viol > settings_.tol * (1.0 + std::abs(lhs) + std::abs(w.dv[k]))) {
      ok = false;
    }
  }
  std::fill(w.ub_row, w.ub_row + w.inputs, -1);
  std::fill(w.lb_row, w.lb_row + w.inputs, -1);
  for (size_t b = 0; b < a.bound_rows.size(); ++b) {
    const int k = a.bound_rows[b], c = a.bound_col[b];
    const double val = w.val[w.ptr[k]];
    if (val == 0.0) continue;  // a kept entry that is zero this period: no bound
    const double bound = w.dv[k] / val;
    int& slot = val > 0.0 ? w.ub_row[c] : w.lb_row[c];
    if (slot < 0) {
      slot = k;
    } else {
      const double old = w.dv[slot] / w.val[w.ptr[slot]];
      if (val > 0.0 ? bound < old : bound > old) slot = k;
    }
  }
  return ok;
}

Status FastMpcSolver::solve_active_set(const OcpQp& qp, bool warm) {
  Workspace& w = *work_;
  ActiveSet& a = *dense_;
  warm = warm && a.warm_valid;
  a.warm_valid = false;
  if (!a.condensed) return solve_converged(qp, false, settings_.max_iter, 0.0, settings_.warm_push);
  const int nx = a.nx, n = a.n, cap = a.cap;
  double* Uw = a.Uw.data();
  double* Kl = a.Kl.data();
  constexpr double inf = std::numeric_limits<double>::infinity();

  const bool fixed = w.fixed_kernels;
  if (fixed)
    detail::FixedStage::gradient(a, qp, w.x, w.ut, w.tm);
  else
    detail::AnyStage::gradient(a, qp, w.x, w.ut, w.tm);
  const double* Hinv = a.Hinv.data();
  Eigen::Map<Vector> uc(a.uc.data(), n);  // uc = -H^-1 f (a product into zeros: no temporary)
  uc.setZero();
  uc.noalias() -= Eigen::Map<const Matrix>(Hinv, n, n) * Eigen::Map<const Vector>(a.f.data(), n);
  // Per row its weight in the entering row's search (ActiveSet::scan_weight; w.inv_s as scratch).
  double* scan = w.inv_s;
  auto set_state = [&](int k, signed char st) {  // (active rows only)
    a.state[k] = st;
    scan[k] = a.scan_weight(k, st);
  };
  std::fill(a.state.begin(), a.state.end(), 0);  // constant rows stay at 0 and are never scanned
  std::copy(a.scan0.begin(), a.scan0.end(), scan);  // set_state(k, 0) of every row
  const double violation_tol = 0.01 * settings_.tol;  // a row counts as violated beyond this x max(1, |d|)
  const int max_iter = settings_.active_set_max_iter;
  int p = 0;  // rows in W

  // uc -= delta U_row (row `row`, its direction in U, reaching or leaving its upper bound: the
  // gradient gains delta gbar): the slacks e_s of W's rows (and of the pending row, slot p) follow.
  auto shift_uc = [&](int row, const double* U, double delta, bool pending) {
    for (int k = 0; k < n; ++k) a.uc[k] -= delta * U[k];
    for (int s = 0; s < p + (pending ? 1 : 0); ++s) a.e[s] += delta * a.gram(w, a.slot_row[s], row);
  };
  // Row k's input direction U = H^-1 gbar_k into column `col` of Uw: its nonzeros' columns of H^-1
  // (inputs) and of Yx_i = H^-1 Gamma_i' (states).
  auto direction = [&](int k, int col) {
    const int i = a.row_stage[k];
    double* U = Uw + static_cast<size_t>(col) * n;
    std::fill(U, U + n, 0.0);
    for (int t = w.ptr[k]; t < w.ptr[k + 1]; ++t) {
      const double val = w.val[t];
      const double* yc = t < w.mid[k] ? Hinv + static_cast<size_t>(a.uo[i] + w.col[t]) * n
                                      : a.Yx.data() + (static_cast<size_t>(i) * nx + w.col[t]) * n;
      for (int r = 0; r < n; ++r) U[r] += val * yc[r];
    }
    return U;
  };
  // Remove slot j from W (its multiplier is at a bound already): shift the slots and the pending
  // column behind it, restore the triangular Gram factor by Givens rotations.
  auto remove_slot = [&](int j, bool pending) {
    const int last = p + (pending ? 1 : 0);
    std::memmove(Uw + static_cast<size_t>(j) * n, Uw + static_cast<size_t>(j + 1) * n, sizeof(double) * n * (last - j - 1));
    for (int s = j; s + 1 < p; ++s) {
      a.slot_row[s] = a.slot_row[s + 1], a.e[s] = a.e[s + 1], a.lam[s] = a.lam[s + 1];
      std::memcpy(Kl + static_cast<size_t>(s) * cap, Kl + static_cast<size_t>(s + 1) * cap, sizeof(double) * (s + 2));
    }
    --p;
    for (int r = j; r < p; ++r) {  // rows r..p-1 have a superdiagonal entry in column r + 1
      double* Kr = Kl + static_cast<size_t>(r) * cap;
      const double x = Kr[r], y = Kr[r + 1], rho = std::hypot(x, y), cs = x / rho, sn = y / rho;
      for (int q = r; q < p; ++q) {
        double* Kq = Kl + static_cast<size_t>(q) * cap;
        const double u0 = Kq[r], u1 = Kq[r + 1];
        Kq[r] = cs * u0 + sn * u1;
        Kq[r + 1] = -sn * u0 + cs * u1;
      }
      Kr[r + 1] = 0.0;
    }
  };
  // The primal point of the current multipliers: u = uc - U_W lam, the states.
  auto primal = [&]() {
    Eigen::Map<Vector> u(w.u, n);
    u = Eigen::Map<const Vector>(a.uc.data(), n);
    if (p > 0)  // (one matrix-vector product: it blocks the columns, where axpys load and store u p times)
      u.noalias() -= Eigen::Map<const Matrix>(Uw, n, p) * Eigen::Map<const Vector>(a.lam.data(), p);
    if (fixed)
      detail::FixedStage::rollout(a, qp, w.x, w.u, w.tm);
    else
      detail::AnyStage::rollout(a, qp, w.x, w.u, w.tm);
  };
  // The row farthest outside its half-space in v (violation / |m_k|; a box row's G z: one product)
  // of those violated by more than the tolerance, in one pass per kind of row: lam = 0 and g'z > d,
  // or a soft row at lam = zs with g'z < d; of equals the first in row order. Every active row's
  // G z is left in w.gz. (By the distance, not the violation: rows of late stages combine many
  // inputs, their violations are large, and taking them first makes the working set wander; README.)
  // Besides it, up to Settings::active_set_bulk more violated hard rows at lam = 0 (the next by
  // distance, kept in more_*) may join W in the same pass. Cold solves only: a warm start's working
  // set is mostly right already, and there a row taken in bulk that leaves again costs more (O(p^2)
  // twice, with p large) than the primal point it saves.
  const int bulk_max = warm ? 0 : settings_.active_set_bulk;  // (within 0..kMaxActiveSetBulk: solve() checks)
  int n_more = 0;
  int more_row[Settings::kMaxActiveSetBulk];
  double more_gz[Settings::kMaxActiveSetBulk], more_dist[Settings::kMaxActiveSetBulk];
  auto most_violated = [&]() {
    int enter = -1;
    double worst = 0.0;
    n_more = 0;
    auto consider = [&](int k, double gz) {
      w.gz[k] = gz;  // (the last scan, at the answer, leaves every active row's G z for the outputs)
      const double r = gz - w.dv[k], dist = r * scan[k];
      if (!(dist > 0.0) || !(std::abs(r) > violation_tol * std::max(1.0, std::abs(w.dv[k])))) return;
      if (dist > worst || (dist == worst && k < enter)) worst = dist, enter = k;
      if (bulk_max > 0 && a.state[k] == 0 && a.ub[k] == inf && (n_more < bulk_max || dist > more_dist[n_more - 1])) {
        int j = n_more < bulk_max ? n_more++ : n_more - 1;  // insertion into the list, largest first
        for (; j > 0 && more_dist[j - 1] < dist; --j)
          more_row[j] = more_row[j - 1], more_gz[j] = more_gz[j - 1], more_dist[j] = more_dist[j - 1];
        more_row[j] = k, more_gz[j] = gz, more_dist[j] = dist;
      }
    };
    const size_t n1 = a.one_row.size(), nm = a.multi_row.size();
    for (size_t j = 0; j < n1; ++j) consider(a.one_row[j], w.val[a.one_pos[j]] * *a.one_src[j]);
    for (size_t j = 0, e = 0; j < nm; ++j) {
      double acc = 0.0;
      for (const size_t end = a.multi_end[j]; e < end; ++e) acc += w.val[a.multi_pos[e]] * *a.multi_src[e];
      consider(a.multi_row[j], acc);
    }
    return enter;
  };

  // Row p of the Gram factor for the pending row k: true when its m is independent of W's rows,
  // with the new diagonal entry written; false when it is (numerically) a combination of them, Kl's
  // row p then holding Kl^-1 M_W'm.
  auto gram_append = [&](int k, double min_pivot = 1e-10) {
    double* Kp = Kl + static_cast<size_t>(p) * cap;
    double mm = a.gram(w, k, k), ll = 0.0;
    for (int s = 0; s < p; ++s) {
      const double* Ks = Kl + static_cast<size_t>(s) * cap;
      a.gram_col[s] = a.gram(w, a.slot_row[s], k);
      Kp[s] = (a.gram_col[s] - detail::dot(Ks, Kp, s)) / Ks[s];
      ll += Kp[s] * Kp[s];
    }
    const double dd = mm - ll;
    if (!(dd > min_pivot * mm)) return false;
    Kp[p] = std::sqrt(dd);
    return true;
  };

  // Row k's slack at lam = 0 on W, given its g'z at the current point: g'z at uc is g'z here plus
  // W's multipliers' share, gbar'U_s lam_s (the Gram entries from gram_append(k), just before).
  auto slack_at_zero = [&](int k, double gz) {
    for (int s = 0; s < p; ++s) gz += a.lam[s] * a.gram_col[s];
    return w.dv[k] - gz;
  };

  Status st = Status::MaxIter;
  int it = 0;
  bool need_primal = true;
  bool degenerate = false;
  bool refactored = false;
  // Warm start: the last solution's rows at their upper bound go there again, and its working set
  // is taken in (each row independent of the ones before it) with zero multipliers. Any
  // multipliers within their bounds are a feasible point of the dual, so the method starts from
  // there: the first pass moves them towards the dual minimiser on W and drops the rows whose
  // multiplier would leave its bounds, one change each. Near the docking port most rows of the
  // last solution stay active, so this saves rebuilding the working set one violated row at a time.
  bool primal_current = false;  // w.u, w.x are the primal point of the current multipliers
  mark_iterations();
  if (warm) {
    for (int k : a.active_rows)
      if (a.warm_state[k] == 2 && a.ub[k] > 0.0 && a.ub[k] < inf) {
        set_state(k, 2);
        shift_uc(k, direction(k, 0), a.ub[k], false);
      }
    primal();  // at lam = 0: the slack of each row taken in
    primal_current = true;
    for (int k : a.active_rows) {
      if (a.warm_state[k] != 1 || a.ub[k] == 0.0 || p >= n || !gram_append(k)) continue;
      direction(k, p);
      const int i = a.row_stage[k];
      a.slot_row[p] = k;
      a.e[p] = w.dv[k] - detail::g_row(w, k, w.u + a.uo[i], w.x + i * nx);  // its slack at lam = 0
      a.lam[p] = 0.0;
      set_state(k, 1);
      ++p;
    }
    need_primal = primal_current = p == 0;
  }
  while (it < max_iter) {
    if (need_primal) {
      if (!primal_current) primal();
      primal_current = false;
      const int enter = most_violated();
      if (enter < 0) {
        // W's rows hold with equality at the dual minimiser, unless rounding in the updated Gram
        // factor spoilt it: then the factor is formed again from W's Gram entries and the
        // minimiser taken again, once; a second failure hands the QP to the interior point.
        bool tight = true;
        for (int s = 0; s < p && tight; ++s) {
          const int k = a.slot_row[s], i = a.row_stage[k];
          const double r = detail::g_row(w, k, w.u + a.uo[i], w.x + i * nx) - w.dv[k];
          tight = std::abs(r) <= settings_.tol * std::max(1.0, std::abs(w.dv[k]));
        }
        if (tight) {
          st = Status::Solved;
          break;
        }
        if (refactored) {
          st = Status::NumericalError;
          break;
        }
        refactored = true;
        const int rows_in_w = p;
        for (p = 0; p < rows_in_w && gram_append(a.slot_row[p]);) ++p;
        if (p < rows_in_w) {
          st = Status::NumericalError;
          break;
        }
        need_primal = false;
        continue;
      }
      if (time_up()) {
        st = Status::TimeLimit;
        break;
      }
      // Row `enter` becomes pending in column p; its multiplier starts at its bound.
      const bool from_upper = a.state[enter] == 2;
      double* U = direction(enter, p);
      ++it;
      // A soft row whose dual minimum along its own multiplier lies past the other bound
      // (violation >= ub |m|^2) goes there at once: one change instead of entering and leaving W.
      if (a.ub[enter] < inf) {
        const double viol = from_upper ? w.dv[enter] - w.gz[enter] : w.gz[enter] - w.dv[enter];
        if (viol >= a.ub[enter] * a.gram(w, enter, enter)) {
          set_state(enter, from_upper ? 0 : 2);
          shift_uc(enter, U, from_upper ? -a.ub[enter] : a.ub[enter], false);
          need_primal = false;  // the working set's multipliers follow the new gradient
          continue;
        }
      }
      // Append to the Gram factor, or move along the null space while it would be singular.
      bool independent = gram_append(enter);
      a.e[p] = slack_at_zero(enter, w.gz[enter]);
      a.slot_row[p] = enter;
      if (from_upper) shift_uc(enter, U, -a.ub[enter], true);
      a.lam[p] = from_upper ? a.ub[enter] : 0.0;
      set_state(enter, 1);
      need_primal = false;
      for (;;) {
        double* Kp = Kl + static_cast<size_t>(p) * cap;
        if (independent) {
          ++p;
          // The other violated hard rows of the scan join W with zero multipliers, each when it is
          // independent of W: any multipliers within their bounds are a feasible point of the dual,
          // so the minimiser's pass below starts from there and drops the rows whose multiplier
          // would turn negative (their violation was another row's), one change each. A primal
          // point and a scan then serve several entering rows, not one.
          // (Not past half the change cap: rows taken in bulk count as changes, and the cap hands
          // the QP to the interior point.)
          for (int j = 0; j < (degenerate || 2 * it >= max_iter ? 0 : n_more) && p < n; ++j) {
            const int c = more_row[j];
            if (c == enter || !gram_append(c, detail::kBulkPivot)) continue;
            direction(c, p);
            a.e[p] = slack_at_zero(c, more_gz[j]);
            a.slot_row[p] = c;
            a.lam[p] = 0.0;
            set_state(c, 1);
            ++p;
            ++it;
          }
          break;
        }
        degenerate = true;  // no more rows in bulk this solve: W is near a dependent set
        // Singular: p_k = +-1, p_W = -Kl^-T l p_k keeps M p = 0.
        const double pk = from_upper ? -1.0 : 1.0;
        for (int s = 0; s < p; ++s) a.dir[s] = -Kp[s] * pk;
        detail::solve_lt(Kl, cap, p, a.dir.data());
        double alpha = from_upper ? a.lam[p] : (a.ub[enter] - a.lam[p]);
        int block = p;
        double dmax = 1.0;
        for (int s = 0; s < p; ++s) dmax = std::max(dmax, std::abs(a.dir[s]));
        for (int s = 0; s < p; ++s) {
          if (std::abs(a.dir[s]) <= 1e-12 * dmax) a.dir[s] = 0.0;  // rounding, not a direction
          const double ds = a.dir[s];
          const double room = ds < 0.0 ? a.lam[s] / -ds : ds > 0.0 ? (a.ub[a.slot_row[s]] - a.lam[s]) / ds : inf;
          if (room < alpha) alpha = room, block = s;
        }
        if (alpha == inf) {
          st = Status::Infeasible;
          break;
        }
        for (int s = 0; s < p; ++s) a.lam[s] += alpha * a.dir[s];
        a.lam[p] += alpha * pk;
        if (block == p) {  // the entering row itself reached its other bound: it leaves at once
          const bool upper = !from_upper;
          set_state(enter, upper ? 2 : 0);
          if (upper) shift_uc(enter, U, a.ub[enter], false);
          need_primal = true;  // uc moved with the saturated row: recompute
          break;
        }
        const int row = a.slot_row[block];
        const bool upper = a.dir[block] > 0.0;
        set_state(row, upper ? 2 : 0);
        if (upper) shift_uc(row, Uw + static_cast<size_t>(block) * n, a.ub[row], true);
        const double lam_p = a.lam[p], e_p = a.e[p];
        remove_slot(block, true);
        U = Uw + static_cast<size_t>(p) * n;
        a.slot_row[p] = enter;
        a.lam[p] = lam_p;
        a.e[p] = e_p;
        ++it;
        independent = gram_append(enter);
      }
      if (st == Status::Infeasible) break;
      continue;
    }
    // Minimiser of the dual on W: Gram lam* = -e.
    for (int s = 0; s < p; ++s) {
      const double* Ks = Kl + static_cast<size_t>(s) * cap;
      a.tmp[s] = (-a.e[s] - detail::dot(Ks, a.tmp.data(), s)) / Ks[s];
    }
    std::copy(a.tmp.begin(), a.tmp.begin() + p, a.lam_star.begin());
    detail::solve_lt(Kl, cap, p, a.lam_star.data());
    double alpha = 1.0;
    int block = -1;
    for (int s = 0; s < p; ++s) {
      const double ds = a.lam_star[s] - a.lam[s], ub = a.ub[a.slot_row[s]];
      if (a.lam_star[s] < 0.0 && ds < 0.0 && a.lam[s] / -ds < alpha) alpha = a.lam[s] / -ds, block = s;
      if (a.lam_star[s] > ub && ds > 0.0 && (ub - a.lam[s]) / ds < alpha) alpha = (ub - a.lam[s]) / ds, block = s;
    }
    if (block < 0) {
      for (int s = 0; s < p; ++s) a.lam[s] = a.lam_star[s];
      need_primal = true;
      continue;
    }
    for (int s = 0; s < p; ++s) a.lam[s] += alpha * (a.lam_star[s] - a.lam[s]);
    const int row = a.slot_row[block];
    const bool upper = a.lam_star[block] > a.ub[row];
    set_state(row, upper ? 2 : 0);
    if (upper) shift_uc(row, Uw + static_cast<size_t>(block) * n, a.ub[row], false);
    remove_slot(block, false);
    ++it;
  }
  info_.active_set_changes = it;
  if (st == Status::MaxIter || st == Status::NumericalError) {  // the cap, or W's rows not tight: the interior point from a cold start
    const Status ipm = solve_converged(qp, false, settings_.max_iter, 0.0, settings_.warm_push);
    return ipm;
  }
  if (st != Status::Solved) return st;
  mark_output();
  std::copy(a.state.begin(), a.state.end(), a.warm_state.begin());
  a.warm_valid = true;
  // The outputs at the answer, which solve() then forms no more: per row the multiplier, soft slack
  // and its dual, and slack, in one pass; the primal residual of the hard rows, the dual residual of
  // the soft ones and the slacks the objective counts (sigt); then the dynamics multipliers and the
  // input stationarity. The last scan was at the answer and left every active row's G z in w.gz; a
  // constant row's is C x0 on stage 0, else 0. The states are the inputs' rollout and the dynamics
  // multipliers the adjoint recursion's, so the dynamics and the state stationarity hold by
  // construction (up to rounding): their residuals are not formed.
  for (int k : a.const_rows) {
    const int i = a.row_stage[k];
    w.gz[k] = detail::g_row(w, k, w.u + a.uo[i], w.x + i * nx);
  }
  for (int k = 0; k < w.rows; ++k) w.lam[k] = a.state[k] == 2 ? a.ub[k] : 0.0;
  for (int s = 0; s < p; ++s) w.lam[a.slot_row[s]] = a.lam[s];
  double pres = 0.0, dres = 0.0, cscale = w.d_max;
  for (int k = 0; k < w.rows; ++k) {
    if (w.soft[k] > 0.0) {
      if (w.act[k] > 0.0) w.sig[k] = std::max(w.gz[k] - w.dv[k], 0.0);
      w.mu[k] = w.zs[k] - w.lam[k];
    }
    w.t[k] = std::max(w.dv[k] - w.gz[k] + w.sig[k], 0.0);
    cscale = std::max(cscale, std::abs(w.gz[k]) * w.act[k]);
    detail::plan_row(w, k, pres, dres);
  }
  const double gscale = fixed ? detail::FixedStage::multipliers(a, w, qp) : detail::AnyStage::multipliers(a, w, qp);
  w.grad_scale = std::max({1.0, gscale, w.zs_max});
  w.cons_scale = std::max(1.0, cscale);
  info_.primal_residual = pres;
  info_.dual_residual = std::max(dres, detail::max_abs(w.rdu, w.inputs));
  outputs_formed_ = true;
  return Status::Solved;
}

}  // namespace rvd::solver
