"""Metrics of one run, taken from its record (meta.json summary, steps.csv, events.csv).

    m = run_metrics(run_dir)        # {"dv_total_mps": ..., "quadrant": 3, "safety_violations": ...}
    s = solves(run_dir)             # one row per solved guidance step, three time sources apart

Every metric is a function of the record only; none measures time except the wall-time columns
named in WALL_TIME_METRICS (they differ from run to run and are kept out of the aggregates that
must repeat). The safety entry of the metadata (a per-run verdict and violation counts written by a
truth-based safety monitor) is optional: records without it give None/NaN for the safety metrics.
"""
from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np

PHASES = {1: "rendezvous", 2: "approach", 3: "docking"}
# Stored metrics.json files are reused only if this file has not changed since they were computed.
METRICS_VERSION = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]
# Radial bins of the starting range [m] (dissertation Fig. 4.3 colours the starts by distance).
RANGE_BINS_M = (0.0, 500.0, 1000.0, 1500.0, 2000.0, 2500.0, math.inf)

RUN_METRICS = (
    "end", "docked", "steps", "t_f_s", "t_f_min", "dv_total_mps", "dv_l1_mps",
    "dv_rendezvous_mps", "dv_approach_mps", "dv_docking_mps",
    "t_rendezvous_s", "t_approach_s", "t_docking_s",
    "actuations_rendezvous", "actuations_approach", "actuations_docking",
    "final_range_to_port_m", "min_range_com_m",
    "x0_m", "y0_m", "z0_m", "vx0_mps", "vy0_mps", "vz0_mps", "range0_m", "range_bin", "quadrant",
    "qp_failures", "fallbacks", "recoveries", "iterations_mean", "iterations_max", "instructions_total",
    "nav_resends", "rejected_messages", "overruns",
    "safety_verdict", "safety_violations",
)
WALL_TIME_METRICS = ("solve_wall_us_mean", "solve_wall_us_max")

# steps.csv columns the metrics read (a smaller read for big studies).
_STEP_COLUMNS = ("step", "t_s", "phase", "guidance_status", "solver_status", "iterations", "instructions",
                 "solve_time_us", "overruns", "range_com_m", "pulse_applied_px_s", "pulse_applied_mx_s",
                 "pulse_applied_py_s", "pulse_applied_my_s", "pulse_applied_pz_s", "pulse_applied_mz_s",
                 "cmd_period_s", "step_time_us", "overrun")


def load(run_dir: str | Path):
    """(meta, steps DataFrame with the columns metrics need, events DataFrame)."""
    from rvd_pil.host_sim.record import load_events, load_run

    meta, steps = load_run(run_dir)
    return meta, steps[[c for c in _STEP_COLUMNS if c in steps.columns]], load_events(run_dir)


def quadrant(position_lvlh_m, port_lvlh_m) -> int:
    """Quadrant of the start in the LVLH x-y plane, numbered 1-4 counter-clockwise from the port's
    side: 1 and 2 lie on the docking port's side of the target (the half-plane the port faces, as
    the dissertation's Fig. 4.2, where quadrants 3 and 4 are "the other half-plane to the docking
    mechanism"), 1 and 4 on the side the port's direction turned by +90 deg about z points to."""
    px, py = float(port_lvlh_m[0]), float(port_lvlh_m[1])
    norm = math.hypot(px, py)
    ux, uy = (px / norm, py / norm) if norm > 0 else (0.0, -1.0)
    along = position_lvlh_m[0] * ux + position_lvlh_m[1] * uy
    across = position_lvlh_m[0] * (-uy) + position_lvlh_m[1] * ux
    if along >= 0:
        return 1 if across >= 0 else 2
    return 4 if across >= 0 else 3


def _port_at_start(scenario: dict) -> np.ndarray:
    tgt = scenario.get("target", {})
    theta = math.radians(float(tgt.get("initial_angle_deg", -90.0)))
    p = np.asarray(tgt.get("docking_port_body_m", (0.5, 0.0, 0.0)), dtype=float)
    c, s = math.cos(theta), math.sin(theta)
    return np.array([c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]])


