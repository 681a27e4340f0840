// The condensed QP and the workspace of the dual active-set method (active_set.cpp). Internal to
// the solver.
//
// Condensing eliminates the states: with the inputs u = (u_0, ..., u_N) stacked (n entries), the
// states are x = x_free + Gamma u (x_free: the rollout of x0 with u = 0), the cost is
// 1/2 u'Hu + f'u + const and a row g'[u_i; x_i] <= d of stage i reads gbar'u <= d - c'x_free,i.
// H and its Cholesky factor depend on A, B, Q, R only (fixed per guidance phase): they are computed
// once and kept, with a copy of the data they came from; a solve whose A, B, Q or R differ
// re-condenses in place (plain loops, no allocation). f and x_free are per solve; a row's input
// direction H^-1 gbar is formed only when it enters the active set.
// The rows' compressed form (the workspace's ptr/col/val) is kept too, with a copy of each stage's
// C, D and soft-row data: a stage whose data are bytewise the same as last solve's keeps it (and
// needs no finiteness check: the copy was checked); only d and x0 are read for it per solve.
#pragma once

#include "flight_sw/solver/ocp_qp.hpp"
#include "flight_sw/solver/workspace.hpp"

namespace rvd::solver::detail {

// Copies of per-stage blocks of the QP (to tell whether a solve's data are those a result was made
// from), a block bytewise equal to the previous stage's stored once: time-invariant dynamics,
// weights and rows keep one copy, which stays cached while a solve compares every stage with it
// (with the caches cold, reading a copy per stage was the largest share of a small solve's misses).
struct StageCopies {
  Array<double> data;
  Array<int> at, len;  // per stage: where its block starts in data, and its length
  void carve(Arena& arena, size_t doubles, size_t stages);
  void clear() { data.clear(); }
  void keep(int i, const Matrix& m);  // after clear(), stages in order 0, 1, ...
};

struct ActiveSet {
  OcpQpDims dims;
  int N = 0, nx = 0, n = 0, rows = 0;
  Array<int> nu, uo;  // inputs of stage i and their offset in u
  bool condensed = false;   // H, its factor and Gamma are those of the cached A, B, Q, R
  StageCopies A, B, Q, R;  // the data condensed, to detect a change
  Array<int> go;        // Gamma: block (j, i), j > i, nx x nu_i column-major at go[i] + (j - i - 1) nx nu_i
  Array<double> gam;
  Array<double> L;      // Cholesky factor of H, n x n, row-major lower triangle
  // Hinv = H^-1 (column-major, n x n) and per stage i >= 1 Yx_i = H^-1 Gamma_i' (column-major, n x nx,
  // at i n nx; Gamma_i = dx_i/du): a row's input direction U_k = H^-1 gbar_k is then a sum of nnz
  // columns. (condense() forms L^-1 and L^-1 Gamma_i' in their place first, for P.)
  Array<double> Hinv, Yx;
  // With m_k = L^-1 gbar_k (row k in v = L'u): per pair of stages i <= j the products P_ij of the
  // v-space columns their rows combine (stage i's are L^-1's columns of u_i, then L^-1 Gamma_i''s:
  // nu_i + nx of them; P_ij row-major (nu_i + nx) x (nu_j + nx) at po[i (N + 1) + j]). A Gram entry
  // m_s'm_k = gbar_s'H^-1 gbar_k is then a sum over the two rows' few nonzeros (gram()), not a
  // product of length n: the working set's Gram matrix costs O(p^2), not O(p^2 n). Per row 1 / |m_k|
  // from P_ii (inf when m_k = 0): the entering row is the one farthest outside its half-space in
  // v, (g'z - d) / |m_k|.
  Array<int> po, row_stage;
  Array<int> ent;  // per nonzero of the rows kept (w.col's positions): its column in P (c or nu_i + s)
  Array<double> P, inv_norm;
  Array<double> scan0;  // per row its weight in the entering row's search at lam = 0: inv_norm, 0 when ub = 0
  // Per solve.
  // condensed gradient f, x_free, adjoint; uc = -H^-1 (f + the saturated soft rows' zs gbar): the
  // inputs at lam = 0 on W
  Array<double> f, xf, lamx, uc;
  // Active set: the rows whose multiplier is free (W, p of them, in slots), their input directions
  // U_k = H^-1 gbar_k (columns of Uw, n each; the inputs are u = uc - U_W lam), the Cholesky factor
  // Kl of the Gram matrix M_W'M_W = G_W H^-1 G_W' (row-major, cap x cap), per slot the row index,
  // e_k = d_k - g_k'z at uc (the row's slack at lam = 0) and the multiplier.
  int cap = 0;
  Array<double> Uw, Kl, e, lam, lam_star, dir, tmp;
  Array<double> gram_col;  // W's Gram entries against the row last appended (its slack at lam = 0 reuses them)
  Array<int> slot_row;
  Array<signed char> state;  // per row: 0 multiplier 0, 1 in W, 2 at its upper bound (soft row, zs)
  Array<double> ub;          // per row: multiplier bound (zs on soft rows, inf on hard rows; kept with the rows)
  // Warm start: the rows' states at the last solve's solution (1 in W, 2 at the upper bound),
  // shifted one stage with the plan; valid after a solve this method finished.
  Array<signed char> warm_state;
  bool warm_valid = false;

