"""Reports per study kind: HTML + PNG figures + CSV/Parquet tables, in OUT/report/.

    sensitivity  (ch. 4) delta-v and t_f by starting quadrant and range; per phase sweep the N x Ts
                 grid of phase delta-v, phase time and actuations, as heat maps and scatter plots
    robustness   (ch. 5) per start the mean and spread across noise repeats, success rate, safety
                 violations (from the records' safety entry), beside the dissertation's figures
    timing       (ch. 6) per target, phase, N and Ts: solve-time histograms with the three time
                 sources apart, and the dissertation's mean QEMU wall times beside ours
    runs         per sweep point: success, delta-v and t_f (and the timing tables when instruction
                 counts exist)

Deterministic tables (everything but wall time) are written as <name>.csv; wall-time tables as
timing_<name>.csv; every run as runs.csv and runs.parquet, every solve as solves.parquet.
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

FIGURES = {
    "sensitivity": ("starts", "dv_tf_by_quadrant", "dv_tf_by_range", "phase_scatter", "heatmaps"),
    "robustness": ("mean_dv_tf", "spread", "success", "safety"),
    "timing": ("histograms", "means"),
    "runs": ("dv_tf",),
}
PHASES = ("rendezvous", "approach", "docking")
# Dissertation ch. 6: mean solve time per phase and horizon (CVXGEN under QEMU ARM, host wall time), ms.
DISSERTATION_MS = {"rendezvous": {15: 119.18, 30: 270.40, 45: 863.91},
                   "approach": {5: 53.40, 15: 181.55, 30: 394.89},
                   "docking": {5: 9.1, 12: 30.1, 30: 98.8}}
# Dissertation ch. 5: average over 100 starts of the standard deviation across 60 noise repeats.
DISSERTATION_CH5 = {"dv_std_mps": 4.25, "t_f_std_min": 19.536}
# Dissertation ch. 4: what failed (of 500 starts) where it says so.
DISSERTATION_CH4 = {("rendezvous", 30, 60.0): "2 of 500 not docked within 200 min",
                    ("rendezvous", 45, 50.0): "1 of 500 not docked within 200 min",
                    ("rendezvous", 45, 60.0): "6 of 500 not docked within 200 min",
                    ("approach", 5, 5.0): "no feasible solutions"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def sweep_phases(runs: pd.DataFrame, sweep: str) -> list[str]:
    """The phases a sweep varies (guidance.<phase>.* axes); all three when it varies none."""
    cols = [c for c in runs.columns if c.startswith("guidance.")]
    g = runs[runs["sweep"] == sweep]
    phases = [ph for ph in PHASES if any(c.startswith(f"guidance.{ph}.") and g[c].notna().any() for c in cols)]
    return phases or list(PHASES)


def _axes(runs: pd.DataFrame, sweep: str) -> list[str]:
    g = runs[runs["sweep"] == sweep]
    return [c for c in runs.columns if c.startswith(("guidance.", "model.", "scenario.")) and g[c].notna().any()]


# ---- sensitivity ---------------------------------------------------------------------------------
def _stats(g: pd.DataFrame, col: str, prefix: str) -> dict:
    v = pd.to_numeric(g[col], errors="coerce")
    return {f"{prefix}_mean": v.mean(), f"{prefix}_min": v.min(), f"{prefix}_max": v.max()}


def sensitivity_tables(runs: pd.DataFrame) -> dict[str, pd.DataFrame]:
    tables = {}
    initial = [s for s in runs["sweep"].unique() if s == "initial" or not _axes(runs, s)]
    base = runs[runs["sweep"] == (initial[0] if initial else runs["sweep"].iloc[0])]
    for name, col in (("by_quadrant", "quadrant"), ("by_range", "range_bin")):
        rows = []
        for v, g in base.groupby(col, sort=True):
            d = g[g["docked"]]
            rows.append({col: v, "runs": len(g), "docked": int(g["docked"].sum()),
                         **_stats(d, "dv_total_mps", "dv_mps"), **_stats(d, "t_f_min", "t_f_min")})
        tables[name] = pd.DataFrame(rows)
    rows = []
    for sweep in runs["sweep"].unique():
        if sweep in initial:
            continue
        for ph in sweep_phases(runs, sweep):
            g = runs[runs["sweep"] == sweep]
            for (n, ts), gg in g.groupby([f"N_{ph}", f"Ts_{ph}_s"], sort=True):
                rows.append({"sweep": sweep, "phase": ph, "N": int(n), "Ts_s": float(ts), "runs": len(gg),
                             "docked": int(gg["docked"].sum()), "not_docked": int((~gg["docked"]).sum()),
                             **_stats(gg, f"dv_{ph}_mps", "phase_dv_mps"), **_stats(gg, f"t_{ph}_s", "phase_time_s"),
                             "actuations_mean": pd.to_numeric(gg[f"actuations_{ph}"]).mean(),
                             "qp_failures": int(gg["qp_failures"].sum()),
                             "dissertation": DISSERTATION_CH4.get((ph, int(n), float(ts)), "")})
    tables["phase_grid"] = pd.DataFrame(rows)
    return tables


def sensitivity_figures(runs, tables, figures, out: Path) -> list[tuple[str, str]]:
    plt = _plt()
    made = []
    initial = [s for s in runs["sweep"].unique() if s == "initial" or not _axes(runs, s)]
    base = runs[runs["sweep"] == (initial[0] if initial else runs["sweep"].iloc[0])]
    qcolors = {1: "tab:blue", 2: "tab:green", 3: "tab:orange", 4: "tab:red"}
    bins = sorted(base["range_bin"].unique())
    bcolors = dict(zip(bins, plt.cm.viridis(np.linspace(0, 0.9, max(len(bins), 1)))))
    if "starts" in figures:
        fig, axes = plt.subplots(1, 2, figsize=(12, 5.5))
        for q, g in base.groupby("quadrant"):
            axes[0].scatter(g["y0_m"], g["x0_m"], s=10, color=qcolors.get(q), label=f"quadrant {q}")
        for b, g in base.groupby("range_bin"):
            axes[1].scatter(g["y0_m"], g["x0_m"], s=10, color=bcolors[b], label=b)
        for ax, title in zip(axes, ("by quadrant", "by starting range")):
            ax.plot([0], [0], "k+", ms=12)
            ax.set_xlabel("y (V-bar) [m]")
            ax.set_ylabel("x (R-bar) [m]")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{len(base)} starts, {title} (cf. Figs. 4.1-4.3a)")
            ax.legend(fontsize=8)
        fig.tight_layout()
        made.append(("starts", _save(fig, out / "starts.png")))
    for key, col, colors, ref in (("dv_tf_by_quadrant", "quadrant", qcolors, "4.2b"),
                                  ("dv_tf_by_range", "range_bin", bcolors, "4.3b")):
        if key not in figures:
            continue
        fig, ax = plt.subplots(figsize=(7.5, 5.5))
        for v, g in base[base["docked"]].groupby(col):
            ax.scatter(g["t_f_min"], g["dv_total_mps"], s=10, color=colors.get(v), label=str(v))
        ax.set_xlabel("t_f [min]")
        ax.set_ylabel("total delta-v [m/s]")
        ax.set_title(f"delta-v vs t_f by {col.replace('_', ' ')} (docked runs; cf. Fig. {ref})")
        ax.legend(fontsize=8)
        fig.tight_layout()
        made.append((key, _save(fig, out / f"{key}.png")))
    grid = tables.get("phase_grid", pd.DataFrame())
    for sweep in (grid["sweep"].unique() if not grid.empty else []):
        g = grid[grid["sweep"] == sweep]
        ph = g["phase"].iloc[0]
        if "heatmaps" in figures:
            ns, tss = sorted(g["N"].unique()), sorted(g["Ts_s"].unique())
            fig, axes = plt.subplots(1, 3, figsize=(15, 3.2 + 0.5 * len(ns)))
            for ax, (col, label) in zip(axes, (("phase_dv_mps_mean", f"mean {ph} delta-v [m/s]"),
                                               ("phase_time_s_mean", f"mean {ph} time [s]"),
                                               ("not_docked", "runs not docked"))):
                m = np.full((len(ns), len(tss)), np.nan)
                for _, r in g.iterrows():
                    m[ns.index(r["N"]), tss.index(r["Ts_s"])] = r[col]
                im = ax.imshow(m, cmap="viridis", aspect="auto", origin="lower")
                lo, hi = np.nanmin(m) if np.isfinite(m).any() else 0.0, np.nanmax(m) if np.isfinite(m).any() else 1.0
                ax.set_xticks(range(len(tss)), [f"{t:g}" for t in tss])
                ax.set_yticks(range(len(ns)), [str(n) for n in ns])
                ax.set_xlabel("Ts [s]")
                ax.set_ylabel("N")
                ax.set_title(label)
                for i in range(len(ns)):
                    for j in range(len(tss)):
                        if np.isfinite(m[i, j]):
                            light = hi > lo and (m[i, j] - lo) / (hi - lo) > 0.6  # viridis is light at the top
                            ax.text(j, i, f"{m[i, j]:.3g}", ha="center", va="center", fontsize=8,
                                    color="k" if light else "w")
                fig.colorbar(im, ax=ax)
            fig.suptitle(f"{sweep}: {ph} phase, Ts x N")
            fig.tight_layout()
            made.append((f"heatmaps_{sweep}", _save(fig, out / f"heatmaps_{sweep}.png")))
        if "phase_scatter" in figures:
            r = runs[runs["sweep"] == sweep]
            ns = sorted(r[f"N_{ph}"].unique())
            tss = sorted(r[f"Ts_{ph}_s"].unique())
            tc = dict(zip(tss, plt.cm.plasma(np.linspace(0, 0.85, max(len(tss), 1)))))
            fig, axes = plt.subplots(2, len(ns), figsize=(5 * len(ns), 8), squeeze=False)
            for j, n in enumerate(ns):
                for ts in tss:
                    gg = r[(r[f"N_{ph}"] == n) & (r[f"Ts_{ph}_s"] == ts)]
                    axes[0, j].scatter(gg[f"t_{ph}_s"] / 60, gg[f"dv_{ph}_mps"], s=8, color=tc[ts], label=f"Ts {ts:g} s")
                    axes[1, j].scatter(gg[f"actuations_{ph}"], gg[f"dv_{ph}_mps"], s=8, color=tc[ts], label=f"Ts {ts:g} s")
                axes[0, j].set_title(f"{ph}, N = {n}")
                axes[0, j].set_xlabel(f"{ph} time [min]")
                axes[1, j].set_xlabel(f"{ph} control actuations")
                for i in range(2):
                    axes[i, j].set_ylabel(f"{ph} delta-v [m/s]")
                    axes[i, j].legend(fontsize=7)
            fig.suptitle(f"{sweep} (cf. Figs. 4.4-4.12)")
            fig.tight_layout()
            made.append((f"phase_scatter_{sweep}", _save(fig, out / f"phase_scatter_{sweep}.png")))
    return made


# ---- robustness ----------------------------------------------------------------------------------
def robustness_tables(runs: pd.DataFrame) -> dict[str, pd.DataFrame]:
    from .aggregate import point_columns

    rows = []
    have_safety = runs["safety_verdict"].notna().any()
    point = point_columns(runs)
    for values, g in runs.groupby([*point, "start_id"], sort=False, dropna=False):
        d = g[g["docked"]]
        coords = dict(zip(point, values))
        rows.append({**coords, "start": g["scenario"].iloc[0], "start_id": values[-1],
                     "range0_m": g["range0_m"].iloc[0], "quadrant": int(g["quadrant"].iloc[0]), "runs": len(g),
                     "docked_pct": 100.0 * g["docked"].mean(),
                     "dv_mean_mps": d["dv_total_mps"].mean(), "dv_std_mps": d["dv_total_mps"].std(ddof=1),
                     "t_f_mean_min": d["t_f_min"].mean(), "t_f_std_min": d["t_f_min"].std(ddof=1),
                     "qp_failures": int(g["qp_failures"].sum()),
                     "safety_violations": g["safety_violations"].sum() if have_safety else math.nan,
                     # a start inside a limit is the scenario's, not the guidance's: counted apart
                     "unsafe_runs": int((g["safety_verdict"].notna() &
                                         ~g["safety_verdict"].isin(["safe", "ok", "pass", "started_unsafe"])).sum())
                     if have_safety else math.nan,
                     "started_unsafe_runs": int((g["safety_verdict"] == "started_unsafe").sum()) if have_safety else math.nan})
    per_start = pd.DataFrame(rows)
    overall = []
    for values, g in per_start.groupby(point, sort=False, dropna=False):
        coords = dict(zip(point, values))
        r = runs.merge(pd.DataFrame([coords]), on=point, how="inner") if point else runs
        overall.append({**coords, "starts": len(g), "runs": len(r),
                        "success_pct": 100.0 * r["docked"].mean(),
                        "dv_mean_mps": r.loc[r["docked"], "dv_total_mps"].mean(),
                        "t_f_mean_min": r.loc[r["docked"], "t_f_min"].mean(),
                        "mean_of_per_start_dv_std_mps": g["dv_std_mps"].mean(),
                        "dissertation_dv_std_mps": DISSERTATION_CH5["dv_std_mps"],
                        "mean_of_per_start_t_f_std_min": g["t_f_std_min"].mean(),
                        "dissertation_t_f_std_min": DISSERTATION_CH5["t_f_std_min"],
                        "runs_with_safety_entry": int(r["safety_verdict"].notna().sum()),
                        "verdicts": ", ".join(f"{v} {n}" for v, n in r["safety_verdict"].value_counts().sort_index().items()),
                        "unsafe_runs": g["unsafe_runs"].sum() if have_safety else math.nan,
                        "started_unsafe_runs": g["started_unsafe_runs"].sum() if have_safety else math.nan,
                        "safety_violations": g["safety_violations"].sum() if have_safety else math.nan})
    tables = {"per_start": per_start, "overall": pd.DataFrame(overall)}
    limits = [c for c in runs.columns if c.startswith("safety.")]
    if limits:  # per limit of the safety monitor: how often, in how many runs
        rows = []
        for (sweep, target), g in runs.groupby(["sweep", "build"], sort=False):
            for c in limits:
                v = pd.to_numeric(g[c], errors="coerce")
                rows.append({"sweep": sweep, "target": target, "limit": c[len("safety."):],
                             "violations": v.sum(), "runs_violating": int((v > 0).sum()), "runs": len(g),
                             "starts_violating": int(g.loc[v > 0, "start_id"].nunique())})
        tables["safety_by_limit"] = pd.DataFrame(rows)
    return tables


def robustness_figures(runs, tables, figures, out: Path) -> list[tuple[str, str]]:
    plt = _plt()
    made = []
    ps = tables["per_start"]
    if "mean_dv_tf" in figures:
        fig, ax = plt.subplots(figsize=(8, 6))
        for (sweep, target), g in ps.groupby(["sweep", "target"], sort=False):
            ax.errorbar(g["t_f_mean_min"], g["dv_mean_mps"], xerr=g["t_f_std_min"], yerr=g["dv_std_mps"], fmt="o",
                        ms=4, elinewidth=0.8, capsize=2, label=f"{sweep} {target}")
        ax.set_xlabel("mean t_f [min] (bars: 1 sigma across noise repeats)")
        ax.set_ylabel("mean total delta-v [m/s]")
        n = int(ps["runs"].median()) if len(ps) else 0
        ax.set_title(f"mean delta-v vs mean t_f per start, {len(ps)} starts x {n} repeats (cf. Fig. 5.2)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        made.append(("mean_dv_tf", _save(fig, out / "mean_dv_tf.png")))
    if "spread" in figures:
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
        for ax, (col, ref, label) in zip(axes, (("dv_std_mps", DISSERTATION_CH5["dv_std_mps"], "std of delta-v per start [m/s]"),
                                                ("t_f_std_min", DISSERTATION_CH5["t_f_std_min"], "std of t_f per start [min]"))):
            v = ps[col].dropna()
            if len(v):
                ax.hist(v, bins=min(30, max(5, len(v) // 3)), color="tab:blue", alpha=0.8)
                ax.axvline(v.mean(), color="tab:blue", ls="-", label=f"ours: mean {v.mean():.3g}")
            ax.axvline(ref, color="k", ls="--", label=f"dissertation: mean {ref:g}")
            ax.set_xlabel(label)
            ax.set_ylabel("starts")
            ax.legend(fontsize=8)
        fig.suptitle("spread across noise repeats (dissertation section 5.4: average 4.25 m/s, 19.54 min)")
        fig.tight_layout()
        made.append(("spread", _save(fig, out / "spread.png")))
    if "success" in figures:
        fig, ax = plt.subplots(figsize=(10, 3.8))
        g = ps.sort_values("docked_pct")
        ax.bar(range(len(g)), g["docked_pct"], color="tab:green")
        ax.set_xlabel("start (sorted)")
        ax.set_ylabel("docked [% of repeats]")
        ax.set_ylim(0, 105)
        ax.set_title(f"success per start: {runs['docked'].mean() * 100:.1f} % of {len(runs)} runs docked")
        fig.tight_layout()
        made.append(("success", _save(fig, out / "success.png")))
    if "safety" in figures:
        fig, ax = plt.subplots(figsize=(10, 4.2))
        if ps["safety_violations"].notna().any():
            order = ps.sort_values("safety_violations", kind="stable")
            limits = [c for c in runs.columns if c.startswith("safety.")]
            x = np.arange(len(order))
            if limits:  # stacked by limit
                per = runs.groupby(["sweep", "build", "start_id"], sort=False)[limits].sum(min_count=1)
                bottom = np.zeros(len(order))
                for c in limits:
                    v = np.array([per.loc[(r.sweep, r.build, r.start_id), c] for r in order.itertuples()], float)
                    v = np.nan_to_num(v)
                    ax.bar(x, v, bottom=bottom, label=c[len("safety."):])
                    bottom += v
                ax.legend(fontsize=8)
            else:
                ax.bar(x, order["safety_violations"], color="tab:red")
            ax.set_xticks(x, order["start"], rotation=90, fontsize=7)
            ax.set_ylabel("violations (all repeats)")
            started = int(ps["started_unsafe_runs"].sum()) if "started_unsafe_runs" in ps else 0
            ax.set_title(f"safety monitor (on truth): {int(ps['unsafe_runs'].sum())} of {int(ps['runs'].sum())} runs "
                         f"unsafe, {int(ps['safety_violations'].sum())} violations"
                         + (f" ({started} runs started inside a limit: not counted)" if started else ""))
            ax.set_xlabel("starts, ordered by violations")
        else:
            ax.text(0.5, 0.5, "no safety entry in these run records\n(no truth-based safety monitor ran)",
                    ha="center", va="center", fontsize=12)
            ax.set_axis_off()
        fig.tight_layout()
        made.append(("safety", _save(fig, out / "safety.png")))
    return made


# ---- timing --------------------------------------------------------------------------------------
def _phase_solves(runs: pd.DataFrame, solves: pd.DataFrame) -> pd.DataFrame:
    """Each sweep's solves of the phases it varies."""
    parts = []
    for sweep in runs["sweep"].unique():
        phases = sweep_phases(runs, sweep)
        parts.append(solves[(solves["sweep"] == sweep) & solves["phase"].isin(phases)])
    return pd.concat(parts, ignore_index=True) if parts else solves.iloc[:0]


