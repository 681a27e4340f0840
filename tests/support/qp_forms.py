"""MPC-like stage-wise OCP QPs for rvd-pil, their conversions to the forms peer solvers take, and the
QP-set file format.

The stage-wise QP (as in ``flight_sw/solver/ocp_qp.hpp``)::

    minimize   sum_{i=0..N} 1/2 x_i'Q_i x_i + q_i'x_i + 1/2 u_i'R_i u_i + r_i'u_i
    subject to x_0 = x0,  x_{i+1} = A_i x_i + B_i u_i + b_i  (i < N),  C_i x_i + D_i u_i <= d_i  (i <= N)

with soft rows: row j = idxs[i][k] of stage i may be violated by s >= 0 at the cost
zs[i][k] s + Zs[i][k] s^2 / 2 (the objective below is taken at the least violation s*).
States are LVLH position [m] and velocity [m/s] (x radial out, y along-track / V-bar, z orbit
normal); inputs are impulsive delta-v [m/s] per axis. Peers without soft constraints get the
expanded form (:func:`expand_soft`: one slack input and one row s >= 0 per soft row).

QP-set file (``.npz``, written by :func:`save_qp_set`, read by :func:`load_qp_set`): flat keys,
one group per QP ``k`` (``k`` = 0 .. n_qps-1)::

    n_qps                      int, number of QPs
    qp{k}/phase                str, e.g. "rendezvous", "approach", "docking" (free text)
    qp{k}/N                    int, horizon
    qp{k}/x0                   (nx,) initial state
    qp{k}/{A,B,b}/{i}          i = 0..N-1: (nx,nx), (nx,nu_i), (nx,)
    qp{k}/{Q,q,R,r,C,D,d}/{i}  i = 0..N:   (nx,nx), (nx,), (nu_i,nu_i), (nu_i,), (nc_i,nx), (nc_i,nu_i), (nc_i,)
    qp{k}/Ts                   optional, sampling period [s]
    qp{k}/{idxs,zs,Zs}/{i}     optional (soft rows), i = 0..N: (ns_i,) int, (ns_i,), (ns_i,)

Empty blocks are stored with their zero dimension (e.g. R_N of shape (0, 0)). No pickled objects.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import scipy.sparse as sp

MU_EARTH_M3_S2 = 3.986004418e14
R_EARTH_M = 6378137.0
STAGE_NAMES = ("Q", "q", "R", "r", "C", "D", "d")
DYN_NAMES = ("A", "B", "b")


def mean_motion_rad_s(altitude_m: float = 500e3) -> float:
    """Mean motion of a circular orbit at this altitude [rad/s]."""
    a = R_EARTH_M + altitude_m
    return float(np.sqrt(MU_EARTH_M3_S2 / a**3))


def cw_stm(n_rad_s: float, t_s: float) -> np.ndarray:
    """Clohessy-Wiltshire state transition matrix (LVLH: x radial, y along-track, z normal)."""
    s, c, nt = np.sin(n_rad_s * t_s), np.cos(n_rad_s * t_s), n_rad_s * t_s
    n = n_rad_s
    return np.array([
        [4 - 3 * c, 0, 0, s / n, 2 * (1 - c) / n, 0],
        [6 * (s - nt), 1, 0, 2 * (c - 1) / n, (4 * s - 3 * nt) / n, 0],
        [0, 0, c, 0, 0, s / n],
        [3 * n * s, 0, 0, c, 2 * s, 0],
        [6 * n * (c - 1), 0, 0, -2 * s, 4 * c - 3, 0],
        [0, 0, -n * s, 0, 0, c],
    ])


def cw_impulsive(ts_s: float, altitude_m: float = 500e3) -> tuple[np.ndarray, np.ndarray]:
    """A = Phi(Ts), B = Phi(Ts)[:, 3:] : a delta-v applied at the start of the period."""
    A = cw_stm(mean_motion_rad_s(altitude_m), ts_s)
    return A, A[:, 3:].copy()


@dataclasses.dataclass
class OcpQpData:
    """One stage-wise QP as lists of per-stage numpy arrays (the argument lists of flight_sw.solve_ocp_qp)."""
    A: list
    B: list
    b: list
    Q: list
    q: list
    R: list
    r: list
    C: list
    D: list
    d: list
    x0: np.ndarray
    phase: str = ""
    Ts: float = float("nan")
    idxs: list | None = None  # soft rows per stage (None: none)
    zs: list | None = None
    Zs: list | None = None

    @property
    def N(self) -> int:
        return len(self.A)

    @property
    def nx(self) -> int:
        return self.A[0].shape[0]

    @property
    def nu(self) -> list[int]:
        return [R.shape[0] for R in self.R]

    @property
    def nc(self) -> list[int]:
        return [C.shape[0] for C in self.C]

    @property
    def ns(self) -> list[int]:
        return [len(k) for k in self.idxs] if self.idxs is not None else [0] * (self.N + 1)

    def args(self) -> tuple:
        return (self.A, self.B, self.b, self.Q, self.q, self.R, self.r, self.C, self.D, self.d, self.x0)

    def kw(self) -> dict:
        """The soft rows as flight_sw.solve_ocp_qp's keyword arguments (empty when there are none)."""
        return {} if self.idxs is None else {"idxs": self.idxs, "zs": self.zs, "Zs": self.Zs}

    def hard_rows(self, i: int) -> np.ndarray:
        mask = np.ones(self.C[i].shape[0], bool)
        if self.idxs is not None:
            mask[np.asarray(self.idxs[i], int)] = False
        return mask

    def objective(self, x: np.ndarray, u: list) -> float:
        """Objective at states x ((N+1) x nx, x[0] = x0) and inputs u (N+1 arrays); soft rows at their
        least violation s* = max(row - d, 0) (inputs beyond nu_i, e.g. a peer's slacks, are ignored)."""
        f = 0.0
        for i in range(self.N + 1):
            ui = np.asarray(u[i])[:self.R[i].shape[0]]
            f += 0.5 * x[i] @ self.Q[i] @ x[i] + self.q[i] @ x[i]
            f += 0.5 * ui @ self.R[i] @ ui + self.r[i] @ ui
            if self.idxs is not None and len(self.idxs[i]):
                rows = np.asarray(self.idxs[i], int)
                s = np.maximum(self.C[i][rows] @ x[i] + self.D[i][rows] @ ui - self.d[i][rows], 0.0)
                f += float(self.zs[i] @ s + 0.5 * (self.Zs[i] * s) @ s)
        return float(f)

    def violation(self, x: np.ndarray, u: list) -> float:
        """Largest dynamics residual or hard-row violation (inf-norm)."""
        v = float(np.max(np.abs(x[0] - self.x0)))
        for i in range(self.N):
            ui = np.asarray(u[i])[:self.R[i].shape[0]]
            v = max(v, float(np.max(np.abs(self.A[i] @ x[i] + self.B[i] @ ui + self.b[i] - x[i + 1]))))
        for i in range(self.N + 1):
            hard = self.hard_rows(i)
            if hard.any():
                ui = np.asarray(u[i])[:self.R[i].shape[0]]
                v = max(v, float(np.max((self.C[i] @ x[i] + self.D[i] @ ui - self.d[i])[hard])))
        return v


