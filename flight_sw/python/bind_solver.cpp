// Python binding of the Fast MPC solver: solve_ocp_qp() for one-off solves, OcpSolver for repeated
// solves with warm start (the flight software's use).
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>
#include <sstream>
#include <string>

#include "flight_sw/solver/fast_mpc.hpp"

namespace py = pybind11;
using namespace rvd::solver;

namespace {

struct SolveResult {
  Matrix x;                // (N+1) x nx
  py::list u;              // N+1 arrays, u[N] may be empty
  py::list lam;            // N+1 arrays of inequality multipliers
  py::list s;              // N+1 arrays of soft slacks (in the order of idxs)
  Matrix pi;               // N x nx dynamics multipliers
  std::string status;
  int iterations = 0, back_solves = 0, active_set_changes = 0;
  bool rows_compressed = false;
  double objective = 0.0, primal_residual = 0.0, dual_residual = 0.0, solve_time_us = 0.0;
  double update_time_us = 0.0, iterate_time_us = 0.0, output_time_us = 0.0;
};

Mode parse_mode(const std::string& mode) {
  if (mode == "converged") return Mode::Converged;
  if (mode == "fixed_barrier") return Mode::FixedBarrier;
  if (mode == "interior_point") return Mode::Converged;  // converged, never the active-set method
  throw py::value_error("mode must be 'converged', 'interior_point' or 'fixed_barrier', got '" + mode + "'");
}

Settings make_settings(const std::string& mode, double tol, std::optional<int> max_iter, double barrier,
                       bool warm_start, double time_limit_us) {
  Settings s;
  s.mode = parse_mode(mode);
  if (mode == "interior_point") s.active_set_max_inputs = 0;
  s.max_iter = max_iter ? *max_iter : (s.mode == Mode::FixedBarrier ? fixed_barrier_settings().max_iter : 100);
  if (s.max_iter < 0) throw py::value_error("max_iter must be >= 0");
  if (!(tol > 0)) throw py::value_error("tol must be > 0");
  if (!(barrier > 0)) throw py::value_error("barrier (kappa) must be > 0");
  if (!(time_limit_us >= 0)) throw py::value_error("time_limit_us must be >= 0");
  s.tol = tol;
  s.barrier = barrier;
  s.warm_start = warm_start;
  s.time_limit_us = time_limit_us;
  return s;
}

template <class T>
T cast_block(const py::handle& h, const char* name, size_t i) {
  try {
    return h.cast<T>();
  } catch (const py::cast_error&) {
    std::ostringstream msg;
    msg << name << "[" << i << "] is not convertible to a float " << (T::ColsAtCompileTime == 1 ? "vector" : "matrix");
    throw py::value_error(msg.str());
  }
}

template <class T>
std::vector<T> cast_list(const py::sequence& seq, const char* name) {
  std::vector<T> out;
  out.reserve(seq.size());
  for (size_t i = 0; i < seq.size(); ++i) out.push_back(cast_block<T>(seq[i], name, i));
  return out;
}

// Builds the QP from per-stage arrays; shape errors raise ValueError (NaN is left to the solver,
// which answers "invalid_input").
OcpQp build_qp(const py::sequence& A, const py::sequence& B, const py::sequence& b, const py::sequence& Q,
               const py::sequence& q, const py::sequence& R, const py::sequence& r, const py::sequence& C,
               const py::sequence& D, const py::sequence& d, const py::object& idxs, const py::object& zs,
               const py::object& Zs) {
  const size_t N = A.size();
  if (N < 1) throw py::value_error("A must hold N >= 1 matrices (one per dynamics stage)");
  std::ostringstream err;
  if (B.size() != N || b.size() != N) err << "A, B, b need N = " << N << " entries (got " << A.size() << ", "
                                          << B.size() << ", " << b.size() << "); ";
  for (auto [seq, name] : {std::pair{&Q, "Q"}, {&q, "q"}, {&R, "R"}, {&r, "r"}, {&C, "C"}, {&D, "D"}, {&d, "d"}})
    if (seq->size() != N + 1) err << name << " needs N+1 = " << N + 1 << " entries (got " << seq->size() << "); ";
  if (!err.str().empty()) throw py::value_error(err.str());

  OcpQp qp;
  qp.A = cast_list<Matrix>(A, "A");
  qp.B = cast_list<Matrix>(B, "B");
  qp.b = cast_list<Vector>(b, "b");
  qp.Q = cast_list<Matrix>(Q, "Q");
  qp.q = cast_list<Vector>(q, "q");
  qp.R = cast_list<Matrix>(R, "R");
  qp.r = cast_list<Vector>(r, "r");
  qp.C = cast_list<Matrix>(C, "C");
  qp.D = cast_list<Matrix>(D, "D");
  qp.d = cast_list<Vector>(d, "d");
  OcpQpDims& dims = qp.dims;
  dims.N = static_cast<int>(N);
  dims.nx = static_cast<int>(qp.A[0].rows());
  dims.nu.resize(N + 1);
  dims.nc.resize(N + 1);
  for (size_t i = 0; i <= N; ++i) {
    dims.nu[i] = static_cast<int>(i < N ? qp.B[i].cols() : qp.R[i].rows());
    dims.nc[i] = static_cast<int>(qp.C[i].rows());
  }
  // Shapes only: a NaN in an otherwise well-shaped QP goes to the solver, which reports it.
  auto shape = [&](const char* name, size_t i, const Matrix& m, long rows, long cols) {
    if (m.rows() != rows || m.cols() != cols)
      err << name << "[" << i << "] has shape (" << m.rows() << ", " << m.cols() << "), expected (" << rows << ", "
          << cols << "); ";
  };
  auto vshape = [&](const char* name, size_t i, const Vector& v, long n) {
    if (v.size() != n) err << name << "[" << i << "] has " << v.size() << " entries, expected " << n << "; ";
  };
  const long nx = dims.nx;
  for (size_t i = 0; i <= N; ++i) {
    const long m = dims.nu[i], k = dims.nc[i];
    if (i < N) {
      shape("A", i, qp.A[i], nx, nx);
      shape("B", i, qp.B[i], nx, m);
      vshape("b", i, qp.b[i], nx);
    }
    shape("Q", i, qp.Q[i], nx, nx);
    vshape("q", i, qp.q[i], nx);
    shape("R", i, qp.R[i], m, m);
    vshape("r", i, qp.r[i], m);
    shape("C", i, qp.C[i], k, nx);
    shape("D", i, qp.D[i], k, m);
    vshape("d", i, qp.d[i], k);
  }
  if (!err.str().empty()) throw py::value_error("inconsistent QP shapes: " + err.str());
  // Soft rows: all three lists or none.
  if (idxs.is_none() != zs.is_none() || idxs.is_none() != Zs.is_none())
    throw py::value_error("idxs, zs and Zs (soft rows) go together");
  if (!idxs.is_none()) {
    const auto si = idxs.cast<py::sequence>(), sz = zs.cast<py::sequence>(), sZ = Zs.cast<py::sequence>();
    if (si.size() != N + 1 || sz.size() != N + 1 || sZ.size() != N + 1)
      throw py::value_error("idxs, zs, Zs need N+1 entries");
    dims.ns.resize(N + 1);
    for (size_t i = 0; i <= N; ++i) {
      qp.idxs.push_back(si[i].cast<std::vector<int>>());
      qp.zs.push_back(cast_block<Vector>(sz[i], "zs", i));
      qp.Zs.push_back(cast_block<Vector>(sZ[i], "Zs", i));
      dims.ns[i] = static_cast<int>(qp.idxs[i].size());
    }
    const std::string v = qp.validate();
    if (!v.empty() && (v.find("idxs") != std::string::npos || v.find("zs") != std::string::npos ||
                       v.find("Zs") != std::string::npos || v.find("ns") != std::string::npos))
      throw py::value_error("soft rows: " + v);
  }
  return qp;
}

SolveResult collect(const FastMpcSolver& solver) {
  SolveResult res;
  const Info& info = solver.info();
  const OcpQpDims& dims = solver.dims();
  res.status = to_string(info.status);
  res.iterations = info.iterations;
  res.back_solves = info.back_solves;
  res.active_set_changes = info.active_set_changes;
  res.rows_compressed = info.rows_compressed;
  res.objective = info.objective;
  res.primal_residual = info.primal_residual;
  res.dual_residual = info.dual_residual;
  res.solve_time_us = info.solve_time_us;
  res.update_time_us = info.update_time_us;
  res.iterate_time_us = info.iterate_time_us;
  res.output_time_us = info.output_time_us;
  const auto& x = solver.x();
  res.x = Matrix::Zero(dims.N + 1, dims.nx);
  res.pi = Matrix::Zero(dims.N, dims.nx);
  for (int i = 0; i <= dims.N && i < static_cast<int>(x.size()); ++i) {
    res.x.row(i) = x[i].transpose();
    res.u.append(py::cast(solver.u()[i]));
    res.lam.append(py::cast(solver.lambda()[i]));
    res.s.append(py::cast(solver.soft_slack()[i]));
    if (i < dims.N) res.pi.row(i) = solver.pi()[i].transpose();
  }
  return res;
}

Vector cast_x0(const py::handle& x0, int nx) {
  Vector v = cast_block<Vector>(x0, "x0", 0);
  if (v.size() != nx) {
    std::ostringstream msg;
    msg << "x0 has " << v.size() << " entries, expected nx = " << nx;
    throw py::value_error(msg.str());
  }
  return v;
}

// Reusable solver: dimensions fixed at construction, workspace allocated once, warm start kept.
class PyOcpSolver {
 public:
  PyOcpSolver(int nx, std::vector<int> nu, std::vector<int> nc, std::optional<std::vector<int>> ns,
              const std::string& mode, double tol, std::optional<int> max_iter, double barrier, bool warm_start,
              double time_limit_us)
      : solver_(make_dims(nx, std::move(nu), std::move(nc), std::move(ns)),
                make_settings(mode, tol, max_iter, barrier, warm_start, time_limit_us)) {}

