"""The PIL report: solve-time statistics and histograms per target, phase and horizon, from the run
records of a campaign directory (bench/campaign.py).

    python -m bench.report reports/pil        rebuild report.html, *.png, stats.csv, runs.csv, report.json

Timing sources, never mixed up:
  - emulated wall time: the flight software's own clock under qemu-user (host time, noisy);
  - instructions: counted by our TCG plugin around every solver call of a guidance step (deterministic);
  - cycles: the cycle model (qemu/cycles.py): per-block execution counts inside the same markers x
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

from host_sim.record import load_events, load_run  # noqa: E402

PHASES = {1: "rendezvous", 2: "approach", 3: "docking"}
# Dissertation ch. 6 (CVXGEN, QEMU ARM, mean emulated solve time, ms) per phase and horizon.
DISSERTATION_MS = {"rendezvous": {15: 119.18, 30: 270.40, 45: 863.91},
                   "approach": {5: 53.40, 15: 181.55, 30: 394.89},
                   "docking": {5: 9.1, 12: 30.1, 30: 98.8}}


def load_campaign(out: Path) -> tuple[list[dict], pd.DataFrame]:
    """All run records under out/runs: (list of meta dicts with 'dir', one DataFrame of every step)."""
    metas, frames = [], []
    for meta_path in sorted((out / "runs").rglob("meta.json")):
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
    rows["cpu_load"] = rows["target_us_nominal"] / (rows["cmd_period_s"] * 1e6)
    return rows


def stats_table(rows: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (target, phase, n), g in rows.groupby(["target", "phase_name", "N"], sort=False):
        worst = g.loc[g["target_us_nominal"].idxmax()]
        out.append({
            "target": target, "phase": phase, "N": n, "solves": len(g),
            "target_ms_mean": g["target_us_nominal"].mean() / 1e3,
            "target_ms_mean_low": g["target_us_low"].mean() / 1e3, "target_ms_mean_high": g["target_us_high"].mean() / 1e3,
            "target_ms_p50": g["target_us_nominal"].median() / 1e3,
            "target_ms_p99": g["target_us_nominal"].quantile(0.99) / 1e3,
            "target_ms_max": worst["target_us_nominal"] / 1e3,
            "target_ms_max_low": worst["target_us_low"] / 1e3, "target_ms_max_high": worst["target_us_high"] / 1e3,
            "max_at": f"{worst['run']} step {int(worst['step'])}",
            "insns_mean": g["instructions"].mean(), "insns_max": g["instructions"].max(),
            "cycles_mean": g["cyc_cycles_nominal"].mean(), "cycles_max": worst["cyc_cycles_nominal"],
            "cycles_max_low": worst["cyc_cycles_low"], "cycles_max_high": worst["cyc_cycles_high"],
            "cpi_model_mean": g["cyc_cycles_nominal"].sum() / g["instructions"].sum(),
            # L1D misses per 1000 instructions (a run without the cache model has borrowed misses, no accesses)
            "l1d_mpki": 1e3 * (g["cyc_l1d_load_misses"] + g["cyc_l1d_store_misses"]).sum() / max(1, g["instructions"].sum()),
            "target_ms_cpi_mean": g["target_us_cpi_nominal"].mean() / 1e3,
            "target_ms_cpi_max": g["target_us_cpi_nominal"].max() / 1e3,
            "calibrated": bool(g["cyc_calibrated"].all()),
            "wall_ms_mean": g["solve_time_us"].mean() / 1e3, "wall_ms_p99": g["solve_time_us"].quantile(0.99) / 1e3,
            "wall_ms_max": g["solve_time_us"].max() / 1e3,
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
            # a comparison of runs that did not dock would compare nothing: say so first
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
    safety monitor's summary in each record (host_sim.safety: judged on the truth)."""
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


