"""HPIPM (Frison & Diehl, "HPIPM: a high-performance quadratic programming framework for model
predictive control", 2020) as a peer, through the C API of the libhpipm / libblasfeo that casadi's
wheel bundles (``pip install casadi``), called with ctypes. HPIPM gets the QP in its own OCP form,
the way an HPIPM user would write it:

  * x0 eliminated (nx_0 = 0, b_0 <- A_0 x0 + b_0; stage-0 rows move C_0 x0 to the right-hand side,
    rows left without any variable are constants and dropped);
  * rows with one nonzero on one input or one state become box bounds (idxbu / idxbx), the rest
    general rows (C, D; column-major, as are A, B; S = 0, HPIPM's nu x nx);
  * one-sided rows: the missing side is switched off with HPIPM's constraint masks (lbu_mask,
    ubu_mask, lbx_mask, ubx_mask, lg_mask = 0), so it is no constraint at all (no placeholder bound,
    no multiplier, not in the complementarity measure);
  * soft rows as HPIPM's own soft constraints (idxs; penalties zu, Zu on the upper side, the same on
    the lower slack, whose bound row is masked: that slack goes to 0; slack bounds lls = lus = 0);
  * the modes are HPIPM's presets (SPEED, ROBUST, ...) with iter_max raised to 100; tolerances
    relative to the QP's data (HpipmSolver); HPIPM's own cold start, or (init="rollout") the primal
    guess a user can give it, with mu0 at the cost's scale as HPIPM's examples advise.

Timing: wall time of the one d_ocp_qp_ipm_solve call, minus the ctypes call overhead (measured in
the same process on d_ocp_qp_dim_get, four arguments like the solve, median of 3000 calls, about
1 us): HPIPM's own solve time. Set-up (dims, packing the data, workspace, the initial guess) is not
timed.

The library: casadi's wheel builds BLASFEO for TARGET=GENERIC (plain C kernels, no SIMD), the
build that runs on any x86-64 CPU. RVD_HPIPM_LIB_DIR=<folder with libhpipm.so and libblasfeo.so>
points the binding at a build of one's own (same C API); the same BLASFEO and HPIPM commits built
for X64_INTEL_HASWELL (AVX2, FMA) were, on the closed-loop set (medians per phase and horizon, one
run each, load 1.5-2 on 2 cores), 1.3-2.4x faster in SPEED mode on rendezvous and approach, 0.9-1.2x
on docking, and 0.7-1.7x in ROBUST mode; iterations the same up to rounding.
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
PRESET_MU0 = {"speed_abs": 1e1, "speed": 1e1, "balance": 1e1, "robust": 1e2}  # hpipm's arg_set_default
STATUS = {0: "success", 1: "max iterations", 2: "min step", 3: "NaN", 4: "inconsistent equality"}
_lib = None
_blasfeo = None
_overhead_ns = None


def library_dir() -> Path:
    """The folder of libhpipm.so / libblasfeo.so: $RVD_HPIPM_LIB_DIR, else casadi's package folder."""
    env = os.environ.get("RVD_HPIPM_LIB_DIR")
    if env:
        return Path(env)
    import casadi
    return Path(casadi.__file__).parent


def library() -> C.CDLL:
    global _lib, _blasfeo
    if _lib is None:
        d = library_dir()
        _blasfeo = C.CDLL(str(d / "libblasfeo.so"), mode=C.RTLD_GLOBAL)
        _lib = C.CDLL(str(d / "libhpipm.so"))
        for name in ("d_ocp_qp_dim_strsize", "d_ocp_qp_strsize", "d_ocp_qp_sol_strsize", "d_ocp_qp_ipm_arg_strsize",
                     "d_ocp_qp_ipm_ws_strsize", "d_ocp_qp_dim_memsize", "d_ocp_qp_memsize", "d_ocp_qp_sol_memsize",
                     "d_ocp_qp_ipm_arg_memsize", "d_ocp_qp_ipm_ws_memsize"):
            getattr(_lib, name).restype = C.c_size_t
    return _lib


