// FastMpcSolver: construction (the one allocation), input checks, solve() dispatch, the solution
// and the warm start. The methods are in ipm.cpp, fixed_barrier.cpp and infeasibility.cpp.
#include "flight_sw/solver/fast_mpc.hpp"

#include <algorithm>
#include <cmath>

#include "flight_sw/solver/active_set.hpp"
#include "flight_sw/solver/elapsed.hpp"
#include "flight_sw/solver/kkt.hpp"

namespace rvd::solver {

using detail::Workspace;

FastMpcSolver::FastMpcSolver(const OcpQpDims& dims, const Settings& settings) : dims_(dims), settings_(settings) {
  if (!dims_.validate().empty()) return;  // every solve() then reports InvalidInput
  int inputs = 0;
  for (int i = 0; i <= dims_.N; ++i) inputs += dims_.nu[i];
  if (inputs <= settings_.active_set_max_inputs && detail::ActiveSet::pair_products(dims_) <= detail::ActiveSet::kMaxPairProducts)
    dense_ = std::make_unique<detail::ActiveSet>(dims_);  // its arrays: in the workspace's arena
  work_ = std::make_unique<Workspace>(dims_, dense_.get());
  kernels_ = &detail::kernels_for(*work_);
  const int N = dims_.N;
  x_.assign(N + 1, Vector::Zero(dims_.nx));
  setup_x0_ = Vector::Zero(dims_.nx);
  pi_.assign(N, Vector::Zero(dims_.nx));
  for (int i = 0; i <= N; ++i) {
    u_.push_back(Vector::Zero(dims_.nu[i]));
    lam_.push_back(Vector::Zero(dims_.nc[i]));
    sig_.push_back(Vector::Zero(dims_.soft_rows(i)));
  }
}

void FastMpcSolver::setup(const OcpQp& qp) {
  if (!dense_ || !inputs_ok(qp, setup_x0_)) return;
  if (!dense_->same_data(qp)) dense_->condense(qp);
  // The rows too, compressed and kept as the first solve would keep them: a solve then redoes only
  // what d and x0 change. (prepare_rows reads x0 only for stage 0's constant rows, which every
  // solve checks again.)
  if (uses_active_set() && dense_->condensed) {
    detail::prepare_rows(*work_, qp, settings_.tol);
    dense_->keep_rows(*work_, qp);
  }
}

FastMpcSolver::~FastMpcSolver() = default;
FastMpcSolver::FastMpcSolver(FastMpcSolver&&) noexcept = default;
FastMpcSolver& FastMpcSolver::operator=(FastMpcSolver&&) noexcept = default;

size_t FastMpcSolver::workspace_bytes() const { return work_ ? work_->bytes() : 0; }

bool FastMpcSolver::time_up() const {
  if (settings_.time_limit_us <= 0.0) return false;
  return elapsed_us(t_start_) > settings_.time_limit_us;
}

// Shapes, finiteness and soft-row data, without allocating (OcpQp::validate() builds a message;
// callers that want the reason call it themselves). With `kept` (the active-set path), blocks
// bytewise equal to the copies it keeps (checked when kept) are not scanned again: A, B, Q, R when
// they are the ones condensed, a stage's C, D and soft-row data when they are the ones its rows
// were prepared from (kept->stage_same[i], for prepare_active_set).
bool FastMpcSolver::inputs_ok(const OcpQp& qp, const Vector& x0, detail::ActiveSet* kept) const {
  if (!work_) return false;
  const int N = dims_.N, nx = dims_.nx;
  if (qp.dims.N != N || qp.dims.nx != nx || qp.dims.nu != dims_.nu || qp.dims.nc != dims_.nc) return false;
  for (int i = 0; i <= N; ++i)
    if (qp.dims.soft_rows(i) != dims_.soft_rows(i)) return false;
  if (x0.size() != nx || !detail::all_finite(x0.data(), nx)) return false;
  const size_t n1 = static_cast<size_t>(N) + 1;
  if (qp.A.size() + 1 != n1 || qp.B.size() + 1 != n1 || qp.b.size() + 1 != n1 || qp.Q.size() != n1 ||
      qp.q.size() != n1 || qp.R.size() != n1 || qp.r.size() != n1 || qp.C.size() != n1 || qp.D.size() != n1 ||
      qp.d.size() != n1)
    return false;
  const bool any_soft = !dims_.ns.empty();
  if (any_soft && (qp.idxs.size() != n1 || qp.zs.size() != n1 || qp.Zs.size() != n1)) return false;
  auto ok = [](const auto& m, long rows, long cols, bool known = false) {
    return m.rows() == rows && m.cols() == cols && (known || detail::all_finite(m.data(), m.size()));
  };
  const bool dyn = kept && (kept->dyn_same = kept->same_data(qp));
  for (int i = 0; i <= N; ++i) {
    const int m = dims_.nu[i], k = dims_.nc[i], ns = dims_.soft_rows(i);
    // (A D equal to the copy is known finite, as is all of a stage equal to it.)
    using StageData = detail::ActiveSet::StageData;
    const StageData same = !kept                     ? StageData::Changed
                           : kept->same_rows(qp, i) ? StageData::Same
                           : kept->same_d(qp, i)    ? StageData::SameD
                                                    : StageData::Changed;
    if (kept) kept->stage_same[i] = same;
    const bool rows = same == StageData::Same;
    if (i < N && !(ok(qp.A[i], nx, nx, dyn) && ok(qp.B[i], nx, m, dyn) && ok(qp.b[i], nx, 1))) return false;
    if (!(ok(qp.Q[i], nx, nx, dyn) && ok(qp.q[i], nx, 1) && ok(qp.R[i], m, m, dyn) && ok(qp.r[i], m, 1) &&
          ok(qp.C[i], k, nx, rows) && ok(qp.D[i], k, m, same != StageData::Changed) && ok(qp.d[i], k, 1)))
      return false;
    if (!any_soft || rows) continue;
    if (static_cast<int>(qp.idxs[i].size()) != ns || !ok(qp.zs[i], ns, 1) || !ok(qp.Zs[i], ns, 1)) return false;
    for (int s = 0; s < ns; ++s) {
      const int j = qp.idxs[i][s];
      if (j < 0 || j >= k || !(qp.zs[i](s) >= 0.0) || !(qp.Zs[i](s) >= 0.0)) return false;
      for (int t = 0; t < s; ++t)
        if (qp.idxs[i][t] == j) return false;
    }
  }
  return true;
}

Status FastMpcSolver::solve(const OcpQp& qp, const Vector& x0) {
  t_start_ = clock_now();
  info_ = Info{};
  outputs_formed_ = iterations_marked_ = output_marked_ = false;
  Status st = Status::InvalidInput;
  detail::ActiveSet* kept = uses_active_set() ? dense_.get() : nullptr;  // rows and data kept across solves
  if (!settings_.invalid() && inputs_ok(qp, x0, kept)) {
    Workspace& w = *work_;
    const detail::Kernels& K = *kernels_;
    std::copy(x0.data(), x0.data() + w.nx, w.x);
    if (dense_ && !kept) dense_->rows_valid = false;  // prepare_rows overwrites the rows kept
    info_.rows_compressed = !kept;
    if (!(kept ? prepare_active_set(qp) : detail::prepare_rows(w, qp, settings_.tol))) {
      st = Status::Infeasible;
    } else {
      const bool warm = settings_.warm_start && has_warm_;
      // The shifted plan's last state: one step past the new x_{N-1}. (Not in FixedBarrier mode:
      // its warm start needs strict feasibility more than consistent dynamics, which its
      // infeasible-start Newton repairs anyway; the propagated state can leave a tight terminal row.)
      if (warm && shifted_ && settings_.mode == Mode::Converged) {
        const int N = w.N, n = w.nx;
        Eigen::Map<Vector> xN(w.x + N * n, n);
        xN = qp.b[N - 1];
        xN.noalias() += qp.A[N - 1].lazyProduct(Eigen::Map<const Vector>(w.x + (N - 1) * n, n));
        xN.noalias() += qp.B[N - 1].lazyProduct(Eigen::Map<const Vector>(w.u + w.uo[N - 1], w.nu[N - 1]));
      }
      shifted_ = false;
      st = active_set_applies()               ? solve_active_set(qp, warm)
           : settings_.mode == Mode::Converged ? solve_converged(qp, warm, settings_.max_iter, 0.0, settings_.warm_push)
                                               : solve_barrier(qp, warm);
      mark_output();
    }
    if (!outputs_formed_) {  // (the active-set method, when it answered alone, formed them at its answer)
      K.residuals(w, qp, w.x, w.u, w.pi, w.lam);
      double pres = detail::max_abs(w.rdyn, w.N * w.nx), dres = 0.0;
      for (int k = 0; k < w.rows; ++k) detail::plan_row(w, k, pres, dres);  // (sigt: the objective's, publish()'s)
      info_.primal_residual = pres;
      info_.dual_residual = std::max({dres, detail::max_abs(w.rdu, w.inputs), detail::max_abs(w.rdx + w.nx, w.N * w.nx)});
    }
    info_.objective = K.cost(w, qp, w.x, w.u) + detail::soft_cost(w, w.sigt) + w.const_soft;
    // A solve the clock stopped early leaves an iterate, not a plan: the next one starts cold.
    has_warm_ = st == Status::Solved || st == Status::MaxIter;
    publish(qp);
    if (st == Status::Infeasible && info_.iterations == 0) has_warm_ = false;
  } else {
    has_warm_ = false;
  }
  info_.status = st;
  FlightClock& clock = flight_clock();
  const TimePoint end = clock.now();
  const TimePoint iterate = iterations_marked_ ? t_iterate_ : end, output = output_marked_ ? t_output_ : end;
  info_.solve_time_us = clock.between_us(t_start_, end);
  info_.update_time_us = clock.between_us(t_start_, iterate);
  info_.iterate_time_us = clock.between_us(iterate, output);
  info_.output_time_us = clock.between_us(output, end);
  return st;
}

void FastMpcSolver::publish(const OcpQp& qp) {
  const Workspace& w = *work_;
  for (int i = 0; i <= w.N; ++i) {
    x_[i] = Eigen::Map<const Vector>(w.x + i * w.nx, w.nx);
    u_[i] = Eigen::Map<const Vector>(w.u + w.uo[i], w.nu[i]);
    for (int j = 0; j < w.nc[i]; ++j) lam_[i](j) = w.act[w.ro[i] + j] * w.lam[w.ro[i] + j];
    if (i < w.N) pi_[i] = Eigen::Map<const Vector>(w.pi + i * w.nx, w.nx);
    for (int s = 0; s < dims_.soft_rows(i); ++s) sig_[i](s) = w.sigt[w.ro[i] + qp.idxs[i][s]];
  }
}

void FastMpcSolver::shift_warm_start() {
  if (!work_ || !has_warm_) return;
  shifted_ = true;
  Workspace& w = *work_;
  if (dense_ && dense_->warm_valid) dense_->shift_warm_state(w);
  const int N = w.N, n = w.nx;
  for (int i = 0; i < N; ++i) {
    std::copy(w.x + (i + 1) * n, w.x + (i + 2) * n, w.x + i * n);
    if (w.nu[i] == w.nu[i + 1]) std::copy(w.u + w.uo[i + 1], w.u + w.uo[i + 2], w.u + w.uo[i]);
    const int a = w.ro[i], b = w.ro[i + 1], j = detail::shifted_rows(w, i);  // (the others keep theirs)
    std::copy(w.lam + b, w.lam + b + j, w.lam + a);
    std::copy(w.sig + b, w.sig + b + j, w.sig + a);
    std::copy(w.mu + b, w.mu + b + j, w.mu + a);
    if (i + 1 < N) std::copy(w.pi + (i + 1) * n, w.pi + (i + 2) * n, w.pi + i * n);
  }
}

void FastMpcSolver::reset_warm_start() { has_warm_ = false; }

}  // namespace rvd::solver
