"""Docking round a platform past stationary debris (rvd_pil/host_sim/scenarios/gupta_debris_docking.toml, after
Gupta, Sarna, Jensen, Sinha and Venkatesh's student project, which solves it by a nonlinear MPC in Pyomo
with IPOPT): our linearized MPC through the PIL harness beside IPOPT on the exact, nonconvex problem.

    python -m rvd_pil.bench.obstacles_gupta          (needs `pip install casadi`: its wheel bundles IPOPT)

Three ways to fly the same start, platform, debris and port, on the same impulsive double integrator
(Ts 2 s, |dv| <= 1.5 N x 2 s / 4000 kg per axis), judged on the same path (every second):
- ours: the flight executable's three-phase MPC (their Q and R, the DARE terminal weight, all phases
  alike) with the holding radius as the platform's circle, the debris as obstacle rows (their tangent
  planes about the previous plan, two per stage), the entry cone, run_pil with the planar truth, no
  noise (rvd-run gupta_debris_docking --ideal); and the same without the obstacle rows;
- IPOPT nonlinear MPC, the project's method: every period an NLP over the same horizon (N 50) with
  the exact circles x'x >= r^2 about the platform and each debris at every sample and every mid-period
  point, their cost (Q, R, the DARE terminal weight, tracking the port at rest), its first delta-v
  applied; until within 2 cm and 2 cm/s of the port (our docked condition);
- IPOPT over the whole manoeuvre: one NLP of K periods (K = our MPC's), the same exact constraints,
  ending at the port at rest, their cost, started from our trajectory: what the linearization and the
  receding horizon cost against the nearest local optimum.
The project gives plots only (docking round the platform and between the debris in about 150 periods
of 2 s with N 100); it states no delta-v or time.
"""
from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.linalg

from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import ServerConfig