def from_dict(d: dict, phase: str = "") -> OcpQpData:
    """A QP from the dict flight_sw's guidance bindings return (PhaseQp.build, build_phase_qp, recorded QPs)."""
    soft = {}
    if "idxs" in d:
        soft = {"idxs": [list(map(int, v)) for v in d["idxs"]], "zs": [np.asarray(v, float) for v in d["zs"]],
                "Zs": [np.asarray(v, float) for v in d["Zs"]]}
    return OcpQpData(d["A"], d["B"], d["b"], d["Q"], d["q"], d["R"], d["r"], d["C"], d["D"], d["d"],
                     np.asarray(d["x0"], float), phase=phase, **soft)


def expand_soft(qp: OcpQpData) -> OcpQpData:
    """The same QP with every soft row's slack as an input of its stage (zero in the dynamics, Hessian
    Zs, linear cost zs) and one more row -s <= 0 per slack: the form for solvers without soft rows.
    Its optimum equals the soft QP's; its first nu_i inputs are the soft QP's inputs."""
    if qp.idxs is None or not any(len(k) for k in qp.idxs):
        return qp
    B, R, r, C, D, d = [], [], [], [], [], []
    for i in range(qp.N + 1):
        nu, ns, nx = qp.R[i].shape[0], len(qp.idxs[i]), qp.nx
        rows = np.asarray(qp.idxs[i], int)
        if i < qp.N:
            B.append(np.hstack([qp.B[i], np.zeros((nx, ns))]))
        Ri = np.zeros((nu + ns, nu + ns))
        Ri[:nu, :nu] = qp.R[i]
        Ri[nu:, nu:] = np.diag(qp.Zs[i])
        R.append(Ri)
        r.append(np.concatenate([qp.r[i], qp.zs[i]]))
        E = np.zeros((qp.C[i].shape[0], ns))
        E[rows, np.arange(ns)] = -1.0
        C.append(np.vstack([qp.C[i], np.zeros((ns, nx))]))
        D.append(np.vstack([np.hstack([qp.D[i], E]), np.hstack([np.zeros((ns, nu)), -np.eye(ns)])]))
        d.append(np.concatenate([qp.d[i], np.zeros(ns)]))
    return OcpQpData(qp.A, B, qp.b, qp.Q, qp.q, R, r, C, D, d, qp.x0, qp.phase, qp.Ts)


