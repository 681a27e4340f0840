"""The PIL report: solve-time statistics and histograms per target, phase and horizon, from the run
records of a campaign directory (rvd_pil/bench/campaign.py).

    python -m rvd_pil.bench.report reports/pil        rebuild report.html, *.png, stats.csv, runs.csv, report.json

Timing sources, never mixed up:
  - the flight clock: what the flight software's deadlines and reported solve times are on; under
    qemu-user with --target-clock (every campaign run) target time, instructions x CPI / f_clk, else
    the host's clock;
  - emulated host time: the host's round trip of a step (nav out, cmd in) when the flight clock was
    on target time, else the flight's own solve time on the host clock (host time, noisy);
  - instructions: counted by our TCG plugin around every solver call of a guidance step (deterministic);
  - cycles: the cycle model (rvd_pil/qemu/cycles.py): per-block execution counts inside the same markers x
    llvm-mca block costs per CPU, corrected where LLVM disagrees with published timings, plus the
    cache model's misses x penalty ranges; an interval (low / nominal / high), deterministic;
  - estimated target time = cycles / f_clk (the old instructions x CPI guess / f_clk beside it).
"""
from __future__ import annotations

import html
import json
import math
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from rvd_pil.host_sim.record import load_events, load_run  # noqa: E402

PHASES = {1: "rendezvous", 2: "approach", 3: "docking"}
# A. Fear, Application of Model Predictive Control for the Autonomous Rendezvous and Docking of Small
# Satellites (PhD dissertation, Georgia Tech, 2023), ch. 6: CVXGEN under QEMU full-system ARM emulation,
# mean solve wall time [ms] per phase and horizon.
DISSERTATION_MS = {"rendezvous": {15: 119.18, 30: 270.40, 45: 863.91},
                   "approach": {5: 53.40, 15: 181.55, 30: 394.89},
                   "docking": {5: 9.1, 12: 30.1, 30: 98.8}}


def campaign_runs(out: Path) -> list[str] | None:
    """The run directories (relative to `out`) the campaign in `out` ran or reused, from its
    campaign.json; None for a folder without one (every record under runs/ is read)."""
    path = Path(out) / "campaign.json"
    if not path.exists():
        return None
    try:
        runs = json.loads(path.read_text()).get("runs")
    except (json.JSONDecodeError, AttributeError):
        raise SystemExit(f"{path}: not a campaign file (invalid JSON)") from None
    return None if runs is None else [str(r) for r in runs]


def load_campaign(out: Path) -> tuple[list[dict], pd.DataFrame]:
    """All run records under out/runs: (list of meta dicts with 'dir', one DataFrame of every step)."""
    metas, frames = [], []
    paths = sorted((out / "runs").rglob("meta.json"))
    owned = campaign_runs(out)
    if owned is not None:  # only this campaign's runs, never those another left in the folder
        paths = [out / d / "meta.json" for d in owned if (out / d / "meta.json").exists()]
    for meta_path in paths:
        run_dir = meta_path.parent
        meta, steps = load_run(run_dir)
        meta["dir"] = str(run_dir.relative_to(out))
        # A CPU override is a build of its own (e.g. q7s-cortex-a8): report it apart, never mixed.
        meta["target"] = meta.get("build") or meta.get("target")
        metas.append(meta)
        steps = steps.copy()
        cyc_path = run_dir / "cycles.csv"
        if cyc_path.exists():
            cyc = pd.read_csv(cyc_path).add_prefix("cyc_").rename(columns={"cyc_step": "step"})
            steps = steps.merge(cyc, on="step", how="left")
        steps["run"] = meta["dir"]
        for key in ("target", "mode", "kind", "scenario_label", "cpu"):
            steps[key] = meta.get(key)
        frames.append(steps)
    df = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return metas, df


def solves(metas: list[dict], df: pd.DataFrame) -> pd.DataFrame:
    """One row per guidance step of the timing runs, with horizon, timing sources and budget."""
    by_dir = {m["dir"]: m for m in metas}
    # A step that computed: a solver ran, or a plug-in law without a solver took time (its solve_time_us).
    rows = df[(df["kind"] == "timing") & df["phase"].isin(PHASES) &
              ((df["solver_status"] != 255) | (df["solve_time_us"] > 0))].copy()
    if rows.empty:
        return rows
    rows["phase_name"] = rows["phase"].map(PHASES)
    rows["N"] = [int(by_dir[r]["horizons"][int(p) - 1]) for r, p in zip(rows["run"], rows["phase"])]
    cpi = {m["dir"]: m["cpi"] for m in metas if m.get("cpi")}
    clock = {m["dir"]: m["clock_hz"] for m in metas if m.get("clock_hz")}
    frac = {m["dir"]: (m.get("flight_hello") or {}).get("deadline_fraction", 0.5) for m in metas}
    for band in ("nominal", "low", "high"):  # the old estimate: instructions x CPI guess / f_clk
        rows[f"target_us_cpi_{band}"] = [i * cpi[r][band] / clock[r] * 1e6 for i, r in zip(rows["instructions"], rows["run"])]
    if "cyc_cycles_nominal" not in rows:
        raise SystemExit("timing runs without cycle estimates (cycles.csv): re-run the campaign")
    for band in ("nominal", "low", "high"):  # the cycle model: cycles / f_clk
        rows[f"target_us_{band}"] = [c / clock[r] * 1e6 for c, r in zip(rows[f"cyc_cycles_{band}"], rows["run"])]
    rows["cpi_model"] = rows["cyc_cycles_nominal"] / rows["instructions"]
    rows["budget_us"] = [frac[r] * ts * 1e6 for r, ts in zip(rows["run"], rows["cmd_period_s"])]
    # Emulated host time. A flight clock on target time (hello step_clock 1) reports target time, so
    # the host's figure is then its round trip of the step: nav out to cmd in, which adds the filter,
    # the allocation, the link and the host's own work to the solve (an upper bound of its host time).
    step_clock = {m["dir"]: (m.get("flight_hello") or {}).get("step_clock", 0) for m in metas}
    rows["flight_clock_target"] = [step_clock.get(r, 0) == 1 for r in rows["run"]]
    round_trip_us = rows["round_trip_ms"] * 1e3 if "round_trip_ms" in rows else math.nan
    rows["host_wall_us"] = np.where(rows["flight_clock_target"], round_trip_us, rows["solve_time_us"])
    rows["cpu_load"] = rows["target_us_nominal"] / (rows["cmd_period_s"] * 1e6)
    return rows