def range_bin(range_m: float) -> str:
    for lo, hi in zip(RANGE_BINS_M, RANGE_BINS_M[1:]):
        if lo <= range_m < hi:
            return f"{lo / 1e3:.1f}-{hi / 1e3:.1f} km" if math.isfinite(hi) else f">{lo / 1e3:.1f} km"
    return "?"


def _count(value) -> float:
    """A violation count from whatever shape the safety monitor gives: a number, a list of
    violations, or a table of either."""
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, list):
        return float(len(value))
    if isinstance(value, dict):
        return float(sum(_count(v) for v in value.values()))
    return 0.0


def safety(meta: dict, events) -> dict:
    """Verdict and violation count of the record's safety entry; None/NaN when there is none."""
    entry = meta.get("safety")
    out: dict = {"safety_verdict": None, "safety_violations": math.nan}
    if not isinstance(entry, dict):
        if isinstance(entry, str):
            out["safety_verdict"] = entry
        return out
    verdict = entry.get("verdict", entry.get("safe", entry.get("ok")))
    if isinstance(verdict, bool):
        verdict = "safe" if verdict else "unsafe"
    out["safety_verdict"] = None if verdict is None else str(verdict)
    for key in ("violations", "violation_counts", "counts"):
        if key in entry:
            out["safety_violations"] = _count(entry[key])
            break
    else:
        if "violation_count" in entry:
            out["safety_violations"] = _count(entry["violation_count"])
        elif events is not None and len(events):
            kinds = events["kind"].astype(str)
            out["safety_violations"] = float(kinds.str.startswith(("safety", "violation")).sum())
    # Every per-limit count, as its own column (safety.<limit>): {"per_limit": {limit: {"violations":
    # n, ...}}} or {"violations": {limit: n or [episodes]}}
    per_limit = entry.get("per_limit")
    if isinstance(per_limit, dict):
        for name, v in per_limit.items():
            out[f"safety.{name}"] = _count(v.get("violations", 0)) if isinstance(v, dict) else _count(v)
    elif isinstance(entry.get("violations"), dict):
        for name, v in entry["violations"].items():
            out[f"safety.{name}"] = _count(v)
    return out