# ------------------------------------------------------------------------------------------------
# Generators: MPC-like QPs of the three guidance phases (dissertation ch. 3) and a randomised mix.

def _cone_facets(axis: np.ndarray, half_angle_rad: float) -> np.ndarray:
    """4 x 3 facets H of the pyramid {p : H p <= 0} around unit `axis` (a polyhedral approach cone)."""
    axis = axis / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.tan(half_angle_rad)
    return np.array([e1 - t * axis, -e1 - t * axis, e2 - t * axis, -e2 - t * axis])


def _box_rows(nu: int, n_thrust: int, umax: float) -> tuple[np.ndarray, np.ndarray]:
    D = np.zeros((2 * n_thrust, nu))
    D[:n_thrust, :n_thrust] = np.eye(n_thrust)
    D[n_thrust:, :n_thrust] = -np.eye(n_thrust)
    return D, np.full(2 * n_thrust, umax)


def rendezvous_qp(N: int, rng: np.random.Generator, *, ts_s: float = 30.0, umax: float = 0.1786,
                  r1_m: float = 200.0, penalty: float = 10.0) -> OcpQpData:
    """Phase 1: |u|inf box, a keep-out hyperplane per stage (rotating towards the V-bar cone axis),
    soft terminal cone (4 soft rows on stage N, penalty per metre outside a face), set-point tracking."""
    A, B = cw_impulsive(ts_s)
    nx = 6
    rng_m = rng.uniform(800.0, 2500.0)
    ang0 = rng.uniform(-np.pi, np.pi)
    pos = rng_m * np.array([np.sin(ang0), -np.cos(ang0), 0.02 * rng.standard_normal()])
    x0 = np.concatenate([pos, rng.normal(0.0, 0.3, 3)])
    axis = np.array([0.0, -1.0, 0.0])  # approach cone along -V-bar
    x_ref = np.concatenate([(r1_m + 50.0) * axis, np.zeros(3)])
    Qd = np.diag([1.0, 1.0, 100.0, 1.0, 1.0, 10.0]) * 1e-3
    Hc = _cone_facets(axis, np.deg2rad(30.0))
    start = np.arctan2(pos[0], -pos[1])
    # The hyperplane normal turns from the chaser's bearing towards the cone axis in N equal steps,
    # no faster than the orbit rate (dissertation eqs. 3.5-3.7).
    step = np.sign(start) * min(abs(start) / N, mean_motion_rad_s() * ts_s)
    As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds = ([] for _ in range(10))
    idxs, zs, Zs = [], [], []
    for i in range(N + 1):
        theta = start - step * i
        nrm = np.array([np.sin(theta), -np.cos(theta), 0.0])
        keep_out_C = np.concatenate([-nrm, np.zeros(3)])[None, :]  # -n'p <= -r1
        if i < N:
            As.append(A)
            Bs.append(B)
            bs.append(np.zeros(nx))
            Dbox, dbox = _box_rows(3, 3, umax)
            Qs.append(Qd)
            qs.append(-Qd @ x_ref)
            Rs.append(1e3 * np.eye(3))
            rs.append(np.zeros(3))
            if i == 0:  # rows on x0 alone are constants; keep only the input box
                Cs.append(np.zeros((6, nx)))
                Ds.append(Dbox)
                ds.append(dbox)
            else:
                Cs.append(np.vstack([np.zeros((6, nx)), keep_out_C]))
                Ds.append(np.vstack([Dbox, np.zeros((1, 3))]))
                ds.append(np.concatenate([dbox, [-r1_m]]))
            idxs.append([])
            zs.append(np.zeros(0))
            Zs.append(np.zeros(0))
        else:
            Qs.append(10 * Qd)
            qs.append(-10 * Qd @ x_ref)
            Rs.append(np.zeros((0, 0)))
            rs.append(np.zeros(0))
            C = np.zeros((5, nx))
            C[:4, :3] = Hc  # H p <= 0, soft
            C[4] = keep_out_C
            Cs.append(C)
            Ds.append(np.zeros((5, 0)))
            ds.append(np.concatenate([np.zeros(4), [-r1_m]]))
            idxs.append([0, 1, 2, 3])
            zs.append(np.full(4, penalty))
            Zs.append(np.zeros(4))
    return OcpQpData(As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds, x0, "rendezvous", ts_s, idxs, zs, Zs)