def timing_tables(runs: pd.DataFrame, solves: pd.DataFrame) -> tuple[dict, dict]:
    """(deterministic tables, wall-time tables)."""
    if solves.empty:
        return {}, {}
    s = _phase_solves(runs, solves)
    det, wall = [], []
    ts_sweeps = {sw for sw in runs["sweep"].unique() if any(c.endswith(".Ts_s") for c in _axes(runs, sw))}
    for (sweep, build, phase, n, ts), g in s.groupby(["sweep", "build", "phase", "N", "Ts_s"], sort=True):
        key = {"sweep": sweep, "target": build, "phase": phase, "N": int(n), "Ts_s": float(ts)}
        ins = g["instructions"].astype(float)
        counted = bool((ins > 0).any())
        det.append({**key, "solves": len(g), "runs": g["key"].nunique(),
                    "iterations_mean": g["iterations"].mean(), "iterations_max": g["iterations"].max(),
                    "qp_not_solved": int((g["solver_status"] != 0).sum()),
                    "insns_mean": ins.mean() if counted else math.nan,
                    "insns_p50": ins.median() if counted else math.nan,
                    "insns_p99": ins.quantile(0.99) if counted else math.nan,
                    "insns_max": ins.max() if counted else math.nan,
                    "target_ms_mean": g["target_us_nominal"].mean() / 1e3,
                    "target_ms_mean_low": g["target_us_low"].mean() / 1e3,
                    "target_ms_mean_high": g["target_us_high"].mean() / 1e3,
                    "target_ms_p99": g["target_us_nominal"].quantile(0.99) / 1e3,
                    "target_ms_max_high": g["target_us_high"].max() / 1e3,
                    "deadline_ms": 0.5 * ts * 1e3,
                    "deadline_misses_high": int((g["target_us_high"] > 0.5 * ts * 1e6).sum())})
        # The dissertation gives means for its horizon sweeps only (Figs. 6.3, 6.5, 6.7); its Ts
        # sweeps (Figs. 6.4, 6.6) show that the spread does not change with Ts, without means.
        diss = math.nan if sweep in ts_sweeps else DISSERTATION_MS.get(phase, {}).get(int(n), math.nan)
        w = g["wall_us"].astype(float) / 1e3
        wall.append({**key, "solves": len(g), "wall_ms_mean": w.mean(), "wall_ms_p50": w.median(),
                     "wall_ms_p99": w.quantile(0.99), "wall_ms_max": w.max(),
                     "dissertation_qemu_wall_ms_mean": diss,
                     "ours_over_dissertation": w.mean() / diss if diss == diss else math.nan,
                     "mode": g["mode"].iloc[0]})
    return {"solve_stats": pd.DataFrame(det)}, {"solve_wall": pd.DataFrame(wall)}