def version() -> str:
    """Where the libraries come from and what BLASFEO was built for. BLASFEO has no version call; its
    processor_library_string lists the instruction-set features the build uses (empty for the
    GENERIC target, which its kernel files then name)."""
    library()
    d = library_dir()
    so = sorted(p.name for p in d.glob("libblasfeo.so.*.*"))  # libblasfeo.so.<version>
    txt = f"HPIPM/BLASFEO from {d}" + (f" (BLASFEO {so[-1][len('libblasfeo.so.'):]})" if so else "")
    try:
        buf = C.create_string_buffer(512)
        _blasfeo.blasfeo_processor_library_string(buf)
        feats = buf.value.decode().strip()
    except AttributeError:
        feats = ""
    if feats:
        return txt + f"; BLASFEO built for: {feats}"
    blob = (d / "libblasfeo.so").read_bytes()
    generic = b"kernel_align_generic.c" in blob or b"_8x4_lib4" not in blob
    return txt + ("; BLASFEO target GENERIC (plain C kernels, no SIMD)" if generic else "; BLASFEO target unknown")


def _aligned(size: int):
    buf = C.create_string_buffer(size + 128)
    addr = (C.addressof(buf) + 63) // 64 * 64
    return buf, C.c_void_p(addr)


def call_overhead_ns() -> float:
    """Median cost of one ctypes call of an HPIPM function with four arguments (the solve's
    signature): d_ocp_qp_dim_get, which compares a field name and copies one int."""
    global _overhead_ns
    if _overhead_ns is None:
        lib = library()
        keep = [_aligned(lib.d_ocp_qp_dim_strsize()), _aligned(lib.d_ocp_qp_dim_memsize(1))]
        dim = keep[0][1]
        lib.d_ocp_qp_dim_create(1, dim, keep[1][1])
        f = lib.d_ocp_qp_dim_get
        field = C.c_char_p(b"nx")
        out = C.c_int()
        ref = C.byref(out)
        samples = []
        for _ in range(3000):
            t0 = time.perf_counter_ns()
            f(dim, field, 0, ref)
            samples.append(time.perf_counter_ns() - t0)
        _overhead_ns = float(np.median(samples))
    return _overhead_ns


def cost_scale(qp: OcpQpData) -> float:
    """The largest |entry| of the cost data (Q, R, q, r and the soft rows' penalties)."""
    m = 0.0
    for blk in list(qp.Q) + list(qp.R) + list(qp.q) + list(qp.r) + list(qp.zs or []) + list(qp.Zs or []):
        a = np.asarray(blk, float)
        if a.size:
            m = max(m, float(np.max(np.abs(a))))
    return m