def approach_qp(N: int, rng: np.random.Generator, *, ts_s: float = 20.0, umax: float = 0.1786,
                r2_m: float = 30.0, penalty: float = 10.0) -> OcpQpData:
    """Phase 2: 3 thrust inputs per stage (none on stage N), soft cone (4 soft rows) on every state
    (on stage 0 constant rows of x0, a constant penalty), hard overshoot plane, |u|inf box."""
    A, B3 = cw_impulsive(ts_s)
    nx = 6
    axis = np.array([0.0, -1.0, 0.0])
    Hc = _cone_facets(axis, np.deg2rad(20.0))
    dist = rng.uniform(150.0, 400.0)
    off = rng.normal(0.0, 0.15 * dist, 3)
    x0 = np.concatenate([dist * axis + off * np.array([1, 0, 1]), rng.normal(0.0, 0.1, 3)])
    x_ref = np.concatenate([(r2_m + 5.0) * axis, np.zeros(3)])
    Qd = np.eye(nx) * 1e-2
    As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds = ([] for _ in range(10))
    idxs, zs, Zs = [], [], []
    for i in range(N + 1):
        nu = 3 if i < N else 0
        C = np.zeros((2 * nu + 5, nx))
        D = np.zeros((2 * nu + 5, nu))
        d = np.zeros(2 * nu + 5)
        if nu:
            D[:2 * nu], d[:2 * nu] = _box_rows(nu, nu, umax)
        o = 2 * nu
        C[o:o + 4, :3] = Hc  # H p <= 0, soft
        C[o + 4, :3] = -axis  # overshoot plane: axis'p >= r2  ->  -axis'p <= -r2
        d[o + 4] = -r2_m
        if i < N:
            As.append(A)
            Bs.append(B3)
            bs.append(np.zeros(nx))
        Qs.append(Qd)
        qs.append(-Qd @ x_ref)
        Rs.append(1e3 * np.eye(nu) * 1e-2)
        rs.append(np.zeros(nu))
        if i == 0:  # the overshoot row on x0 alone is a constant: drop it
            C, D, d = C[:-1], D[:-1], d[:-1]
        Cs.append(C)
        Ds.append(D)
        ds.append(d)
        idxs.append(list(range(o, o + 4)))
        zs.append(np.full(4, penalty * 1e-2))
        Zs.append(np.zeros(4))
    return OcpQpData(As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds, x0, "approach", ts_s, idxs, zs, Zs)


def docking_qp(N: int, rng: np.random.Generator, *, ts_s: float = 5.0, umax: float = 0.0357,
               vmax: float = 0.1, half_angle_deg: float = 8.0, r3_m: float = 0.5) -> OcpQpData:
    """Phase 3: hard cone (4 rows) about the docking port, |v|inf <= vmax (6 rows), |u|inf box (6 rows);
    no input on stage N. Stage 0's cone and velocity rows involve x0 only (constants)."""
    A, B = cw_impulsive(ts_s)
    nx = 6
    axis = np.array([0.0, -1.0, 0.0])
    port = r3_m * axis
    Hc = _cone_facets(axis, np.deg2rad(half_angle_deg))
    dist = rng.uniform(5.0, 30.0)
    lateral = rng.uniform(-0.5, 0.5, 2) * np.tan(np.deg2rad(half_angle_deg)) * dist
    pos = port + dist * axis + np.array([lateral[0], 0.0, lateral[1]])
    x0 = np.concatenate([pos, rng.uniform(-0.3, 0.3, 3) * vmax])
    x_ref = np.concatenate([port, np.zeros(3)])
    Qd = 20.0 * np.eye(nx)
    As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds = ([] for _ in range(10))
    for i in range(N + 1):
        nu = 3 if i < N else 0
        C = np.zeros((10, nx))
        C[:4, :3] = Hc
        C[4:7, 3:] = np.eye(3)
        C[7:10, 3:] = -np.eye(3)
        d = np.concatenate([Hc @ port, np.full(6, vmax)])
        D = np.zeros((10, nu))
        if nu:
            Dbox, dbox = _box_rows(nu, 3, umax)
            C = np.vstack([C, np.zeros((6, nx))])
            D = np.vstack([D, Dbox])
            d = np.concatenate([d, dbox])
            As.append(A)
            Bs.append(B)
            bs.append(np.zeros(nx))
        Qs.append(Qd)
        qs.append(-Qd @ x_ref)
        Rs.append(1e6 * np.eye(nu))
        rs.append(np.zeros(nu))
        Cs.append(C)
        Ds.append(D)
        ds.append(d)
    return OcpQpData(As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds, x0, "docking", ts_s)