def stats_table(rows: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (target, phase, n), g in rows.groupby(["target", "phase_name", "N"], sort=False):
        worst = g.loc[g["target_us_nominal"].idxmax()]
        # max / median over every run of the cell, and within each run: a harder scenario (more
        # active rows, a turning target) raises the first only, an unpredictable solve both
        within = g.groupby("run")["target_us_nominal"].agg(lambda t: t.max() / t.median())
        out.append({
            "target": target, "phase": phase, "N": n, "solves": len(g),
            "target_ms_mean": g["target_us_nominal"].mean() / 1e3,
            "target_ms_mean_low": g["target_us_low"].mean() / 1e3, "target_ms_mean_high": g["target_us_high"].mean() / 1e3,
            "target_ms_p50": g["target_us_nominal"].median() / 1e3,
            "target_ms_p99": g["target_us_nominal"].quantile(0.99) / 1e3,
            "target_ms_max": worst["target_us_nominal"] / 1e3,
            "target_ms_max_low": worst["target_us_low"] / 1e3, "target_ms_max_high": worst["target_us_high"] / 1e3,
            "max_at": f"{worst['run']} step {int(worst['step'])}",
            "max_over_p50": worst["target_us_nominal"] / g["target_us_nominal"].median(),
            "run_max_over_p50": within.max(), "run_max_over_p50_at": within.idxmax(),
            "insns_mean": g["instructions"].mean(), "insns_max": g["instructions"].max(),
            "cycles_mean": g["cyc_cycles_nominal"].mean(), "cycles_max": worst["cyc_cycles_nominal"],
            "cycles_max_low": worst["cyc_cycles_low"], "cycles_max_high": worst["cyc_cycles_high"],
            "cpi_model_mean": g["cyc_cycles_nominal"].sum() / g["instructions"].sum(),
            # L1D misses per 1000 instructions (a run without the cache model has borrowed misses, no accesses)
            "l1d_mpki": 1e3 * (g["cyc_l1d_load_misses"] + g["cyc_l1d_store_misses"]).sum() / max(1, g["instructions"].sum()),
            "target_ms_cpi_mean": g["target_us_cpi_nominal"].mean() / 1e3,
            "target_ms_cpi_max": g["target_us_cpi_nominal"].max() / 1e3,
            "calibrated": bool(g["cyc_calibrated"].all()),
            "wall_ms_mean": g["host_wall_us"].mean() / 1e3, "wall_ms_p99": g["host_wall_us"].quantile(0.99) / 1e3,
            "wall_ms_max": g["host_wall_us"].max() / 1e3,
            "wall_is_round_trip": bool(g["flight_clock_target"].any()),
            "flight_clock_ms_mean": g["solve_time_us"].mean() / 1e3, "flight_clock_ms_max": g["solve_time_us"].max() / 1e3,
            "iterations_mean": g["iterations"].mean(), "iterations_max": g["iterations"].max(),
            "overruns_flight_clock": int(g["overrun"].sum()),
            "deadline_misses_est": int((g["target_us_high"] > g["budget_us"]).sum()),
            "deadline_ms": g["budget_us"].iloc[0] / 1e3,
            "cpu_load_mean_pct": 100 * g["cpu_load"].mean(), "cpu_load_max_pct": 100 * g["cpu_load"].max(),
            "dissertation_cvxgen_ms": DISSERTATION_MS.get(phase, {}).get(int(n), math.nan),
        })
    return pd.DataFrame(out).sort_values(["target", "phase", "N"], key=lambda c: c.map(
        {"rendezvous": 0, "approach": 1, "docking": 2}) if c.name == "phase" else c)


def checks(metas: list[dict], df: pd.DataFrame) -> dict:
    """Determinism and native-vs-QEMU agreement from the check runs."""
    by_dir = {m["dir"]: m for m in metas}
    out: dict = {}
    native = [m for m in metas if m.get("mode") == "native" and m.get("kind") == "check"]
    native_dv = native[0].get("dv_total_mps") if native else None
    for target in sorted({m.get("target") for m in metas if m.get("kind") == "check" and m.get("mode") != "native"}):
        res: dict = {}
        for mode, col in (("user", "instructions"), ("user", "cyc_cycles_nominal"), ("system", "solve_time_us"),
                          ("system", "instructions")):
            dirs = sorted(d for d, m in by_dir.items() if m.get("target") == target and m.get("kind") == "check"
                          and m.get("mode") == mode)
            if len(dirs) < 2:
                continue
            # a comparison of runs that did not dock would compare nothing: say so first (runs cut at a
            # set simulated time, for a law that never docks there, must both reach that cut instead)
            cut = by_dir[dirs[0]].get("check_timeout_s")
            if cut is not None:
                res[f"{mode}_check_timeout_s"] = cut
                res[f"{mode}_runs_ends"] = [f"{by_dir[d].get('end')} at {by_dir[d].get('t_end_s', math.nan):.0f} s"
                                            for d in dirs]
                res[f"{mode}_runs_reached_cut"] = all(bool(by_dir[d].get("docked")) or by_dir[d].get("end") == "timeout"
                                                      for d in dirs)
            else:
                res[f"{mode}_runs_docked"] = all(bool(by_dir[d].get("docked")) for d in dirs)
            a = df[df["run"] == dirs[0]][col].to_numpy()
            b = df[df["run"] == dirs[1]][col].to_numpy()
            if not (np.nan_to_num(a).any() or np.nan_to_num(b).any()):
                # nothing counted (e.g. no PMU in the CPU model): say so rather than "identical"
                res[f"{mode}_{col}"] = "not measured"
                continue
            same = len(a) == len(b) and bool(np.array_equal(np.nan_to_num(a), np.nan_to_num(b)))
            res[f"{mode}_{col}_identical"] = same
            res[f"{mode}_{col}_compared"] = int(min(len(a), len(b)))
            res[f"{mode}_{col}_sum"] = float(np.nansum(a))
            if len(a) == len(b) and len(a):
                diff = np.abs(np.nan_to_num(a) - np.nan_to_num(b))
                res[f"{mode}_{col}_steps_identical"] = int(np.sum(diff == 0))
                res[f"{mode}_{col}_max_difference"] = float(diff.max())
            dvs = [by_dir[d].get("dv_total_mps") for d in dirs]
            if native_dv is not None:
                res[f"{mode}_dv_minus_native_mps"] = [None if v is None else v - native_dv for v in dvs]
                res[f"{mode}_steps"] = [by_dir[d].get("steps") for d in dirs]
        res["native_dv_mps"] = native_dv
        res["native_steps"] = native[0].get("steps") if native else None
        # Every priced solve of this target: the block profiler's total (sum of executions x block
        # size) must equal the instruction counter's figure that travelled in the telemetry.
        user = df[(df["target"] == target) & (df["mode"] == "user")]
        if "cyc_instructions" in user:
            priced = user[user["cyc_instructions"].notna() & (user["instructions"] > 0)]
            res["block_counts_equal_instruction_counts"] = bool(
                len(priced) and (priced["cyc_instructions"] == priced["instructions"]).all())
            res["block_counts_compared"] = int(len(priced))
        out[target] = res
    return out


# ---- plots -------------------------------------------------------------------------------------
def safety_tables(metas: list[dict]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(verdict per run, violations per target, phase, scenario and limit with the worst one) from the
    safety monitor's summary in each record (rvd_pil.host_sim.safety: judged on the truth)."""
    verdicts, rows = [], []
    for m in metas:
        s = m.get("safety") or {}
        if not s:
            continue
        fig = s.get("figures", {})
        verdicts.append({"run": m["dir"], "target": m.get("target"), "kind": m.get("kind"),
                         "scenario": m.get("scenario_label"), "verdict": s.get("verdict"),
                         "violations": s.get("violations"), "excursions": s.get("excursions"),
                         "dock_cone_margin_cm": None if fig.get("max_docking_cone_excursion_m") is None
                         else -100 * fig["max_docking_cone_excursion_m"],
                         "closest_axial_approach_m": fig.get("min_axial_distance_approach_m"),
                         "max_speed_docking_mm_s": 1000 * (fig.get("max_speed_inf_docking_mps") or 0.0)})
        for ep in s.get("episodes", []):
            rows.append({"target": m.get("target"), "phase": ep["phase"], "scenario": m.get("scenario_label"),
                         "limit": ep["limit"], "kind": ep["kind"], "worst": ep["worst"], "unit": ep["unit"],
                         "run": m["dir"], "step": ep["worst_step"]})
    per_run = pd.DataFrame(verdicts)
    if not rows:
        return per_run, pd.DataFrame()
    ep = pd.DataFrame(rows)
    worst = ep.loc[ep.groupby(["target", "phase", "scenario", "limit", "kind"])["worst"].idxmax()]
    counts = ep.groupby(["target", "phase", "scenario", "limit", "kind"]).size().rename("count").reset_index()
    table = counts.merge(worst[["target", "phase", "scenario", "limit", "kind", "worst", "unit", "run", "step"]],
                         on=["target", "phase", "scenario", "limit", "kind"])
    return per_run, table


def host_time_label(rows: pd.DataFrame) -> str:
    """What the emulated host time of these solves is (solves()'s host_wall_us)."""
    if len(rows) and rows["flight_clock_target"].all():
        return "emulated host time: round trip of the step, nav out to cmd in"
    if len(rows) and rows["flight_clock_target"].any():
        return "emulated host time: round trip of the step (flight clock on target time) or the flight's host clock"
    return "emulated wall time, qemu-user on this host"


def plot_histograms(rows: pd.DataFrame, target: str, path: Path, cpu_label: str) -> None:
    """Per phase: the estimated target time (top) and the emulated host time (bottom), one step
    histogram per horizon, on a log time axis that reaches the deadline (marked) so that the margin
    is visible; the dissertation's mean CVXGEN QEMU wall time is marked beside our host times only
    (the closest pair: both host time)."""
    g = rows[rows["target"] == target]
    host_label = host_time_label(g)
    fig, axes = plt.subplots(2, 3, figsize=(15, 7.5))
    for j, phase in enumerate(("rendezvous", "approach", "docking")):
        gp = g[g["phase_name"] == phase]
        deadline_ms = gp["budget_us"].max() / 1e3 if len(gp) else math.nan
        for i, (col, label) in enumerate((("target_us_nominal", f"estimated target time on {cpu_label} [ms]"),
                                          ("host_wall_us", f"{host_label} [ms]"))):
            ax = axes[i, j]
            data = [(n, gp[gp["N"] == n][col].to_numpy() / 1e3) for n in sorted(gp["N"].unique())]
            data = [(n, d[d > 0]) for n, d in data if (d > 0).any()]
            colors = {}
            if data:
                lo = min(d.min() for _, d in data)
                hi = max([d.max() for _, d in data] + ([deadline_ms] if math.isfinite(deadline_ms) else []))
                bins = np.geomspace(lo / 1.2, hi * 1.2, 60)
                for n, d in data:
                    _, _, patches = ax.hist(d, bins=bins, histtype="step", linewidth=1.6, label=f"N = {n}: {len(d)} solves")
                    colors[n] = patches[0].get_edgecolor()
                ax.set_xscale("log")
                ax.minorticks_off()  # labelled minor ticks of a log axis cost seconds each to lay out
            if math.isfinite(deadline_ms):
                ax.axvline(deadline_ms, color="tab:red", lw=2, label=f"deadline {_fmt(deadline_ms)} ms (0.5 Ts)")
            if i == 1:  # the like-for-like reference: the dissertation's mean QEMU wall time, per horizon
                for n, ms in DISSERTATION_MS.get(phase, {}).items():
                    if n in colors:
                        ax.axvline(ms, color=colors[n], ls="--", lw=1.2,
                                   label=f"dissertation N = {n}: mean {_fmt(ms)} ms")
            ax.legend(fontsize=7, loc="upper right", framealpha=0.9)
            ax.set_xlabel(label)
            ax.set_ylabel("solves per bin")
            if i == 0:
                ax.set_title(f"{phase}: Ts = {_fmt(gp['cmd_period_s'].max())} s" if len(gp) else phase)
    fig.suptitle(f"{target} ({cpu_label}): time per guidance solve, per phase and horizon N")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_scaling(table: pd.DataFrame, path: Path, cpu_labels: dict, host_cpu: str) -> None:
    """Top: QEMU host times, ours beside the dissertation's (both host time; ours the step's round trip
    when the flight clock was on target time).
    Bottom: our estimated target times per CPU with the deadline, a series of their own."""
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    for j, phase in enumerate(("rendezvous", "approach", "docking")):
        t = table[table["phase"] == phase]
        ax, bx = axes[0, j], axes[1, j]
        for target, g in t.groupby("target"):
            g = g.sort_values("N")
            ax.plot(g["N"], g["wall_ms_mean"], "o-", label=f"ours: {cpu_labels.get(target, target)} under qemu-user")
            bx.plot(g["N"], g["target_ms_mean"], "o-", label=f"{cpu_labels.get(target, target)}: cycle-model estimate")
            bx.fill_between(g["N"], g["target_ms_mean_low"], g["target_ms_mean_high"], alpha=0.2)
        ref = DISSERTATION_MS[phase]
        ax.plot(list(ref), list(ref.values()), "ks--", label="dissertation: CVXGEN, QEMU full-system ARM")
        if len(t):
            bx.axhline(t["deadline_ms"].max(), color="tab:red", lw=2, label=f"deadline {_fmt(t['deadline_ms'].max())} ms")
        round_trip = bool(t["wall_is_round_trip"].any()) if len(t) else False
        for x, title in ((ax, "QEMU host time" + (" (step round trip)" if round_trip else "")), (bx, "estimated target time")):
            x.set_yscale("log")
            x.minorticks_off()
            x.set_xlabel("horizon N")
            x.set_ylabel("mean time per solve [ms]")
            x.set_title(f"{phase}: {title}")
            x.legend(fontsize=7)
    fig.suptitle(f"Scaling with the horizon (our host times: {host_cpu})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_trajectory(meta: dict, steps: pd.DataFrame, path: Path) -> None:
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 5.5))
    colors = {1: "tab:blue", 2: "tab:orange", 3: "tab:green"}
    for ph, g in steps.groupby("phase"):
        if ph in PHASES:
            ax.plot(g["truth_y_m"], g["truth_x_m"], ".", ms=3, color=colors[ph], label=PHASES[ph])
    r1 = float(((meta.get("scenario") or {}).get("safety") or {}).get("keepout_radius_m", 200.0))
    th = np.linspace(0, 2 * np.pi, 200)
    ax.plot(r1 * np.cos(th), r1 * np.sin(th), "k:", lw=1, label=f"keep-out r1 = {r1:g} m")
    ax.plot([0], [0], "k+", ms=12)
    ax.set_xlabel("V-bar y [m]")
    ax.set_ylabel("R-bar x [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    ax.set_title(f"{meta.get('scenario_label', meta.get('scenario_name'))}: in-plane trajectory (truth)")
    dv = np.sqrt(steps["dv_x_mps"] ** 2 + steps["dv_y_mps"] ** 2 + steps["dv_z_mps"] ** 2)
    for ph, g in steps.groupby("phase"):
        if ph in PHASES:
            bx.vlines(g["t_s"], 0, dv[g.index], color=colors[ph], lw=1.2, label=PHASES[ph])
    bx.set_xlabel("t [s]")
    bx.set_ylabel("realised |delta-v| per period [m/s]")
    bx.set_title(f"thrust: total {meta.get('dv_total_mps', float('nan')):.2f} m/s, {meta.get('end')}")
    bx.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ---- HTML --------------------------------------------------------------------------------------
def _fmt(v, digits: int = 3) -> str:
    """A readable number: `digits` significant figures, never an exponent, thousands grouped
    (15000 -> "15 000", 0.01234 -> "0.0123", 2 -> "2")."""
    if v is None or isinstance(v, str):
        return "" if v is None else v
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    v = float(v)
    if not math.isfinite(v):
        return ""
    if v == 0:
        return "0"
    if float(v).is_integer() and abs(v) < 1e15:
        return f"{int(v):,}".replace(",", "\u2009")
    exponent = int(math.floor(math.log10(abs(v))))
    if exponent < -4:  # 2.13 x 10^-9, not 0.00000000213 (and never 2.13e-09)
        mantissa = f"{v / 10 ** exponent:.{digits - 1}f}"
        return f"{mantissa} \u00d7 10" + str(exponent).translate(str.maketrans("-0123456789", "\u207b\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079"))
    decimals = max(0, digits - 1 - exponent)
    text = f"{v:,.{decimals}f}"
    short = decimals
    while short > 0 and round(v, short - 1) == v:  # 0.500 -> 0.5 where the value is exactly that
        short -= 1
    if short < decimals:
        text = f"{v:,.{short}f}"
    return text.replace(",", "\u2009")


class Cell:
    """A table cell with its own display text, sort key, hover text, link or CSS class."""

    def __init__(self, text, sort=None, title=None, href=None, cls=None):
        self.text, self.sort, self.title, self.href, self.cls = text, sort, title, href, cls


def _table_html(df: pd.DataFrame, table_id: str | None = None, digits: int = 3, caption: str | None = None) -> str:
    """A sortable table (click a heading): numbers formatted by `_fmt`, the exact value on hover."""
    def cell(v):
        if isinstance(v, Cell):
            attrs = "" if v.sort is None else f" data-v='{html.escape(str(v.sort))}'"
            attrs += "" if v.title is None else f" title='{html.escape(str(v.title))}'"
            attrs += "" if v.cls is None else f" class='{v.cls}'"
            text = html.escape(str(v.text))
            if v.href:
                text = f"<a href='{html.escape(v.href)}'>{text}</a>"
            return f"<td{attrs}>{text}</td>"
        if isinstance(v, (bool, np.bool_)):
            return f"<td>{'yes' if v else 'no'}</td>"
        if isinstance(v, (int, float, np.integer, np.floating)):
            if isinstance(v, (float, np.floating)) and not math.isfinite(v):
                return "<td data-v=''></td>"
            return f"<td data-v='{float(v)!r}' title='{v!r}'>{html.escape(_fmt(v, digits))}</td>"
        if v is None:
            return "<td></td>"
        return f"<td class='t'>{html.escape(str(v))}</td>"
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = "".join("<tr>" + "".join(cell(v) for v in row) + "</tr>" for row in df.itertuples(index=False))
    tid = f" id='{table_id}'" if table_id else ""
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return (f"<div class='scroll'><table class='sortable'{tid}>{cap}<thead><tr>{head}</tr></thead>"
            f"<tbody>{body}</tbody></table></div>")


CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1340px;padding:0 1em;color:#222;line-height:1.4}
h1{font-size:1.6em}h2{margin-top:1.8em;border-bottom:2px solid #ddd}
.scroll{max-width:100%;overflow-x:auto}
table{border-collapse:collapse;font-size:13px;margin:.5em 0}
caption{text-align:left;font-weight:bold;padding:.3em 0}
td,th{border:1px solid #ccc;padding:3px 6px;text-align:right;white-space:nowrap}
th{white-space:normal;vertical-align:bottom;max-width:11em}
td.t{text-align:left}
th{background:#eee;cursor:pointer;user-select:none}th.asc:after{content:" \25B2"}th.desc:after{content:" \25BC"}
tbody tr:hover{background:#f4f8ff}
.pass{color:#080;font-weight:bold}.fail{color:#b00;font-weight:bold}.na{color:#888}
.verdict{font-size:1.1em;padding:.6em 1em;border-left:6px solid #080;background:#f3fbf3}
.verdict.bad{border-color:#b00;background:#fdf3f3}
img{max-width:100%}
nav a{margin-right:1em}
"""

# Sortable tables: a click on a heading sorts by that column (numbers by their exact value), a second
# click reverses. No external script, works offline from file://.
SCRIPT = """
(function(){
  function key(td){var v=td.getAttribute('data-v');if(v!==null&&v!==''&&!isNaN(+v))return +v;return td.textContent.trim().toLowerCase();}
  document.querySelectorAll('table.sortable').forEach(function(table){
    var heads=table.tHead.rows[0].cells;
    Array.prototype.forEach.call(heads,function(th,col){
      th.title='sort by '+th.textContent;
      th.addEventListener('click',function(){
        var asc=!th.classList.contains('asc');
        Array.prototype.forEach.call(heads,function(h){h.classList.remove('asc','desc');});
        th.classList.add(asc?'asc':'desc');
        var body=table.tBodies[0], rows=Array.prototype.slice.call(body.rows);
        rows.sort(function(a,b){var x=key(a.cells[col]),y=key(b.cells[col]);
          if(typeof x!==typeof y){x=String(x);y=String(y);} return (x<y?-1:x>y?1:0)*(asc?1:-1);});
        rows.forEach(function(r){body.appendChild(r);});
      });
    });
  });
  document.body.setAttribute('data-script','ready');
})();
"""


def _pf(ok: bool | None) -> Cell:
    if ok is None:
        return Cell("n/a", cls="na")
    return Cell("PASS" if ok else "FAIL", sort=int(bool(ok)), cls="pass" if ok else "fail")


def _phase_name(p) -> str:
    return PHASES.get(p, str(p)) if not isinstance(p, str) else p


def verdict_table(rows: pd.DataFrame, metas: list[dict], cpu_labels: dict) -> pd.DataFrame:
    """One row per target, phase, horizon and period: the deadline, the worst and p99 estimated target time,
    the margins, the safety violations of that phase in the runs flown with that horizon, the verdict."""
    out = []
    by_dir = {m["dir"]: m for m in metas}
    # Per control period too: scenarios flown at their own periods (the obstacle campaign) have their own deadlines.
    for (target, phase, n, _), g in rows.groupby(["target", "phase_name", "N", "cmd_period_s"], sort=False):
        deadline_us = g["budget_us"].max()
        worst = g.loc[g["target_us_high"].idxmax()]
        p99 = g["target_us_nominal"].quantile(0.99)
        runs = sorted(set(g["run"]))
        violations = 0
        for r in runs:
            for ep in (by_dir[r].get("safety") or {}).get("episodes", []):
                if ep.get("kind", "safety_violation") == "safety_violation" and _phase_name(ep.get("phase")) == phase:
                    violations += 1
        monitored = all((by_dir[r].get("safety") or {}).get("verdict") for r in runs)
        misses = int((g["target_us_high"] > g["budget_us"]).sum())
        fits = bool(worst["target_us_high"] <= deadline_us)
        safe = (violations == 0) if monitored else None
        out.append({
            "target": target, "CPU": cpu_labels.get(target, target), "phase": phase, "N": int(n),
            "Ts [s]": float(g["cmd_period_s"].max()), "deadline [ms]": deadline_us / 1e3, "solves": len(g),
            "worst est. [ms]": Cell(_fmt(worst["target_us_high"] / 1e3), sort=worst["target_us_high"] / 1e3,
                                    title=f"high end of the interval; {worst['run']} step {int(worst['step'])}",
                                    href=f"{worst['run']}/steps.csv"),
            "p99 est. [ms]": p99 / 1e3,
            "margin (worst)": Cell(f"{_fmt(deadline_us / worst['target_us_high'])}\u00d7",
                                   sort=deadline_us / worst["target_us_high"], title="deadline / worst estimated time"),
            "margin (p99)": Cell(f"{_fmt(deadline_us / p99)}\u00d7", sort=deadline_us / p99,
                                 title="deadline / 99th percentile of the nominal estimate"),
            "misses": misses,
            "safety": Cell("not monitored", cls="na", title=f"{len(runs)} runs") if safe is None else
            Cell("safe" if safe else f"{violations} violation(s)", sort=violations, cls="pass" if safe else "fail",
                 title=f"{len(runs)} runs: " + ", ".join(runs)),
            "verdict": _pf(fits and safe is not False),
            "_fits": fits, "_safe": safe, "_margin": deadline_us / worst["target_us_high"],
            "_margin_p99": deadline_us / p99, "_worst_ms": worst["target_us_high"] / 1e3, "_p99_ms": p99 / 1e3,
            "_deadline_ms": deadline_us / 1e3, "_violations": violations, "_max_at": f"{worst['run']} step {int(worst['step'])}",
        })
    order = {"rendezvous": 0, "approach": 1, "docking": 2}
    df = pd.DataFrame(out)
    if df.empty:
        return df
    return df.sort_values(["target", "phase", "N"], key=lambda c: c.map(order) if c.name == "phase" else c,
                          ignore_index=True)


def checks_table(chk: dict) -> pd.DataFrame:
    """The campaign's checks as rows: what was checked, the figure, the limit, pass/fail."""
    rows = []

    def add(target, what, figure, limit, ok):
        rows.append({"target": target, "what was checked": what, "figure": figure, "limit": limit, "result": _pf(ok)})

    for t, c in chk.items():
        for mode, name in (("user", "qemu-user"), ("system", "QEMU system mode")):
            if f"{mode}_runs_reached_cut" in c:
                add(t, f"both {name} runs of the ideal Case 1, cut at {c[f'{mode}_check_timeout_s']:.0f} s simulated, "
                       "docked or reached the cut", "; ".join(c[f"{mode}_runs_ends"]), "both dock or reach the cut",
                    c[f"{mode}_runs_reached_cut"])
            if f"{mode}_runs_docked" in c:
                add(t, f"both {name} runs of the ideal Case 1 docked", "docked" if c[f"{mode}_runs_docked"] else "not docked",
                    "both dock", c[f"{mode}_runs_docked"])
        for key, what in (("user_instructions", "instructions per solve, two qemu-user runs (plugin)"),
                          ("user_cyc_cycles_nominal", "cycle-model cycles per solve, two qemu-user runs"),
                          ("system_solve_time_us", "in-guest solve times, two QEMU system-mode runs (-icount)"),
                          ("system_instructions", "guest PMU instructions per solve, two system-mode runs")):
            if c.get(key) == "not measured":
                add(t, what, "not measured (no counter in this CPU model)", "identical", None)
            elif f"{key}_identical" in c:
                n = c.get(f"{key}_compared", 0)
                same = c.get(f"{key}_steps_identical")
                fig = (f"{same} of {n} steps identical" if same is not None else f"{n} steps compared, lengths differ")
                if c.get(f"{key}_max_difference"):
                    fig += f", largest difference {_fmt(c[f'{key}_max_difference'])}"
                add(t, what, fig, "every step identical", c[f"{key}_identical"])
        for mode in ("user", "system"):
            d = c.get(f"{mode}_dv_minus_native_mps")
            if d:
                worst = max((abs(x) for x in d if x is not None), default=math.nan)
                ok = all(x is not None for x in d) and worst <= 1e-6
                add(t, f"total delta-v under {'qemu-user' if mode == 'user' else 'system mode'} minus the native build's",
                    f"{_fmt(worst * 1e3)} mm/s (largest of {len(d)} runs)", "at most 0.001 mm/s", ok)
        if "block_counts_equal_instruction_counts" in c:
            add(t, "block profiler total = instruction counter, every priced solve",
                f"{c.get('block_counts_compared', 0)} solves compared", "equal in every solve",
                c["block_counts_equal_instruction_counts"])
    return pd.DataFrame(rows)


def _git(*args) -> str | None:
    try:
        r = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), *args], capture_output=True,
                           text=True, timeout=5)
        return r.stdout.strip() if r.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def host_cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance(metas: list[dict]) -> dict:
    """Where the figures come from: the commits and dates of the runs and of this report, the flight
    executables' hashes, the QEMU, compiler and LLVM versions, the host."""
    import datetime as _dt

    commits = sorted({(m.get("versions") or {}).get("git_commit") for m in metas} - {None})
    dirty = any((m.get("versions") or {}).get("git_dirty") for m in metas)
    created = sorted(m.get("created_utc") for m in metas if m.get("created_utc"))
    exes, compilers = {}, {}
    for m in metas:
        if m.get("exe_sha") and m.get("target"):
            exes[m["target"]] = {"sha256_prefix": m["exe_sha"], "size_bytes": m.get("exe_size_bytes"),
                                 "arch": m.get("arch"), "cpu": m.get("cpu")}
        hello = m.get("flight_hello") or {}
        if hello.get("compiler") and m.get("target"):
            compilers[m["target"]] = hello["compiler"]
    qemu = {}
    for arch in sorted({m.get("arch") for m in metas if m.get("arch")}):
        tool = {"armhf": "qemu-arm", "aarch64": "qemu-aarch64"}.get(arch, f"qemu-{arch}")
        qemu[tool] = _tool_version([tool, "--version"])
    try:
        from rvd_pil.qemu import cycles
        llvm = cycles.llvm_version()
    except Exception:  # the report still renders without the cycle model's tools
        llvm = "unknown"
    return {"run_commits": commits, "run_tree_dirty": dirty,
            "runs_from_utc": created[0] if created else None, "runs_to_utc": created[-1] if created else None,
            "report_commit": _git("rev-parse", "HEAD"), "report_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
            "executables": exes, "flight_compilers": compilers, "qemu": qemu, "llvm": llvm,
            "host": platform.platform(), "host_cpu": host_cpu(), "python": sys.version.split()[0]}


def _tool_version(cmd: list[str]) -> str:
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=10).stdout.splitlines()[0]
    except Exception:
        return "unknown"


MODEL_IGNORES = ("dependencies between translation blocks (each block is priced on its own: steady state as if it "
                 "repeated back to back, cold as if the pipeline were empty before it)", "branch prediction and "
                 "mispredictions", "hardware prefetch", "TLB misses and page walks", "the kernel (system calls, "
                 "interrupts, page faults)", "bus and DRAM contention, other cores", "memory-level parallelism beyond "
                 "the memory term's range", "physical indexing and the real replacement policies of the caches "
                 "(the cache model is virtually indexed, LRU)")


def _timing_model_html(out: Path, targets_meta: dict, rows: pd.DataFrame) -> str:
    """What the target times are, where their parts come from, what the model ignores and what a
    board calibration would change."""
    from rvd_pil.qemu import cycles

    parts = ["<p>QEMU is not cycle-accurate: host wall time under emulation is not target time. The flight software "
             "therefore takes its deadlines (and reports its solve and step times) on target time: instructions read "
             "from the counter &times; the CPI of the control delay / f<sub>clk</sub> (<code>--target-clock</code>). "
             "Two plugins run "
             "in every user-mode run, between markers the flight software places around every solver call of a "
             "guidance step: the instruction counter (exact, written back into the guest's telemetry) and the "
             "block profiler (executions of every translation block, plus a cache model with the CPU's L1D/L1I/L2 "
             "geometry). The cycle model (<code>rvd_pil/qemu/cycles.py</code>) prices each block once per executable: "
             "Debian's <code>llvm-mca</code> (LLVM " + html.escape(cycles.llvm_version()) + ") with the CPU's "
             "scheduling model, moved by a correction table where LLVM disagrees with published timings "
             "(<code>rvd_pil/qemu/cycle_models.toml</code>, each figure with its source), or the stated Cortex-A8 model. "
             "Cycles of a solve = &Sigma; executions &times; block cost + cache misses &times; penalty.</p>",
             "<p><b>Estimated, not measured</b>: every target time and cycle figure below. <b>Intervals</b>: "
             "<i>low</i> = steady-state pipeline + memory term low (load misses at the low penalties); "
             "<i>high</i> = cold pipeline + memory term high (every miss, loads, stores and instruction fetch, at "
             "the high penalties); <i>nominal</i> = steady state + the memory term's midpoint. Exact and "
             "deterministic: instruction counts, block counts and cache-model miss counts (same executable, same "
             "inputs). The memory penalties are engineering ranges, not published figures. The cache model (a "
             "callback per memory access) runs in the ideal Case 1; the timing runs take its per-block miss rates "
             "(misses per execution of each block; blocks it did not run get its misses per instruction). At larger "
             "horizons than the ideal run's (30/15/12) this underestimates the memory term (measured at 45/30/30: "
             "13-16 % low in total, nominal cycles 3-6 % low; rvd_pil/qemu/README.md).</p>",
             "<p><b>The model ignores</b>: " + "; ".join(html.escape(x) for x in MODEL_IGNORES) + ".</p>"]
    model_rows = []
    for t, m in targets_meta.items():
        cpu = m.get("cpu")
        try:
            entry = cycles.models()[cpu]
        except KeyError:
            continue
        g = rows[rows["target"] == t] if not rows.empty else rows
        cal = cycles.calibrations().get(cpu)
        mem = entry["memory"]
        model_rows.append({
            "target": t, "cpu": cpu, "clock MHz": int(round(m["clock_hz"] / 1e6)),
            "pipeline model": f"llvm-mca -mcpu={entry['mca_cpu']}" if entry.get("engine") != "a8" else "own (Cortex-A8 TRM)",
            "corrections": len(entry.get("correction", [])),
            "L1D / L1I / L2": " / ".join(f"{g_[0] // 1024}K {g_[1]}-way {g_[2]}B" for g_ in
                                          (entry["cache"]["l1d"], entry["cache"]["l1i"], entry["cache"]["l2"])),
            "L2 hit cycles": f"{mem['l2_hit_cycles'][0]}-{mem['l2_hit_cycles'][1]}",
            "DRAM ns": f"{mem['dram_ns'][0]}-{mem['dram_ns'][1]}",
            "CPI (model, solves)": (g["cyc_cycles_nominal"].sum() / g["instructions"].sum()) if len(g) else math.nan,
            "CPI guess [low-high]": f"{m['cpi']['nominal']} [{m['cpi']['low']}-{m['cpi']['high']}]",
            "calibrated": f"yes: factor {cal['factor']:.3f} ({html.escape(str(cal.get('board', '')))})" if cal else "no",
        })
    if model_rows:
        parts.append(_table_html(pd.DataFrame(model_rows)))
    corr = []
    for t, m in targets_meta.items():
        entry = cycles.models().get(m.get("cpu"), {})
        for c in entry.get("correction", []):
            corr.append({"cpu": m.get("cpu"), "instructions": c["mnemonic"], "operand": c.get("operand", ""),
                         "LLVM": "/".join(str(c[k]) for k in ("llvm_latency", "llvm_accumulate_latency", "llvm_occupancy") if k in c),
                         "published": "/".join(str(c[k]) for k in ("latency", "accumulate_latency", "occupancy") if k in c),
                         "what": "/".join(k for k in ("latency", "accumulate_latency", "occupancy") if k in c),
                         "read as": c.get("how", ""), "source": " ".join(c["source"].split())})
        if entry.get("engine") == "a8":
            corr.append({"cpu": m.get("cpu"), "instructions": "VFP data processing", "operand": "", "LLVM": "no model",
                         "published": "Table 16.25 cycles", "what": "occupancy", "read as": entry["vfp"]["how"],
                         "source": entry["vfp"]["source"]})
    if corr:
        parts.append("<h3>Correction table (LLVM vs published)</h3>" + _table_html(pd.DataFrame(corr)))
    micro = []
    for f in sorted(out.glob("microbench-*.json")):
        for r in json.loads(f.read_text()):
            if "error" in r:
                micro.append({"cpu": r["cpu"], "kernel": "-", "model steady": math.nan, "model cold": math.nan,
                              "published": "-", "within 10 %": "not run", "read as": "", "source": r["error"]})
                continue
            pub = r.get("published")
            micro.append({"cpu": r["cpu"], "kernel": r["kernel"], "model steady": r["steady_per_iteration"],
                          "model cold": r["cold_per_iteration"],
                          "published": "-" if not pub else (f"{pub[0]:g}" if pub[0] == pub[1] else f"{pub[0]:g}-{pub[1]:g}"),
                          "within 10 %": {True: "yes", False: "NO", None: "no published figure"}[r.get("within")],
                          "read as": r.get("how", ""), "source": r.get("source", "")})
    if micro:
        parts.append("<h3>Microbenchmarks with known answers (cycles per loop iteration)</h3>"
                     "<p><code>rvd_pil/bench/microbench/</code>: hand-written loops (a dependent FP64 multiply-add chain, 8 "
                     "independent ones, a pointer-chasing load chain, a divide chain, a call loop) cross-built for "
                     "the CPU, counted by the same plugins, priced by the same model. Where no published figure "
                     "could be used the row says so.</p>" + _table_html(pd.DataFrame(micro)))
    anchor = out / "osqp-anchor.json"
    if anchor.exists():
        a = json.loads(anchor.read_text())
        parts.append("<h3>External anchor: OSQP generated code on a Raspberry Pi 3B</h3><p>" + html.escape(a["summary"]) + "</p>"
                     + _table_html(pd.DataFrame(a["rows"])))
    parts.append("<h3>What a board calibration would change</h3><p>Run the same static executable on the board "
                 "with the recorded inputs of the ideal Case 1 (<code>python -m rvd_pil.bench.calibrate</code> prints the "
                 "commands) under <code>perf stat -e cycles:u,instructions:u,L1-dcache-load-misses:u</code>. The "
                 "measured cycles over the model's nominal cycles for the same run become the CPU's factor in "
                 "<code>rvd_pil/qemu/calibration.toml</code>; every nominal figure is then scaled by it and marked "
                 "<i>calibrated</i>. The measured instructions check that the board ran what QEMU counted; the "
                 "measured L1D misses check the cache model. A calibration replaces the engineering memory ranges and "
                 "the pipeline model's systematic error by one measured ratio; it does not remove the per-solve "
                 "spread the interval shows.</p>")
    return "\n".join(parts)


PHASE_ORDER = ("rendezvous", "approach", "docking")


def _cpu_labels(metas: list[dict]) -> dict:
    """'Cortex-A53 at 1.2 GHz' per target (build name), from the run records."""
    out = {}
    for m in metas:
        t = m.get("target")
        if t and m.get("cpu") and m.get("clock_hz") and t not in out:
            cpu = str(m["cpu"]).replace("cortex-", "Cortex-").replace("Cortex-a", "Cortex-A")
            out[t] = f"{cpu} at {_fmt(m['clock_hz'] / 1e9)} GHz"
    return out


def _img(out: Path, name: str, alt: str) -> str:
    """The figure inside the page (a data: URI), so that report.html alone shows everything; the PNG
    file stays beside it, and a click opens it."""
    import base64

    data = base64.b64encode((out / name).read_bytes()).decode()
    return (f"<a href='{html.escape(name)}'><img src='data:image/png;base64,{data}' alt='{html.escape(alt)}' "
            f"title='{html.escape(alt)} ({html.escape(name)})'></a>")


def write(out: Path) -> Path:
    out = Path(out)
    metas, df = load_campaign(out)
    if df.empty:
        raise SystemExit(f"no run records under {out / 'runs'}")
    rows = solves(metas, df)
    table = stats_table(rows) if not rows.empty else pd.DataFrame()
    chk = checks(metas, df)
    table.to_csv(out / "stats.csv", index=False)
    run_cols = ["dir", "target", "cpu", "mode", "kind", "scenario_label", "end", "steps", "t_end_s",
                "dv_total_mps", "nav_resends", "rejected_messages", "exe_size_bytes"]

    def horizons(m):  # numbers, one column per phase (not the string "[30, 15, 12]")
        h = list(m.get("horizons") or [None] * 3)
        return {f"N_{ph}": (int(h[i]) if h[i] is not None else None) for i, ph in enumerate(PHASE_ORDER)}
    runs = pd.DataFrame([{**{c: m.get(c) for c in run_cols[:6]}, **horizons(m), **{c: m.get(c) for c in run_cols[6:]}}
                         for m in metas])
    for c in ("N_rendezvous", "N_approach", "N_docking"):
        runs[c] = runs[c].astype("Int64")
    for m, (i, r) in zip(metas, runs.iterrows()):
        tel = m.get("flight_telemetry") or {}
        runs.loc[i, "peak_heap_kib"] = tel.get("peak_heap_bytes", math.nan) / 1024 if tel else math.nan
        runs.loc[i, "qemu_max_rss_mib"] = tel.get("max_rss_kb", math.nan) / 1024 if tel else math.nan
        runs.loc[i, "safety"] = (m.get("safety") or {}).get("verdict")
    runs.to_csv(out / "runs.csv", index=False)

    prov = provenance(metas)
    cpu_labels = _cpu_labels(metas)
    targets = [t for t in dict.fromkeys(rows["target"])] if not rows.empty else []
    images = []
    for t in targets:
        p = out / f"hist_{t}.png"
        plot_histograms(rows, t, p, cpu_labels.get(t, t))
        images.append((t, p.name))
    if not table.empty:
        plot_scaling(table, out / "scaling.png", cpu_labels, prov["host_cpu"])
    traj = []
    seen = set()
    # One trajectory per scenario: its run at the default horizons, else its first timing run (a campaign
    # that flies each scenario at its own horizons).
    timing = [m for m in metas if m.get("kind") == "timing"]
    for m in sorted(timing, key=lambda m: tuple(m.get("horizons", ())) != (30, 15, 12)):
        label = m.get("scenario_label")
        if label not in seen:
            seen.add(label)
            _, steps = load_run(out / m["dir"])
            name = Path(label).stem if str(label).endswith(".toml") else str(label).replace(":", "")
            p = out / f"trajectory_{name}.png"
            plot_trajectory(m, steps, p)
            traj.append((label, m["dir"], p.name))

    targets_meta = {}
    for m in metas:
        if m.get("target") and m.get("cpi") and m["target"] not in targets_meta:
            targets_meta[m["target"]] = m
    memory = runs[runs["kind"] == "timing"].groupby("target").agg(
        exe_size_kib=("exe_size_bytes", lambda s: s.max() / 1024), peak_heap_kib=("peak_heap_kib", "max"),
        qemu_max_rss_mib=("qemu_max_rss_mib", "max")).reset_index() if not runs.empty else pd.DataFrame()

    scaling = {}
    for (target, phase), g in table.groupby(["target", "phase"]) if not table.empty else []:
        g = g.sort_values("N")
        scaling[f"{target} {phase}"] = {"N": g["N"].tolist(), "mean_ms": g["target_ms_mean"].tolist(),
                                       "ratio_last_first": float(g["target_ms_mean"].iloc[-1] / g["target_ms_mean"].iloc[0])}
    per_run_safety, safety_violations = safety_tables(metas)
    verdict = verdict_table(rows, metas, cpu_labels) if not rows.empty else pd.DataFrame()
    check_rows = checks_table(chk)
    verdict_json = [] if verdict.empty else [
        {"target": r["target"], "cpu": r["CPU"], "phase": r["phase"], "N": r["N"], "period_s": r["Ts [s]"],
         "deadline_ms": r["_deadline_ms"], "solves": r["solves"], "worst_target_ms": r["_worst_ms"],
         "p99_target_ms": r["_p99_ms"], "margin_worst": r["_margin"], "margin_p99": r["_margin_p99"],
         "misses": r["misses"], "worst_at": r["_max_at"], "safety_violations": r["_violations"],
         "safety_monitored": r["_safe"] is not None, "fits": r["_fits"],
         "pass": bool(r["_fits"] and r["_safe"] is not False)} for _, r in verdict.iterrows()]
    report = {"verdict": verdict_json, "stats": table.to_dict(orient="records"), "checks": chk,
              "check_table": [{**{k: v for k, v in r.items() if k != "result"}, "result": r["result"].text}
                              for r in check_rows.to_dict(orient="records")],
              "scaling": scaling,
              "safety": {"runs": per_run_safety.to_dict(orient="records"),
                         "violations": safety_violations.to_dict(orient="records")},
              "runs": runs.to_dict(orient="records"), "provenance": prov,
              "environment": {"host": prov["host"], "python": prov["python"],
                              "qemu": _tool_version(["qemu-arm", "--version"])}}
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str))

    # ---- HTML: the verdict first, then the evidence ------------------------------------------
    e = html.escape
    periods = ""
    deadline_fraction = 0.5
    if not verdict.empty:
        per_phase = verdict.groupby("phase", sort=False)["Ts [s]"].max()
        periods = ", ".join(f"{ph} {_fmt(per_phase[ph])} s" for ph in PHASE_ORDER if ph in per_phase)
        fr = {(m.get("flight_hello") or {}).get("deadline_fraction") for m in metas if m.get("kind") == "timing"} - {None}
        deadline_fraction = fr.pop() if len(fr) == 1 else deadline_fraction
    parts = ["<!doctype html><html lang='en'><head><meta charset='utf-8'>"
             "<meta name='viewport' content='width=device-width'><title>rvd-pil PIL report</title>"
             f"<style>{CSS}</style></head><body>",
             "<h1>Processor-in-the-loop report: does the guidance fit the flight computer, with what margin, "
             "and is it safe?</h1>",
             "<nav><a href='#verdict-section'>Verdict</a><a href='#safety'>Safety</a><a href='#checks'>Checks</a>"
             "<a href='#distributions'>Solve-time distributions</a><a href='#dissertation'>Beside the dissertation</a>"
             "<a href='#details'>Details</a><a href='#timing-model'>Timing model</a><a href='#runs'>Runs</a>"
             "<a href='#provenance'>Provenance</a></nav>"]
    parts.append("<h2 id='verdict-section'>Verdict per target, phase and horizon</h2>")
    if verdict.empty:
        parts.append("<p class='verdict bad'>No timed guidance solve in these runs: no verdict.</p>")
    else:
        for t, g in verdict.groupby("target", sort=False):
            ok = bool(g["verdict"].map(lambda c: c.text == "PASS").all())
            low = g.loc[g["_margin"].idxmin()]
            safety_t = per_run_safety[per_run_safety["target"] == t] if not per_run_safety.empty else per_run_safety
            n_safe = int((safety_t["verdict"] != "unsafe").sum()) if len(safety_t) else 0
            parts.append(
                f"<p class='verdict{'' if ok else ' bad'}'><b>{e(t)} ({e(cpu_labels.get(t, t))}): "
                f"{'fits and is safe' if ok else 'does NOT pass'}</b> in {int((g['verdict'].map(lambda c: c.text) == 'PASS').sum())} "
                f"of {len(g)} phase/horizon cases. Smallest margin {_fmt(low['_margin'])}\u00d7 the worst estimated "
                f"solve ({e(low['phase'])}, N = {low['N']}: {_fmt(low['_worst_ms'])} ms against a "
                f"{_fmt(low['_deadline_ms'])} ms deadline); {n_safe} of {len(safety_t)} runs without a safety "
                "violation (judged on the truth).</p>")
        parts.append(
            f"<p><b>Deadline rule</b>: a solve must finish within {_fmt(deadline_fraction)} &times; T<sub>s</sub>, the "
            f"control period of its phase ({e(periods)}). <b>Worst est.</b>: the largest estimated target time of "
            "any solve, at the high end of the cycle model's interval (cold pipeline, every cache miss at the high "
            "penalty); <b>p99 est.</b>: the 99th percentile of the nominal estimate. <b>Margin</b> = deadline "
            "&divide; time. <b>Misses</b>: solves whose high end exceeds the deadline. <b>Safety</b>: violations of "
            "this phase's limits in the runs flown with this horizon. <b>PASS</b> = worst estimate within the "
            "deadline and no safety violation. Estimated, not measured on hardware (see the timing model). "
            "Click a heading to sort; hover for exact values; the worst time links to its run's steps.</p>")
        show = verdict[[c for c in verdict.columns if not c.startswith("_") and c != "target"]].copy()
        show.insert(0, "target", [Cell(t, href=f"#hist-{t}") for t in verdict["target"]])
        parts.append(_table_html(show, table_id="verdict"))

    parts.append("<h2 id='safety'>Safety verdicts (judged on the truth)</h2><p>The host's safety monitor "
                 "(<code>rvd_pil/host_sim/safety.py</code>) checks every limit the guidance is meant to hold on the true "
                 "path, at most 1 s apart and at every burn start and end: keep-out sphere outside the approach "
                 "corridor, approach corridor, overshoot plane, docking cone, |v|<sub>&infin;</sub> in docking, "
                 "collision, commanded and realised &Delta;v, contact conditions. <i>started unsafe</i>: a random "
                 "start already inside a limit (the scenario's, not the guidance's). Limits, sources and tolerances "
                 "are in each run's <code>meta.json</code>.</p>")
    if per_run_safety.empty:
        parts.append("<p class='na'>No run carries a safety summary.</p>")
    else:
        tally = []
        for (t, kind), g in per_run_safety.groupby(["target", "kind"], sort=False):
            v = g["verdict"].value_counts()
            tally.append({"target": t, "runs": kind, "count": len(g), "safe": int(v.get("safe", 0)),
                          "started unsafe": int(v.get("started_unsafe", 0)), "unsafe": int(v.get("unsafe", 0)),
                          "violations": int(g["violations"].fillna(0).sum()),
                          "excursions within tolerance": int(g["excursions"].fillna(0).sum()),
                          "verdict": _pf(int(v.get("unsafe", 0)) == 0)})
        parts.append(_table_html(pd.DataFrame(tally), table_id="safety-table"))
        if safety_violations.empty:
            parts.append("<p class='pass'>No violation in any run.</p>")
        else:
            sv = safety_violations.copy()
            sv["run"] = [Cell(r, href=f"{r}/events.csv") for r in sv["run"]]
            parts.append("<p class='fail'>Violations per target, phase, scenario and limit, with the worst one:</p>"
                         + _table_html(sv))
        pr = per_run_safety.rename(columns={"dock_cone_margin_cm": "docking-cone margin [cm]",
                                            "closest_axial_approach_m": "closest axial distance in approach [m]",
                                            "max_speed_docking_mm_s": "max |v|inf in docking [mm/s]"})
        pr["run"] = [Cell(r, href=f"{r}/meta.json") for r in pr["run"]]
        parts.append("<details><summary>per run</summary>" + _table_html(pr) + "</details>")

    parts.append("<h2 id='checks'>Checks</h2><p>Case 1 in the ideal setting (CW truth, no noise, impulsive burns, "
                 "no control delay), natively and twice under QEMU: user mode with the counting plugins, and "
                 "system mode with <code>-icount</code> (the guest's own clock, 2<sup>shift</sup> ns per "
                 "instruction, its kernel's interrupt work included; the link goes through semihosting so that the "
                 "guest clock stands still while the host computes, <code>rvd_pil/qemu/semihosting_link.py</code>). "
                 "Delta-v differences against the native build come from floating point differing between "
                 "instruction sets and libm.</p>")
    parts.append(_table_html(check_rows, table_id="checks-table") if not check_rows.empty
                 else "<p class='na'>No check runs in this campaign.</p>")

    round_trip = bool(len(rows)) and bool(rows["flight_clock_target"].any())
    host_what = ("the host's round trip of the same steps (nav out to cmd in, host time under qemu-user with the "
                 "counting plugins attached, which slow emulation: the solve plus the filter, the allocation and the "
                 "link; the flight's own clock was on target time)" if round_trip else
                 "the emulated wall time of the same solves (host time under qemu-user with the counting plugins "
                 "attached, which slow emulation)")
    parts.append("<h2 id='distributions'>Solve-time distributions</h2><p>Top row: our estimated target time; bottom "
                 f"row: {host_what}, with the dissertation's mean CVXGEN QEMU wall time "
                 "per horizon marked (dashed, in the colour of that horizon's curve). The red line is the "
                 "deadline. Log time axis; one curve per horizon N with its number of solves.</p>")
    for t, img in images:
        parts.append(f"<h3 id='hist-{e(t)}'>{e(t)}: {e(cpu_labels.get(t, t))}</h3>"
                     + _img(out, img, f"solve-time histograms for {t}"))

    parts.append("<h2 id='dissertation'>Beside the dissertation</h2>")
    if not table.empty:
        ours = ("our mean round trips of the same steps under qemu-user on this host "
                f"({e(prov['host_cpu'])}): host time too, emulator-dependent, but of the whole step and its link, "
                "an upper bound of the solve's (the flight's own clock was on target time)" if round_trip else
                f"our mean wall times under qemu-user on this host ({e(prov['host_cpu'])}), the same kind of figure "
                "(host time, emulator-dependent)")
        parts.append("<p>Host time beside host time only. The dissertation (A. Fear, <i>Application of Model Predictive "
                     "Control for the Autonomous Rendezvous and Docking of Small Satellites</i>, PhD dissertation, Georgia "
                     "Institute of Technology, 2023, ch. 6) reports the mean wall time of CVXGEN solves under QEMU "
                     f"full-system ARM emulation on its host; beside it stand {ours}. "
                     "Our estimated target times are a different quantity and stand in their own column and "
                     "plot row.</p>")
        cmp_rows = []
        wall_name = "round trip" if round_trip else "wall"
        for _, r in table.iterrows():
            ref = r["dissertation_cvxgen_ms"]
            cmp_rows.append({"target": r["target"], "CPU (emulated)": cpu_labels.get(r["target"], r["target"]),
                             "phase": r["phase"], "N": int(r["N"]),
                             "dissertation QEMU wall, mean [ms]": ref,
                             f"ours QEMU {wall_name}, mean [ms]": r["wall_ms_mean"],
                             "ratio (dissertation / ours)": ref / r["wall_ms_mean"] if math.isfinite(ref) else math.nan,
                             f"ours QEMU {wall_name}, max [ms]": r["wall_ms_max"],
                             "ours estimated target, mean [ms]": r["target_ms_mean"]})
        parts.append(_table_html(pd.DataFrame(cmp_rows), table_id="dissertation-table"))
        parts.append(_img(out, "scaling.png", "solve time against the horizon"))
        parts.append("<ul>" + "".join(f"<li>{e(k)}: estimated t(N = {v['N'][-1]}) / t(N = {v['N'][0]}) = "
                                      f"{_fmt(v['ratio_last_first'])}</li>" for k, v in scaling.items()) + "</ul>")

    parts.append("<h2 id='details'>Details per phase and horizon</h2>")
    if not table.empty:
        est = pd.DataFrame({
            "target": table["target"], "phase": table["phase"], "N": table["N"], "solves": table["solves"],
            "mean [ms]": [Cell(f"{_fmt(m)} [{_fmt(lo)}\u2013{_fmt(hi)}]", sort=m) for m, lo, hi in
                          zip(table["target_ms_mean"], table["target_ms_mean_low"], table["target_ms_mean_high"])],
            "p50 [ms]": table["target_ms_p50"], "p99 [ms]": table["target_ms_p99"],
            "max [ms]": [Cell(f"{_fmt(m)} [{_fmt(lo)}\u2013{_fmt(hi)}]", sort=m, title=at, href=at.split(" step")[0] + "/steps.csv")
                         for m, lo, hi, at in zip(table["target_ms_max"], table["target_ms_max_low"],
                                                  table["target_ms_max_high"], table["max_at"])],
            "max / p50": table["max_over_p50"],
            "max / p50 within a run (worst run)": [Cell(_fmt(v), sort=v, title=at) for v, at in
                                                   zip(table["run_max_over_p50"], table["run_max_over_p50_at"])],
            "CPI (model)": table["cpi_model_mean"], "L1D misses per 1000 instr.": table["l1d_mpki"],
            "CPI-guess mean [ms]": table["target_ms_cpi_mean"], "CPU load mean [%]": table["cpu_load_mean_pct"],
            "CPU load max [%]": table["cpu_load_max_pct"], "calibrated": table["calibrated"]})
        parts.append("<p>Estimated target times from the cycle model: <i>mean</i> and <i>max</i> are the nominal "
                     "estimate (steady-state pipeline plus the midpoint of the memory term), in brackets the "
                     "interval (steady-state pipeline plus the memory term's low end, to cold pipeline plus its "
                     "high end). <i>CPI guess</i>: the old instructions &times; CPI / f<sub>clk</sub> figure, "
                     "beside it. CPU load: nominal estimate over the control period. <i>max / p50</i>: the "
                     "largest solve over the median of all the campaign's solves of that phase and horizon; "
                     "<i>within a run</i>: the same ratio in each run alone, its worst run on hover. A harder "
                     "scenario (a turning target, more active constraints) raises the first only; a solve "
                     "that costs more than its neighbours in the same flight raises both.</p>"
                     + _table_html(est, table_id="estimates-table", caption="Estimated target time"))
        counts = pd.DataFrame({
            "target": table["target"], "phase": table["phase"], "N": table["N"],
            "instructions mean": table["insns_mean"].round(), "instructions max": table["insns_max"],
            "cycles mean": table["cycles_mean"].round(),
            "cycles max [low\u2013high]": [Cell(f"{_fmt(m)} [{_fmt(lo)}\u2013{_fmt(hi)}]", sort=m) for m, lo, hi in
                                           zip(table["cycles_max"], table["cycles_max_low"], table["cycles_max_high"])],
            "iterations mean": table["iterations_mean"], "iterations max": table["iterations_max"],
            f"QEMU {wall_name} mean [ms]": table["wall_ms_mean"], f"QEMU {wall_name} p99 [ms]": table["wall_ms_p99"],
            f"QEMU {wall_name} max [ms]": table["wall_ms_max"],
            "flight clock mean [ms]": table["flight_clock_ms_mean"], "flight clock max [ms]": table["flight_clock_ms_max"],
            "overruns on the flight clock": table["overruns_flight_clock"]})
        flight_clock_text = (
            "QEMU round trip: the host's time from nav out to cmd in (host time). Flight clock: the solve times "
            "the flight software reports, on target time (instructions &times; the control delay's CPI / "
            "f<sub>clk</sub>); its overruns count solves over the deadline on that clock, as the target would "
            "have seen them (with that CPI), whatever this host's speed." if round_trip else
            "QEMU wall and flight clock: the flight software's own clock under qemu-user (host time); its "
            "overruns count solves over the deadline on that clock, a statement about this host, not the target.")
        parts.append(f"<p>Instructions: counted by the plugin (exact). {flight_clock_text}</p>"
                     + _table_html(counts, table_id="counts-table",
                                   caption="Instructions, cycles, iterations, emulated host time, flight clock"))

    parts.append("<h2 id='timing-model'>Timing model</h2>" + _timing_model_html(out, targets_meta, rows))
    parts.append("<h2>Memory and size</h2>")
    if not memory.empty:
        mem = memory.rename(columns={"exe_size_kib": "executable [KiB]", "peak_heap_kib": "peak heap [KiB]",
                                     "qemu_max_rss_mib": "QEMU max RSS [MiB]"})
        parts.append(_table_html(mem))
        parts.append("<p>Peak heap: malloc statistics of the flight software; QEMU max RSS: the QEMU process "
                     "(guest plus emulator), an upper bound.</p>")
    parts.append("<h2>Trajectories</h2>")
    for label, d, img in traj:
        parts.append(f"<h3>{e(label)} (<a href='{e(d)}/meta.json'>run record</a>)</h3>"
                     + _img(out, img, f"trajectory of {label}"))
    parts.append("<h2 id='runs'>Runs</h2><p>Each run's record: <code>meta.json</code> (settings, versions, "
                 "summary, safety), <code>steps.csv</code> (one line per control step), <code>events.csv</code>, "
                 "<code>flight_sw.log</code>.</p>")
    rshow = runs.rename(columns={"dir": "run", "scenario_label": "scenario", "t_end_s": "t end [s]",
                                 "dv_total_mps": "delta-v [m/s]", "exe_size_bytes": "executable [bytes]",
                                 "peak_heap_kib": "peak heap [KiB]", "qemu_max_rss_mib": "QEMU RSS [MiB]"})
    rshow["run"] = [Cell(d, href=f"{d}/meta.json") for d in runs["dir"]]
    rshow.insert(1, "steps.csv", [Cell("steps", href=f"{d}/steps.csv") for d in runs["dir"]])
    parts.append(_table_html(rshow, table_id="runs-table"))
    events = []
    for m in metas:
        ev = load_events(out / m["dir"])
        for _, ev_row in ev[ev["kind"].isin(["fault", "flight_software_lost", "collision", "timeout", "rejected_message"])].iterrows():
            events.append({"run": Cell(m["dir"], href=f"{m['dir']}/events.csv"), "t [s]": ev_row["t_s"],
                           "kind": ev_row["kind"], "detail": ev_row["detail"]})
    if events:
        parts.append("<h2>Faults and end events</h2>" + _table_html(pd.DataFrame(events)))

    prow = [("report written", prov["report_utc"]), ("report commit", prov["report_commit"] or "not a git checkout"),
            ("runs recorded", f"{prov['runs_from_utc']} to {prov['runs_to_utc']}"),
            ("runs' source commit(s)", ", ".join(prov["run_commits"]) + (" (uncommitted changes)" if prov["run_tree_dirty"] else "")),
            *[(f"flight executable {t}", f"SHA-256 {x['sha256_prefix']}\u2026, {_fmt(x['size_bytes'])} bytes, "
               f"{x['arch']} {x['cpu']}") for t, x in prov["executables"].items()],
            *[(f"flight compiler {t}", c) for t, c in prov["flight_compilers"].items()],
            *[(k, v) for k, v in prov["qemu"].items()], ("LLVM (llvm-mca)", prov["llvm"]),
            ("host", f"{prov['host_cpu']}; {prov['host']}; Python {prov['python']}"),
            ("runs, timed solves", f"{len(metas)} runs, {len(rows)} timed guidance solves")]
    parts.append("<h2 id='provenance'>Provenance</h2>" + _table_html(pd.DataFrame(prow, columns=["what", "value"]),
                                                                   table_id="provenance-table"))
    parts.append(f"<script>{SCRIPT}</script></body></html>")
    index = out / "report.html"
    index.write_text("\n".join(parts))
    return index


if __name__ == "__main__":
    print(write(Path(sys.argv[1] if len(sys.argv) > 1 else "reports/pil")))
