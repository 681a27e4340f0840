"""Side-by-side solve times: flight_sw's Fast MPC solver vs ProxSuite, OSQP, DAQP, PIQP and Clarabel on
the same MPC QPs, measured in one run. Prints figures; asserts nothing about speed.

    python -m rvd_pil.bench.solvers                      # synthetic QPs per guidance phase and horizon
    python -m rvd_pil.bench.solvers --qp-set run.npz     # a recorded QP set (format: tests/support/qp_forms.py)
    python -m rvd_pil.bench.solvers --quick              # fewer QPs and repeats (a smoke run)
    python -m rvd_pil.bench.solvers --record-cases real.npz  # record the closed-loop QPs of Cases 1-3, bench them
    python -m rvd_pil.bench.solvers --closed-loop-set cl.npz --per-group 40   # the project's closed-loop set:
        # Cases 1-3 and seeded random starts (rotating targets among them) at the three horizon sets,
        # sampled per phase and horizon, written to cl.npz, then benched
    python -m rvd_pil.bench.solvers --warm-cold                # closed loops solved warm and cold side by side
    python -m rvd_pil.bench.solvers --tails --repeats 3        # noisy closed loops: each phase's worst solve
        # against its median, as flown and cold, with flight_sw's interior point warm and DAQP (cold and
        # warm) on the same QPs
    python -m rvd_pil.bench.solvers --qp-set run.npz --cold-cache   # every timed solve starts with its
        # code and data out of the caches, as a guidance that solves once per control period meets them

With two or more repeats, each QP's first timed solve is set against its repeats, per solver and cell:
the first follows the reference solver and the other solvers, the repeats run back to back on one QP.

Accuracy is matched, not assumed: every solver's objective is compared with a reference (ProxSuite,
eps_abs 1e-10, or looser where it cannot get there; Clarabel at 1e-10 where ProxSuite fails) and
disagreements are counted in the table. QPs the reference finds infeasible are listed, not timed.

Clocks (each solver's own, setup excluded; microseconds):
  flight_sw          steady_clock around FastMpcSolver::solve() in C++ (Info::solve_time_us); the
                     workspace is allocated once before, as in flight; cold start (no warm start).
                     The settings the guidance flies: docking and approach by the dual active-set
                     method (A, B, Q, R condensed by setup(), once per phase in flight: its time is
                     the setup column), rendezvous by the interior point. After the table, its time by
                     part (Info's update / iterations / output) and, with daqp in the run, DAQP's
                     clock against flight_sw's iterations: the part both clocks cover
  flight_sw-ipm      the same, every phase by the interior point
  proxsuite sparse/  results.info.solve_time (compute_timings=True): solve after init()
  proxsuite dense
  osqp               info.solve_time + info.polish_time (setup_time excluded)
  daqp               info['solve_time'] (setup_time excluded); on the condensed QP (states
                     eliminated; condensing is not timed). A new model per solve, set up untimed: the
                     setup also turns the QP's f and bounds into DAQP's LDP form, so that per-QP
                     update is outside the clock, and so is copying the result out
  piqp               result.info.solve_time (setup_time excluded), sparse interface
  clarabel           solution.solve_time (the DefaultSolver constructor does the setup)
  hpipm              wall time of the one d_ocp_qp_ipm_solve call minus the measured ctypes call
                     overhead (rvd_pil/bench/hpipm.py: casadi's bundled HPIPM/BLASFEO, BLASFEO built for
                     its GENERIC target; or a build of one's own through RVD_HPIPM_LIB_DIR), set-up not
                     timed; its own OCP form: box bounds, one-sided rows with the missing side masked
                     off, native soft constraints. hpipm: SPEED mode, hpipm-robust: ROBUST mode, both
                     with HPIPM's own cold start (primal 0, its presets' mu0); hpipm-rollout and
                     hpipm-robust-rollout: the same with the initial guess a user can give it
                     (warm_start 1 on u = 0 and the states rolled out from x0, what flight_sw's cold
                     start does inside its solve) and mu0 at the cost's scale (HPIPM's advice)
Tolerances: flight_sw tol 1e-8 (relative residuals and duality gap); ProxSuite eps_abs 1e-8,
eps_rel 0; PIQP eps_abs 1e-8 eps_rel 1e-9 (defaults); Clarabel tol_gap_abs/rel 1e-8, tol_feas 1e-8
(defaults); DAQP primal/dual tolerances 1e-6 with automatic proximal regularisation (active set:
exact up to rounding once the active set is right); OSQP eps_abs = eps_rel = 1e-6 with polishing
(ADMM does not reach 1e-8 in practical iteration counts; the polished solution usually is exact);
HPIPM flight_sw's 1e-8 made relative to the QP's data, as HPIPM's absolute tolerances: tol_stat = 1e-8 x
max(1, largest |cost entry|), tol_eq = tol_ineq = tol_comp = 1e-8 x max(1, largest |x0, b, d|)
(rvd_pil/bench/hpipm.py says why absolute ones do not fit these QPs).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from rvd_pil import paths

paths.require_checkout("the peer-solver benchmark (its QP forms are tests/support/qp_forms.py)")
from support.qp_forms import (PHASE_HORIZONS, PHASES, OcpQpData, PeerResult, condense, from_dict, load_qp_set,  # noqa: E402
                            save_qp_set, solve_clarabel, solve_proxsuite, to_stacked)

AGREE_REL = 1e-6  # objective agreement with the reference, relative to max(1, |f*|)
PHASE_NAMES = tuple(PHASES)  # rendezvous, approach, docking: the guidance's Phase 1, 2, 3


# ------------------------------------------------------------------------------------------------
# One function per solver: (qp, prepared forms) -> (objective, status, solve time in us, setup time
# in us as the solver reports it, nan if it does not). Each calls before_timed_solve(forms) between
# its set-up and the call its clock times.

def before_timed_solve(forms: dict) -> None:
    """What main() asks to run just before a timed solve, after the solver's untimed set-up (with
    --cold-cache: the cache eviction, so that no solver's set-up warms its data for its solve)."""
    hook = forms.get("_before_solve")
    if hook:
        hook()