def random_mpc_qp(N: int, rng: np.random.Generator, *, ts_s: float | None = None, umax: float = 0.2,
                  n_hard: int = 2, n_soft: int = 2, stage0_const_rows: bool = True) -> OcpQpData:
    """A randomised MPC-like QP that is feasible by construction: CW dynamics, 3 thrust inputs plus
    0-4 slack inputs on each stage (stage-varying sizes), |u|inf box, hard halfspaces on the state
    that a reference rollout satisfies (some exactly, so they are active), soft halfspaces with
    slack inputs, PSD state cost, random x0. Stage 0 may carry constant rows on x0 alone (satisfied)."""
    ts = ts_s if ts_s is not None else float(rng.choice([5.0, 20.0, 30.0]))
    A, B3 = cw_impulsive(ts)
    nx = 6
    x0 = np.concatenate([rng.normal(0.0, 300.0, 3), rng.normal(0.0, 0.2, 3)])
    n_slack = [int(rng.integers(0, 5)) for _ in range(N + 1)]
    n_thrust = [3] * N + [int(rng.choice([0, 3]))]
    # Reference rollout inside the input box: the hard rows are built around it, so it is feasible.
    x_ref = [x0]
    u_ref = []
    for i in range(N):
        u_ref.append(rng.uniform(-0.8 * umax, 0.8 * umax, 3))
        x_ref.append(A @ x_ref[-1] + B3 @ u_ref[-1])
    As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds = ([] for _ in range(10))
    target = np.concatenate([rng.normal(0.0, 200.0, 3), np.zeros(3)])
    for i in range(N + 1):
        nth, nsl = n_thrust[i], n_slack[i]
        nu = nth + nsl
        rows_C, rows_D, rows_d = [], [], []
        if nth:
            Dbox, dbox = _box_rows(nu, nth, umax)
            rows_C.append(np.zeros((2 * nth, nx)))
            rows_D.append(Dbox)
            rows_d.append(dbox)
        if i > 0:
            for _ in range(n_hard):
                a = np.concatenate([rng.standard_normal(3), 0.3 * rng.standard_normal(3)])
                margin = 0.0 if rng.random() < 0.5 else rng.uniform(0.0, 50.0)
                rows_C.append(a[None, :])
                rows_D.append(np.zeros((1, nu)))
                rows_d.append([a @ x_ref[i] + margin])
        elif stage0_const_rows:  # a satisfied constant row (x0 only): must not disturb the solve
            a = rng.standard_normal(nx)
            rows_C.append(a[None, :])
            rows_D.append(np.zeros((1, nu)))
            rows_d.append([a @ x0 + 1.0])
        for k in range(nsl):  # soft halfspace a'p - v_k <= c and v_k >= 0
            a = rng.standard_normal(3)
            a /= np.linalg.norm(a)
            c = a @ x_ref[i][:3] - rng.uniform(0.0, 100.0)
            Crow = np.zeros((2, nx))
            Crow[0, :3] = a
            Drow = np.zeros((2, nu))
            Drow[0, nth + k] = -1.0
            Drow[1, nth + k] = -1.0
            rows_C.append(Crow)
            rows_D.append(Drow)
            rows_d.append([c, 0.0])
        C = np.vstack(rows_C) if rows_C else np.zeros((0, nx))
        D = np.vstack(rows_D) if rows_D else np.zeros((0, nu))
        d = np.concatenate([np.asarray(x, float) for x in rows_d]) if rows_d else np.zeros(0)
        qdiag = rng.uniform(0.0, 1.0, nx) * (rng.random(nx) < 0.7)  # PSD: some zero weights
        Q = np.diag(qdiag) * 1e-3
        M = rng.standard_normal((nth, nth))
        R = np.zeros((nu, nu))
        R[:nth, :nth] = (M @ M.T + nth * np.eye(nth)) * rng.uniform(1.0, 100.0)
        r = np.zeros(nu)
        r[:nth] = rng.normal(0.0, 1.0, nth)
        r[nth:] = rng.uniform(0.1, 10.0, nsl)
        if i < N:
            As.append(A)
            Bs.append(np.hstack([B3, np.zeros((nx, nsl))]))
            bs.append(np.zeros(nx))
        Qs.append(Q)
        qs.append(-Q @ target)
        Rs.append(R)
        rs.append(r)
        Cs.append(C)
        Ds.append(D)
        ds.append(d)
    return OcpQpData(As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds, x0, "random", ts)


