// The solver's workspace: one contiguous arena, sized once from the dimensions (as HPIPM's
// memsize/create), holding the iterate, residuals, Newton steps and Riccati factors, and the dual
// active-set method's condensed QP and factors (active_set.hpp). Nothing in it is allocated after
// the constructor. Internal to the solver.
//
// Layout: vectors over the stages are stored back to back (x of stage i at x + i*nx, u at
// u + uo[i], rows of stage i at ro[i]..ro[i+1]), so whole-iterate updates are single loops.
// Row arrays cover every row of every stage; constant rows (no decision variable in them, e.g.
// stage-0 rows of x0 alone) carry act = 0 and never enter a step.
#pragma once

#include <cassert>
#include <cstddef>
#include <memory>
#include <vector>

#include "flight_sw/solver/ocp_qp.hpp"

namespace rvd::solver::detail {

// A piece of the arena with a fixed capacity: an array (size = capacity) or a list filled by
// push_back up to its capacity, which the dimensions fix (it never grows: no allocation after the
// constructor). The subset of std::vector's interface the solver uses.
template <class T>
class Array {
 public:
  T* data() { return p_; }
  const T* data() const { return p_; }
  size_t size() const { return n_; }
  T& operator[](size_t k) { return p_[k]; }
  const T& operator[](size_t k) const { return p_[k]; }
  T* begin() { return p_; }
  T* end() { return p_ + n_; }
  const T* begin() const { return p_; }
  const T* end() const { return p_ + n_; }
  void clear() { n_ = 0; }
  void push_back(const T& v) {
    assert(n_ < cap_);
    p_[n_++] = v;
  }
  void place(T* p, size_t cap, size_t size) { p_ = p, cap_ = cap, n_ = size; }

 private:
  T* p_ = nullptr;
  size_t n_ = 0, cap_ = 0;
};

// Bump allocator over one block: a first pass over the layout counts the bytes (no block yet),
// a second, after start(), hands out aligned pieces.
class Arena {
 public:
  template <class T>
  T* take(size_t n) {
    const size_t align = 64;
    used_ = (used_ + align - 1) / align * align;
    T* p = base_ ? reinterpret_cast<T*>(base_ + used_) : nullptr;
    used_ += n * sizeof(T);
    if (p)
      for (size_t k = 0; k < n; ++k) new (p + k) T();
    return p;
  }
  // An array of n entries, or (list) an empty one with room for n.
  template <class T>
  void take(Array<T>& a, size_t n, bool list = false) {
    a.place(take<T>(n), n, list ? 0 : n);
  }
  size_t used() const { return used_; }
  void start(unsigned char* base) { base_ = base, used_ = 0; }

 private:
  unsigned char* base_ = nullptr;
  size_t used_ = 0;
};

struct ActiveSet;

// One Newton step of every variable.
struct Step {
  double *dx, *du, *dpi;           // states (stage 0 stays 0), inputs, dynamics multipliers
  double *dt, *dlam, *dsig, *dmu;  // row slacks, row duals, soft slacks, their duals
};

// The rows of a Newton step by kind (detail::prepare_step_rows): bound rows on an input (bu) and
// on a state (bx) as (row, index in u / x, value); the others (gen) as row, offsets of their
// stage in u and x and the end of the nonzeros used (stage 0: its inputs' only).
struct StepRows {
  int n_bu = 0, n_bx = 0, n_gen = 0;
  int *bu_row, *bu_idx, *bx_row, *bx_idx;
  double *bu_val, *bx_val;
  int *gen_row, *gen_uo, *gen_xo, *gen_end;
};

struct Workspace {
  int N = 0, nx = 0, nu_max = 0, rows = 0, inputs = 0;
  bool fixed_kernels = false;  // nx = 6, nu = 3 on stages 0..N-1, nu_N in {0, 3}
  // Stage layout (ints): inputs, input offset, rows, row offset.
  int *nu, *uo, *nc, *ro, *lo;  // lo: offset of stage i's nu x nu factor in L
  // Per solve: structure flags per stage (B_i = A_i [0; I], Q_i and R_i diagonal).
  int *b_tail, *q_diag, *r_diag;
  // Rows: act (1 active, 0 constant), soft (1 soft row); compressed rows of [D_i C_i]: row k's
  // nonzeros are [ptr[k], mid[k]) on inputs and [mid[k], ptr[k+1]) on states (col: index in u_i/x_i).
  double *act, *soft;
  int *ptr, *mid, *col;
  double *val;
  int *ub_row, *lb_row;  // per input: the tightest hard bound row u_j <= . / u_j >= . (-1: none)
  int rows_active = 0, soft_active = 0;
  double const_soft = 0.0;
  double d_max = 0.0, zs_max = 0.0;  // per solve: max |d| over active rows, max soft penalty (problem scales)  // penalty of constant soft rows (x0 alone): part of the objective

  // Iterate.
  double *x, *u, *pi, *t, *lam, *sig, *mu;
  // Row data of the current QP: d, soft penalties (0 on hard rows).
  double *dv, *zs, *Zs;
  // Residuals: stationarity (x, u), dynamics, rows (Gz - s + t - d), soft slack stationarity; Gz.
  double *rdx, *rdu, *rdyn, *rin, *rsig, *gz;
  // Newton system weights: w = lam/t, the soft-eliminated weight, h = Zs + w + mu/sig; the
  // complementarity targets (rows, soft slacks) and the step QP's row term.
  double *w, *weff, *hs, *rc, *rcs, *vrow;
  double *inv_t, *inv_s, *inv_h, *asoft;  // per iteration: 1/t, 1/s, 1/h; the soft rows' eliminated right-hand side
  double *inv_lam, *inv_mu;               // per iteration: 1/lam (0 on constant rows), 1/mu (soft rows): step bounds
  int* soft_list;                         // per solve (interior point): the active soft rows, n_soft of them
  int n_soft = 0;
  StepRows srows;                         // per solve (interior point)
  // Step QP gradient.
  double *gx, *gu;
  // Riccati factors: cost-to-go P (nx x nx per stage), Cholesky L of the input block, Y = L^-1 S,
  // and the vector recursion l = L^-1 (...), p.
  double *P, *L, *Y, *l, *p;
  Step step, spare, corr;  // the current step, a spare (corrector trials), an iterative-refinement correction
  double *dt_aff, *dlam_aff, *dsig_aff, *dmu_aff;  // the predictor's row/soft steps
  double *edyn;                                       // refinement: dynamics residual of the step
  double *s_xx, *s_xx2, *s_ux, *tn, *tm;              // kernel scratch (nx x nx, nu_max x nx, vectors)
  double *xt, *ut, *pit, *sigt;                       // a trial point (line search)
  double grad_scale = 1.0, cons_scale = 1.0;

  Workspace() = default;
  // The arena holds the dual active-set method's arrays too when `dense` is given (carved after
  // the interior point's; bytes() counts both).
  explicit Workspace(const OcpQpDims& dims, ActiveSet* dense = nullptr);
  Workspace(const Workspace&) = delete;
  Workspace& operator=(const Workspace&) = delete;
  size_t bytes() const { return bytes_; }

 private:
  void carve(Arena& a);
  std::unique_ptr<unsigned char[]> block_;
  size_t bytes_ = 0;
  OcpQpDims dims_;
};

}  // namespace rvd::solver::detail