def ocp_form(qp: OcpQpData) -> list[dict]:
    """HPIPM's per-stage data for `qp` (see the module docstring): one dict per stage with nx, nu,
    idxbu/lbu/ubu and their masks, idxbx/lbx/ubx and masks, C, D, lg, ug and masks, idxs and the
    soft penalties, the cost and (i < N) the dynamics. Masked-off sides carry the bound 0."""
    N, nxf = qp.N, qp.nx
    x0 = np.asarray(qp.x0, float)
    stages = []
    for i in range(N + 1):
        soft = {}
        if qp.idxs is not None:
            for k, j in enumerate(qp.idxs[i]):
                soft[int(j)] = (float(qp.zs[i][k]), float(qp.Zs[i][k]))
        Ci = np.asarray(qp.C[i], float)
        Di = np.asarray(qp.D[i], float)
        di = np.asarray(qp.d[i], float).copy()
        nx = nxf if i > 0 else 0
        nu = qp.R[i].shape[0]
        if i == 0:
            di = di - Ci @ x0
            Ci = np.zeros((Ci.shape[0], 0))
        ub_u, lb_u, ub_x, lb_x = {}, {}, {}, {}
        gen = []
        for j in range(Ci.shape[0]):
            cu = np.flatnonzero(Di[j]) if nu else np.zeros(0, int)
            cx = np.flatnonzero(Ci[j]) if nx else np.zeros(0, int)
            if len(cu) == 0 and len(cx) == 0:
                continue  # a constant row (x0 alone); the QP set holds it (a soft one is a constant cost)
            if j not in soft and len(cu) + len(cx) == 1:
                if len(cu):
                    a, c, ub, lb = Di[j, cu[0]], int(cu[0]), ub_u, lb_u
                else:
                    a, c, ub, lb = Ci[j, cx[0]], int(cx[0]), ub_x, lb_x
                bound = di[j] / a
                if a > 0:
                    ub[c] = min(ub.get(c, np.inf), bound)
                else:
                    lb[c] = max(lb.get(c, -np.inf), bound)
                continue
            gen.append(j)
        s = {"nx": nx, "nu": nu}
        for kind, ub, lb in (("u", ub_u, lb_u), ("x", ub_x, lb_x)):
            idx = sorted(set(ub) | set(lb))
            s[f"idxb{kind}"] = np.array(idx, np.int32)
            s[f"lb{kind}"] = np.array([lb.get(c, 0.0) for c in idx], float)
            s[f"ub{kind}"] = np.array([ub.get(c, 0.0) for c in idx], float)
            s[f"lb{kind}_mask"] = np.array([1.0 if c in lb else 0.0 for c in idx])
            s[f"ub{kind}_mask"] = np.array([1.0 if c in ub else 0.0 for c in idx])
        s["C"] = np.asfortranarray(Ci[gen]) if nx else np.zeros((len(gen), 0), order="F")
        s["D"] = np.asfortranarray(Di[gen]) if nu else np.zeros((len(gen), 0), order="F")
        s["ug"] = di[gen].copy()
        s["lg"] = np.zeros(len(gen))
        s["lg_mask"] = np.zeros(len(gen))  # every row here is C x + D u <= d: no lower side
        s["ug_mask"] = np.ones(len(gen))
        # Soft rows: indices into HPIPM's [bu, bx, g] list of this stage.
        nb = len(s["idxbu"]) + len(s["idxbx"])
        sidx = [nb + k for k, j in enumerate(gen) if j in soft]
        pen = [soft[j] for j in gen if j in soft]
        s["idxs"] = np.array(sidx, np.int32)
        s["zu"] = np.array([p[0] for p in pen], float)
        s["Zu"] = np.array([p[1] for p in pen], float)
        s["zl"], s["Zl"] = s["zu"].copy(), s["Zu"].copy()  # the lower slack: its row is masked, so it is 0
        s["lls"] = np.zeros(len(sidx))
        s["lus"] = np.zeros(len(sidx))
        if i < N:
            Ai = np.asarray(qp.A[i], float)
            s["A"] = np.asfortranarray(Ai if i > 0 else np.zeros((nxf, 0)))
            s["B"] = np.asfortranarray(np.asarray(qp.B[i], float))
            s["b"] = np.asarray(qp.b[i], float) + (Ai @ x0 if i == 0 else 0.0)
        s["Q"] = np.asfortranarray(np.asarray(qp.Q[i], float) if i > 0 else np.zeros((0, 0)))
        s["q"] = np.asarray(qp.q[i], float) if i > 0 else np.zeros(0)
        s["R"] = np.asfortranarray(np.asarray(qp.R[i], float))
        s["r"] = np.asarray(qp.r[i], float)
        s["S"] = np.zeros((nu, nx), order="F")
        stages.append(s)
    return stages