  SolveResult solve(const py::sequence& A, const py::sequence& B, const py::sequence& b, const py::sequence& Q,
                    const py::sequence& q, const py::sequence& R, const py::sequence& r, const py::sequence& C,
                    const py::sequence& D, const py::sequence& d, const py::handle& x0, const py::object& idxs,
                    const py::object& zs, const py::object& Zs) {
    OcpQp qp = build_qp(A, B, b, Q, q, R, r, C, D, d, idxs, zs, Zs);
    const OcpQpDims& dims = solver_.dims();
    if (qp.dims.N != dims.N || qp.dims.nx != dims.nx || qp.dims.nu != dims.nu || qp.dims.nc != dims.nc ||
        qp.dims.ns != dims.ns)
      throw py::value_error("QP dimensions differ from the ones this OcpSolver was built for");
    Vector xv = cast_x0(x0, dims.nx);
    {
      py::gil_scoped_release release;
      solver_.solve(qp, xv);
    }
    return collect(solver_);
  }
  // Condense A, B, Q, R for the active-set method ahead of the solves (what solve() would do on its first call).
  void setup(const py::sequence& A, const py::sequence& B, const py::sequence& b, const py::sequence& Q,
             const py::sequence& q, const py::sequence& R, const py::sequence& r, const py::sequence& C,
             const py::sequence& D, const py::sequence& d, const py::object& idxs, const py::object& zs,
             const py::object& Zs) {
    OcpQp qp = build_qp(A, B, b, Q, q, R, r, C, D, d, idxs, zs, Zs);
    solver_.setup(qp);
  }
  FastMpcSolver& solver() { return solver_; }