  // Rows (per stage): the C, D, idxs, zs, Zs whose compression the workspace holds (the soft-row
  // data at offsets so[i]); valid when rows_valid (another row preparation clears it).
  bool rows_valid = false;
  StageCopies Cc, Dc;
  Array<double> zsc, Zsc;
  Array<int> idxc, so;
  // Per solve, stage i's row data against the copy: all equal, only D equal (a turning target turns
  // C only), or neither.
  enum class StageData : signed char { Changed, SameD, Same };
  Array<StageData> stage_same;
  bool dyn_same = false;                // per solve: A, B, Q, R are the ones condensed
  Array<int> flags;              // b_tail, q_diag, r_diag of the condensed data (3 (N+1))
  // Per-solve refresh of kept rows (fast_mpc.cpp's prepare_rows does the same on all rows):
  // constant rows (k, soft in the QP), single-input hard rows (input bounds), active rows.
  Array<int> const_rows, const_soft, bound_rows, bound_col, active_rows;
  bool quadratic_soft = false;  // an active soft row with Zs > 0: the interior point's QP
  // G z of the active rows in the primal check: rows with one nonzero (row, the variable's address
  // in the workspace, the value's position in w.val), and the others (row, end of its entries in
  // multi_src / multi_pos). A box row costs one product.
  Array<int> one_row, one_pos, multi_row, multi_end, multi_pos;
  Array<const double*> one_src, multi_src;

  // The dimensions only: the arrays are carved from the solver's arena (Workspace's constructor
  // calls carve() on its counting pass and on its creating pass, then init()).
  explicit ActiveSet(const OcpQpDims& dims);
  void carve(Arena& arena);
  void init();  // the layout's fixed entries (offsets, row stages), once the arrays are placed
  // Doubles of the stage-pair products P for these dimensions, and the most the method takes on
  // (8 MB: far above the guidance's 315 KB at N = 30; a QP with many states and few inputs above it
  // goes to the interior point rather than allocate that).
  static size_t pair_products(const OcpQpDims& dims);
  static constexpr size_t kMaxPairProducts = size_t{1} << 20;
  bool same_data(const OcpQp& qp) const;
  // Stage i's C, D and soft-row data equal the copy kept with the rows.
  bool same_rows(const OcpQp& qp, int i) const;
  // Stage i's D equals the copy kept with the rows (a turning target turns C only).
  bool same_d(const OcpQp& qp, int i) const;
  // Stage i's nonzeros in C, D are among the entries of the rows kept (and its soft rows are the
  // same): their values (zeros included, where a kept entry is zero now) replace the kept ones in the
  // workspace (the copies: keep_copies, once every stage is through), and each row whose values
  // changed gets its norm again (row_norm). False (values partly written) otherwise. So rows kept
  // with a pattern wider than a period's (a caller's structural fill, FastMpcSolver::setup) take
  // that period as is. d_same: D equals its copy (same_d), so only C is read.
  bool same_pattern(Workspace& w, const OcpQp& qp, int i, bool d_same);
  // Keep the rows the workspace holds now (after prepare_rows) with the QP's data they came from.
  void keep_rows(const Workspace& w, const OcpQp& qp);
  void keep_copies(const OcpQp& qp);  // the C, D and soft-row data part of it
  // H = Gamma'Qbar Gamma + Rbar and its Cholesky factor; false when H is not positive definite.
  bool condense(const OcpQp& qp);
  // inv_norm and scan0 of stage i's rows (as the workspace compresses them) from P_ii; needs condensed.
  void row_norms(const Workspace& w, int i);
  void row_norm(const Workspace& w, int k);  // one row's
  // m_r'm_k of two rows as the workspace compresses them, from P; needs condensed.
  double gram(const Workspace& w, int r, int k) const;
  // Row k's weight of g'z - d in the entering row's search in state st (0: at lam = 0, 1: in W,
  // 2: at lam = ub): 1 / |m_k|, its negative at the upper bound, 0 in W or when ub = 0 (never enters).
  double scan_weight(int k, signed char st) const {
    return ub[k] == 0.0 || st == 1 ? 0.0 : st == 0 ? inv_norm[k] : -inv_norm[k];
  }
  // The warm state one stage on (FastMpcSolver::shift_warm_start): stage i takes stage i + 1's
  // rows that shift (kkt.hpp, shifted_rows), its other rows leave W; stage N keeps its own.
  void shift_warm_state(const Workspace& w);
};

}  // namespace rvd::solver::detail