class HpipmSolver:
    """One QP set up in HPIPM's structures (not timed); solve() runs the interior point (timed).

    Tolerances. HPIPM's are absolute, on the inf-norms of its residuals; by default they are
    flight_sw's tol = 1e-8 made relative to the QP's data, once per QP: tol_stat = tol x max(1,
    largest |entry| of Q, R, q, r, penalties), tol_eq = tol_ineq = tol_comp = tol x max(1, largest
    |entry| of x0, b, d) (complementarity products t lam are in the rows' units). Absolute ones do
    not fit these QPs: 1e-6 on the stationarity of km-scale rendezvous data is below its rounding
    floor (SPEED stops at max iterations or min step), 1e-8 on complementarity asks for slacks of
    1e-13 m on rows of 1e3 m; an absolute 2e-2 (1e-8 x R = 2e6) on docking's complementarity stops
    with objectives off by 1e-3. rel_tol=False takes `tol` as absolute for all four.

    init "cold": HPIPM's own cold start (primal 0, its slack / dual heuristics); "rollout": the
    primal guess u = 0 with the states rolled out from x0 (warm_start 1), set before each solve, not
    timed. mu0: None keeps the preset's, "cost" = max(preset's, largest |cost entry|) (HPIPM's
    examples: "max element in cost function as estimate of max multiplier"), or a number.
    masks=False puts the missing sides of one-sided rows at -+1e4 instead (for comparisons only).
    """

    def __init__(self, qp: OcpQpData, mode: str = "speed", tol: float = 1e-8, rel_tol: bool = True,
                 iter_max: int = 100, mu0: float | str | None = None, masks: bool = True, init: str = "cold"):
        lib = library()
        self.qp = qp
        N = qp.N
        st = ocp_form(qp)
        if not masks:  # the missing sides as placeholder bounds at -+1e4, every side active
            for s in st:
                for k in ("lbu", "lbx", "lg"):
                    s[k] = np.where(s[k + "_mask"] > 0, s[k], -1e4)
                    s[k + "_mask"] = np.ones_like(s[k + "_mask"])
                for k in ("ubu", "ubx", "ug"):
                    s[k] = np.where(s[k + "_mask"] > 0, s[k], 1e4)
                    s[k + "_mask"] = np.ones_like(s[k + "_mask"])
        self.stages = st  # referenced while HPIPM copies it in
        self._dim_s, self.dim = _aligned(lib.d_ocp_qp_dim_strsize())
        self._dim_m, dim_mem = _aligned(lib.d_ocp_qp_dim_memsize(N))
        lib.d_ocp_qp_dim_create(N, self.dim, dim_mem)
        for i, s in enumerate(st):
            for field, v in (("nx", s["nx"]), ("nu", s["nu"]), ("nbx", len(s["idxbx"])), ("nbu", len(s["idxbu"])),
                             ("ng", len(s["ug"])), ("ns", len(s["idxs"]))):
                lib.d_ocp_qp_dim_set(field.encode(), i, v, self.dim)
        self._qp_s, self.hqp = _aligned(lib.d_ocp_qp_strsize())
        self._qp_m, qp_mem = _aligned(lib.d_ocp_qp_memsize(self.dim))
        lib.d_ocp_qp_create(self.dim, self.hqp, qp_mem)
        dp = lambda a: a.ctypes.data_as(C.c_void_p)  # noqa: E731
        for i, s in enumerate(st):
            fields = ["Q", "S", "R", "q", "r"] + (["A", "B", "b"] if i < N else [])
            if len(s["idxbx"]):
                fields += ["idxbx", "lbx", "ubx", "lbx_mask", "ubx_mask"]
            if len(s["idxbu"]):
                fields += ["idxbu", "lbu", "ubu", "lbu_mask", "ubu_mask"]
            if len(s["ug"]):
                fields += ["C", "D", "lg", "ug", "lg_mask", "ug_mask"]
            if len(s["idxs"]):
                fields += ["idxs", "Zl", "Zu", "zl", "zu", "lls", "lus"]
            for field in fields:
                arr = s[field]
                if arr.size:
                    lib.d_ocp_qp_set(field.encode(), i, dp(arr), self.hqp)
        self._sol_s, self.sol = _aligned(lib.d_ocp_qp_sol_strsize())
        self._sol_m, sol_mem = _aligned(lib.d_ocp_qp_sol_memsize(self.dim))
        lib.d_ocp_qp_sol_create(self.dim, self.sol, sol_mem)
        self._arg_s, self.arg = _aligned(lib.d_ocp_qp_ipm_arg_strsize())
        self._arg_m, arg_mem = _aligned(lib.d_ocp_qp_ipm_arg_memsize(self.dim))
        lib.d_ocp_qp_ipm_arg_create(self.dim, self.arg, arg_mem)
        lib.d_ocp_qp_ipm_arg_set_default(MODES[mode], self.arg)
        cscale = max(1.0, cost_scale(qp))
        if rel_tol:
            rhs = [np.asarray(qp.x0, float)] + [np.asarray(v, float) for v in list(qp.b) + list(qp.d)]
            bscale = max([1.0] + [float(np.max(np.abs(v))) for v in rhs if v.size])
            self.tols = {"tol_stat": tol * cscale, "tol_eq": tol * bscale, "tol_ineq": tol * bscale,
                         "tol_comp": tol * bscale}
        else:
            self.tols = {k: tol for k in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp")}
        for name, v in self.tols.items():
            t = C.c_double(v)
            getattr(lib, f"d_ocp_qp_ipm_arg_set_{name}")(C.byref(t), self.arg)
        it = C.c_int(iter_max)
        lib.d_ocp_qp_ipm_arg_set_iter_max(C.byref(it), self.arg)
        if mu0 == "cost":
            mu0 = max(PRESET_MU0[mode], cscale)
        self.mu0 = mu0 if mu0 is not None else PRESET_MU0[mode]
        if mu0 is not None:
            m0 = C.c_double(mu0)
            lib.d_ocp_qp_ipm_arg_set_mu0(C.byref(m0), self.arg)
        self.init = init
        w0 = C.c_int(1 if init == "rollout" else 0)
        lib.d_ocp_qp_ipm_arg_set_warm_start(C.byref(w0), self.arg)
        if init == "rollout":  # the primal guess: u = 0, states rolled out from x0 (HPIPM's warm_start 1)
            xs = [np.asarray(qp.x0, float)]
            for i in range(N):
                xs.append(np.asarray(qp.A[i], float) @ xs[-1] + np.asarray(qp.b[i], float))
            self._guess = [(np.zeros(st[i]["nu"]), xs[i] if i > 0 else np.zeros(0), np.zeros(len(st[i]["idxs"])))
                           for i in range(N + 1)]
        self._ws_s, self.ws = _aligned(lib.d_ocp_qp_ipm_ws_strsize())
        self._ws_m, ws_mem = _aligned(lib.d_ocp_qp_ipm_ws_memsize(self.dim, self.arg))
        lib.d_ocp_qp_ipm_ws_create(self.dim, self.arg, self.ws, ws_mem)
        self._solve = lib.d_ocp_qp_ipm_solve
        self._lib = lib
        call_overhead_ns()

    def solve(self):
        """(status, iterations, own solve time in us, x (N+1) x nx, u list); status 0 success, 1 max
        iterations, 2 min step, 3 NaN (STATUS)."""
        if self.init == "rollout":  # not timed: the guess is data, as in any warm-started solve
            for i, (ui, xi, si) in enumerate(self._guess):
                if si.size:
                    self._lib.d_ocp_qp_sol_set_sl(i, si.ctypes.data_as(C.c_void_p), self.sol)
                    self._lib.d_ocp_qp_sol_set_su(i, si.ctypes.data_as(C.c_void_p), self.sol)
                if ui.size:
                    self._lib.d_ocp_qp_sol_set_u(i, ui.ctypes.data_as(C.c_void_p), self.sol)
                if xi.size:
                    self._lib.d_ocp_qp_sol_set_x(i, xi.ctypes.data_as(C.c_void_p), self.sol)
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
        return int(st.value), int(it.value), max(t_ns, 0.0) / 1e3, x, u

    def residuals(self) -> dict:
        """HPIPM's own inf-norm residuals after the last solve (stat, eq, ineq, comp)."""
        out = {}
        for name in ("stat", "eq", "ineq", "comp"):
            v = C.c_double()
            getattr(self._lib, f"d_ocp_qp_ipm_get_max_res_{name}")(self.ws, C.byref(v))
            out[name] = v.value
        return out


if __name__ == "__main__":  # a smoke run: one phase QP of each kind against the reference
    from support.qp_forms import PHASES, solve_proxsuite
    rng = np.random.default_rng(0)
    print(version(), f"call overhead {call_overhead_ns():.0f} ns")
    for name, gen in PHASES.items():
        qp = gen(15, rng)
        ref = solve_proxsuite(qp)
        for mode in ("speed", "robust"):
            s = HpipmSolver(qp, mode=mode)
            st, it, t, x, u = s.solve()
            print(name, mode, STATUS.get(st, st), it, f"{t:.1f} us", qp.objective(x, u), ref.objective,
                  qp.violation(x, u))