def timing_figures(runs, solves, tables, wall, figures, out: Path) -> list[tuple[str, str]]:
    plt = _plt()
    made = []
    if solves.empty:
        return made
    s = _phase_solves(runs, solves)
    sweeps = list(runs["sweep"].unique())
    if "histograms" in figures:
        for build in s["build"].unique():
            sb = s[s["build"] == build]
            counted = bool((sb["instructions"] > 0).any())
            cols = [("target_us_nominal", "estimated target time [ms]")] if counted else []
            cols.append(("wall_us", "emulated wall time [ms]" if sb["mode"].iloc[0] == "qemu-user" else "host wall time [ms]"))
            fig, axes = plt.subplots(len(sweeps), len(cols), figsize=(6.5 * len(cols), 3.2 * len(sweeps)), squeeze=False)
            for i, sweep in enumerate(sweeps):
                g = sb[sb["sweep"] == sweep]
                axis_cols = _axes(runs, sweep)
                var = "Ts_s" if any(c.endswith(".Ts_s") for c in axis_cols) else "N"
                for j, (col, label) in enumerate(cols):
                    ax = axes[i, j]
                    data = [(v, g[g[var] == v][col].to_numpy() / 1e3) for v in sorted(g[var].unique())]
                    data = [(v, d) for v, d in data if len(d)]
                    if data:
                        hi = max(d.max() for _, d in data)
                        bins = np.linspace(0, hi * 1.02 if hi > 0 else 1, 40)
                        for v, d in data:
                            name = f"Ts = {v:g} s" if var == "Ts_s" else f"N = {v:g}"
                            ax.hist(d, bins=bins, histtype="step", lw=1.5, label=f"{name} ({len(d)} solves)")
                        ax.legend(fontsize=7)
                    ax.set_title(f"{sweep}: {', '.join(sorted(g['phase'].unique()))}", fontsize=9)
                    ax.set_xlabel(label)
                    ax.set_ylabel("solves")
            fig.suptitle(f"{build}: solve time per phase (cf. Figs. 6.3-6.7)")
            fig.tight_layout()
            made.append((f"histograms_{build}", _save(fig, out / f"histograms_{build}.png")))
    if "means" in figures and wall:
        w = wall["solve_wall"]
        det = tables.get("solve_stats", pd.DataFrame())
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
        for ax, ph in zip(axes, PHASES):
            gw = w[(w["phase"] == ph)]
            gw = gw.loc[gw.groupby(["target", "N"])["solves"].idxmax()] if len(gw) else gw
            for build, g in gw.groupby("target"):
                g = g.sort_values("N")
                ax.plot(g["N"], g["wall_ms_mean"], "o-", label=f"{build}: emulated wall (mean)")
                gd = det[(det["target"] == build) & (det["phase"] == ph)] if not det.empty else det
                gd = gd.loc[gd.groupby("N")["solves"].idxmax()].sort_values("N") if len(gd) else gd
                if len(gd) and gd["target_ms_mean"].notna().any():
                    ax.plot(gd["N"], gd["target_ms_mean"], "s:", label=f"{build}: estimated target (mean)")
            ref = DISSERTATION_MS[ph]
            ax.plot(list(ref), list(ref.values()), "k^--", label="dissertation: CVXGEN, QEMU wall (mean)")
            ax.set_yscale("log")
            ax.set_xlabel("horizon N")
            ax.set_ylabel("mean time per solve [ms]")
            ax.set_title(ph)
            ax.legend(fontsize=7)
        fig.tight_layout()
        made.append(("means", _save(fig, out / "means.png")))
    return made