def flight_sw_solver(qp: OcpQpData, mode: str, warm_start: bool):
    """flight_sw's solver for qp's shape at tol 1e-8, with the interior point's cold start as the
    guidance sets it for qp's phase."""
    from rvd_pil import flight_sw
    solver = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, mode=mode, tol=1e-8,
                                 warm_start=warm_start)
    if qp.phase in PHASES:
        solver.cold_slack_floor = getattr(flight_sw.GuidanceParams(), qp.phase).solver_cold_slack_floor
    return solver


def run_flight_sw(qp: OcpQpData, forms: dict, mode: str = "converged"):
    if mode == "converged" and qp.phase == "rendezvous":
        mode = "interior_point"  # as the guidance flies it (PhaseParams of the rendezvous)
    key = ("flight_sw", mode)
    if key not in forms:
        solver = forms[key] = flight_sw_solver(qp, mode, warm_start=False)
        # Condensing A, B, Q, R (fixed per phase: done once when the guidance is built), as DAQP's setup.
        t0 = time.perf_counter()
        solver.setup(*qp.args()[:-1], **qp.kw())
        forms[key + ("setup",)] = (time.perf_counter() - t0) * 1e6 if mode == "converged" else math.nan
    before_timed_solve(forms)
    r = forms[key].solve(*qp.args(), **qp.kw())
    forms["_iterations"] = r.iterations if r.iterations else r.active_set_changes  # the active set: its changes
    forms["_bytes"] = forms[key].workspace_bytes
    forms["_parts"] = (r.update_time_us, r.iterate_time_us, r.output_time_us)
    return r.objective, r.status, r.solve_time_us, forms[key + ("setup",)]


def run_proxsuite(qp: OcpQpData, forms: dict, dense: bool):
    import proxsuite
    s = forms["stacked"]
    nz, neq, nin = s.H.shape[0], s.Aeq.shape[0], s.Cin.shape[0]
    if dense:
        solver = proxsuite.proxqp.dense.QP(nz, neq, nin)
        mats = (forms["H_dense"], s.g, forms["Aeq_dense"], s.beq, forms["Cin_dense"])
    else:
        solver = proxsuite.proxqp.sparse.QP(nz, neq, nin)
        mats = (s.H, s.g, s.Aeq, s.beq, s.Cin)
    solver.settings.eps_abs = 1e-8
    solver.settings.eps_rel = 0.0
    solver.settings.verbose = False
    solver.settings.compute_timings = True
    solver.init(*mats, np.full(nin, -1e20), s.din)
    before_timed_solve(forms)
    solver.solve()
    info = solver.results.info
    ok = info.status == proxsuite.proxqp.PROXQP_SOLVED
    x, u = s.unstack(np.asarray(solver.results.x), qp.x0)
    return (qp.objective(x, u) if ok else math.nan), ("solved" if ok else str(info.status)), float(info.solve_time), \
        float(info.setup_time)


def run_osqp(qp: OcpQpData, forms: dict):
    import osqp
    s = forms["stacked"]
    A = sp.vstack([s.Aeq, s.Cin]).tocsc()
    lower = np.concatenate([s.beq, np.full(s.Cin.shape[0], -np.inf)])
    upper = np.concatenate([s.beq, s.din])
    solver = osqp.OSQP()
    solver.setup(sp.triu(s.H).tocsc(), s.g, A, lower, upper, eps_abs=1e-6, eps_rel=1e-6, polishing=True,
                 max_iter=200000, verbose=False)
    before_timed_solve(forms)
    res = solver.solve()
    ok = res.info.status in ("solved", "solved inaccurate")
    x, u = s.unstack(np.asarray(res.x), qp.x0) if res.x is not None else (None, None)
    t_us = (res.info.solve_time + res.info.polish_time) * 1e6
    return (qp.objective(x, u) if ok else math.nan), ("solved" if ok else res.info.status), t_us, \
        res.info.setup_time * 1e6


def daqp_model(c):
    """A DAQP model of the condensed QP `c`, set up with the benchmark's settings (one-sided rows)."""
    import daqp
    m = len(c.h)
    model = daqp.Model()
    model.settings = {**model.settings, "eps_prox": -1.0, "primal_tol": 1e-6, "dual_tol": 1e-6, "iter_limit": 100000}
    model.setup(c.H, c.g, c.G, c.h, np.full(m, -1e30), np.zeros(m, dtype=np.int32))
    return model


def daqp_objective(qp: OcpQpData, c, U, exitflag: int) -> float:
    """The OCP objective of DAQP's answer U on the condensed QP c, NaN when it did not solve."""
    if exitflag != 1:
        return math.nan
    x, u = c.unstack(np.asarray(U), qp)
    return qp.objective(x, u)


def agrees(objective: float, reference: float) -> bool:
    return abs(objective - reference) <= AGREE_REL * max(1.0, abs(reference))