def plot_histograms(rows: pd.DataFrame, target: str, path: Path) -> None:
    g = rows[rows["target"] == target]
    fig, axes = plt.subplots(2, 3, figsize=(15, 7.5))
    for j, phase in enumerate(("rendezvous", "approach", "docking")):
        gp = g[g["phase_name"] == phase]
        for i, (col, label) in enumerate((("target_us_nominal", "estimated target time [ms]"),
                                          ("solve_time_us", "emulated wall time (qemu-user) [ms]"))):
            ax = axes[i, j]
            data = [(n, gp[gp["N"] == n][col].to_numpy() / 1e3) for n in sorted(gp["N"].unique())]
            if data:
                hi = max(d.max() for _, d in data if len(d))
                bins = np.linspace(0, hi * 1.02 if hi > 0 else 1, 40)
                for n, d in data:
                    ax.hist(d, bins=bins, histtype="step", linewidth=1.6, label=f"N = {n} ({len(d)})")
                ax.legend(fontsize=8)
            ax.set_xlabel(label)
            ax.set_ylabel("solves")
            if i == 0:
                ax.set_title(phase)
    fig.suptitle(f"{target}: solve time per phase and horizon")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_scaling(table: pd.DataFrame, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for j, phase in enumerate(("rendezvous", "approach", "docking")):
        ax = axes[j]
        t = table[table["phase"] == phase]
        for target, g in t.groupby("target"):
            g = g.sort_values("N")
            ax.errorbar(g["N"], g["target_ms_mean"], fmt="o-", label=f"{target} (estimate)")
        ref = DISSERTATION_MS[phase]
        ax.plot(list(ref), list(ref.values()), "ks--", label="dissertation CVXGEN, QEMU wall")
        ax.set_yscale("log")
        ax.set_xlabel("horizon N")
        ax.set_ylabel("mean time per solve [ms]")
        ax.set_title(phase)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_trajectory(meta: dict, steps: pd.DataFrame, path: Path) -> None:
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(14, 5.5))
    colors = {1: "tab:blue", 2: "tab:orange", 3: "tab:green"}
    for ph, g in steps.groupby("phase"):
        if ph in PHASES:
            ax.plot(g["truth_y_m"], g["truth_x_m"], ".", ms=3, color=colors[ph], label=PHASES[ph])
    r1 = 200.0
    th = np.linspace(0, 2 * np.pi, 200)
    ax.plot(r1 * np.cos(th), r1 * np.sin(th), "k:", lw=1, label="keep-out r1 = 200 m")
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
def _table_html(df: pd.DataFrame, floatfmt: str = "{:.3g}") -> str:
    def cell(v):
        if isinstance(v, float):
            return "" if math.isnan(v) else floatfmt.format(v)
        return html.escape(str(v))
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in row) + "</tr>" for row in df.itertuples(index=False))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


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
    from qemu import cycles

    parts = ["<p>QEMU is not cycle-accurate: host wall time under emulation is not target time. Two plugins run "
             "in every user-mode run, between markers the flight software places around every solver call of a "
             "guidance step: the instruction counter (exact, written back into the guest's telemetry) and the "
             "block profiler (executions of every translation block, plus a cache model with the CPU's L1D/L1I/L2 "
             "geometry). The cycle model (<code>qemu/cycles.py</code>) prices each block once per executable: "
             "Debian's <code>llvm-mca</code> (LLVM " + html.escape(cycles.llvm_version()) + ") with the CPU's "
             "scheduling model, moved by a correction table where LLVM disagrees with published timings "
             "(<code>qemu/cycle_models.toml</code>, each figure with its source), or the stated Cortex-A8 model. "
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
             "13-16 % low in total, nominal cycles 3-6 % low; qemu/README.md).</p>",
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
                     "<p><code>bench/microbench/</code>: hand-written loops (a dependent FP64 multiply-add chain, 8 "
                     "independent ones, a pointer-chasing load chain, a divide chain, a call loop) cross-built for "
                     "the CPU, counted by the same plugins, priced by the same model. Where no published figure "
                     "could be used the row says so.</p>" + _table_html(pd.DataFrame(micro)))
    anchor = out / "osqp-anchor.json"
    if anchor.exists():
        a = json.loads(anchor.read_text())
        parts.append("<h3>External anchor: OSQP generated code on a Raspberry Pi 3B</h3><p>" + html.escape(a["summary"]) + "</p>"
                     + _table_html(pd.DataFrame(a["rows"])))
    parts.append("<h3>What a board calibration would change</h3><p>Run the same static executable on the board "
                 "with the recorded inputs of the ideal Case 1 (<code>python -m bench.calibrate</code> prints the "
                 "commands) under <code>perf stat -e cycles:u,instructions:u,L1-dcache-load-misses:u</code>. The "
                 "measured cycles over the model's nominal cycles for the same run become the CPU's factor in "
                 "<code>qemu/calibration.toml</code>; every nominal figure is then scaled by it and marked "
                 "<i>calibrated</i>. The measured instructions check that the board ran what QEMU counted; the "
                 "measured L1D misses check the cache model. A calibration replaces the engineering memory ranges and "
                 "the pipeline model's systematic error by one measured ratio; it does not remove the per-solve "
                 "spread the interval shows.</p>")
    return "\n".join(parts)