SC = scenario.load("gupta_debris_docking")
MASS_KG = SC.chaser.mass_kg
TS_S = float(SC.guidance["phases.Ts_s"])
N = int(SC.guidance["phases.N"])
U_MAX = float(SC.guidance["phases.u_max_mps"])
R_STATION = float(SC.guidance["holding_radius_m"])
PORT = np.array(SC.target.docking_port_body_m[:2])  # the target does not turn: body = table axes
DEBRIS = [(np.array(o.position_lvlh_m[:2]), o.semi_axes_m[0]) for o in SC.obstacles]
X0 = np.r_[SC.chaser.position_lvlh_m[:2], SC.chaser.velocity_lvlh_mps[:2]]
Q = np.diag([10.0, 10.0, 300.0, 300.0])                  # their weights on x, y, x', y'
R = np.diag(SC.guidance["phases.R"][:2])                 # on the period's delta-v (10 per N^2 of force)
A = np.block([[np.eye(2), TS_S * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
B = A[:, 2:]                                             # the impulse at the period start
DOCK_TOL_M, DOCK_SPEED_MPS = float(SC.guidance["dock_tolerance_m"]), float(SC.guidance["v_max_mps"])


def path_clearance(x: np.ndarray, u: np.ndarray) -> tuple[float, list[float]]:
    """Closest |p| to the platform's centre and each debris' clearance |p - c|^2 / r^2 along the
    path flown (impulse at the period start, then straight), sampled every second."""
    closest, clear = math.inf, [math.inf] * len(DEBRIS)
    for k in range(len(u)):
        v = x[k, 2:] + u[k]
        for tau in np.arange(0.0, TS_S + 1e-9, 1.0):
            p = x[k, :2] + tau * v
            closest = min(closest, float(np.linalg.norm(p)))
            for j, (c, r) in enumerate(DEBRIS):
                clear[j] = min(clear[j], float((p - c) @ (p - c)) / r ** 2)
    return closest, clear


def ours(out: Path, flight_args=()) -> dict:
    summary, run_dir = run_pil(SC, sensor_noise=False, thrust_noise=False, impulsive=True, flight_args=list(flight_args),
                               config=ServerConfig(delay_model="none"), run_dir=out / f"ours{len(flight_args)}")
    _, steps = load_run(run_dir)
    x = steps[["truth_x_m", "truth_y_m", "truth_vx_mps", "truth_vy_mps"]].to_numpy(dtype=float)
    u = steps[["dv_x_mps", "dv_y_mps"]].to_numpy(dtype=float)[:-1]  # the last row is the docked declaration
    return {"end": summary.end, "t_s": summary.t_s, "x": x, "u": u, "safety": summary.safety["verdict"],
            "solve_ms": np.nanmedian(steps["solve_time_us"].to_numpy(dtype=float)) / 1e3}


def _exact_constraints(opti, ca, X, U, k):
    """The platform's and the debris' circles at the sample after period k and at its middle."""
    xp = X[:, k] + ca.vertcat(0, 0, U[:, k])
    for p in (X[0:2, k + 1], xp[0:2] + 0.5 * TS_S * xp[2:4]):
        opti.subject_to(ca.sumsqr(p) >= R_STATION ** 2)
        for c, r in DEBRIS:
            opti.subject_to(ca.sumsqr(p - c) >= r ** 2)


def nmpc(timeout_s: float = SC.timeout_s) -> dict:
    """IPOPT's nonlinear MPC in closed loop on the impulsive double integrator."""
    import casadi as ca

    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    ref = np.r_[PORT, 0.0, 0.0]
    opti = ca.Opti()
    X, U, x0 = opti.variable(4, N + 1), opti.variable(2, N), opti.parameter(4)
    opti.subject_to(X[:, 0] == x0)
    cost = 0
    for k in range(N):
        opti.subject_to(X[:, k + 1] == A @ (X[:, k] + ca.vertcat(0, 0, U[:, k])))
        opti.subject_to(opti.bounded(-U_MAX, U[:, k], U_MAX))
        _exact_constraints(opti, ca, X, U, k)
        e = X[:, k + 1] - ref
        cost += ca.bilin(Q if k < N - 1 else P, e, e) + ca.bilin(R, U[:, k], U[:, k])
    opti.minimize(cost)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "max_iter": 500, "tol": 1e-8})
    x, t, xs, us, walls, fails = X0.copy(), 0.0, [X0.copy()], [], [], 0
    guess_x, guess_u = np.tile(X0, (N + 1, 1)).T, np.zeros((2, N))
    while t < timeout_s and not (np.linalg.norm(x[:2] - PORT) <= DOCK_TOL_M and np.abs(x[2:]).max() <= DOCK_SPEED_MPS):
        opti.set_value(x0, x)
        opti.set_initial(X, guess_x)
        opti.set_initial(U, guess_u)
        t0 = time.perf_counter()
        try:
            sol = opti.solve()
            u_plan, x_plan = np.array(sol.value(U)).reshape(2, N), np.array(sol.value(X))
        except RuntimeError:  # no convergence: the last iterate, as a flight MPC would fall back
            fails += 1
            u_plan, x_plan = np.array(opti.debug.value(U)).reshape(2, N), np.array(opti.debug.value(X))
        walls.append(time.perf_counter() - t0)
        u = np.clip(u_plan[:, 0], -U_MAX, U_MAX)
        x = A @ (x + np.r_[0.0, 0.0, u])
        t += TS_S
        xs.append(x.copy())
        us.append(u)
        guess_x = np.hstack((x_plan[:, 1:], x_plan[:, -1:]))
        guess_u = np.hstack((u_plan[:, 1:], np.zeros((2, 1))))
    docked = np.linalg.norm(x[:2] - PORT) <= DOCK_TOL_M
    return {"end": "docked" if docked else "timeout", "t_s": t, "x": np.array(xs), "u": np.array(us),
            "solve_ms": 1e3 * float(np.median(walls)), "fails": fails}


def whole(mpc: dict) -> dict:
    """One NLP over the whole manoeuvre (K = the MPC's periods), ending at the port at rest."""
    import casadi as ca

    K = len(mpc["u"])
    opti = ca.Opti()
    X, U = opti.variable(4, K + 1), opti.variable(2, K)
    opti.subject_to(X[:, 0] == X0)
    ref = np.r_[PORT, 0.0, 0.0]
    cost = 0
    for k in range(K):
        opti.subject_to(X[:, k + 1] == A @ (X[:, k] + ca.vertcat(0, 0, U[:, k])))
        opti.subject_to(opti.bounded(-U_MAX, U[:, k], U_MAX))
        _exact_constraints(opti, ca, X, U, k)
        e = X[:, k + 1] - ref
        cost += ca.bilin(Q, e, e) + ca.bilin(R, U[:, k], U[:, k])
    opti.subject_to(X[:, K] == ref)
    opti.minimize(cost)
    opti.set_initial(X, mpc["x"][:K + 1].T)
    opti.set_initial(U, mpc["u"].T)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "max_iter": 3000, "tol": 1e-8})
    t0 = time.perf_counter()
    sol = opti.solve()
    return {"end": "docked", "t_s": K * TS_S, "x": np.array(sol.value(X)).T, "u": np.array(sol.value(U)).T,
            "wall_s": time.perf_counter() - t0}


def line(label: str, r: dict) -> str:
    closest, clear = path_clearance(r["x"], r["u"])
    impulse2 = MASS_KG * float(np.linalg.norm(r["u"], axis=1).sum())
    impulse1 = MASS_KG * float(np.abs(r["u"]).sum())
    extra = f"; median solve {r['solve_ms']:.2f} ms" if "solve_ms" in r else f"; solved in {r['wall_s']:.1f} s"
    if r.get("fails"):
        extra += f" ({r['fails']} solves without convergence)"
    return (f"{label:<34} {r['end']} at t = {r['t_s']:.0f} s; total impulse {impulse2:.1f} N s (1-norm {impulse1:.1f}); "
            f"closest to the platform's centre {closest:.3f} m (circle {R_STATION} m); debris clearance "
            + ", ".join(f"{c:.3f}" for c in clear) + extra)


def main() -> int:
    print("published (the project's Figs. 3-4, no values in the text): docks round the platform and between "
          "both debris, about 150 periods of 2 s with N 100")
    with tempfile.TemporaryDirectory() as tmp:
        mpc = ours(Path(tmp))
        print(line("ours (linearized MPC, PIL ideal)", mpc) + f", safety in truth {mpc['safety']}")
        print(line("IPOPT nonlinear MPC (N 50)", nmpc()))
        print(line("IPOPT whole manoeuvre (K ours)", whole(mpc)))
        blind = ours(Path(tmp), ["--obstacles", "off"])
        print(line("ours without the obstacle rows", blind) + f", safety in truth {blind['safety']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