def run_daqp(qp: OcpQpData, forms: dict):
    c = forms["condensed"]
    model = daqp_model(c)  # a new one per solve: a model solved before starts from its last working set
    before_timed_solve(forms)
    U, _, exitflag, info = model.solve()
    return daqp_objective(qp, c, U, exitflag), ("solved" if exitflag == 1 else f"exitflag {exitflag}"), \
        info["solve_time"] * 1e6, info["setup_time"] * 1e6


def run_piqp(qp: OcpQpData, forms: dict):
    import piqp
    s = forms["stacked"]
    solver = piqp.SparseSolver()
    solver.settings.verbose = False
    solver.settings.compute_timings = True
    solver.setup(s.H, s.g, s.Aeq, s.beq, s.Cin, None, s.din)
    before_timed_solve(forms)
    status = solver.solve()
    ok = status == piqp.PIQP_SOLVED
    x, u = s.unstack(np.asarray(solver.result.x), qp.x0)
    return (qp.objective(x, u) if ok else math.nan), ("solved" if ok else str(status)), \
        solver.result.info.solve_time * 1e6, solver.result.info.setup_time * 1e6


def run_clarabel(qp: OcpQpData, forms: dict):
    import clarabel
    s = forms["stacked"]
    A = sp.vstack([s.Aeq, s.Cin]).tocsc()
    b = np.concatenate([s.beq, s.din])
    cones = [clarabel.ZeroConeT(s.Aeq.shape[0]), clarabel.NonnegativeConeT(s.Cin.shape[0])]
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(sp.triu(s.H).tocsc(), s.g, A, b, cones, settings)
    before_timed_solve(forms)
    sol = solver.solve()
    ok = str(sol.status) == "Solved"
    x, u = s.unstack(np.asarray(sol.x), qp.x0)
    return (qp.objective(x, u) if ok else math.nan), ("solved" if ok else str(sol.status)), sol.solve_time * 1e6, \
        math.nan


def run_hpipm(qp: OcpQpData, forms: dict, mode: str = "speed", init: str = "cold"):
    from rvd_pil.bench.hpipm import HpipmSolver
    key = ("hpipm", mode, init)
    solver = forms.get(key)
    if solver is None:
        solver = forms[key] = HpipmSolver(qp, mode=mode, init=init, mu0="cost" if init == "rollout" else None)
    before_timed_solve(forms)
    st, it, t_us, x, u = solver.solve()
    forms["_iterations"] = it
    ok = st == 0
    return (qp.objective(x, u) if ok else math.nan), ("solved" if ok else f"status {st}"), t_us, math.nan


SOLVERS = {
    "flight_sw": run_flight_sw,
    "flight_sw-ipm": lambda qp, f: run_flight_sw(qp, f, mode="interior_point"),
    "hpipm": run_hpipm,
    "hpipm-robust": lambda qp, f: run_hpipm(qp, f, mode="robust"),
    "hpipm-rollout": lambda qp, f: run_hpipm(qp, f, init="rollout"),
    "hpipm-robust-rollout": lambda qp, f: run_hpipm(qp, f, mode="robust", init="rollout"),
    "proxsuite-sparse": lambda qp, f: run_proxsuite(qp, f, dense=False),
    "proxsuite-dense": lambda qp, f: run_proxsuite(qp, f, dense=True),
    "osqp": run_osqp,
    "daqp": run_daqp,
    "piqp": run_piqp,
    "clarabel": run_clarabel,
}


def prepare(qp: OcpQpData) -> dict:
    s = to_stacked(qp)
    return {"stacked": s, "condensed": condense(qp), "H_dense": s.H.toarray(), "Aeq_dense": s.Aeq.toarray(),
            "Cin_dense": s.Cin.toarray()}


def reference(qp: OcpQpData, forms: dict):
    """The objective the others are checked against: ProxSuite at eps_abs 1e-10 (1e-9, 1e-8 where it
    cannot get there); where ProxSuite fails or calls the QP infeasible, Clarabel at 1e-10 (on real
    closed-loop QPs ProxSuite calls some feasible QPs infeasible). Returns (result, who)."""
    for eps in (1e-10, 1e-9, 1e-8):
        ref = solve_proxsuite(qp, eps_abs=eps, stacked=forms["stacked"], max_iter=20000)
        if ref.status == "solved":
            return ref, f"proxsuite {eps:g}"
    ref = solve_clarabel(qp, stacked=forms["stacked"])
    return ref, ("clarabel 1e-10" if ref.status == "solved" else "proxsuite+clarabel")


