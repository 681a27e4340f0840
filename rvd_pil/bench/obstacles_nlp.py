"""NLP baseline of the obstacle rows: the 3-D scenario of Dong, Ghiglino et al. (rvd_pil/bench/obstacles_dong3d.py)
solved once over the whole manoeuvre with the exact, nonconvex keep-out constraints by IPOPT (through
CasADi, whose wheel bundles it), beside our receding-horizon MPC with linearized rows. It says how much
delta-v the linearization (and the receding horizon) costs; not flight code.

    python -m rvd_pil.bench.obstacles_nlp          (needs `pip install casadi`)

The NLP: impulsive CW dynamics with Ts = 15 s over K periods, K the number our MPC took to reach the
holding distance; the MPC's own cost (sum x'Qx + u'Ru over the whole manoeuvre, Q and R as in the
bench); |dv|_inf <= u_max; the chaser within 2.3 m of the target at rest at the end; each obstacle's
clearance (r - r_obs)' S (r - r_obs) >= 1 at every sample and at every mid-period point. Started from
the MPC's own trajectory (the NLP is nonconvex: it finds the local optimum nearest it). Both with and
without obstacles; clearance checked in truth every second afterwards.
"""
from __future__ import annotations

import math
import time

import numpy as np

from rvd_pil.bench import obstacles_dong3d as seed
from rvd_pil.host_sim.cw import cw_stm
from rvd_pil.host_sim.obstacles import ObstacleField


def solve_nlp(p, mpc, obstacles):
    import casadi as ca

    n = p.mean_motion_rad_s()
    K = len(mpc["dv"])
    A = cw_stm(n, seed.TS_S)
    Ah = cw_stm(n, seed.TS_S / 2)
    Bv = np.vstack((np.zeros((3, 3)), np.eye(3)))
    Q = np.diag(p.rendezvous.Q_diag)
    R = np.diag(p.rendezvous.R_diag)
    u_max = p.rendezvous.u_max_mps
    field = ObstacleField(obstacles, n)
    opti = ca.Opti()
    X = opti.variable(6, K + 1)
    U = opti.variable(3, K)
    opti.subject_to(X[:, 0] == mpc["x"][0])
    cost = 0
    for k in range(K):
        xp = X[:, k] + Bv @ U[:, k]
        opti.subject_to(X[:, k + 1] == A @ xp)
        opti.subject_to(opti.bounded(-u_max, U[:, k], u_max))
        cost += ca.bilin(Q, X[:, k + 1], X[:, k + 1]) + ca.bilin(R, U[:, k], U[:, k])
        for o in obstacles:
            S = field.shape(o)
            for tau, r in ((seed.TS_S, X[0:3, k + 1]), (seed.TS_S / 2, (Ah @ xp)[0:3])):
                d = r - o.state(k * seed.TS_S + tau, n)[0:3]
                opti.subject_to(ca.bilin(S, d, d) >= 1.0)
    opti.subject_to(ca.sumsqr(X[0:3, K]) <= seed.HOLD_M ** 2)
    opti.subject_to(X[3:6, K] == 0)
    opti.minimize(cost)
    opti.set_initial(X, mpc["x"][:K + 1].T)
    opti.set_initial(U, mpc["dv"].T)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "max_iter": 3000, "tol": 1e-8})
    t0 = time.perf_counter()
    sol = opti.solve()
    wall = time.perf_counter() - t0
    x, u = np.array(sol.value(X)).T, np.array(sol.value(U)).T
    worst = {o.id: math.inf for o in obstacles}
    for k in range(K):
        xp = np.r_[x[k, :3], x[k, 3:] + u[k]]
        for tau in np.arange(0.0, seed.TS_S + 1e-9, 1.0):
            for o in obstacles:
                worst[o.id] = min(worst[o.id], field.clearance(o, (cw_stm(n, tau) @ xp)[:3], k * seed.TS_S + tau))
    return {"impulse2_kNs": seed.MASS_KG * np.linalg.norm(u, axis=1).sum() / 1e3,
            "impulse1_kNs": seed.MASS_KG * np.abs(u).sum() / 1e3, "clearance": worst, "wall_s": wall, "K": K}


def main() -> int:
    print("published total impulse [kN s] (with obstacles): " +
          ", ".join(f"{k} {v:.2f}" for k, v in seed.PUBLISHED_KNS.items()))
    for with_obstacles in (False, True):
        p = seed.params(False, with_obstacles)
        mpc = seed.fly(p, seed.OBSTACLES)
        nlp = solve_nlp(p, mpc, seed.OBSTACLES if with_obstacles else [])
        cl = ", ".join(f"{i}: {v:.3f}" for i, v in nlp["clearance"].items()) or "not constrained"
        print(f"{'with' if with_obstacles else 'without'} obstacles, {nlp['K']} periods of {seed.TS_S:g} s: "
              f"MPC {mpc['impulse2_kNs']:.2f} kN s (1-norm {mpc['impulse1_kNs']:.2f}); exact NLP (IPOPT) "
              f"{nlp['impulse2_kNs']:.2f} kN s (1-norm {nlp['impulse1_kNs']:.2f}), clearance in truth {cl}, "
              f"solved in {nlp['wall_s']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
