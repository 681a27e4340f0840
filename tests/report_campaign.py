"""A small synthetic PIL campaign folder for the report's tests: run records in the format the
campaign writes (meta.json, steps.csv, events.csv, cycles.csv), with solve times chosen so that the
verdict's figures are known beforehand.

Two targets: rpi3 (Cortex-A53, 1.2 GHz) whose solves all fit, and q7s (Cortex-A9, 667 MHz) with one
docking solve whose interval's high end exceeds the deadline (2.5 s at Ts = 5 s) and one approach
corridor violation in the safety summary.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

PERIODS = {1: 30.0, 2: 20.0, 3: 5.0}  # the flight software's control periods per phase [s]
TARGETS = {"rpi3": ("cortex-a53", 1.2e9, "aarch64"), "q7s": ("cortex-a9", 667e6, "armhf")}


# random:1's rendezvous solves cost 1.6x case1_vbar's (a harder scenario): max / p50 over both runs
# exceeds the one within either run
SCALE = {("random:1", 1): 1.6}


def solve_cycles(target: str, phase: int, k: int, scenario: str = "case1_vbar") -> tuple[float, float, float]:
    """(low, nominal, high) cycles of the k-th solve of a phase: a ramp, so max and p99 are known."""
    nominal = 1e6 * phase * (1 + 0.01 * k) * SCALE.get((scenario, phase), 1.0)
    if target == "q7s" and phase == 3 and k == 7:
        nominal = 2.0e9  # 3.0 s at 667 MHz at the high end: over the 2.5 s docking deadline
    return 0.8 * nominal, nominal, 1.5 * nominal


def _run(out: Path, target: str, scenario: str, unsafe: bool, n_per_phase: int = 20) -> str:
    cpu, clock, arch = TARGETS[target]
    rel = f"runs/{target}/{scenario.replace(':', '')}-N30-15-12"
    d = out / rel
    d.mkdir(parents=True)
    rows, cyc = [], []
    step = 0
    t = 0.0
    for phase in (1, 2, 3):
        for k in range(n_per_phase):
            lo, nom, hi = solve_cycles(target, phase, k, scenario)
            insns = nom / 1.5
            rows.append({"step": step, "t_s": t, "period_s": PERIODS[phase], "phase": phase, "solver_status": 0,
                         "cmd_period_s": PERIODS[phase], "solve_time_us": 5000.0 * phase + 10 * k,
                         "instructions": insns, "iterations": 8 + k % 3, "overrun": 0,
                         "truth_x_m": -1000.0 + 10 * step, "truth_y_m": -500.0 + 5 * step,
                         "dv_x_mps": 0.01, "dv_y_mps": 0.0, "dv_z_mps": 0.0})
            cyc.append({"step": step, "instructions": insns, "cycles_low": lo, "cycles_nominal": nom,
                        "cycles_high": hi, "l1d_load_misses": 100, "l1d_store_misses": 10, "calibrated": False})
            step += 1
            t += PERIODS[phase]
    pd.DataFrame(rows).to_csv(d / "steps.csv", index=False)
    pd.DataFrame(cyc).to_csv(d / "cycles.csv", index=False)
    (d / "events.csv").write_text("wall_time_utc,step,t_s,kind,detail\n")
    episodes = [{"limit": "approach_corridor", "kind": "safety_violation", "phase": "approach", "worst": 0.42,
                 "unit": "m", "worst_step": 25, "worst_t_s": 700.0, "start_t_s": 690.0, "end_t_s": 720.0}] if unsafe else []
    meta = {"status": "finished", "created_utc": "2026-01-02T03:04:05Z", "target": target, "build": target,
            "cpu": cpu, "arch": arch, "clock_hz": clock, "cpi": {"nominal": 1.5, "low": 1.0, "high": 2.0},
            "exe_size_bytes": 1234567, "exe_sha": "0123456789abcdef", "mode": "user", "kind": "timing",
            "scenario_label": scenario, "horizons": [30, 15, 12], "end": "docked", "docked": True, "steps": step,
            "t_end_s": t, "dv_total_mps": 3.25, "versions": {"git_commit": "f" * 40, "git_dirty": False},
            "flight_hello": {"deadline_fraction": 0.5, "compiler": "GCC 12.2.0", "period_s": [30.0, 20.0, 5.0]},
            "safety": {"verdict": "unsafe" if unsafe else "safe", "violations": len(episodes), "excursions": 0,
                       "episodes": episodes, "figures": {}}}
    (d / "meta.json").write_text(json.dumps(meta))
    return rel


def make(out: Path) -> dict:
    """Write the campaign into `out`; returns the expected verdict figures per (target, phase)."""
    owned = [_run(out, "rpi3", "case1_vbar", False), _run(out, "rpi3", "random:1", False),
             _run(out, "q7s", "case1_vbar", False), _run(out, "q7s", "random:1", True)]
    (out / "campaign.json").write_text(json.dumps({"spec": {"targets": ["rpi3", "q7s"]}, "status": "finished",
                                                   "runs": owned}))
    expected = {}
    for target, (_, clock, _) in TARGETS.items():
        for phase, name in ((1, "rendezvous"), (2, "approach"), (3, "docking")):
            c = np.array([solve_cycles(target, phase, k, sc) for sc in ("case1_vbar", "random:1") for k in range(20)])
            deadline_ms = 0.5 * PERIODS[phase] * 1e3
            worst_ms = c[:, 2].max() / clock * 1e3
            p99_ms = np.quantile(c[:, 1] / clock * 1e3, 0.99)
            within = max(c[i:i + 20, 1].max() / np.median(c[i:i + 20, 1]) for i in (0, 20))
            expected[(target, name)] = {"deadline_ms": deadline_ms, "worst_ms": worst_ms, "p99_ms": p99_ms,
                                        "max_over_p50": c[:, 1].max() / np.median(c[:, 1]), "run_max_over_p50": within,
                                        "margin_worst": deadline_ms / worst_ms, "margin_p99": deadline_ms / p99_ms,
                                        "misses": int((c[:, 2] / clock * 1e3 > deadline_ms).sum())}
    return expected