def with_reach_row(qp: OcpQpData, stage: int, direction: np.ndarray, margin: float) -> OcpQpData:
    """Copy of `qp` with one more row on stage `stage`:  direction'x_stage >= reach + margin, where
    `reach` is the largest direction'x_stage any feasible plan attains (an LP, HiGHS). margin > 0
    makes the QP infeasible through the dynamics and input limits (no single row is contradictory
    by itself); margin < 0 leaves it feasible with that much room."""
    from scipy.optimize import linprog
    if not 1 <= stage <= qp.N:
        raise ValueError("stage must be in 1..N")
    s = to_stacked(qp)
    c = np.zeros(s.H.shape[0])
    c[s.x_idx[stage]] = -np.asarray(direction, float)
    lp = linprog(c, A_ub=s.Cin, b_ub=s.din, A_eq=s.Aeq, b_eq=s.beq, bounds=(None, None), method="highs")
    if lp.status != 0:
        raise ValueError(f"reach LP failed: {lp.message}")
    reach = -lp.fun
    out = dataclasses.replace(qp, C=list(qp.C), D=list(qp.D), d=list(qp.d))
    out.C[stage] = np.vstack([qp.C[stage], -np.asarray(direction, float)[None, :]])
    out.D[stage] = np.vstack([qp.D[stage], np.zeros((1, qp.D[stage].shape[1]))])
    out.d[stage] = np.concatenate([qp.d[stage], [-(reach + margin)]])
    return out


PHASES = {"rendezvous": rendezvous_qp, "approach": approach_qp, "docking": docking_qp}
# Horizons per phase for the timing sweep (the dissertation's ch. 6).
PHASE_HORIZONS = {"rendezvous": (15, 30, 45), "approach": (5, 15, 30), "docking": (5, 12, 30)}


# ------------------------------------------------------------------------------------------------
# Stacked (sparse) form: z = [u_0, x_1, u_1, ..., x_N, u_N]
#   minimize 1/2 z'Hz + g'z + const  s.t.  Aeq z = beq,  Cin z <= din

@dataclasses.dataclass
class StackedQp:
    H: sp.csc_matrix
    g: np.ndarray
    Aeq: sp.csc_matrix
    beq: np.ndarray
    Cin: sp.csc_matrix
    din: np.ndarray
    const: float
    u_idx: list  # slices of u_i in z
    x_idx: list  # slices of x_i in z (x_idx[0] is None: x0 is data)

    def unstack(self, z: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, list]:
        x = np.vstack([x0] + [z[s] for s in self.x_idx[1:]])
        u = [z[s].copy() for s in self.u_idx]
        return x, u


def to_stacked(qp: OcpQpData) -> StackedQp:
    qp = expand_soft(qp)
    N, nx = qp.N, qp.nx
    u_idx, x_idx = [], [None]
    off = 0
    for i in range(N + 1):
        if i > 0:
            x_idx.append(slice(off, off + nx))
            off += nx
        nu = qp.R[i].shape[0]
        u_idx.append(slice(off, off + nu))
        off += nu
    nz = off
    H = sp.lil_matrix((nz, nz))
    g = np.zeros(nz)
    x0 = qp.x0
    const = 0.5 * x0 @ qp.Q[0] @ x0 + qp.q[0] @ x0
    for i in range(N + 1):
        su = u_idx[i]
        if su.stop > su.start:
            H[su, su] = qp.R[i]
            g[su] = qp.r[i]
        if i > 0:
            H[x_idx[i], x_idx[i]] = qp.Q[i]
            g[x_idx[i]] = qp.q[i]
    Aeq = sp.lil_matrix((N * nx, nz))
    beq = np.zeros(N * nx)
    for i in range(N):
        rows = slice(i * nx, (i + 1) * nx)
        Aeq[rows, x_idx[i + 1]] = np.eye(nx)
        if u_idx[i].stop > u_idx[i].start:
            Aeq[rows, u_idx[i]] = -qp.B[i]
        if i == 0:
            beq[rows] = qp.A[0] @ x0 + qp.b[0]
        else:
            Aeq[rows, x_idx[i]] = -qp.A[i]
            beq[rows] = qp.b[i]
    nin = sum(qp.nc)
    Cin = sp.lil_matrix((nin, nz))
    din = np.zeros(nin)
    r0 = 0
    for i in range(N + 1):
        k = qp.C[i].shape[0]
        if k == 0:
            continue
        rows = slice(r0, r0 + k)
        if u_idx[i].stop > u_idx[i].start:
            Cin[rows, u_idx[i]] = qp.D[i]
        if i == 0:
            din[rows] = qp.d[0] - qp.C[0] @ x0
        else:
            Cin[rows, x_idx[i]] = qp.C[i]
            din[rows] = qp.d[i]
        r0 += k
    return StackedQp(H.tocsc(), g, Aeq.tocsc(), beq, Cin.tocsc(), din, float(const), u_idx, x_idx)


