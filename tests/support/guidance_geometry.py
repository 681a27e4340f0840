"""Geometry and dense reference QP solvers the guidance tests share, written from the equations here
(quaternion rotation, the four-sided pyramid, the stacked QP), never taken from flight_sw. (The
attitude under a constant rate is the host simulator's: rvd_pil.host_sim.frames.quaternion_after.)"""
import math

import numpy as np

from support.qp_forms import expand_soft, from_dict

DEG = math.pi / 180.0


def quat_about_z(angle_rad):
    return np.array([math.cos(angle_rad / 2), 0.0, 0.0, math.sin(angle_rad / 2)])


def rotate(q, v):
    """Rotate v by the unit quaternion q = [w, x, y, z] (written out: v' = v + 2w (u x v) + 2 u x (u x v))."""
    w, u = q[0], np.asarray(q[1:])
    t = 2.0 * np.cross(u, v)
    return np.asarray(v) + w * t + np.cross(u, t)


def in_pyramid(q, rel, half_angle_rad, tol=0.0):
    """True when the LVLH vector rel (from the apex) is inside the four-sided pyramid around body +x:
    in body axes, x tan(a) >= |y| and >= |z| (up to tol metres measured along the face normals)."""
    qc = np.array([q[0], -q[1], -q[2], -q[3]])
    b = rotate(qc, rel)
    c, s = math.cos(half_angle_rad), math.sin(half_angle_rad)
    return max(abs(b[1]) * c - b[0] * s, abs(b[2]) * c - b[0] * s) <= tol


def ocp_to_dense(qp):
    """Stack the stage-wise QP into z = [x_0..x_N, u_0..u_N]: min 1/2 z'Hz + g'z, Ae z = be, Ci z <= ci.
    Soft rows become slack inputs first (support.qp_forms.expand_soft): u_i then ends with stage i's slacks."""
    if "idxs" in qp:
        e = expand_soft(from_dict(qp))
        qp = {**{k: getattr(e, k) for k in ("A", "B", "b", "Q", "q", "R", "r", "C", "D", "d")}, "x0": e.x0}
    A, B, b, Q, q, R, r, C, D, d, x0 = (qp[k] for k in ("A", "B", "b", "Q", "q", "R", "r", "C", "D", "d", "x0"))
    N, nx = len(A), len(x0)
    nu = [np.asarray(Ri).shape[0] for Ri in R]
    xo = [i * nx for i in range(N + 1)]
    uo = list(np.cumsum([(N + 1) * nx] + nu[:-1]))
    n = (N + 1) * nx + sum(nu)
    H, g = np.zeros((n, n)), np.zeros(n)
    Ae, be = np.zeros(((N + 1) * nx, n)), np.zeros((N + 1) * nx)
    Ae[:nx, :nx], be[:nx] = np.eye(nx), x0
    rows, ub = [], []
    for i in range(N + 1):
        H[xo[i]:xo[i] + nx, xo[i]:xo[i] + nx], g[xo[i]:xo[i] + nx] = Q[i], q[i]
        H[uo[i]:uo[i] + nu[i], uo[i]:uo[i] + nu[i]], g[uo[i]:uo[i] + nu[i]] = R[i], r[i]
        if i < N:
            k = (i + 1) * nx
            Ae[k:k + nx, xo[i + 1]:xo[i + 1] + nx] = np.eye(nx)
            Ae[k:k + nx, xo[i]:xo[i] + nx] = -A[i]
            Ae[k:k + nx, uo[i]:uo[i] + nu[i]] = -B[i]
            be[k:k + nx] = b[i]
        if len(d[i]):
            G = np.zeros((len(d[i]), n))
            G[:, xo[i]:xo[i] + nx], G[:, uo[i]:uo[i] + nu[i]] = C[i], D[i]
            rows.append(G)
            ub.append(d[i])
    return H, g, Ae, be, np.vstack(rows), np.concatenate(ub), xo, uo, nu


def solve_proxsuite(qp):
    """Reference solution by ProxSuite's dense solver; returns (status, u list, x list)."""
    import proxsuite

    H, g, Ae, be, Ci, ci, xo, uo, nu = ocp_to_dense(qp)
    s = proxsuite.proxqp.dense.QP(len(g), Ae.shape[0], Ci.shape[0])
    s.settings.eps_abs, s.settings.eps_rel, s.settings.max_iter = 1e-9, 0.0, 20000
    # The default infeasibility thresholds (1e-4) misjudge these QPs (km-scale states, 1e4 penalties) as
    # infeasible; Clarabel and the Fast MPC solver both solve them. Tight thresholds make ProxSuite converge.
    s.settings.eps_primal_inf = s.settings.eps_dual_inf = 1e-12
    s.init(H, g, Ae, be, Ci, np.full(len(ci), -1e20), ci)
    s.solve()
    z = s.results.x
    return (str(s.results.info.status).split(".")[-1], [z[o:o + m] for o, m in zip(uo, nu)],
            [z[o:o + 6] for o in xo])


def solve_clarabel(qp):
    """Second reference (an interior point method) for the recovery QPs: on their large elastic costs ProxSuite
    reaches its iteration cap (with the same first input)."""
    import clarabel
    import scipy.sparse as sp

    H, g, Ae, be, Ci, ci, xo, uo, nu = ocp_to_dense(qp)
    s = clarabel.DefaultSettings()
    s.verbose = False
    s.tol_gap_abs = s.tol_gap_rel = s.tol_feas = 1e-10
    sol = clarabel.DefaultSolver(sp.csc_matrix(np.triu(H)), g, sp.csc_matrix(np.vstack([Ae, Ci])), np.r_[be, ci],
                                 [clarabel.ZeroConeT(Ae.shape[0]), clarabel.NonnegativeConeT(Ci.shape[0])], s).solve()
    z = np.array(sol.x)
    return str(sol.status), [z[o:o + m] for o, m in zip(uo, nu)], [z[o:o + 6] for o in xo]


# Docking axis (body +x) along LVLH -y (V-bar, port facing -y) and along +x (R-bar).
VBAR = quat_about_z(-90 * DEG)
RBAR = np.array([1.0, 0, 0, 0])