 private:
  static OcpQpDims make_dims(int nx, std::vector<int> nu, std::vector<int> nc, std::optional<std::vector<int>> ns) {
    OcpQpDims d;
    d.N = static_cast<int>(nu.size()) - 1;
    d.nx = nx;
    d.nu = std::move(nu);
    d.nc = std::move(nc);
    if (ns) d.ns = std::move(*ns);
    const std::string err = d.validate();
    if (!err.empty()) throw py::value_error("invalid OcpSolver dimensions: " + err);
    return d;
  }
  FastMpcSolver solver_;
};

}  // namespace

void bind_solver(py::module_& m) {
  py::class_<SolveResult>(m, "OcpQpResult", "Result of an OCP QP solve (SI units as given in the data).")
      .def_readonly("x", &SolveResult::x, "states, (N+1) x nx; x[0] is the given initial state")
      .def_readonly("u", &SolveResult::u, "inputs, list of N+1 arrays (u[N] may be empty)")
      .def_readonly("lam", &SolveResult::lam, "inequality multipliers, list of N+1 arrays")
      .def_readonly("s", &SolveResult::s, "soft slacks (violations of the soft rows), list of N+1 arrays")
      .def_readonly("pi", &SolveResult::pi, "dynamics multipliers, N x nx")
      .def_readonly("status", &SolveResult::status,
                    "'solved', 'max_iter', 'infeasible', 'invalid_input', 'numerical_error' or 'time_limit'")
      .def_readonly("iterations", &SolveResult::iterations, "Newton systems factored")
      .def_readonly("back_solves", &SolveResult::back_solves, "solves with those factors")
      .def_readonly("active_set_changes", &SolveResult::active_set_changes,
                    "rows that entered or left the active set (dual active-set method; 0: interior point only)")
      .def_readonly("rows_compressed", &SolveResult::rows_compressed,
                    "the solve compressed its rows itself (interior point: always; active set: when they differ "
                    "from the rows kept by setup() or an earlier solve)")
      .def_readonly("objective", &SolveResult::objective, "objective at the returned iterate")
      .def_readonly("primal_residual", &SolveResult::primal_residual,
                    "inf-norm of the dynamics residual and of the inequality violation")
      .def_readonly("dual_residual", &SolveResult::dual_residual, "inf-norm of the stationarity residual")
      .def_readonly("solve_time_us", &SolveResult::solve_time_us, "wall time of the C++ solve, microseconds")
      .def_readonly("update_time_us", &SolveResult::update_time_us,
                    "part of solve_time_us taking in the QP: input checks, its rows, x0's terms, the start point")
      .def_readonly("iterate_time_us", &SolveResult::iterate_time_us,
                    "part of solve_time_us in the method's iterations, to the answer's primal point")
      .def_readonly("output_time_us", &SolveResult::output_time_us,
                    "part of solve_time_us forming the outputs: multipliers, residuals, objective")
      .def("__repr__", [](const SolveResult& r) {
        std::ostringstream s;
        s << "OcpQpResult(status='" << r.status << "', iterations=" << r.iterations << ", objective=" << r.objective
          << ")";
        return s.str();
      });

  m.def(
      "solve_ocp_qp",
      [](const py::sequence& A, const py::sequence& B, const py::sequence& b, const py::sequence& Q,
         const py::sequence& q, const py::sequence& R, const py::sequence& r, const py::sequence& C,
         const py::sequence& D, const py::sequence& d, const py::handle& x0, const py::object& idxs,
         const py::object& zs, const py::object& Zs, double tol, std::optional<int> max_iter, const std::string& mode,
         double barrier, double time_limit_us) {
        OcpQp qp = build_qp(A, B, b, Q, q, R, r, C, D, d, idxs, zs, Zs);
        Vector xv = cast_x0(x0, qp.dims.nx);
        FastMpcSolver solver(qp.dims, make_settings(mode, tol, max_iter, barrier, false, time_limit_us));
        {
          py::gil_scoped_release release;
          solver.solve(qp, xv);
        }
        return collect(solver);
      },
      py::arg("A"), py::arg("B"), py::arg("b"), py::arg("Q"), py::arg("q"), py::arg("R"), py::arg("r"),
      py::arg("C"), py::arg("D"), py::arg("d"), py::arg("x0"), py::kw_only(), py::arg("idxs") = py::none(),
      py::arg("zs") = py::none(), py::arg("Zs") = py::none(), py::arg("tol") = 1e-8,
      py::arg("max_iter") = py::none(), py::arg("mode") = "converged", py::arg("barrier") = 1e-4,
      py::arg("time_limit_us") = 0.0,
      R"doc(Solve the stage-wise OCP QP

    minimize   sum_{i=0..N} 1/2 x_i'Q_i x_i + q_i'x_i + 1/2 u_i'R_i u_i + r_i'u_i
    subject to x_0 = x0, x_{i+1} = A_i x_i + B_i u_i + b_i (i < N), C_i x_i + D_i u_i <= d_i (i <= N)

Soft rows (optional, all three or none): idxs[i] lists rows of stage i that may be violated by
s >= 0 at the cost zs[i][k] s + Zs[i][k] s^2 / 2 (penalties >= 0); result.s holds the violations.

A, B, b are lists over i = 0..N-1; Q, q, R, r, C, D, d over i = 0..N (R_N, r_N, D_N may have zero
columns). mode 'converged' is the dual active-set method on the condensed QP when the inputs
are few (Settings::active_set_max_inputs, exact once the active set is found; soft rows with a
quadratic penalty excepted), else the primal-dual interior point to relative accuracy tol;
'interior_point' is the interior point always;
'fixed_barrier' is Wang and Boyd's Fast MPC (log barrier weight `barrier`, infeasible-start Newton).
max_iter defaults to 100 (converged) or 15 (fixed_barrier). Shape errors raise ValueError; NaN/Inf
gives status 'invalid_input'.)doc");

  py::class_<PyOcpSolver>(m, "OcpSolver",
                          "Reusable Fast MPC solver: workspace allocated once, warm start from the shifted plan.")
      .def(py::init<int, std::vector<int>, std::vector<int>, std::optional<std::vector<int>>, const std::string&, double,
                    std::optional<int>, double, bool, double>(),
           py::arg("nx"), py::arg("nu"), py::arg("nc"), py::arg("ns") = py::none(), py::kw_only(),
           py::arg("mode") = "converged",
           py::arg("tol") = 1e-8, py::arg("max_iter") = py::none(), py::arg("barrier") = 1e-4,
           py::arg("warm_start") = true, py::arg("time_limit_us") = 0.0,
           "nu, nc (and ns) list the inputs, inequality rows (and soft rows) of stages 0..N (N = len(nu) - 1)")
      .def("solve", &PyOcpSolver::solve, py::arg("A"), py::arg("B"), py::arg("b"), py::arg("Q"), py::arg("q"),
           py::arg("R"), py::arg("r"), py::arg("C"), py::arg("D"), py::arg("d"), py::arg("x0"), py::kw_only(),
           py::arg("idxs") = py::none(), py::arg("zs") = py::none(), py::arg("Zs") = py::none())
      .def("setup", &PyOcpSolver::setup, py::arg("A"), py::arg("B"), py::arg("b"), py::arg("Q"), py::arg("q"),
           py::arg("R"), py::arg("r"), py::arg("C"), py::arg("D"), py::arg("d"), py::kw_only(),
           py::arg("idxs") = py::none(), py::arg("zs") = py::none(), py::arg("Zs") = py::none(),
           "condense A, B, Q, R for the dual active-set method (otherwise the first solve does it)")
      .def("shift_warm_start", [](PyOcpSolver& s) { s.solver().shift_warm_start(); },
           "shift the last plan one stage: the warm start for the next control period")
      .def("reset_warm_start", [](PyOcpSolver& s) { s.solver().reset_warm_start(); })
      .def_property_readonly("N", [](PyOcpSolver& s) { return s.solver().dims().N; })
      .def_property_readonly("workspace_bytes", [](PyOcpSolver& s) { return s.solver().workspace_bytes(); },
                             "bytes of the one arena the constructor allocated: the interior point's iterate and "
                             "factors, and the active-set method's condensed QP when it is built")
      .def_property(
          "time_limit_us", [](PyOcpSolver& s) { return s.solver().settings().time_limit_us; },
          [](PyOcpSolver& s, double v) { s.solver().settings().time_limit_us = v; })
      .def_property(
          "max_iter", [](PyOcpSolver& s) { return s.solver().settings().max_iter; },
          [](PyOcpSolver& s, int v) { s.solver().settings().max_iter = v; })
      .def_property(
          "active_set_bulk", [](PyOcpSolver& s) { return s.solver().settings().active_set_bulk; },
          [](PyOcpSolver& s, int v) {
            if (v < 0 || v > Settings::kMaxActiveSetBulk) throw py::value_error("active_set_bulk must be in 0.." + std::to_string(Settings::kMaxActiveSetBulk));
            s.solver().settings().active_set_bulk = v;
          },
          "violated rows that may join the most violated one per primal point of the active-set method (0: one at a time)")
      .def_property(
          "separate_steps_above", [](PyOcpSolver& s) { return s.solver().settings().separate_steps_above; },
          [](PyOcpSolver& s, double v) {
            if (!(v >= 0.0)) throw py::value_error("separate_steps_above must be >= 0 (inf: never)");
            s.solver().settings().separate_steps_above = v;
          },
          "relative primal residual above which the interior point's primal and dual variables take their own step "
          "lengths (inf: one step length always)")
      .def_property(
          "cold_slack_floor", [](PyOcpSolver& s) { return s.solver().settings().cold_slack_floor; },
          [](PyOcpSolver& s, double v) {
            if (!(v > 0.0)) throw py::value_error("cold_slack_floor must be > 0");
            s.solver().settings().cold_slack_floor = v;
          },
          "the interior point's cold start: a hard row's least slack (its residual at the start when larger), in the "
          "row's units");
}