@dataclasses.dataclass
class CondensedQp:
    """States eliminated through the dynamics: U = [u_0; ...; u_N],
    minimize 1/2 U'HU + g'U + const  s.t.  G U <= h  (the usual dense MPC form)."""
    H: np.ndarray
    g: np.ndarray
    G: np.ndarray
    h: np.ndarray
    const: float
    u_idx: list

    def unstack(self, U: np.ndarray, qp: "OcpQpData") -> tuple[np.ndarray, list]:
        u = [U[s][:qp.R[i].shape[0]].copy() for i, s in enumerate(self.u_idx)]
        x = [qp.x0]
        for i in range(qp.N):
            x.append(qp.A[i] @ x[-1] + qp.B[i] @ u[i] + qp.b[i])
        return np.vstack(x), u


def condense(qp: OcpQpData) -> CondensedQp:
    qp = expand_soft(qp)
    N, nx = qp.N, qp.nx
    u_idx, off = [], 0
    for i in range(N + 1):
        u_idx.append(slice(off, off + qp.nu[i]))
        off += qp.nu[i]
    nU = off
    # x_i = X0[i] + Su[i] @ U (X0: free response incl. b; Su: input-to-state map)
    X0 = [qp.x0]
    Su = [np.zeros((nx, nU))]
    for i in range(N):
        X0.append(qp.A[i] @ X0[-1] + qp.b[i])
        S = qp.A[i] @ Su[-1]
        S[:, u_idx[i]] += qp.B[i]
        Su.append(S)
    H = np.zeros((nU, nU))
    g = np.zeros(nU)
    const = 0.0
    rows_G, rows_h = [], []
    for i in range(N + 1):
        su = u_idx[i]
        H[su, su] += qp.R[i]
        g[su] += qp.r[i]
        H += Su[i].T @ qp.Q[i] @ Su[i]
        g += Su[i].T @ (qp.Q[i] @ X0[i] + qp.q[i])
        const += 0.5 * X0[i] @ qp.Q[i] @ X0[i] + qp.q[i] @ X0[i]
        if qp.nc[i]:
            Gi = qp.C[i] @ Su[i]
            Gi[:, su] += qp.D[i]
            rows_G.append(Gi)
            rows_h.append(qp.d[i] - qp.C[i] @ X0[i])
    G = np.vstack(rows_G) if rows_G else np.zeros((0, nU))
    h = np.concatenate(rows_h) if rows_h else np.zeros(0)
    # Rows without any input (x0-only rows on stage 0) are constants: keep them out of the QP.
    keep = np.any(G != 0.0, axis=1)
    return CondensedQp(0.5 * (H + H.T), g, G[keep], h[keep], float(const), u_idx)


@dataclasses.dataclass
class PeerResult:
    status: str          # "solved", "infeasible", or the peer's own status text
    objective: float     # objective of the stage-wise QP (constant included), nan if not solved
    x: np.ndarray | None
    u: list | None
    solve_time_us: float  # the peer's own reported solve time (setup excluded), microseconds


def solve_proxsuite(qp: OcpQpData, *, eps_abs: float = 1e-10, eps_infeasible: float = 1e-8, dense: bool = False,
                    stacked: StackedQp | None = None, max_iter: int = 100000) -> PeerResult:
    """Reference solve with ProxSuite (proxqp): eps_abs as given, eps_rel = 0. Its infeasibility
    thresholds (eps_primal_inf, eps_dual_inf) default to 1e-4, which calls some feasible MPC QPs
    (1 m of room, km-scale states) infeasible; 1e-8 does not."""
    import proxsuite
    s = stacked if stacked is not None else to_stacked(qp)
    nz, neq, nin = s.H.shape[0], s.Aeq.shape[0], s.Cin.shape[0]
    lower = np.full(nin, -1e20)
    if dense:
        solver = proxsuite.proxqp.dense.QP(nz, neq, nin)
        H, Aeq, Cin = s.H.toarray(), s.Aeq.toarray(), s.Cin.toarray()
    else:
        solver = proxsuite.proxqp.sparse.QP(nz, neq, nin)
        H, Aeq, Cin = s.H, s.Aeq, s.Cin
    solver.settings.eps_abs = eps_abs
    solver.settings.eps_rel = 0.0
    solver.settings.eps_primal_inf = eps_infeasible
    solver.settings.eps_dual_inf = eps_infeasible
    solver.settings.max_iter = max_iter
    solver.settings.verbose = False
    solver.settings.compute_timings = True
    solver.init(H, s.g, Aeq, s.beq, Cin, lower, s.din)
    solver.solve()
    info = solver.results.info
    st = info.status
    if st == proxsuite.proxqp.PROXQP_SOLVED:
        status = "solved"
    elif st == proxsuite.proxqp.PROXQP_PRIMAL_INFEASIBLE:
        status = "infeasible"
    else:
        status = str(st)
    z = np.array(solver.results.x)
    x, u = s.unstack(z, qp.x0)
    obj = qp.objective(x, u) if status == "solved" else float("nan")
    return PeerResult(status, obj, x, u, float(info.solve_time))