def write(out: Path) -> Path:
    out = Path(out)
    metas, df = load_campaign(out)
    if df.empty:
        raise SystemExit(f"no run records under {out / 'runs'}")
    rows = solves(metas, df)
    table = stats_table(rows) if not rows.empty else pd.DataFrame()
    chk = checks(metas, df)
    table.to_csv(out / "stats.csv", index=False)
    run_cols = ["dir", "target", "cpu", "mode", "kind", "scenario_label", "horizons", "end", "steps", "t_end_s",
                "dv_total_mps", "nav_resends", "rejected_messages", "exe_size_bytes"]
    runs = pd.DataFrame([{c: (str(m.get(c)) if isinstance(m.get(c), (list, tuple)) else m.get(c)) for c in run_cols}
                         for m in metas])
    for m, (i, r) in zip(metas, runs.iterrows()):
        tel = m.get("flight_telemetry") or {}
        runs.loc[i, "peak_heap_kib"] = tel.get("peak_heap_bytes", math.nan) / 1024 if tel else math.nan
        runs.loc[i, "qemu_max_rss_mib"] = tel.get("max_rss_kb", math.nan) / 1024 if tel else math.nan
    runs.to_csv(out / "runs.csv", index=False)

    targets = [t for t in dict.fromkeys(rows["target"])] if not rows.empty else []
    images = []
    for t in targets:
        p = out / f"hist_{t}.png"
        plot_histograms(rows, t, p)
        images.append(p.name)
    if not table.empty:
        plot_scaling(table, out / "scaling.png")
    traj = []
    seen = set()
    for m in metas:
        label = m.get("scenario_label")
        if m.get("kind") == "timing" and tuple(m.get("horizons", ())) == (30, 15, 12) and label not in seen:
            seen.add(label)
            _, steps = load_run(out / m["dir"])
            p = out / f"trajectory_{label.replace(':', '')}.png"
            plot_trajectory(m, steps, p)
            traj.append((label, p.name))

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
    report = {"stats": table.to_dict(orient="records"), "checks": chk, "scaling": scaling,
              "safety": {"runs": per_run_safety.to_dict(orient="records"),
                         "violations": safety_violations.to_dict(orient="records")},
              "runs": runs.to_dict(orient="records"),
              "environment": {"host": platform.platform(), "python": sys.version.split()[0],
                              "qemu": _tool_version(["qemu-arm", "--version"])}}
    (out / "report.json").write_text(json.dumps(report, indent=1, default=str))

    # HTML
    parts = ["<!doctype html><meta charset='utf-8'><title>rvd-pil PIL report</title>",
             "<style>body{font-family:sans-serif;margin:2em;max-width:1400px}table{border-collapse:collapse;"
             "font-size:12px}td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}th{background:#eee}"
             "td:first-child,th:first-child{text-align:left}.ok{color:green}.bad{color:#b00}</style>",
             "<h1>rvd-pil processor-in-the-loop report</h1>",
             f"<p>{len(metas)} runs, {len(rows)} timed guidance steps. Host {html.escape(platform.platform())}; "
             f"{html.escape(report['environment']['qemu'])}.</p>",
             "<h2>Timing model</h2>" + _timing_model_html(out, targets_meta, rows)]
    parts.append("<h2>Per phase and horizon</h2>")
    if not table.empty:
        parts.append("<p>Target times from the cycle model: <i>mean</i> and <i>max</i> are the nominal estimate "
                     "(steady-state pipeline plus the midpoint of the memory term), <i>[low-high]</i> the interval "
                     "(steady-state pipeline plus the memory term's low end, to cold pipeline plus its high end). "
                     "<i>CPI guess</i>: the old instructions &times; CPI / f<sub>clk</sub> figure, beside it during the "
                     "transition. Deadline misses are counted against the interval's high end.</p>")
        show = table.copy()
        show["target ms mean [low-high]"] = [f"{m:.3g} [{lo:.3g}-{hi:.3g}]" for m, lo, hi in
                                            zip(show["target_ms_mean"], show["target_ms_mean_low"], show["target_ms_mean_high"])]
        show["target ms max [low-high]"] = [f"{m:.3g} [{lo:.3g}-{hi:.3g}]" for m, lo, hi in
                                           zip(show["target_ms_max"], show["target_ms_max_low"], show["target_ms_max_high"])]
        show["cycles max [low-high]"] = [f"{m:.3g} [{lo:.3g}-{hi:.3g}]" for m, lo, hi in
                                        zip(show["cycles_max"], show["cycles_max_low"], show["cycles_max_high"])]
        show = show.rename(columns={"target_ms_cpi_mean": "CPI guess ms mean", "target_ms_cpi_max": "CPI guess ms max",
                                    "cpi_model_mean": "CPI (model)", "l1d_mpki": "L1D misses /1000 insns"})
        show = show[["target", "phase", "N", "solves", "insns_mean", "insns_max", "cycles_mean", "cycles max [low-high]",
                     "target ms mean [low-high]", "target_ms_p50", "target_ms_p99", "target ms max [low-high]", "max_at",
                     "CPI (model)", "L1D misses /1000 insns", "CPI guess ms mean", "CPI guess ms max", "calibrated",
                     "wall_ms_mean", "wall_ms_max", "iterations_mean", "deadline_ms", "overruns_flight_clock",
                     "deadline_misses_est", "cpu_load_mean_pct", "cpu_load_max_pct", "dissertation_cvxgen_ms"]]
        parts.append(_table_html(show))
    for img in images:
        parts.append(f"<h3>{html.escape(img)}</h3><img src='{img}' style='max-width:100%'>")
    if not table.empty:
        parts.append("<h2>Scaling with the horizon</h2><img src='scaling.png' style='max-width:100%'>")
        parts.append("<ul>" + "".join(f"<li>{html.escape(k)}: t(N={v['N'][-1]})/t(N={v['N'][0]}) = "
                                      f"{v['ratio_last_first']:.2f}</li>" for k, v in scaling.items()) + "</ul>")
    parts.append("<h2>Checks</h2><p>Case 1 in the ideal setting (CW truth, no noise, impulsive burns, no "
                 "delay). <i>user_instructions</i>: the plugin's counts, two runs under qemu-user. "
                 "<i>system_solve_time_us</i>: the guest's own clock in QEMU system mode with -icount "
                 "(2<sup>shift</sup> ns per instruction, the guest kernel's interrupt work included), two runs "
                 "whose link goes through semihosting so that the guest clock stands still while the host "
                 "computes (qemu/semihosting_link.py); "
                 "<i>system_instructions</i>: the guest PMU's user-mode instruction count (QEMU's Cortex-A53 "
                 "on virt; the A9 model has no PMU). <i>dv_minus_native</i>: total delta-v under QEMU minus "
                 "the native build's (floating-point differences between instruction sets and libm).</p>")
    for t, c in chk.items():
        items = []
        for k, v in c.items():
            cls = ""
            if k.endswith("_identical") or k.endswith("_runs_docked") or k.endswith("_equal_instruction_counts"):
                cls = "ok" if v else "bad"
            if k.endswith("_dv_minus_native_mps") and v:
                cls = "ok" if all(x is not None and abs(x) <= 1e-6 for x in v) else "bad"
            items.append(f"<li class='{cls}'>{html.escape(k)}: {html.escape(json.dumps(v))}</li>")
        parts.append(f"<h3>{html.escape(t)}</h3><ul>{''.join(items)}</ul>")
    per_run, violations = safety_tables(metas)
    parts.append("<h2>Safety (judged on the truth)</h2><p>The host's safety monitor checks every limit the "
                 "guidance is meant to hold on the true path, at most 1 s apart and at every burn edge: keep-out "
                 "sphere outside the approach corridor, approach corridor, overshoot plane, docking cone, "
                 "|v|<sub>&infin;</sub> in docking, collision, commanded and realised &Delta;v, contact conditions "
                 "(host_sim/safety.py; limits and their sources in each record's meta.json).</p>")
    if not per_run.empty:
        tally = per_run.groupby(["target", "verdict"]).size().rename("runs").reset_index()
        parts.append(_table_html(tally))
        if violations.empty:
            parts.append("<p class='ok'>No violation in any run.</p>")
        else:
            parts.append("<p class='bad'>Violations per target, phase, scenario and limit, with the worst one:</p>"
                         + _table_html(violations))
        parts.append("<details><summary>per run</summary>" + _table_html(per_run) + "</details>")
    parts.append("<h2>Memory and size</h2>")
    if not memory.empty:
        parts.append(_table_html(memory))
        parts.append("<p>peak heap: malloc statistics of the flight software; qemu max RSS: the QEMU process "
                     "(guest plus emulator), an upper bound.</p>")
    parts.append("<h2>Trajectories</h2>")
    for label, img in traj:
        parts.append(f"<h3>{html.escape(label)}</h3><img src='{img}' style='max-width:100%'>")
    parts.append("<h2>Runs</h2>" + _table_html(runs))
    events = []
    for m in metas:
        ev = load_events(out / m["dir"])
        for _, e in ev[ev["kind"].isin(["fault", "flight_software_lost", "collision", "timeout", "rejected_message"])].iterrows():
            events.append({"run": m["dir"], "t_s": e["t_s"], "kind": e["kind"], "detail": e["detail"]})
    if events:
        parts.append("<h2>Faults and end events</h2>" + _table_html(pd.DataFrame(events)))
    index = out / "report.html"
    index.write_text("\n".join(parts))
    return index


if __name__ == "__main__":
    print(write(Path(sys.argv[1] if len(sys.argv) > 1 else "reports/pil")))