def run_metrics(run_dir: str | Path | None = None, *, meta=None, steps=None, events=None) -> dict:
    """Scalar metrics of one run (see RUN_METRICS; plus WALL_TIME_METRICS and safety.<limit>)."""
    if meta is None:
        meta, steps, events = load(run_dir)
    m: dict = {"build": meta.get("build") or meta.get("target"), "end": meta.get("end"),
               "docked": bool(meta.get("docked")), "steps": meta.get("steps")}
    t_f = float(meta.get("t_end_s", math.nan))
    m["t_f_s"], m["t_f_min"] = t_f, t_f / 60.0
    m["dv_total_mps"] = float(meta.get("dv_total_mps", math.nan))
    m["dv_l1_mps"] = float(meta.get("dv_l1_mps", math.nan))
    dvp, tp = meta.get("dv_per_phase_mps") or {}, meta.get("time_per_phase_s") or {}
    for ph in PHASES.values():
        m[f"dv_{ph}_mps"] = float(dvp.get(ph, math.nan))
        m[f"t_{ph}_s"] = float(tp.get(ph, math.nan))
    phase = steps["phase"] if "phase" in steps else None
    for code, ph in PHASES.items():
        m[f"actuations_{ph}"] = int((phase == code).sum()) if phase is not None else 0
    m["final_range_to_port_m"] = float(meta.get("final_range_to_port_m", math.nan))
    m["min_range_com_m"] = float(steps["range_com_m"].min()) if len(steps) else math.nan
    chaser = (meta.get("scenario") or {}).get("chaser", {})
    pos = [float(v) for v in chaser.get("position_lvlh_m", (math.nan,) * 3)]
    vel = [float(v) for v in chaser.get("velocity_lvlh_mps", (math.nan,) * 3)]
    for name, v in zip(("x0_m", "y0_m", "z0_m", "vx0_mps", "vy0_mps", "vz0_mps"), pos + vel):
        m[name] = v
    m["range0_m"] = float(np.linalg.norm(pos))
    m["range_bin"] = range_bin(m["range0_m"])
    m["quadrant"] = quadrant(pos, _port_at_start(meta.get("scenario") or {}))
    solved = steps[steps["solver_status"].notna() & (steps["solver_status"] != 255)] if "solver_status" in steps else steps.iloc[:0]
    m["qp_failures"] = int(((solved["solver_status"] != 0)).sum()) if len(solved) else 0
    gs = steps["guidance_status"] if "guidance_status" in steps else None
    m["fallbacks"] = int(gs.isin([1, 2]).sum()) if gs is not None else 0
    m["recoveries"] = int((gs == 5).sum()) if gs is not None else 0
    m["iterations_mean"] = float(solved["iterations"].mean()) if len(solved) else math.nan
    m["iterations_max"] = float(solved["iterations"].max()) if len(solved) else math.nan
    m["instructions_total"] = float(steps["instructions"].sum()) if "instructions" in steps else 0.0
    m["nav_resends"] = int(meta.get("nav_resends") or 0)
    m["rejected_messages"] = int(meta.get("rejected_messages") or 0)
    m["overruns"] = int(steps["overruns"].max()) if "overruns" in steps and steps["overruns"].notna().any() else 0
    m.update(safety(meta, events))
    wall = len(solved) and (meta.get("flight_hello") or {}).get("step_clock") != 1  # not on target time
    m["solve_wall_us_mean"] = float(solved["solve_time_us"].mean()) if wall else math.nan
    m["solve_wall_us_max"] = float(solved["solve_time_us"].max()) if wall else math.nan
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in m.items()}


def solves(meta: dict, steps):
    """One row per solved guidance step: phase, N and Ts of that phase, iterations and the three
    time sources apart: emulated/host wall time (solve_time_us), instructions, and the estimated
    target time (instructions x CPI / f_clk, nominal/low/high) when the run has a CPU model."""
    import pandas as pd

    if "solver_status" not in steps or not len(steps):
        return pd.DataFrame()
    rows = steps[steps["phase"].isin(list(PHASES)) & steps["solver_status"].notna()
                 & (steps["solver_status"] != 255)].copy()
    study = meta.get("study_run") or {}
    horizon = (study.get("guidance") or {}).get("horizon") or (meta.get("flight_hello") or {}).get("horizon")
    period = (study.get("guidance") or {}).get("period_s") or (meta.get("flight_hello") or {}).get("period_s")
    out = pd.DataFrame({
        "step": rows["step"].astype(int), "phase": rows["phase"].astype(int).map(PHASES),
        "N": [int(horizon[int(p) - 1]) for p in rows["phase"]] if horizon else np.nan,
        "Ts_s": [float(period[int(p) - 1]) for p in rows["phase"]] if period else np.nan,
        "solver_status": rows["solver_status"].astype(int), "iterations": rows["iterations"],
        "wall_us": rows["solve_time_us"], "step_wall_us": rows.get("step_time_us"),
        "instructions": rows["instructions"], "overrun": rows.get("overrun"),
    })
    if (meta.get("flight_hello") or {}).get("step_clock") == 1:  # the flight clock was on target time, not wall time
        out["wall_us"] = out["step_wall_us"] = np.nan
    cpi, clock = meta.get("cpi"), meta.get("clock_hz")
    for band in ("nominal", "low", "high"):
        out[f"target_us_{band}"] = (rows["instructions"] * cpi[band] / clock * 1e6) if cpi and clock else np.nan
    return out.reset_index(drop=True)
