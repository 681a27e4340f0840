"""HPIPM (Frison & Diehl, "HPIPM: a high-performance quadratic programming framework for model
predictive control", 2020) as a peer, through the C API of the libhpipm / libblasfeo that casadi's
wheel bundles (``pip install casadi``), called with ctypes. HPIPM gets the QP in its own OCP form,
the way an HPIPM user would write it:

  * x0 eliminated (nx_0 = 0, b_0 <- A_0 x0 + b_0; stage-0 rows move C_0 x0 to the right-hand side);
  * rows with one nonzero on one input or one state become box bounds (idxbu / idxbx), the rest
    general rows (C, D) with the unused lower side masked off;
  * soft rows as HPIPM's own soft constraints (idxs, Zu, zu on the upper side; slack bound 0).

Timing: wall time of the one d_ocp_qp_ipm_solve call, minus the ctypes call overhead (measured on
the same process with a trivial HPIPM getter, median of many calls): HPIPM's own solve time.
"""
from __future__ import annotations

import ctypes as C
import os
import time
from pathlib import Path

import numpy as np

from rvd_pil import paths

paths.require_checkout("HPIPM's benchmark (its QP forms are tests/support/qp_forms.py)")
from support.qp_forms import OcpQpData  # noqa: E402

MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}
_lib = None
_overhead_ns = None


def library() -> C.CDLL:
    global _lib
    if _lib is None:
        import casadi
        d = Path(casadi.__file__).parent
        C.CDLL(str(d / "libblasfeo.so"), mode=C.RTLD_GLOBAL)
        _lib = C.CDLL(str(d / "libhpipm.so"))
        for name in ("d_ocp_qp_dim_strsize", "d_ocp_qp_strsize", "d_ocp_qp_sol_strsize", "d_ocp_qp_ipm_arg_strsize",
                     "d_ocp_qp_ipm_ws_strsize"):
            getattr(_lib, name).restype = C.c_size_t
        for name in ("d_ocp_qp_dim_memsize", "d_ocp_qp_memsize", "d_ocp_qp_sol_memsize", "d_ocp_qp_ipm_arg_memsize",
                     "d_ocp_qp_ipm_ws_memsize"):
            getattr(_lib, name).restype = C.c_size_t
    return _lib


def version() -> str:
    lib = library()
    try:
        f = C.CDLL(str(Path(__import__("casadi").__file__).parent / "libblasfeo.so")).blasfeo_processor_library_string
        buf = C.create_string_buffer(256)
        f(buf)
        return "blasfeo target " + buf.value.decode()
    except (AttributeError, OSError):
        return "blasfeo target unknown"
    finally:
        del lib


def _aligned(size: int):
    buf = C.create_string_buffer(size + 128)
    addr = (C.addressof(buf) + 63) // 64 * 64
    return buf, C.c_void_p(addr)


def call_overhead_ns() -> float:
    """Median cost of one ctypes call of an HPIPM function with two pointer arguments."""
    global _overhead_ns
    if _overhead_ns is None:
        lib = library()
        buf, ws = _aligned(1 << 16)
        out = C.c_int()
        f = lib.d_ocp_qp_ipm_get_iter
        samples = []
        for _ in range(2000):
            t0 = time.perf_counter_ns()
            f(ws, C.byref(out))
            samples.append(time.perf_counter_ns() - t0)
        _overhead_ns = float(np.median(samples))
    return _overhead_ns


def _ptrs(arrays, ctype=C.c_double):
    return (C.POINTER(ctype) * len(arrays))(*[a.ctypes.data_as(C.POINTER(ctype)) for a in arrays])


