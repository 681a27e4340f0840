"""The dissertation's closed-loop cases in process (flight_sw guidance against the impulsive CW plant, no
noise, no delay), with delta-v and time per phase printed beside Tables 3.3-3.5.

    python -m rvd_pil.bench.closed_loop_cases                  Cases 1-3 beside the dissertation (+ solver figures)
    python -m rvd_pil.bench.closed_loop_cases --horizons       the benchmark horizons, one phase at a time
    python -m rvd_pil.bench.closed_loop_cases --variants       Table 3.6: set point / no set point / 1-norm (Case 1)
    python -m rvd_pil.bench.closed_loop_cases --ablations      the choices flight_sw/guidance/README.md argues for
    python -m rvd_pil.bench.closed_loop_cases --save-qps qps.npz [--max-qps 300]   the QPs solved, support.qp_forms format

Delta-v is the sum of |dv|_2 of the realised (allocated) impulses, as the dissertation's resultant; |dv|_1
(what six axis thrusters burn) is printed beside it. Solve times are host wall time of the C++ solver.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from rvd_pil import flight_sw as fsw

PHASES = ("rendezvous", "approach", "docking")
# Tables 3.3-3.5: (delta-v [m/s], time [s]) per phase.
DISSERTATION = {1: ((10.24, 1169), (2.84, 260), (0.20, 315)),
                2: ((9.19, 989), (2.76, 280), (0.18, 310)),
                3: ((8.38, 929), (4.04, 360), (0.25, 280))}
CASE_NAMES = {1: "V-bar", 2: "R-bar", 3: "rotating 0.15 deg/s"}
# Table 3.6 (Case 1): total delta-v [m/s], time [min].
TABLE_3_6 = {"QP with set point": (13.28, 29.07), "QP without set point": (12.65, 71.23), "LP": (12.74, 40.57)}


def run_case(params: fsw.GuidanceParams, k: int, record_qps: bool = False):
    c = fsw.dissertation_case(k)
    t0 = time.perf_counter()
    r = fsw.run_closed_loop(params, c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"], record_qps=record_qps)
    return r, time.perf_counter() - t0


def safety_flags(r) -> str:
    flags = []
    if r.keepout_violations:
        flags.append(f"KEEP-OUT x{r.keepout_violations} (min {r.min_range_outside_cone_m:.1f} m)")
    if r.max_u_inf_ratio > 1 + 1e-12:
        flags.append(f"|u| {r.max_u_inf_ratio:.3f} u_max")
    if r.fallbacks:
        flags.append(f"{r.fallbacks} fallbacks")
    if r.recoveries:
        flags.append(f"{r.recoveries} recovered")
    return ", ".join(flags) or "clean"


def cases_table(params: fsw.GuidanceParams) -> None:
    print("Cases 1-3, CW plant, no noise (ours beside dissertation Tables 3.3-3.5)")
    print(f"{'case':<22} {'phase':<11} {'dv':>7} {'|dv|_1':>7} {'diss.':>6} {'ratio':>6} "
          f"{'t [s]':>6} {'diss.':>6} {'ratio':>6}")
    for k in (1, 2, 3):
        r, wall = run_case(params, k)
        rows = [(name, r.phases[name], ref) for name, ref in zip(PHASES, DISSERTATION[k])]
        tot_ref = (sum(v[0] for v in DISSERTATION[k]), sum(v[1] for v in DISSERTATION[k]))
        rows.append(("total", r.total, tot_ref))
        for name, d, (dv_ref, t_ref) in rows:
            print(f"{(f'{k} ' + CASE_NAMES[k]) if name == 'rendezvous' else '':<22} {name:<11} {d['dv_mps']:7.2f} "
                  f"{d['dv_l1_mps']:7.2f} {dv_ref:6.2f} {d['dv_mps'] / dv_ref:6.2f} {d['time_s']:6.0f} {t_ref:6.0f} "
                  f"{d['time_s'] / t_ref:6.2f}")
        st = r.solve_time_us[r.phase < 4]
        it = r.iterations[r.phase < 4]
        print(f"{'':<22} {'':<11} {'docked' if r.docked else r.reason}; {safety_flags(r)}; "
              f"final {r.final_port_distance_m:.2f} m from port at {r.final_closing_speed_mps * 1e3:.0f} mm/s; "
              f"{len(st)} solves, mean {st.mean():.0f} us, max {st.max():.0f} us, "
              f"{statistics.mean(it):.1f} iterations; loop wall {wall:.2f} s")


def summary_row(label: str, r) -> str:
    ph = r.phases
    dv = "/".join(f"{ph[n]['dv_mps']:.2f}" for n in PHASES)
    t = "/".join(f"{ph[n]['time_s']:.0f}" for n in PHASES)
    st = r.solve_time_us[r.phase < 4]
    return (f"{label:<34} {'D' if r.docked else 'X'} dv {dv} = {r.total['dv_mps']:6.2f}  t {t} = "
            f"{r.total['time_s']:5.0f} s  solve mean {st.mean():6.0f} us  {safety_flags(r)}")


def horizons_table(base: fsw.GuidanceParams) -> None:
    print("\nHorizon sweep (one phase changed at a time; others at Table 3.1)")
    sweeps = {"rendezvous": (15, 30, 45), "approach": (5, 15, 30), "docking": (5, 12, 30)}
    for phase, values in sweeps.items():
        for N in values:
            p = fsw.GuidanceParams()
            getattr(p, phase).N = N
            for k in (1, 2, 3):
                r, _ = run_case(p, k)
                print(summary_row(f"{phase} N={N} case {k}", r))


def variants_table() -> None:
    print("\nRendezvous objective variants, Case 1 (dissertation Table 3.6: total dv, time)")
    variants = {"QP with set point": {}, "QP without set point": {"rendezvous_use_setpoint": False},
                "LP": {"rendezvous_objective": fsw.RendezvousObjective.OneNorm}}
    for name, kw in variants.items():
        p = fsw.GuidanceParams()
        for key, v in kw.items():
            setattr(p, key, v)
        r, _ = run_case(p, 1)
        ref_dv, ref_min = TABLE_3_6[name]
        print(f"{summary_row(name, r)}   [diss. {ref_dv:.2f} m/s, {ref_min * 60:.0f} s]")


def ablations_table() -> None:
    print("\nAblations of the choices in flight_sw/guidance/README.md (Cases 1-3)")

    def approach_lambda_10(p):
        p.approach.lambda_ = 10.0

    def shortest(p):
        p.keepout_direction = fsw.KeepoutDirection.Shortest

    def dare(p):
        for ph in (p.rendezvous, p.approach, p.docking):
            ph.terminal_weight = fsw.TerminalWeight.Dare

    def no_recovery(p):
        p.recovery = False

    def rendezvous_lambda_1e4(p):
        p.rendezvous.lambda_ = 1e4

    def cold_start(p):
        for ph in (p.rendezvous, p.approach, p.docking):
            ph.solver_warm_start = False

    for label, change in (("defaults", lambda p: None), ("approach lambda 10 per m", approach_lambda_10),
                          ("rendezvous lambda 1e4 per m", rendezvous_lambda_1e4), ("keep-out shortest way", shortest),
                          ("Q_f = DARE (all phases)", dare), ("no recovery QP", no_recovery),
                          ("solver cold start", cold_start)):
        p = fsw.GuidanceParams()
        change(p)
        for k in (1, 2, 3):
            r, _ = run_case(p, k)
            print(summary_row(f"{label}, case {k}", r))


def save_qps(path: str, max_qps: int) -> None:
    from rvd_pil import paths

    paths.require_checkout("a recorded QP set (tests/support/qp_forms.py)")
    from support.qp_forms import from_dict, save_qp_set

    p = fsw.GuidanceParams()
    qps = []
    for k in (1, 2, 3):
        r, _ = run_case(p, k, record_qps=True)
        for rec in r.qps:
            phase = fsw.Phase(rec["phase"]).name.lower()
            qp = from_dict(rec["qp"], f"case{k}/{phase}")
            qp.Ts = p.phase(rec["phase"]).Ts_s
            qps.append(qp)
    if max_qps and len(qps) > max_qps:  # spread the subset evenly over the three runs
        qps = [qps[i] for i in np.linspace(0, len(qps) - 1, max_qps).round().astype(int)]
    save_qp_set(path, qps)
    print(f"wrote {len(qps)} QPs to {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--horizons", action="store_true", help="sweep the benchmark horizons")
    ap.add_argument("--variants", action="store_true", help="Table 3.6 rendezvous objectives")
    ap.add_argument("--ablations", action="store_true", help="the README's parameter choices, each undone")
    ap.add_argument("--save-qps", metavar="PATH", help="write the QPs of Cases 1-3 (support.qp_forms .npz)")
    ap.add_argument("--max-qps", type=int, default=0, help="with --save-qps: keep this many, evenly spread")
    a = ap.parse_args(argv)
    if a.save_qps:
        save_qps(a.save_qps, a.max_qps)
        return 0
    cases_table(fsw.GuidanceParams())
    if a.horizons:
        horizons_table(fsw.GuidanceParams())
    if a.variants:
        variants_table()
    if a.ablations:
        ablations_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