def runs_figures(runs, figures, out: Path) -> list[tuple[str, str]]:
    plt = _plt()
    made = []
    if "dv_tf" in figures:
        fig, ax = plt.subplots(figsize=(7.5, 5.5))
        for sweep, g in runs[runs["docked"]].groupby("sweep", sort=False):
            ax.scatter(g["t_f_min"], g["dv_total_mps"], s=12, label=sweep)
        ax.set_xlabel("t_f [min]")
        ax.set_ylabel("total delta-v [m/s]")
        ax.set_title(f"docked runs: {int(runs['docked'].sum())} of {len(runs)}")
        ax.legend(fontsize=8)
        fig.tight_layout()
        made.append(("dv_tf", _save(fig, out / "dv_tf.png")))
    return made


# ---- writing -------------------------------------------------------------------------------------
def _save(fig, path: Path) -> str:
    fig.savefig(path, dpi=90)
    _plt().close(fig)
    return path.name


def _table_html(df: pd.DataFrame, max_rows: int = 400) -> str:
    if df is None or df.empty:
        return "<p><i>(empty)</i></p>"
    note = f"<p><i>first {max_rows} of {len(df)} rows; all in the CSV</i></p>" if len(df) > max_rows else ""

    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return "" if not np.isfinite(v) else f"{v:.4g}"
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = "".join("<tr>" + "".join(f"<td>{fmt(v)}</td>" for v in row) + "</tr>"
                   for row in df.head(max_rows).itertuples(index=False))
    return f"{note}<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def repeat_checks(runs: pd.DataFrame) -> pd.DataFrame:
    """Points run more than once with identical inputs (execution.repeat): do the records agree?"""
    if "repeat" not in runs or not (runs["repeat"] > 0).any():
        return pd.DataFrame()
    same = ["sweep", "build", "mode", "scenario", "start_id", "seed",
            *[c for c in runs.columns if c.startswith(("guidance.", "model.", "N_", "Ts_"))]]
    rows = []
    for _, g in runs.groupby(same, sort=False, dropna=False):
        if len(g) < 2:
            continue
        ins = g["instructions_total"]
        rows.append({"sweep": g["sweep"].iloc[0], "target": g["build"].iloc[0], "mode": g["mode"].iloc[0],
                     "scenario": g["scenario"].iloc[0], "seed": int(g["seed"].iloc[0]), "repeats": len(g),
                     "end": " / ".join(sorted(set(map(str, g["end"])))),
                     "trajectory_identical": bool(g[["steps", "dv_total_mps", "t_f_s", "final_range_to_port_m"]]
                                                  .nunique(dropna=False).max() == 1),
                     "instructions_identical": (bool(ins.nunique() == 1) if (ins > 0).any() else "not counted"),
                     "instructions_total": ins.iloc[0]})
    return pd.DataFrame(rows)