class CacheEvictor:
    """Writes a buffer twice the size of this machine's caches (all levels, from sysfs; 64 MiB when it
    does not say) before a timed solve, after the solver's untimed set-up (before_timed_solve), so
    that the solve finds none of its code or data cached: the cost of a solver's memory footprint,
    which a guidance solving once per control period, with its navigation and link in between, pays
    on every solve. (The repeats of one QP otherwise run back to back and find everything cached.)"""

    def __init__(self):
        total = 0
        for index in Path("/sys/devices/system/cpu/cpu0/cache").glob("index*"):
            try:
                size = (index / "size").read_text().strip()
            except OSError:
                continue
            scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(size[-1:], 1)
            total += int(size.rstrip("KMG")) * scale
        self.bytes = 2 * total if total else 64 << 20
        self._buffer = np.zeros(self.bytes // 8)

    def __call__(self):
        self._buffer += 1.0  # every line read and written back


# ------------------------------------------------------------------------------------------------

def synthetic_set(per_group: int, seed: int) -> list[OcpQpData]:
    """per_group feasible QPs per (phase, horizon) of the dissertation's timing study."""
    rng = np.random.default_rng(seed)
    qps = []
    for phase, horizons in PHASE_HORIZONS.items():
        for N in horizons:
            made = 0
            for _ in range(20 * per_group):
                qp = PHASES[phase](N, rng)
                if solve_proxsuite(qp, eps_abs=1e-8, max_iter=20000).status == "solved":
                    qps.append(qp)
                    made += 1
                if made == per_group:
                    break
    return qps


def record_cases(path: str, cases=(1, 2, 3)) -> list[OcpQpData]:
    """Every QP the guidance solved in closed loops of the dissertation's cases (CW plant, default
    GuidanceParams), written as a QP-set file: the real closed-loop set."""
    from rvd_pil import flight_sw
    params = flight_sw.GuidanceParams()
    qps = []
    for case in cases:
        c = flight_sw.dissertation_case(case)
        run = flight_sw.run_closed_loop(params, c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"], record_qps=True)
        for rec in run.qps:
            phase = str(rec["phase"]).split(".")[-1].lower()
            qps.append(from_dict(rec["qp"], phase))
    save_qp_set(path, qps)
    return qps


def closed_loop_set(path: str, per_group: int, seed: int = 0, random_starts: int = 12) -> list[OcpQpData]:
    """The project's closed-loop QP set: every QP the guidance solves in closed loops (CW plant, in
    process) of Cases 1-3 and `random_starts` seeded random starts (rvd_pil.host_sim.scenario.random_scenario;
    every third one with a target spinning at 0.1-0.3 deg/s about a random body axis), at the three
    horizon sets (rendezvous 15/30/45, approach 5/15/30, docking 5/12/30); per_group QPs drawn per
    phase and horizon. Written to `path` (tests/support/qp_forms.py format)."""
    from rvd_pil import flight_sw
    from rvd_pil.host_sim.scenario import random_scenario
    rng = np.random.default_rng(seed)
    starts = []
    for case in (1, 2, 3):
        c = flight_sw.dissertation_case(case)
        starts.append((f"case{case}", c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"]))
    for k in range(random_starts):
        sc = random_scenario(1000 + k)
        x0 = np.concatenate([sc.chaser.position_lvlh_m, sc.chaser.velocity_lvlh_mps])
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        w = np.zeros(3)
        if k % 3 == 0:
            axis = rng.standard_normal(3)
            w = np.deg2rad(rng.uniform(0.1, 0.3)) * axis / np.linalg.norm(axis)
        starts.append((f"random{k}", x0, q, w))
    groups: dict = defaultdict(list)
    names = {1: "rendezvous", 2: "approach", 3: "docking"}
    for horizons in ((15, 5, 5), (30, 15, 12), (45, 30, 30)):
        params = flight_sw.GuidanceParams()
        params.rendezvous.N, params.approach.N, params.docking.N = horizons
        for label, x0, q, w in starts:
            run = flight_sw.run_closed_loop(params, x0, q, w, record_qps=True)
            for rec in run.qps:
                phase = int(rec["phase"])
                groups[(names[phase], horizons[phase - 1])].append(from_dict(rec["qp"], names[phase]))
    qps = []
    for key in sorted(groups):
        pool = groups[key]
        pick = rng.choice(len(pool), size=min(per_group, len(pool)), replace=False)
        qps += [pool[i] for i in sorted(pick)]
    save_qp_set(path, qps)
    return qps


def warm_cold(seed: int = 0, random_starts: int = 6) -> None:
    """Closed loops (CW plant, in process) run twice per start, warm-started and cold: iterations and
    solve times per phase side by side (the same loop, interleaved by start)."""
    from rvd_pil import flight_sw
    from rvd_pil.host_sim.scenario import random_scenario
    rows = defaultdict(lambda: defaultdict(list))
    for horizons in ((15, 5, 5), (30, 15, 12), (45, 30, 30)):
        starts = [flight_sw.dissertation_case(c) for c in (1, 2, 3)]
        for k in range(random_starts):
            sc = random_scenario(2000 + k)
            starts.append({"x0": np.concatenate([sc.chaser.position_lvlh_m, sc.chaser.velocity_lvlh_mps]),
                           "q_lvlh_body": np.array([0.7071067811865476, 0.0, 0.0, -0.7071067811865476]),
                           "omega_body_rad_s": np.zeros(3)})
        for c in starts:
            for warm in (True, False):
                params = flight_sw.GuidanceParams()
                params.rendezvous.N, params.approach.N, params.docking.N = horizons
                for ph in (params.rendezvous, params.approach, params.docking):
                    ph.solver_warm_start = warm
                run = flight_sw.run_closed_loop(params, c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"])
                for ph, ipm_it, changes, t, status in zip(run.phase, run.iterations, run.active_set_changes,
                                                          run.solve_time_us, run.solver_status):
                    if int(ph) not in (1, 2, 3) or status == "not_run" or t <= 0.0:  # docked, or no solve
                        continue
                    # The interior point's iterations, or the active-set method's row changes (the
                    # cap falls back to the interior point: then both count)
                    it = ipm_it + changes
                    name = ("rendezvous", "approach", "docking")[int(ph) - 1]
                    N = horizons[("rendezvous", "approach", "docking").index(name)]
                    rows[(name, N)]["warm" if warm else "cold"].append((it, t))
    print("closed loops warm vs cold (Cases 1-3 and random starts, CW plant), per phase and horizon")
    print(f"{'phase':<11}{'N':>4}  {'solves':>6}  {'it warm':>8}{'it cold':>8}  {'t warm':>8}{'t cold':>8}  "
          f"{'max it w/c':>11}  {'p90 t w/c':>15}  {'cold/warm t':>11}")
    for key in sorted(rows, key=lambda k: (("rendezvous", "approach", "docking").index(k[0]), k[1])):
        w, c = np.array(rows[key]["warm"]), np.array(rows[key]["cold"])
        print(f"{key[0]:<11}{key[1]:>4}  {len(w):>6}  {np.mean(w[:, 0]):>8.1f}{np.mean(c[:, 0]):>8.1f}  "
              f"{np.median(w[:, 1]):>8.1f}{np.median(c[:, 1]):>8.1f}  {int(w[:, 0].max()):>5}/{int(c[:, 0].max()):<5}  "
              f"{np.percentile(w[:, 1], 90):>7.1f}/{np.percentile(c[:, 1], 90):<7.1f}  "
              f"{np.median(c[:, 1]) / np.median(w[:, 1]):>11.2f}")
    print("it = mean iterations per solve (interior point; in the active-set method's phases, approach and "
          "docking, its row changes); t = median solve time [us] (host wall time, C++ clock); the warm "
          "loop and the cold loop may fly slightly different trajectories (same QPs only at the first step)\n")


def fly_repeated(case: int, horizons, seed: int, noise_scale: float, thrust_error: float, repeats: int):
    """One noisy loop flown `repeats` times (bench.noisy_loops): per solved step its least flown solve
    time and, from the first flight, its phase and QP; and the steps whose QP was infeasible (the
    recovery QP flew) per phase. Raises when a repeat commands otherwise than the first flight."""
    from rvd_pil.bench.noisy_loops import noisy_loop
    from rvd_pil import flight_sw
    flown, qps, commands, infeasible = {}, {}, {}, defaultdict(int)
    for rep in range(repeats):
        for k, g, cmd in noisy_loop(case, horizons, seed, noise_scale, thrust_error):
            dv = tuple(cmd.dv_cmd_mps)
            if commands.setdefault(k, dv) != dv:  # the repeat must fly the loop it times again
                raise RuntimeError(f"Case {case} seed {seed}: repeat {rep} commanded {dv} at step {k}, "
                                   f"not {commands[k]}: the loop is not deterministic")
            ph = int(cmd.phase)
            if ph not in (1, 2, 3) or not cmd.solved:
                continue
            if cmd.status == flight_sw.StepStatus.Recovered or cmd.solver_status != "solved":
                infeasible[ph] += rep == 0
                continue
            flown[k] = min(flown.get(k, math.inf), cmd.solve_time_us)
            if rep == 0:
                qps[k] = (ph, from_dict(g.last_qp(cmd.phase), PHASE_NAMES[ph - 1]))
    return flown, qps, infeasible


def closed_loop_tails(seeds: int = 2, noise_scale: float = 0.02, thrust_error: float = 0.03, repeats: int = 3,
                      horizon_sets=None) -> None:
    """The closed loop's worst solve against its median, per phase and horizon, with the same QPs solved
    by DAQP side by side. Noisy in-process loops (bench.noisy_loops: CW plant, sensor noise, thrust
    error) of Cases 1-3, `seeds` seeds each. Each loop is flown `repeats` times (the same QPs: the noise
    is seeded and the guidance deterministic) and each step keeps its least time: flight_sw as flown
    (warm, Command.solve_time_us). Then each step's QP is solved `repeats` times by flight_sw cold,
    DAQP cold (a new model per solve) and DAQP warm (one model per loop phase and repeat, updated with
    each QP: it starts from its last working set, unshifted), least time kept. Steps whose QP was
    infeasible (the recovery QP flew) are left out and counted. Besides, the loop's QPs are solved in
    sequence by flight_sw's interior point warm-started (one solver per loop phase and repeat, its plan
    shifted after each solve, as the guidance does): the method whose work per iteration does not grow
    with the active rows, here in approach and docking too. Each answer is checked: against flight_sw
    cold's objective, and where one differs, against the reference solver's (`reference`).
    horizon_sets: default bench.noisy_loops'."""
    from rvd_pil.bench.noisy_loops import HORIZON_SETS
    solvers = ("flown", "flight_sw cold", "interior point warm", "daqp cold", "daqp warm")
    times = defaultdict(lambda: defaultdict(list))  # (phase, N) -> solver -> least time per step
    where = defaultdict(list)                       # (phase, N) -> (case, seed, step) per step
    bad = defaultdict(lambda: defaultdict(int))     # (phase, N) -> solver -> not solved / objective off
    skipped = defaultdict(int)
    t0 = time.time()
    for horizons in horizon_sets or HORIZON_SETS:
        for case in (1, 2, 3):
            for seed in range(seeds):
                flown, qps, infeasible = fly_repeated(case, horizons, seed, noise_scale, thrust_error, repeats)
                for ph, n in infeasible.items():
                    skipped[(PHASE_NAMES[ph - 1], horizons[ph - 1])] += n
                models = {}  # DAQP warm: (phase, repeat) -> the loop's model
                ipm = {}     # interior point warm: (phase, repeat) -> the loop's solver
                for k in sorted(qps):
                    ph, qp = qps[k]
                    key = (PHASE_NAMES[ph - 1], horizons[ph - 1])
                    forms = {"condensed": condense(qp)}
                    c = forms["condensed"]
                    least = defaultdict(lambda: math.inf, flown=flown[k])
                    answers = {}  # solver -> (objective, solved) of its first solve
                    for rep in range(repeats):
                        obj, status, t_us, _setup = run_flight_sw(qp, forms)
                        least["flight_sw cold"] = min(least["flight_sw cold"], t_us)
                        answers.setdefault("flight_sw cold", (obj, status == "solved"))
                        obj, status, t_us, _setup = run_daqp(qp, forms)
                        least["daqp cold"] = min(least["daqp cold"], t_us)
                        answers.setdefault("daqp cold", (obj, status == "solved"))
                        if (ph, rep) not in ipm:
                            ipm[(ph, rep)] = flight_sw_solver(qp, "interior_point", warm_start=True)
                        r = ipm[(ph, rep)].solve(*qp.args(), **qp.kw())
                        ipm[(ph, rep)].shift_warm_start()
                        least["interior point warm"] = min(least["interior point warm"], r.solve_time_us)
                        answers.setdefault("interior point warm", (r.objective, r.status == "solved"))
                        if (ph, rep) in models:
                            models[(ph, rep)].update(H=c.H, f=c.g, A=c.G, bupper=c.h, blower=np.full(len(c.h), -1e30))
                        else:
                            models[(ph, rep)] = daqp_model(c)
                        U, _, exitflag, info = models[(ph, rep)].solve()
                        least["daqp warm"] = min(least["daqp warm"], info["solve_time"] * 1e6)
                        answers.setdefault("daqp warm", (daqp_objective(qp, c, U, exitflag), exitflag == 1))
                    # Every answer against flight_sw cold's; where any differs or did not solve, every one
                    # against the reference solver's, and only the answers off it count. (A disagreement
                    # counted on both charged flight_sw with DAQP's answers 1e-5 to 3e-3 off at the docking
                    # port, where flight_sw's are within 1e-10 of ProxSuite's.)
                    yardstick = answers["flight_sw cold"][0]
                    if not all(ok and agrees(obj, yardstick) for obj, ok in answers.values()):
                        ref, _who = reference(qp, {"stacked": to_stacked(qp)})
                        if ref.status == "solved":
                            yardstick = ref.objective
                    for name, (obj, ok) in answers.items():
                        bad[key][name] += not (ok and agrees(obj, yardstick))
                    for name in solvers:
                        times[key][name].append(least[name])
                    where[key].append((case, seed, k))
        print(f"  ... horizons {horizons} done, {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
    print(f"closed-loop tails: Cases 1-3 x {seeds} seeds, noise scale {noise_scale}, thrust error {thrust_error:.0%} "
          f"(CW plant, in process); least of {repeats} per step; times in us (each solver's own clock)")
    print(f"{'phase':<11}{'N':>4}{'solves':>7}  {'solver':<15}{'median':>9}{'p99':>9}{'max':>9}{'max/median':>11}"
          f"{'bad':>5}")
    for key in sorted(times, key=lambda k: (PHASE_NAMES.index(k[0]), k[1])):
        for name in solvers:
            t = np.array(times[key][name])
            print(f"{key[0]:<11}{key[1]:>4}{len(t):>7}  {name:<15}{np.median(t):>9.1f}{pct(t, 99):>9.1f}{t.max():>9.1f}"
                  f"{t.max() / np.median(t):>11.2f}{bad[key][name] if name != 'flown' else '-':>5}")
        case, seed, k = where[key][int(np.argmax(times[key]["flown"]))]
        note = f" (and {skipped[key]} infeasible steps left out)" if skipped[key] else ""
        print(f"{'':<15}flown maximum: Case {case} seed {seed} step {k}{note}\n")
    print("flown = the guidance's own solve, warm-started (interior point in the rendezvous, dual active set in "
          "approach and docking); flight_sw cold = the same QP solved from scratch; interior point warm = "
          "flight_sw's interior point along the loop's QPs, warm-started from its shifted plan (in the rendezvous "
          "the flown method again); bad = not solved, or the objective more than "
          f"{AGREE_REL:g} (relative) from the reference solver's (ProxSuite at 1e-10, or Clarabel), which is "
          "consulted when an answer differs from flight_sw cold's\n")


def print_first_solves(times, groups, names, repeats: int) -> None:
    """Each QP's first timed solve against its repeats, per solver. The first follows the reference
    solve and the other solvers' runs (code and data partly out of the caches, branch predictors
    trained on other code); the repeats run back to back on the same QP. A guidance solves each QP
    once, after its own navigation and link code: between the two."""
    def medians(key, name):  # times holds each QP's `repeats` solves in a block, the first solve first
        t = times[key + (name,)]
        return np.median(t[::repeats]), np.median([v for i, v in enumerate(t) if i % repeats])

    print(f"each QP's first timed solve / its {repeats - 1} repeat(s), medians in us (in brackets: against "
          "flight_sw's of the same kind, above 1: flight_sw is faster). The first runs after the reference solver "
          "and the other solvers, code and data partly out of the caches; the repeats run back to back on one QP")
    for key in groups:
        ours = medians(key, "flight_sw") if "flight_sw" in names else (math.nan, math.nan)
        cells = []
        for name in names:
            a, b = medians(key, name)
            cells.append(f"{name} {a:.1f} / {b:.1f}" + ("" if name == "flight_sw" else f" ({a / ours[0]:.2f} / {b / ours[1]:.2f})"))
        print(f"  {key[0]:<11}{key[1]:>4}  " + ", ".join(cells))
    print()


def print_parts(parts, times, groups, names) -> None:
    """flight_sw's solve time by part, and against DAQP's clock on what that clock covers."""
    ours = [n for n in names if any(k + (n,) in parts for k in groups)]  # the flight_sw forms in the run
    if not ours:
        return
    print("flight_sw's solve time by part (Info::update_time_us / iterate_time_us / output_time_us), medians in us: "
          "the update takes in the QP (input checks, rows, x0's terms: the rollout, the gradient and the "
          "unconstrained inputs, the start point), the iterations run the method to the answer's primal point, "
          "the output forms the multipliers, residuals and objective")
    daqp = "daqp" in names
    if daqp:
        print("  DAQP's clock covers its iterations and the primal answer only: the update of its LDP form for the QP "
              "(v = R^-T f, the rows' bounds shifted by M v; in its setup or update call) and the copy-out of the "
              "result are outside it, and the condensed QP's f and bounds for x0 are formed before. "
              "'daqp / iterations' compares the two clocks on that common part (above 1: flight_sw's is shorter)")
    for key in groups:
        for name in ours:
            p = np.array(parts.get(key + (name,), []))
            if not len(p):
                continue
            med = np.median(p, axis=0)
            txt = (f"  {key[0]:<11}{key[1]:>4}  {name:<14} update {med[0]:7.1f}  iterations {med[1]:8.1f} "
                   f"(p90 {pct(p[:, 1], 90):8.1f})  output {med[2]:6.1f}")
            if daqp and name == "flight_sw" and times.get(key + ("daqp",)):
                t = times[key + ("daqp",)]
                txt += (f"   daqp / iterations: median {np.median(t) / med[1]:.2f}, "
                        f"p90 {pct(t, 90) / pct(p[:, 1], 90):.2f}")
            print(txt)
    print()


def pct(values, q):
    return float(np.percentile(values, q)) if len(values) else math.nan


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--qp-set", help="QP-set .npz file (tests/support/qp_forms.py format); default: synthetic")
    ap.add_argument("--per-group", type=int, default=10, help="synthetic QPs per phase and horizon")
    ap.add_argument("--repeats", type=int, default=5, help="timed solves per QP and solver")
    ap.add_argument("--solvers", default=",".join(SOLVERS), help="comma-separated subset of " + ",".join(SOLVERS))
    ap.add_argument("--quick", action="store_true", help="2 QPs per group, 2 repeats")
    ap.add_argument("--record-cases", metavar="FILE",
                    help="record every QP of closed loops of the dissertation's Cases 1-3 into FILE, then bench them")
    ap.add_argument("--closed-loop-set", metavar="FILE",
                    help="record the project's closed-loop set (Cases 1-3 + random starts, all horizons; "
                         "--per-group QPs per phase and horizon) into FILE, then bench it")
    ap.add_argument("--random-starts", type=int, default=12, help="random starts in --closed-loop-set")
    ap.add_argument("--warm-cold", action="store_true", help="closed loops warm vs cold, then exit")
    ap.add_argument("--tails", action="store_true",
                    help="noisy closed loops: each phase's worst solve against its median, flown and cold, with "
                         "the interior point warm and DAQP cold and warm on the same QPs; then exit "
                         "(--seeds-per-case, --repeats)")
    ap.add_argument("--seeds-per-case", type=int, default=2, help="seeds per case in --tails")
    ap.add_argument("--cold-cache", action="store_true",
                    help="evict the caches before every timed solve (twice the caches' size written over), "
                         "as a solve once per control period meets them; default: the repeats of a QP run back "
                         "to back, caches warm")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.warm_cold:
        warm_cold(args.seed)
        return 0
    if args.tails:
        if args.seeds_per_case < 1 or args.repeats < 1:
            ap.error("--seeds-per-case and --repeats must be >= 1")
        closed_loop_tails(args.seeds_per_case, repeats=args.repeats)
        return 0
    if args.quick:
        args.per_group, args.repeats = 2, 2
    names = [n for n in args.solvers.split(",") if n]
    unknown = set(names) - set(SOLVERS)
    if unknown:
        ap.error(f"unknown solvers: {sorted(unknown)}")

    t0 = time.time()
    if args.record_cases:
        qps = record_cases(args.record_cases)
        args.qp_set = args.record_cases
    elif args.closed_loop_set:
        qps = closed_loop_set(args.closed_loop_set, args.per_group, args.seed, args.random_starts)
        args.qp_set = args.closed_loop_set
    else:
        qps = load_qp_set(args.qp_set) if args.qp_set else synthetic_set(args.per_group, args.seed)
    evict = CacheEvictor() if args.cold_cache else None
    print(f"{len(qps)} QPs from {args.qp_set or 'the synthetic MPC set'}; {args.repeats} timed solves per QP "
          f"and solver; times in microseconds (each solver's own clock, see the module docstring)")
    print(f"caches: {f'evicted before every timed solve ({evict.bytes >> 20} MiB written)' if evict else 'warm (the repeats of a QP back to back)'}\n")
    if any(n.startswith("hpipm") for n in names):
        from rvd_pil.bench.hpipm import call_overhead_ns, version
        print(f"{version()}; ctypes call overhead subtracted: {call_overhead_ns():.0f} ns\n")

    times = defaultdict(list)      # (phase, N, solver) -> solve times
    setups = defaultdict(list)     # (phase, N, solver) -> setup times the solver reports
    parts = defaultdict(list)      # (phase, N, flight_sw form) -> its solve time by part
    wrong = defaultdict(int)       # (phase, N, solver) -> objective disagreements / failures
    worst = defaultdict(float)     # (phase, N, solver) -> worst relative objective difference
    iters = defaultdict(list)      # (phase, N, solver) -> iterations (solvers that report them)
    arena = {}                     # (phase, N, solver) -> flight_sw's working memory in bytes
    count = defaultdict(int)
    used = defaultdict(int)        # which reference solved how many QPs
    for i, qp in enumerate(qps):
        if i and i % 20 == 0:  # a long run says where it is (stderr: the figures stay on stdout)
            print(f"  ... {i} of {len(qps)} QPs, {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
        key = (qp.phase or "set", qp.N)
        forms = prepare(qp)
        ref, who = reference(qp, forms)
        used[who] += 1
        if ref.status != "solved":
            ours = run_flight_sw(qp, forms)[1] if "flight_sw" in names else "-"
            print(f"  skipped a {key} QP: the reference ({who}) says {ref.status}; flight_sw says {ours}")
            continue
        count[key] += 1
        forms["_before_solve"] = evict
        for name in names:
            for rep in range(args.repeats):
                forms.pop("_iterations", None)
                forms.pop("_bytes", None)
                forms.pop("_parts", None)
                obj, status, t_us, setup_us = SOLVERS[name](qp, forms)
                if "_bytes" in forms:
                    arena[key + (name,)] = forms["_bytes"]
                if "_parts" in forms:
                    parts[key + (name,)].append(forms["_parts"])
                times[key + (name,)].append(t_us)
                setups[key + (name,)].append(setup_us)
                if rep == 0:
                    if "_iterations" in forms:
                        iters[key + (name,)].append(forms["_iterations"])
                    err = abs(obj - ref.objective) / max(1.0, abs(ref.objective)) if status == "solved" else math.inf
                    worst[key + (name,)] = max(worst[key + (name,)], err)
                    if not err <= AGREE_REL:
                        wrong[key + (name,)] += 1

    print("reference objectives: " + ", ".join(f"{who} {n}" for who, n in used.items()) + "\n")
    groups = sorted(count, key=lambda k: (list(PHASE_HORIZONS).index(k[0]) if k[0] in PHASE_HORIZONS else 99, k[1]))
    print(f"{'phase':<11}{'N':>4}  {'solver':<21}{'median':>10}{'p90':>10}{'p99':>10}{'ratio':>8}  {'worst rel. obj':>15}  "
          f"{'bad':<6}{'setup (not in median)':>22}  {'iterations mean/max':>19}")
    for key in groups:
        ours = np.median(times[key + ("flight_sw",)]) if "flight_sw" in names else math.nan
        for name in names:
            t = times[key + (name,)]
            med = np.median(t)
            setup = np.median(setups[key + (name,)])
            setup_txt = "-" if math.isnan(setup) else f"{setup:.1f}"
            it = iters[key + (name,)]
            it_txt = f"{np.mean(it):.1f}/{max(it)}" if it else "-"
            print(f"{key[0]:<11}{key[1]:>4}  {name:<21}{med:>10.1f}{pct(t, 90):>10.1f}{pct(t, 99):>10.1f}{med / ours:>8.2f}  "
                  f"{worst[key + (name,)]:>15.1e}  {str(wrong[key + (name,)]) + '/' + str(count[key]):<6}{setup_txt:>22}  {it_txt:>19}")
        print()
    print("ratio = solver median / flight_sw median (above 1: flight_sw is faster); bad = objective off the "
          f"reference by more than {AGREE_REL:g} relative, or not solved; setup = the solver's own setup time "
          "(median), where it reports one (flight_sw allocates its workspace once per phase, before any solve); "
          "iterations: per solve, where the solver reports them (HPIPM; flight_sw: interior-point iterations, "
          "active-set changes where it runs the active-set method)\n")

    if args.repeats > 1:
        print_first_solves(times, groups, names, args.repeats)
    print_parts(parts, times, groups, names)

    if arena:
        print("flight_sw working memory (its one arena, allocated by the constructor once per phase; the "
              "published solution aside), KiB:")
        for name in [n for n in names if any(k[2] == n for k in arena)]:
            print(f"  {name}: " + ", ".join(f"{k[0]} {k[1]} {arena[k + (name,)] / 1024:.0f}"
                                             for k in groups if k + (name,) in arena))
        print()

    # Growth with the horizon: linear scaling gives N_max / N_min; the dissertation's CVXGEN gave
    # 864/119 = 7.3 for rendezvous N 45 vs 15.
    print("time growth with the horizon: t(N_max) / t(N_min) per phase (linear scaling = N_max / N_min)")
    phases = sorted({k[0] for k in groups}, key=lambda p: list(PHASE_HORIZONS).index(p) if p in PHASE_HORIZONS else 99)
    for phase in phases:
        Ns = sorted(k[1] for k in groups if k[0] == phase)
        if len(Ns) < 2:
            continue
        lo, hi = Ns[0], Ns[-1]
        cells = []
        for name in names:
            r = np.median(times[(phase, hi, name)]) / np.median(times[(phase, lo, name)])
            cells.append(f"{name} {r:.2f}")
        print(f"  {phase} N {hi}/{lo} (linear {hi / lo:.1f}): " + ", ".join(cells))
    print(f"\nbenchmark wall time {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