def solve_clarabel(qp: OcpQpData, *, tol: float = 1e-10, stacked: StackedQp | None = None) -> PeerResult:
    """Reference solve with Clarabel (an interior point; gap and feasibility tolerances `tol`). It answers
    where ProxSuite reaches its iteration cap or calls a feasible closed-loop QP infeasible."""
    import math

    import clarabel
    import scipy.sparse as sp
    s = stacked if stacked is not None else to_stacked(qp)
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = tol
    sol = clarabel.DefaultSolver(sp.triu(s.H).tocsc(), s.g, sp.vstack([s.Aeq, s.Cin]).tocsc(),
                                 np.concatenate([s.beq, s.din]),
                                 [clarabel.ZeroConeT(s.Aeq.shape[0]), clarabel.NonnegativeConeT(s.Cin.shape[0])],
                                 settings).solve()
    status = str(sol.status)
    if status in ("Solved", "AlmostSolved"):
        x, u = s.unstack(np.asarray(sol.x), qp.x0)
        return PeerResult("solved", qp.objective(x, u), x, u, float(sol.solve_time) * 1e6)
    return PeerResult("infeasible" if "Infeasible" in status else status, math.nan, None, None, math.nan)


# ------------------------------------------------------------------------------------------------
# QP-set files

def save_qp_set(path: str | Path, qps: list[OcpQpData]) -> None:
    """Write QPs in the flat .npz format described in the module docstring."""
    arrays: dict[str, np.ndarray] = {"n_qps": np.array(len(qps))}
    for k, qp in enumerate(qps):
        pre = f"qp{k}/"
        arrays[pre + "phase"] = np.array(qp.phase)
        arrays[pre + "N"] = np.array(qp.N)
        arrays[pre + "x0"] = np.asarray(qp.x0, float)
        arrays[pre + "Ts"] = np.array(qp.Ts, float)
        for name in DYN_NAMES + STAGE_NAMES:
            for i, blk in enumerate(getattr(qp, name)):
                arrays[f"{pre}{name}/{i}"] = np.asarray(blk, float)
        if qp.idxs is not None:
            for i in range(qp.N + 1):
                arrays[f"{pre}idxs/{i}"] = np.asarray(qp.idxs[i], np.int64)
                arrays[f"{pre}zs/{i}"] = np.asarray(qp.zs[i], float)
                arrays[f"{pre}Zs/{i}"] = np.asarray(qp.Zs[i], float)
    np.savez_compressed(path, **arrays)


def load_qp_set(path: str | Path) -> list[OcpQpData]:
    """Read a QP-set .npz file; raises ValueError naming the first missing or malformed key."""
    with np.load(path, allow_pickle=False) as f:
        keys = set(f.files)
        if "n_qps" not in keys:
            raise ValueError(f"{path}: not a QP set (no 'n_qps' key)")
        qps = []
        for k in range(int(f["n_qps"])):
            pre = f"qp{k}/"
            for must in ("N", "x0"):
                if pre + must not in keys:
                    raise ValueError(f"{path}: missing key '{pre + must}'")
            N = int(f[pre + "N"])
            blocks = {}
            for name in DYN_NAMES + STAGE_NAMES:
                count = N if name in DYN_NAMES else N + 1
                lst = []
                for i in range(count):
                    key = f"{pre}{name}/{i}"
                    if key not in keys:
                        raise ValueError(f"{path}: missing key '{key}'")
                    arr = np.asarray(f[key], float)
                    if name in ("b", "q", "r", "d"):
                        arr = arr.reshape(-1)
                    lst.append(arr)
                blocks[name] = lst
            phase = str(f[pre + "phase"]) if pre + "phase" in keys else ""
            ts = float(f[pre + "Ts"]) if pre + "Ts" in keys else float("nan")
            soft = {}
            if pre + "idxs/0" in keys:
                soft = {"idxs": [np.asarray(f[f"{pre}idxs/{i}"], np.int64).reshape(-1).tolist() for i in range(N + 1)],
                        "zs": [np.asarray(f[f"{pre}zs/{i}"], float).reshape(-1) for i in range(N + 1)],
                        "Zs": [np.asarray(f[f"{pre}Zs/{i}"], float).reshape(-1) for i in range(N + 1)]}
            qps.append(OcpQpData(**blocks, x0=np.asarray(f[pre + "x0"], float).reshape(-1), phase=phase, Ts=ts,
                                 **soft))
    return qps