def build_tables(result) -> tuple[dict, dict]:
    """(deterministic tables, wall-time tables) of the study's report kind."""
    kind = result.study.report["kind"]
    runs, solves = result.runs, result.solves
    tables, wall = {"summary": result.summary}, {}
    if runs.empty:
        return tables, wall
    if kind == "sensitivity":
        tables.update(sensitivity_tables(runs))
    elif kind == "robustness":
        tables.update(robustness_tables(runs))
    if not solves.empty:
        det, wall = timing_tables(runs, solves)
        tables.update(det)
    checks = repeat_checks(runs)
    if not checks.empty:
        tables["repeat_checks"] = checks
    return tables, wall


def write(result) -> Path:
    study = result.study
    kind = study.report["kind"]
    out = result.out / "report"
    out.mkdir(parents=True, exist_ok=True)
    figures = study.report["figures"] or FIGURES[kind]
    runs, solves = result.runs, result.solves
    tables, wall = result.tables, result.timing
    runs.to_csv(out / "runs.csv", index=False)
    runs.to_parquet(out / "runs.parquet", index=False)
    if not solves.empty:
        solves.to_parquet(out / "solves.parquet", index=False)
    for name, df in tables.items():
        df.to_csv(out / f"{name}.csv", index=False)
    for name, df in wall.items():
        df.to_csv(out / f"timing_{name}.csv", index=False)
    made = []
    if not runs.empty:
        if kind == "sensitivity":
            made = sensitivity_figures(runs, tables, figures, out)
        elif kind == "robustness":
            made = robustness_figures(runs, tables, figures, out)
        elif kind == "timing":
            made = timing_figures(runs, solves, tables, wall, figures, out)
        else:
            made = runs_figures(runs, figures, out)
    o = result.outcome
    facts = {"study": study.name, "quick": study.quick, "kind": kind, "runs_in_grid": result.total,
             "runs_stored": result.finished, "complete": result.complete,
             "grid": result.fingerprint, "executor": getattr(o, "executor", None)}
    (out / "report.json").write_text(json.dumps({"facts": facts, "tables": {k: v.to_dict(orient="records")
                                                                            for k, v in tables.items()}},
                                                indent=1, default=str, allow_nan=True))
    css = ("body{font-family:sans-serif;margin:2em;max-width:1500px}table{border-collapse:collapse;font-size:12px}"
           "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#eee}"
           "td:first-child,th:first-child{text-align:left}")
    parts = [f"<!doctype html><meta charset='utf-8'><title>{html.escape(study.label)}</title><style>{css}</style>",
             f"<h1>{html.escape(study.label)}</h1><p>{html.escape(study.description)}</p>",
             f"<p>{result.finished} of {result.total} runs stored"
             f"{'' if result.complete else ' <b>(incomplete: run the study again to finish it)</b>'}; "
             f"grid {result.fingerprint[:12]}; study file <code>{html.escape(str(study.source.name))}</code>.</p>"]
    if kind == "timing" or (not solves.empty):
        parts.append("<p>Three time sources, never mixed: <b>emulated wall time</b> (the flight software's own "
                     "clock under qemu-user: host time, noisy; the dissertation's figures are of this kind), "
                     "<b>instructions</b> counted by the TCG plugin around every solver call (deterministic), "
                     "and the <b>estimated target time</b> = instructions x CPI / f_clk of the target's CPU model "
                     "(an engineering estimate with a low-high band, not calibrated on hardware).</p>")
    if kind == "robustness":
        parts.append("<p>Spread across noise repeats: for each start the standard deviation of delta-v and t_f "
                     "over its docked repeats; the dissertation (section 5.4) reports their average over 100 "
                     "starts x 60 repeats: 4.25 m/s and 19.54 min. Safety: from the <code>safety</code> entry "
                     "of each run record (a truth-based monitor), when the records have one.</p>")
    for name, df in tables.items():
        parts.append(f"<h2>{html.escape(name)}</h2>{_table_html(df)}")
    for name, df in wall.items():
        parts.append(f"<h2>{html.escape(name)} (wall time: varies from run to run)</h2>{_table_html(df)}")
    for name, img in made:
        parts.append(f"<h2>{html.escape(name)}</h2><img src='{img}' style='max-width:100%'>")
    index = out / "report.html"
    index.write_text("\n".join(parts))
    return index
