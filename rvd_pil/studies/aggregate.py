"""From stored runs to pandas DataFrames.

    runs      one row per grid point (a run shared by two sweeps appears under both): its sweep, the
              swept values, the run's coordinates (mode, target, guidance, model, scenario, seed)
              and its metrics (rvd_pil.studies.metrics)
    summary   per sweep point (sweep x swept values x target): run counts, success rate and the
              mean, spread and range of the study's metrics
    solves    timing studies: one row per solved guidance step, with the point's coordinates

Everything here is a function of the stored records and the grid, in grid order, so the same runs
give the same frames whichever executor computed them; wall-clock metrics are kept in columns
named in metrics.WALL_TIME_METRICS and out of `summary`.
"""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import pandas as pd

from .metrics import METRICS_VERSION, PHASES, WALL_TIME_METRICS, run_metrics, solves as run_solves

DEFAULT_SUMMARY_METRICS = ("dv_total_mps", "t_f_min", "dv_rendezvous_mps", "dv_approach_mps", "dv_docking_mps",
                           "t_rendezvous_s", "t_approach_s", "t_docking_s", "qp_failures", "safety_violations")


def _metrics(run_dir: Path) -> dict:
    path = run_dir / "metrics.json"
    if path.is_file():
        stored = json.loads(path.read_text())
        if stored.get("version") == METRICS_VERSION:
            return stored["metrics"]
    return run_metrics(run_dir)


def coordinates(point, key: str) -> dict:
    g = point.guidance
    row = {"key": key, "sweep": point.sweep}
    for path, value in point.axes:
        row[path] = value
    row.update(mode=point.mode, target=point.target, cpu=point.cpu or "", scenario=point.scenario_label,
               start_id=hashlib.sha256(point.scenario.encode()).hexdigest()[:10], seed=point.seed,
               repeat=point.repeat)
    for name, value in point.model:
        row[name] = value
    for i, ph in enumerate(PHASES.values()):
        row[f"N_{ph}"] = g.horizon[i]
        row[f"Ts_{ph}_s"] = g.period_s[i]
    return row


def runs_frame(plan, store) -> pd.DataFrame:
    """One row per grid point whose run is stored, in grid order."""
    done = store.finished()
    cache: dict = {}
    rows = []
    for point, key in zip(plan.points, plan.keys):
        if key not in done:
            continue
        if key not in cache:
            cache[key] = _metrics(store.runs / key)
        row = coordinates(point, key)
        row.update(cache[key])  # with the record's build (target, or target-cpu for a CPU override)
        rows.append(row)
    df = pd.DataFrame(rows)
    for c in df.columns:  # swept integers stay integers where another sweep leaves them empty
        if c.startswith(("guidance.", "model.")) and df[c].dtype.kind == "f":
            v = df[c].dropna()
            if len(v) and (v == v.round()).all() and c.endswith(".N"):
                df[c] = df[c].astype("Int64")
    return df


def point_columns(runs: pd.DataFrame) -> list[str]:
    """The columns that tell sweep points apart: sweep, the swept paths, target and build."""
    axes = [c for c in runs.columns if c.startswith(("guidance.", "model.", "scenario."))]
    return ["sweep", *axes, "target", "build"]


def summary_frame(runs: pd.DataFrame, metrics=()) -> pd.DataFrame:
    if runs.empty:
        return pd.DataFrame()
    metrics = [m for m in (metrics or DEFAULT_SUMMARY_METRICS) if m in runs.columns and m not in WALL_TIME_METRICS]
    group = point_columns(runs)
    out = []
    for values, g in runs.groupby(group, sort=False, dropna=False):
        row = dict(zip(group, values if isinstance(values, tuple) else (values,)))
        row.update(runs=len(g), starts=g["start_id"].nunique(), docked_pct=100.0 * g["docked"].mean())
        for m in metrics:
            col = pd.to_numeric(g[m], errors="coerce")
            if col.notna().any():
                row[f"{m}_mean"], row[f"{m}_std"] = col.mean(), col.std(ddof=1) if col.notna().sum() > 1 else math.nan
                row[f"{m}_min"], row[f"{m}_max"] = col.min(), col.max()
        out.append(row)
    return pd.DataFrame(out)


def solves_frame(plan, store, runs: pd.DataFrame) -> pd.DataFrame:
    """Every solved guidance step of the stored runs, with the run's point columns."""
    from rvd_pil.host_sim.record import load_run

    frames = []
    seen: dict = {}
    cols = [c for c in point_columns(runs) if c in runs.columns] + ["key", "scenario", "seed", "mode", "cpu"]
    for rec in runs[cols].drop_duplicates().to_dict("records") if not runs.empty else []:
        key = rec["key"]
        if key not in seen:
            meta, steps = load_run(store.runs / key)
            seen[key] = run_solves(meta, steps)
        s = seen[key]
        if s.empty:
            continue
        s = s.copy()
        for c, v in rec.items():
            s[c] = v
        frames.append(s)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def frames_equal(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    """Same columns, same rows, same values and types (NaN equal to NaN)."""
    if list(a.columns) != list(b.columns) or len(a) != len(b):
        return False
    return all(a[c].reset_index(drop=True).equals(b[c].reset_index(drop=True)) for c in a.columns)