class HpipmSolver:
    """One QP set up in HPIPM's structures (not timed); solve() runs the interior point (timed)."""

    def __init__(self, qp: OcpQpData, mode: str = "balance", tol: float = 1e-8, iter_max: int = 100,
                 inf_bound: float = 1e4, masks: bool = True, mu0: float | None = None):
        lib = library()
        self.qp = qp
        N = qp.N
        nx_full = qp.nx
        nx = [0] + [nx_full] * N
        nu = list(qp.nu)
        keep = []  # numpy arrays referenced by HPIPM's setters until the data is copied in
        big = inf_bound
        A, B, b, Q, S, R, q, r = [], [], [], [], [], [], [], []
        idxbx, lbx, ubx, idxbu, lbu, ubu, Cg, Dg, lg, ug = ([] for _ in range(10))
        Zl, Zu, zl, zu, idxs, ls, us = ([] for _ in range(7))
        nbx, nbu, ng, nsbx, nsbu, nsg = ([] for _ in range(6))
        lg_mask, lbu_mask, ubu_mask, lbx_mask, ubx_mask = [], [], [], [], []
        x0 = qp.x0
        for i in range(N + 1):
            soft = {}
            if qp.idxs is not None:
                for k, j in enumerate(qp.idxs[i]):
                    soft[int(j)] = (float(qp.zs[i][k]), float(qp.Zs[i][k]))
            Ci = np.asarray(qp.C[i], float)
            Di = np.asarray(qp.D[i], float)
            di = np.asarray(qp.d[i], float).copy()
            if i == 0:
                di = di - Ci @ x0
                Ci = np.zeros((Ci.shape[0], 0))
            ub_u, lb_u = {}, {}
            ub_x, lb_x = {}, {}
            gen = []
            for j in range(Ci.shape[0]):
                cu = np.flatnonzero(Di[j]) if Di.shape[1] else np.zeros(0, int)
                cx = np.flatnonzero(Ci[j]) if Ci.shape[1] else np.zeros(0, int)
                if len(cu) == 0 and len(cx) == 0:
                    continue  # a constant row (x0 alone); the QP set holds it (a soft one is a constant cost)
                if j not in soft and len(cu) + len(cx) == 1:
                    if len(cu):
                        a, c, tab = Di[j, cu[0]], int(cu[0]), (ub_u, lb_u)
                    else:
                        a, c, tab = Ci[j, cx[0]], int(cx[0]), (ub_x, lb_x)
                    bound = di[j] / a
                    if a > 0:
                        tab[0][c] = min(tab[0].get(c, np.inf), bound)
                    else:
                        tab[1][c] = max(tab[1].get(c, -np.inf), bound)
                    continue
                gen.append(j)
            bu_idx = sorted(set(ub_u) | set(lb_u))
            bx_idx = sorted(set(ub_x) | set(lb_x))
            nbu.append(len(bu_idx))
            nbx.append(len(bx_idx))
            ng.append(len(gen))
            idxbu.append(np.array(bu_idx, np.int32))
            idxbx.append(np.array(bx_idx, np.int32))
            lbu.append(np.array([lb_u.get(c, -big) for c in bu_idx], float))
            ubu.append(np.array([ub_u.get(c, big) for c in bu_idx], float))
            lbx.append(np.array([lb_x.get(c, -big) for c in bx_idx], float))
            ubx.append(np.array([ub_x.get(c, big) for c in bx_idx], float))
            lbu_mask.append(np.array([1.0 if c in lb_u else 0.0 for c in bu_idx]))
            ubu_mask.append(np.array([1.0 if c in ub_u else 0.0 for c in bu_idx]))
            lbx_mask.append(np.array([1.0 if c in lb_x else 0.0 for c in bx_idx]))
            ubx_mask.append(np.array([1.0 if c in ub_x else 0.0 for c in bx_idx]))
            Cg.append(np.asfortranarray(Ci[gen]) if Ci.shape[1] else np.zeros((len(gen), 0), order="F"))
            Dg.append(np.asfortranarray(Di[gen]))
            ug.append(di[gen].copy())
            lg.append(np.full(len(gen), -big))
            lg_mask.append(np.zeros(len(gen)))
            # Soft constraints: indices into HPIPM's [bu, bx, g] list of this stage.
            sidx = [len(bu_idx) + len(bx_idx) + k for k, j in enumerate(gen) if j in soft]
            pen = [soft[j] for j in gen if j in soft]
            nsbu.append(0)
            nsbx.append(0)
            nsg.append(len(sidx))
            idxs.append(np.array(sidx, np.int32))
            zu.append(np.array([p[0] for p in pen], float))
            zl.append(np.array([p[0] for p in pen], float))
            Zu.append(np.array([p[1] for p in pen], float))
            Zl.append(np.array([p[1] for p in pen], float))
            ls.append(np.zeros(len(sidx)))
            us.append(np.zeros(len(sidx)))
            if i < N:
                Ai = np.asarray(qp.A[i], float)
                A.append(np.asfortranarray(Ai if i > 0 else np.zeros((nx_full, 0))))
                B.append(np.asfortranarray(qp.B[i]))
                b.append(np.asarray(qp.b[i], float) + (Ai @ x0 if i == 0 else 0.0))
            Q.append(np.asfortranarray(qp.Q[i] if i > 0 else np.zeros((0, 0))))
            q.append(np.asarray(qp.q[i], float) if i > 0 else np.zeros(0))
            R.append(np.asfortranarray(qp.R[i]))
            r.append(np.asarray(qp.r[i], float))
            S.append(np.zeros((nu[i], nx[i]), order="F"))
        keep += [A, B, b, Q, S, R, q, r, idxbx, lbx, ubx, idxbu, lbu, ubu, Cg, Dg, lg, ug, Zl, Zu, zl, zu, idxs, ls, us]
        self._keep = keep
        # The field setters (d_ocp_qp_dim_set / d_ocp_qp_set): their signature is the same in every
        # HPIPM release, unlike the set_all ones.
        self._dim_s, self.dim = _aligned(lib.d_ocp_qp_dim_strsize())
        self._dim_m, dim_mem = _aligned(lib.d_ocp_qp_dim_memsize(N))
        lib.d_ocp_qp_dim_create(N, self.dim, dim_mem)
        for i in range(N + 1):
            for field, v in (("nx", nx[i]), ("nu", nu[i]), ("nbx", nbx[i]), ("nbu", nbu[i]), ("ng", ng[i]),
                             ("ns", nsg[i])):  # every soft row here is a general one (idxs says which)
                lib.d_ocp_qp_dim_set(field.encode(), i, v, self.dim)
        self._qp_s, self.hqp = _aligned(lib.d_ocp_qp_strsize())
        self._qp_m, qp_mem = _aligned(lib.d_ocp_qp_memsize(self.dim))
        lib.d_ocp_qp_create(self.dim, self.hqp, qp_mem)
        dp = lambda a: a.ctypes.data_as(C.c_void_p)  # noqa: E731
        for i in range(N + 1):
            fields = [("Q", Q[i]), ("S", S[i]), ("R", R[i]), ("q", q[i]), ("r", r[i])]
            if i < N:
                fields += [("A", A[i]), ("B", B[i]), ("b", b[i])]
            if nbx[i]:
                fields += [("idxbx", idxbx[i]), ("lbx", lbx[i]), ("ubx", ubx[i])]
            if nbu[i]:
                fields += [("idxbu", idxbu[i]), ("lbu", lbu[i]), ("ubu", ubu[i])]
            if ng[i]:
                fields += [("C", Cg[i]), ("D", Dg[i]), ("lg", lg[i]), ("ug", ug[i])]
            if nsg[i]:
                fields += [("idxs", idxs[i]), ("Zl", Zl[i]), ("Zu", Zu[i]), ("zl", zl[i]), ("zu", zu[i]),
                           ("lls", ls[i]), ("lus", us[i])]
            for field, arr in fields:
                if arr.size:
                    if os.environ.get("RVD_HPIPM_TRACE"):
                        print("set", field, i, arr.shape, flush=True)
                    lib.d_ocp_qp_set(field.encode(), i, dp(arr), self.hqp)
        self._sol_s, self.sol = _aligned(lib.d_ocp_qp_sol_strsize())
        self._sol_m, sol_mem = _aligned(lib.d_ocp_qp_sol_memsize(self.dim))
        lib.d_ocp_qp_sol_create(self.dim, self.sol, sol_mem)
        self._arg_s, self.arg = _aligned(lib.d_ocp_qp_ipm_arg_strsize())
        self._arg_m, arg_mem = _aligned(lib.d_ocp_qp_ipm_arg_memsize(self.dim))
        lib.d_ocp_qp_ipm_arg_create(self.dim, self.arg, arg_mem)
        lib.d_ocp_qp_ipm_arg_set_default(MODES[mode], self.arg)
        t = C.c_double(tol)
        for name in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp"):
            getattr(lib, f"d_ocp_qp_ipm_arg_set_{name}")(C.byref(t), self.arg)
        it = C.c_int(iter_max)
        lib.d_ocp_qp_ipm_arg_set_iter_max(C.byref(it), self.arg)
        if mu0 is not None:
            m0 = C.c_double(mu0)
            lib.d_ocp_qp_ipm_arg_set_mu0(C.byref(m0), self.arg)
        w0 = C.c_int(0)
        lib.d_ocp_qp_ipm_arg_set_warm_start(C.byref(w0), self.arg)
        self._ws_s, self.ws = _aligned(lib.d_ocp_qp_ipm_ws_strsize())
        self._ws_m, ws_mem = _aligned(lib.d_ocp_qp_ipm_ws_memsize(self.dim, self.arg))
        lib.d_ocp_qp_ipm_ws_create(self.dim, self.arg, self.ws, ws_mem)
        self._solve = lib.d_ocp_qp_ipm_solve
        self._lib = lib

    def solve(self):
        """(status, iterations, own solve time in us, x (N+1) x nx, u list)."""
        t0 = time.perf_counter_ns()
        self._solve(self.hqp, self.sol, self.arg, self.ws)
        t_ns = time.perf_counter_ns() - t0 - call_overhead_ns()
        st, it = C.c_int(), C.c_int()
        self._lib.d_ocp_qp_ipm_get_status(self.ws, C.byref(st))
        self._lib.d_ocp_qp_ipm_get_iter(self.ws, C.byref(it))
        qp = self.qp
        x = np.zeros((qp.N + 1, qp.nx))
        x[0] = qp.x0
        u = []
        for i in range(qp.N + 1):
            ui = np.zeros(qp.nu[i])
            if qp.nu[i]:
                self._lib.d_ocp_qp_sol_get_u(i, self.sol, ui.ctypes.data_as(C.POINTER(C.c_double)))
            u.append(ui)
            if i > 0:
                xi = np.zeros(qp.nx)
                self._lib.d_ocp_qp_sol_get_x(i, self.sol, xi.ctypes.data_as(C.POINTER(C.c_double)))
                x[i] = xi
        # status 0 success, 1 max iter, 2 min step, 3 NaN
        return int(st.value), int(it.value), max(t_ns, 0.0) / 1e3, x, u


if __name__ == "__main__":  # a smoke run: one phase QP of each kind against the reference
    from support.qp_forms import PHASES, solve_proxsuite
    rng = np.random.default_rng(0)
    print(version(), f"call overhead {call_overhead_ns():.0f} ns")
    for name, gen in PHASES.items():
        qp = gen(15, rng)
        s = HpipmSolver(qp)
        st, it, t, x, u = s.solve()
        ref = solve_proxsuite(qp)
        print(name, st, it, f"{t:.1f} us", qp.objective(x, u), ref.objective, qp.violation(x, u))
